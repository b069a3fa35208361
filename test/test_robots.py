"""One-argument multi-robot settings and several bridge parameter files (m4k_bringup.robots).

The pure helpers that bringup and the launch file share, and what rcl makes of several
``--params-file`` arguments for the bridge (the two recipes whose m4k_bridge sections must
both apply: the Nav2 file's sonar_no_echo and the EKF file's publish_tf).
"""

import os

import pytest
import rclpy
from rclpy.node import Node
from wsenv import ROOT

from m4k_bridge import params
from m4k_bringup import bringup, recipes, robots

pytestmark = pytest.mark.allow_leaks('fds')  # FastDDS keeps its sockets for the process
CONFIG = os.path.join(ROOT, 'config')
NAV2 = os.path.join(CONFIG, 'nav2', 'nav2_params.yaml')
EKF = os.path.join(CONFIG, 'robot_localization', 'ekf.yaml')


def test_robot_name_sets_namespace_and_namespaced_tf_with_unprefixed_frames():
    # Nav2's multi-robot layout: the robot's tree on /r1/tf, frames as in a single robot
    assert robots.robot_settings('r1') == ('/r1', {'tf_namespaced': True})


@pytest.mark.parametrize('name', ['', '1r', 'r-1', 'r1/', '/r1', 'r 1'])
def test_robot_name_that_is_no_ros_token_is_refused(name):
    with pytest.raises(ValueError, match='ROS name token'):
        robots.robot_settings(name)
    with pytest.raises(ValueError, match='ROS name token'):
        recipes.Names(name) if name else robots.robot_settings(name)


def test_several_bridge_parameter_files_keep_their_order_and_missing_ones_are_named(tmp_path):
    assert robots.param_files('{}, {}'.format(NAV2, EKF)) == [NAV2, EKF]
    assert robots.param_files('') == []
    with pytest.raises(ValueError, match="'nope.yaml' does not exist"):
        robots.param_files([NAV2, 'nope.yaml'])


def test_two_recipes_bridge_sections_both_apply_in_the_launch_values():
    values = robots.effective_bridge_values({'publish_tf': True}, [NAV2, EKF])
    assert values['sonar_no_echo'] == 'max_range' and values['publish_tf'] is False


def test_rcl_gives_the_bridge_both_files_later_wins(tmp_path):
    # the bridge's own view: rcl merges --params-file arguments in order
    later = tmp_path / 'later.yaml'
    later.write_text('m4k_bridge:\n  ros__parameters:\n    sonar_no_echo: positive_infinity\n')
    ctx = rclpy.Context()
    rclpy.init(context=ctx, args=['--ros-args', '--params-file', NAV2, '--params-file', EKF])
    node = Node(params.NODE_NAME, context=ctx)
    try:
        got = {k: v.value for k, v in node._parameter_overrides.items()}
        assert got == {'sonar_no_echo': 'max_range', 'publish_tf': False}
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, args=['--ros-args', '--params-file', NAV2, '--params-file',
                                  str(later)])
    node = Node(params.NODE_NAME, context=ctx)
    try:
        assert node._parameter_overrides['sonar_no_echo'].value == 'positive_infinity'
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)


def test_robot_state_publisher_follows_the_bridges_tf_mode_and_prefix(tmp_path):
    urdf = '<robot name="m4k"/>'
    assert robots.robot_state_publisher_setup({'robot_description': urdf}) == (
        {'robot_description': urdf}, [])
    _, values = robots.robot_settings('r2')
    assert robots.robot_state_publisher_setup({'robot_description': urdf, **values}) == (
        {'robot_description': urdf}, [('/tf', 'tf'), ('/tf_static', 'tf_static')])
    # set through a bridge_params file instead of robot:= -- the lost frame_prefix
    f = tmp_path / 'p.yaml'
    f.write_text("m4k_bridge:\n  ros__parameters:\n    frame_prefix: 'r3/'\n"
                 '    tf_namespaced: true\n')
    rsp, remaps = robots.robot_state_publisher_setup(robots.effective_bridge_values(
        {'robot_description': urdf}, [str(f)]))
    assert rsp['frame_prefix'] == 'r3/' and remaps == list(robots.TF_REMAPS)


def test_bringup_hands_the_bridge_every_extra_file_after_its_own():
    specs = bringup.child_specs(None, '/tmp/overlay.yaml', '/cfg/bridge.yaml', '/tmp/rt',
                                sim=False, namespace='r1', extra_params=[NAV2, EKF])
    bridge = [s for s in specs if s.executable == 'bridge'][0]
    files = [a for i, a in enumerate(bridge.args) if bridge.args[i - 1] == '--params-file']
    assert files == ['/cfg/bridge.yaml', '/tmp/overlay.yaml', NAV2, EKF]
    assert '__ns:=/r1' in bridge.args


def test_a_bare_bridge_section_is_rekeyed_so_rcl_applies_it_under_the_namespace(tmp_path):
    # rcl matches 'm4k_bridge' as /m4k_bridge only: under /r1 the section would not apply
    files = robots.namespaced_files([NAV2, EKF], '/r1', str(tmp_path))
    for path in files:
        ctx = rclpy.Context()
        rclpy.init(context=ctx, args=['--ros-args', '--params-file', path])
        node = Node(params.NODE_NAME, namespace='/r1', context=ctx)
        try:
            assert node._parameter_overrides, path
        finally:
            node.destroy_node()
            rclpy.try_shutdown(context=ctx)
    assert robots.namespaced_files([NAV2], '', str(tmp_path)) == [NAV2]
    assert robots.for_namespace({'m4k_bridge': 1, '/**': 2}, 'r1') == {'/r1/m4k_bridge': 1,
                                                                       '/**': 2}
