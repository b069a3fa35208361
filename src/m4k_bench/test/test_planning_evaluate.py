"""Judging a drive against the room (pure): world: parsing, clearance, contacts, frames."""

import math

import numpy as np
import pytest

from m4k_bench.planning.evaluate import (
    contacts,
    densify,
    EvaluateError,
    odom_to_world,
    trajectory_clearance,
    WorldGeometry,
)

ROOM = {'walls': {'rectangle': [-0.8, -1.5, 4.2, 1.5]},
        'obstacles': [[[1.5, -0.25], [1.5, 0.25], [1.9, 0.0]]],
        'start': [0.0, 0.0, 0.0], 'robot': {'length_m': 0.45, 'width_m': 0.28}}


def test_world_section_is_read_like_the_simulator_reads_it():
    g = WorldGeometry.from_config(ROOM)
    assert len(g.walls) == 4 and len(g.obstacles) == 1 and len(g.segments()) == 7
    assert (g.length, g.width, g.start) == (0.45, 0.28, (0.0, 0.0, 0.0))
    segs = WorldGeometry.from_config({'walls': [[0, 0, 1, 0]], 'obstacles': []})
    assert segs.walls == ((0.0, 0.0, 1.0, 0.0),) and segs.obstacles == ()
    # No section at all: the simulator's defaults (the paper's room).
    assert WorldGeometry.from_config(None).segments() == g.segments()


@pytest.mark.parametrize('world,match', [
    ({'walls': {'rectangle': [0, 0, 1]}},
     r'world\.walls\.rectangle: expected \[xmin, ymin, xmax, ymax\] \(4 finite numbers\)'),
    ({'walls': 'room'}, r'world\.walls: expected a list of \[x1, y1, x2, y2\] segments'),
    ({'obstacles': [[[0, 0], [1, 0]]]}, r'world\.obstacles\[0\]'),
    ({'obstacles': [[[0, 0], [1, 0], [0, math.nan]]]}, r'world\.obstacles\[0\]'),
    ({'start': [0, 0]}, r'world\.start: expected a list of 3 numbers'),
    ({'colour': 'red'}, r'world\.colour: unknown key \(allowed: events, faults, '),
])
def test_bad_world_section_names_the_field(world, match):
    with pytest.raises(EvaluateError, match=match):
        WorldGeometry.from_config(world)


def test_clearance_along_a_trajectory_and_contact_onsets():
    g = WorldGeometry.from_config(ROOM)
    # Driving straight at the obstacle face (x = 1.5): the front is at x + 0.225.
    xs = np.array([0.0, 1.0, 1.2, 1.275, 1.28, 1.0])
    poses = np.column_stack((xs, np.zeros_like(xs), np.zeros_like(xs)))
    clear = trajectory_clearance(poses, g)
    assert clear[1] == pytest.approx(0.275, abs=0.003)
    assert clear[2] == pytest.approx(0.075, abs=0.003)
    assert clear[0] == pytest.approx(0.8 - 0.225, abs=0.003)   # the wall behind at x = -0.8
    assert clear[3] <= 0.005 and clear[4] < 0.0
    assert contacts(clear) == 1
    assert contacts(np.array([0.0, 0.1, 0.0, 0.0, 0.2, -0.1])) == 3
    assert contacts(np.array([])) == 0


def test_footprint_is_the_simulators_robot_body():
    # The judge's footprint is the simulated robot's: robot.body of the layered configuration,
    # overridden by world.robot -- what m4k_drivers.world.World.footprint collides with.
    from m4k_drivers.config import validate as driver_config
    doc = {'robot': {'body': {'length': 0.6, 'width': 0.3}}, 'control': {}}
    sim = driver_config({'world': {}}, control=doc['control'], body=doc['robot']['body'])
    g = WorldGeometry.from_config({}, doc)
    assert (g.length, g.width) == (sim.world.robot.length_m, sim.world.robot.width_m) == \
        (0.6, 0.3)
    g = WorldGeometry.from_config({'robot': {'width_m': 0.5}}, doc)
    assert (g.length, g.width) == (0.6, 0.5)


def test_odom_poses_map_through_the_start_pose():
    world = odom_to_world(np.array([[1.0, 0.0, 0.0]]), (0.0, 0.9, math.pi / 2))
    assert world[0] == pytest.approx((0.0, 1.9, math.pi / 2))


def test_densify_keeps_segment_ends_and_spacing():
    pts = densify([(0.0, 0.0, 1.0, 0.0)], 0.1)
    assert pts[0] == pytest.approx((0.0, 0.0)) and pts[-1] == pytest.approx((1.0, 0.0))
    assert np.diff(pts[:, 0]).max() <= 0.1 + 1e-12
    with pytest.raises(EvaluateError, match='spacing'):
        densify([(0, 0, 1, 0)], 0.0)


def test_world_geometry_takes_scene_obstacles_at_rest():
    from m4k_bench.planning.evaluate import WorldGeometry
    geom = WorldGeometry.from_config({'obstacles': [
        [[1.0, 0.0], [1.2, 0.0], [1.1, 0.2]],
        {'polygon': [[2.0, 0.0], [2.2, 0.0], [2.1, 0.2]], 'surface': 'glass', 'height': 0.5}]})
    assert geom.obstacles[1][0] == (2.0, 0.0) and len(geom.obstacles) == 2
