"""The robot's outline seen from above: the body and the drive wheels outside it (pure).

The M4K's 0.45 x 0.28 m body (paper Table 2) rides on two 20.32 cm wheels whose centres are
``control.track_width`` (0.40 m) apart, each ``robot.wheel_width`` (5 cm) wide: the wheels
stand outside the body, their outer faces 0.225 m from the centre line where the body's sides
are 0.14 m from it. Whatever the robot can touch, it touches with this outline, so every part
that reasons about contact takes it from here:

* the simulator's contact test and clearance (``m4k_drivers.world``), so a chair leg that
  passes the body but not the wheel is a contact on ground truth;
* the collision guard's corridor (the laser's and the memory's), which is the outline's
  widest half width plus ``guard.lateral_margin`` -- not the body's, which let a leg 0.2 m
  off the centre line into the wheel's path unseen;
* Nav2's footprint in the generated recipes.

The outline is a simple polygon, counter-clockwise from the body's front-left corner, in
base_link (x forward, y left; base_link on the axle midway between the wheels). The wheel
parts are the tyres' side view (x within +-wheel_radius of the axle) spanning from the body's
side to the wheel's outer face (the hub and the gap to the body are part of the wheel well).
Wheels inside the body's width add nothing: the outline is then the body's rectangle.
"""

from __future__ import annotations

import math
from typing import Any

__all__ = ['DEFAULT_HALF_WIDTH', 'half_width', 'half_width_of', 'outline', 'outline_of']

DEFAULT_HALF_WIDTH = 0.14    # m, a bare test config without a robot section: the body's


def half_width(width: float, track_width: float, wheel_width: float) -> float:
    """Return the outline's widest half width: the body's or the wheels' outer faces (m)."""
    return max(width / 2.0, track_width / 2.0 + wheel_width / 2.0)


def outline(length: float, width: float, track_width: float, wheel_radius: float,
            wheel_width: float) -> tuple[tuple[float, float], ...]:
    """Return the outline's vertices (x, y), counter-clockwise from the front-left corner."""
    hl = length / 2.0
    hw = width / 2.0
    out = track_width / 2.0 + wheel_width / 2.0
    if out <= hw:
        return ((hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw))
    r = min(wheel_radius, hl)
    return ((hl, hw), (r, hw), (r, out), (-r, out), (-r, hw), (-hl, hw),
            (-hl, -hw), (-r, -hw), (-r, -out), (r, -out), (r, -hw), (hl, -hw))


def _number(section: Any, *keys: str) -> float | None:
    v: Any = section
    try:
        for k in keys:
            v = v[k]
        f = float(v)
    except (KeyError, TypeError, IndexError, ValueError):
        return None
    return f if math.isfinite(f) and f > 0.0 else None


def half_width_of(robot: Any, track_width: float) -> float:
    """Return :func:`half_width` for a raw ``robot:`` section and ``control.track_width``.

    A section without the body's width (a bare test config) gives ``DEFAULT_HALF_WIDTH``;
    without ``wheel_width`` the wheels count as having none (their centres still count).
    """
    width = _number(robot, 'body', 'width')
    if width is None:
        return DEFAULT_HALF_WIDTH
    return half_width(width, track_width, _number(robot, 'wheel_width') or 0.0)


def outline_of(robot: Any, track_width: float,
               wheel_radius: float) -> tuple[tuple[float, float], ...]:
    """Return :func:`outline` for a raw ``robot:`` section and the control's wheel geometry."""
    length = _number(robot, 'body', 'length')
    width = _number(robot, 'body', 'width')
    if length is None or width is None:
        raise ValueError('robot.body.length and robot.body.width are needed for the outline')
    return outline(length, width, track_width, wheel_radius, _number(robot, 'wheel_width') or 0.0)
