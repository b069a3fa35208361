"""src/m4k_bringup/launch/m4k.launch.py, evaluated by the real launch/launch_ros and ros2 launch.

launch, launch_ros and ros2cli are not on PyPI: on the wheels path these tests are skipped
with that reason. They run under a full ROS install, or with the ros-verify environment's
packages on the path (../shared/notes/ros-verify.md).
"""

import os
import shutil
import signal
import subprocess
import time

import pytest
from wsenv import ROOT, stack_env
import yaml

from m4k_rt import description

try:  # the ros2cli marker skips every test here, with the reason, when these are missing
    import launch
    from launch.events.process import ProcessIO
    from launch.launch_description_sources import PythonLaunchDescriptionSource
except ImportError:
    launch = None

LAUNCH = os.path.join(ROOT, 'src', 'm4k_bringup', 'launch', 'm4k.launch.py')
pytestmark = [pytest.mark.ros2cli, pytest.mark.allow_leaks('fds')]


def _evaluate(monkeypatch, runtime_dir, **args):
    """Return the Node actions of the launch file for ``args``, substitutions performed."""
    for k, v in stack_env(runtime_dir).items():
        monkeypatch.setenv(k, v)
    ctx = launch.LaunchContext()
    ld = PythonLaunchDescriptionSource(LAUNCH).get_launch_description(ctx)
    ctx.launch_configurations.update(args)
    for entity in ld.entities:
        if isinstance(entity, launch.actions.DeclareLaunchArgument):
            entity.execute(ctx)
    opaque = [e for e in ld.entities if isinstance(e, launch.actions.OpaqueFunction)][0]
    nodes = []
    for e in opaque._OpaqueFunction__function(ctx):
        if isinstance(e, launch.actions.RegisterEventHandler):
            # The rest starts once sim_robot says it serves (as bringup waits for it).
            def line(text, sim=nodes[0]):
                return ProcessIO(action=sim, name='sim_robot', cmd=[], cwd=None, env=None,
                                 pid=1, text=text, fd=2)
            assert e.event_handler.handle(line(b'INFO: loading the world'), ctx) is None
            nodes += list(e.event_handler.handle(line(b'INFO: simulating motor on x'), ctx))
            assert e.event_handler.handle(line(b'INFO: simulating again'), ctx) is None
        else:
            nodes.append(e)
    for n in nodes:
        n._perform_substitutions(ctx)
    return nodes


def _bridge_params(node):
    values = {}
    for path, is_file in node._Node__expanded_parameter_arguments:
        assert is_file
        with open(path, encoding='utf-8') as f:
            doc = yaml.safe_load(f)
        for key, section in doc.items():
            if key.rsplit('/', 1)[-1] == 'm4k_bridge':
                values.update(section['ros__parameters'])
    return values


def test_launch_starts_what_bringup_starts_with_the_derived_bridge_parameters(
        monkeypatch, m4k_runtime_dir):
    nodes = _evaluate(monkeypatch, m4k_runtime_dir)
    exes = [n.node_executable for n in nodes]
    assert exes[0] == 'sim_robot' and {'rt_core', 'driver_host', 'bridge'} <= set(exes)
    bridge = nodes[exes.index('bridge')]
    values = _bridge_params(bridge)
    assert values['runtime_dir'] == m4k_runtime_dir
    assert [j.name for j in description.wheel_joints(values['robot_description'])] == list(
        description.WHEEL_JOINTS)
    assert values.get('publish_robot_state', True) is True


def test_launch_derives_the_bridge_timeout_from_the_overlays_control_section(
        monkeypatch, tmp_path, m4k_runtime_dir):
    overlay = tmp_path / 'o.yaml'
    overlay.write_text(yaml.safe_dump({'control': {'cmd_vel_timeout': 0.8}}))
    nodes = _evaluate(monkeypatch, m4k_runtime_dir, config=str(overlay))
    bridge = nodes[[n.node_executable for n in nodes].index('bridge')]
    assert _bridge_params(bridge)['cmd_vel_timeout'] == 0.8


def test_sim_false_refuses_a_configuration_with_simulated_devices(monkeypatch,
                                                                  m4k_runtime_dir):
    with pytest.raises(RuntimeError, match='sim:=false but the configuration has simulated'):
        _evaluate(monkeypatch, m4k_runtime_dir, sim='false')


@pytest.mark.needs_ros_package('robot_state_publisher')   # a C++ package: not on PyPI
def test_robot_state_publisher_takes_over_the_static_transforms(monkeypatch, m4k_runtime_dir):
    nodes = _evaluate(monkeypatch, m4k_runtime_dir, robot_state_publisher='true')
    exes = [n.node_executable for n in nodes]
    assert 'robot_state_publisher' in exes
    assert _bridge_params(nodes[exes.index('bridge')])['publish_robot_state'] is False


def test_foxglove_true_adds_the_live_view_on_localhost(monkeypatch, m4k_runtime_dir):
    assert 'foxglove' not in [n.node_executable for n in _evaluate(monkeypatch,
                                                                   m4k_runtime_dir)]
    nodes = _evaluate(monkeypatch, m4k_runtime_dir, foxglove='true')
    live = [n for n in nodes if n.node_executable == 'foxglove']
    assert len(live) == 1 and live[0].node_package == 'm4k_bridge'


def test_ros2_launch_brings_the_stack_up_and_down(procs, tmp_path, m4k_runtime_dir):
    from nav_msgs.msg import Odometry
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    ros2 = shutil.which('ros2') or ''
    assert ros2 and 'tools/bin' not in ros2, 'ros2launch imports but the real ros2 is not on PATH'
    log = open(tmp_path / 'launch.log', 'w')
    proc = procs.start(['ros2', 'launch', 'm4k_bringup', 'm4k.launch.py'],
                       env=dict(stack_env(m4k_runtime_dir), PYTHONUNBUFFERED='1'),
                       stdout=log, stderr=log)
    log.close()
    context = rclpy.context.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('launch_probe', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    got = []
    node.create_subscription(Odometry, 'odom', got.append, 10)
    try:
        end = time.monotonic() + 60
        while not got and time.monotonic() < end and proc.poll() is None:
            executor.spin_once(timeout_sec=0.1)
        assert got, (tmp_path / 'launch.log').read_text()[-3000:]
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(60)
    except subprocess.TimeoutExpired:
        # What is still there, for whoever reads the failure (seen once, under a full run's
        # load on a ROS-env machine, never reproduced alone or under stress-ng).
        tree = subprocess.run(['ps', '-o', 'pid,ppid,stat,wchan:20,etime,args', '--forest',
                               '-g', str(os.getpgid(proc.pid))], capture_output=True,
                              text=True).stdout
        pytest.fail('ros2 launch did not stop on SIGINT within 60 s\n{}\n{}'.format(
            tree, (tmp_path / 'launch.log').read_text()[-3000:]))
    text = (tmp_path / 'launch.log').read_text()
    for name in ('rt_core', 'driver_host', 'bridge'):
        assert '[{}-'.format(name) in text and 'process has died' not in text, text[-3000:]


def test_robot_state_publisher_true_is_refused_where_the_package_is_missing(monkeypatch,
                                                                          m4k_runtime_dir):
    from ament_index_python.packages import get_package_prefix, PackageNotFoundError
    try:
        get_package_prefix('robot_state_publisher')
    except PackageNotFoundError:
        pass
    else:
        pytest.skip('robot_state_publisher is installed here: nothing to refuse')
    with pytest.raises(RuntimeError, match='robot_state_publisher is not installed'):
        _evaluate(monkeypatch, m4k_runtime_dir, robot_state_publisher='true', namespace='r1')


@pytest.mark.needs_ros_package('robot_state_publisher')   # skipped, naming it, when absent
def test_namespaced_launch_with_robot_state_publisher_keeps_one_tree(monkeypatch,
                                                                     m4k_runtime_dir):
    # namespace:=r1 robot_state_publisher:=true: the bridge publishes odom -> base_footprint
    # (and the wheels) on the absolute /tf, robot_state_publisher (in r1) the fixed joints on
    # /tf_static -- tf2_ros's absolute topics -- and robot_description alone. Without the
    # package the launch file refuses robot_state_publisher:=true (the test beside this one
    # that needs no package checks that refusal).
    nodes = _evaluate(monkeypatch, m4k_runtime_dir, robot_state_publisher='true',
                      namespace='r1')
    exes = [n.node_executable for n in nodes]
    bridge = nodes[exes.index('bridge')]
    rsp = nodes[exes.index('robot_state_publisher')]
    assert rsp.expanded_node_namespace == '/r1' == bridge.expanded_node_namespace
    values = _bridge_params(bridge)
    assert values['publish_robot_state'] is False
    assert values.get('tf_namespaced', False) is False
    assert values.get('topics', {}).get('diagnostics', '/diagnostics') == '/diagnostics'
    urdf = values['robot_description']
    assert {j.parent for j in description.fixed_joints(urdf)} >= {'base_footprint', 'base_link'}


def test_namespaced_launch_without_robot_state_publisher(monkeypatch, m4k_runtime_dir):
    nodes = _evaluate(monkeypatch, m4k_runtime_dir, namespace='r1')
    exes = [n.node_executable for n in nodes]
    assert 'robot_state_publisher' not in exes
    bridge = nodes[exes.index('bridge')]
    assert bridge.expanded_node_namespace == '/r1'
    assert _bridge_params(bridge).get('publish_robot_state', True) is True


def test_robot_argument_namespaces_tf_for_bridge_and_robot_state_publisher(
        monkeypatch, m4k_runtime_dir):
    # robot:=r1: namespace /r1, tf on /r1/tf for the bridge (tf_namespaced) and for
    # robot_state_publisher (its /tf:=tf remaps), frames unprefixed for both
    try:
        nodes = _evaluate(monkeypatch, m4k_runtime_dir, robot='r1',
                          robot_state_publisher='true')
    except RuntimeError as exc:   # the wheels path has no robot_state_publisher
        assert 'robot_state_publisher is not installed' in str(exc)
        return
    exes = [n.node_executable for n in nodes]
    bridge = nodes[exes.index('bridge')]
    rsp = nodes[exes.index('robot_state_publisher')]
    assert rsp.expanded_node_namespace == '/r1' == bridge.expanded_node_namespace
    values = _bridge_params(bridge)
    assert values['tf_namespaced'] is True and not values.get('frame_prefix')
    assert set(rsp.expanded_remapping_rules) == {('/tf', 'tf'), ('/tf_static', 'tf_static')}


def test_several_bridge_params_files_reach_the_bridge_in_order(monkeypatch, m4k_runtime_dir):
    nav2 = os.path.join(ROOT, 'config', 'nav2', 'nav2_params.yaml')
    ekf = os.path.join(ROOT, 'config', 'robot_localization', 'ekf.yaml')
    nodes = _evaluate(monkeypatch, m4k_runtime_dir, bridge_params='{},{}'.format(nav2, ekf))
    bridge = nodes[[n.node_executable for n in nodes].index('bridge')]
    values = _bridge_params(bridge)
    assert values['sonar_no_echo'] == 'max_range' and values['publish_tf'] is False
