"""The robot's outline: body and the drive wheels outside it (m4k_rt.control.footprint)."""

import pathlib

import pytest
import yaml

from m4k_rt.control.footprint import (
    DEFAULT_HALF_WIDTH,
    half_width,
    half_width_of,
    outline,
    outline_of,
)


def _area(pts):
    pairs = zip(pts, pts[1:] + pts[:1], strict=True)
    return 0.5 * sum(x1 * y2 - x2 * y1 for (x1, y1), (x2, y2) in pairs)


def test_the_m4k_outline_takes_in_the_wheels_outside_the_body():
    # 0.45 x 0.28 body, wheels 0.2032 m in diameter, 5 cm wide, centres 0.40 m apart: the
    # wheels' outer faces are 0.225 m from the centre line, the body's sides 0.14 m
    pts = list(outline(0.45, 0.28, 0.40, 0.1016, 0.05))
    assert len(pts) == 12
    assert max(y for _, y in pts) == pytest.approx(0.225)
    assert min(y for _, y in pts) == pytest.approx(-0.225)
    assert max(x for x, _ in pts) == pytest.approx(0.225)
    assert _area(pts) > 0.0                                     # counter-clockwise
    # body plus two wheel wells (0.2032 x 0.085 m each)
    assert _area(pts) == pytest.approx(0.45 * 0.28 + 2 * 0.2032 * 0.085)
    assert half_width(0.28, 0.40, 0.05) == pytest.approx(0.225)


def test_wheels_inside_the_body_leave_the_rectangle():
    pts = outline(0.45, 0.50, 0.40, 0.1016, 0.05)
    assert len(pts) == 4 and _area(list(pts)) == pytest.approx(0.45 * 0.50)
    assert half_width(0.50, 0.40, 0.05) == pytest.approx(0.25)


def test_the_shipped_configuration_gives_the_wheels_half_width():
    config_dir = pathlib.Path(__file__).resolve().parents[3] / 'config'
    with open(config_dir / 'robot.yaml', encoding='utf-8') as f:
        robot = yaml.safe_load(f)['robot']
    with open(config_dir / 'control.yaml', encoding='utf-8') as f:
        control = yaml.safe_load(f)['control']
    assert half_width_of(robot, control['track_width']) == pytest.approx(
        control['track_width'] / 2 + robot['wheel_width'] / 2)
    assert len(outline_of(robot, control['track_width'], control['wheel_radius'])) == 12


def test_a_bare_section_falls_back_to_the_body_default():
    assert half_width_of({}, 0.40) == DEFAULT_HALF_WIDTH
    assert half_width_of({'body': {'width': 0.3}}, 0.20) == pytest.approx(0.15)
    with pytest.raises(ValueError, match='robot.body.length'):
        outline_of({}, 0.40, 0.1)
