"""Launch the m4k stack with ros2 launch (needs launch/launch_ros: a full ROS 2 install).

    ros2 launch m4k_bringup m4k.launch.py [config:=/path/overlay.yaml] [namespace:=robot1]
        [robot:=r1] [sim:=auto|true|false] [robot_state_publisher:=false|true]
        [bridge_params:=FILE[,FILE...]] [foxglove:=false|true] [foxglove_address:=127.0.0.1]
        [foxglove_params:=FILE]

Starts what ``bringup`` starts, built by bringup's own code (``child_specs``,
``bridge_overlay``, ``uses_sim``) from the same layered configuration and overlay: the
simulated robot (``sim_robot``, when ``sim`` is on), rt_core, driver_host and the bridge (node
m4k_bridge, parameters: share/m4k_bringup/config/bridge.yaml, then those derived from the
configuration -- runtime directory, command timeout, velocity limits, sensor frames, port
labels, robot description -- and the overlay's ``m4k_bridge:`` section, then each
``bridge_params`` file in order, comma-separated: e.g. the Nav2 and the EKF recipes together).

``robot:=r1`` (one robot of several; ``m4k_bringup.robots``): namespace ``/r1``, the bridge's
``tf_namespaced: true``, frames unprefixed; robot_state_publisher follows the bridge's
tf mode and prefix however they were set (``robot``, ``config``, ``bridge_params``), with the
``/tf:=tf`` remaps a namespaced tf needs.

``sim``: ``auto`` (default) simulates when the configuration has any ``backend: sim`` device;
``true`` requires such devices; ``false`` refuses a configuration that still has simulated
devices (give ``config:=`` an overlay with the real backends) -- so a real robot never runs with
a simulated sensor by mistake.

``robot_state_publisher:=true`` starts robot_state_publisher (a full ROS install has it) with
the same URDF, and turns the bridge's own static transforms and robot_description off
(``publish_robot_state``), so no transform and no description has two publishers. With
``namespace:=r1`` both the bridge (odom -> base_footprint, wheels) and robot_state_publisher
(the fixed joints) publish on the absolute /tf and /tf_static: one tree from odom to every
sensor. ``foxglove:=true`` starts the live view (``ros2 run m4k_bridge foxglove``: the Foxglove
WebSocket protocol on port 8765, on ``foxglove_address``, localhost by default since the
protocol has no authentication). For supervision with restarts and the live status line use
``bringup`` instead.
"""

import os
import tempfile

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction, RegisterEventHandler
from launch.event_handlers import OnProcessIO
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

_TRUE = ('true', '1', 'yes', 'on')
_FALSE = ('false', '0', 'no', 'off')


def _flag(context, name, allow_auto=False):
    """Return True/False (or None for 'auto') of a boolean launch argument."""
    value = LaunchConfiguration(name).perform(context).strip().lower()
    if value in _TRUE:
        return True
    if value in _FALSE:
        return False
    if allow_auto and value == 'auto':
        return None
    raise RuntimeError('{}:={!r}: expected true or false{}'.format(
        name, value, ' or auto' if allow_auto else ''))


def _installed(package, executable):
    from ament_index_python.packages import get_package_prefix, PackageNotFoundError
    try:
        prefix = get_package_prefix(package)
    except PackageNotFoundError:
        return False
    return os.access(os.path.join(prefix, 'lib', package, executable), os.X_OK)


def _nodes(context, *args, **kwargs):
    """Build the actions once the launch arguments are known (bringup's plan, as ROS nodes)."""
    from m4k_bridge import params as bridge_params
    from m4k_bringup import bringup, robots
    from m4k_rt import channel, config, estop_request

    arg = lambda name: LaunchConfiguration(name).perform(context)  # noqa: E731
    overlay = os.path.abspath(arg('config')) if arg('config') else None
    namespace = arg('namespace')
    robot_values = {}
    if arg('robot'):
        robot_ns, robot_values = robots.robot_settings(arg('robot'))
        if namespace and namespace.strip('/') != robot_ns.strip('/'):
            raise RuntimeError('robot:={} puts the bridge in {}, namespace:={} says otherwise: '
                               'give one'.format(arg('robot'), robot_ns, namespace))
        namespace = robot_ns
    extra_files = robots.param_files(arg('bridge_params'))
    sim = _flag(context, 'sim', allow_auto=True)
    with_rsp = _flag(context, 'robot_state_publisher')

    cfg = config.load(overlay)                       # ConfigError names the field
    doc = config.load_layered(overlay)
    simulated = bringup.uses_sim(doc)
    if sim is False and simulated:
        raise RuntimeError('sim:=false but the configuration has simulated devices (backend: '
                           'sim); give config:= an overlay with their real backends')
    if sim is True and not simulated:
        raise RuntimeError('sim:=true but no device has backend: sim in the configuration')
    runtime_dir = channel.ensure_runtime_dir(cfg.runtime.runtime_dir, cfg.runtime.group)
    bridge_doc = bringup.bridge_overlay(doc, runtime_dir)
    bridge_values = bridge_params.flatten_section(bridge_doc)
    bridge_values.update(robot_values)
    if with_rsp:
        bridge_values['publish_robot_state'] = False
    bridge_yaml = os.path.join(config.find_config_dir(), 'bridge.yaml')
    # sim_robot first (the world outlives a driver-host restart, as the real robot would).
    specs = bringup.child_specs(overlay, '', bridge_yaml, runtime_dir, sim=simulated)
    # the e-stop request's state directory, resolved before the children get M4K_RUNTIME_DIR
    env = {'M4K_RUNTIME_DIR': runtime_dir, 'PYTHONUNBUFFERED': '1',
           'M4K_STATE_DIR': estop_request.state_dir()}
    actions = []
    sim_node = None
    for spec in specs:
        if spec.executable == 'bridge':
            # a bare m4k_bridge section would not reach the namespaced node: re-keyed copies
            params = [bridge_yaml, bridge_values, *robots.namespaced_files(
                extra_files, namespace, tempfile.mkdtemp(prefix='m4k-launch-'))]
            actions.append(Node(package=spec.package, executable=spec.executable,
                                name=bridge_params.NODE_NAME, namespace=namespace,
                                parameters=params, additional_env=env, output='screen',
                                respawn=True, respawn_delay=1.0))
        else:
            node = Node(package=spec.package, executable=spec.executable, name=spec.name,
                        arguments=list(spec.args), additional_env=env, output='screen',
                        respawn=True, respawn_delay=1.0)
            if spec.executable == 'sim_robot':
                sim_node = node
            else:
                actions.append(node)
    if _flag(context, 'foxglove'):
        live_params = [arg('foxglove_params')] if arg('foxglove_params') else []
        actions.append(Node(package='m4k_bridge', executable='foxglove', name='m4k_foxglove',
                            namespace=namespace, output='screen', parameters=[
                                *live_params, {'address': arg('foxglove_address')}]))
    if with_rsp:
        if not _installed('robot_state_publisher', 'robot_state_publisher'):
            raise RuntimeError('robot_state_publisher:=true but robot_state_publisher is not '
                               'installed (a full ROS install has it; without it the bridge '
                               'publishes the transforms itself)')
        # robot_state_publisher publishes /tf and /tf_static (absolute, tf2_ros's broadcasters)
        # and robot_description in the namespace; the bridge leaves both to it. Its tf mode and
        # frame prefix are the bridge's as the bridge ends up with them (bridge_params last).
        rsp_params, rsp_remaps = robots.robot_state_publisher_setup(
            robots.effective_bridge_values(bridge_values, extra_files))
        actions.append(Node(package='robot_state_publisher', executable='robot_state_publisher',
                            namespace=namespace, output='screen', parameters=[rsp_params],
                            remappings=rsp_remaps))
    if sim_node is None:
        return actions
    ready = _once_ready(actions)
    return [sim_node, RegisterEventHandler(OnProcessIO(
        target_action=sim_node, on_stdout=ready, on_stderr=ready))]


def _once_ready(actions, marker=b'simulating '):
    """Return an IO handler that starts ``actions`` once, when sim_robot says it serves.

    As bringup waits for the sim-bus before starting the driver host: devices configured
    against a simulator that is not listening yet would fail their configure.
    """
    state = {'done': False}

    def handler(event):
        if state['done'] or marker not in event.text:
            return None
        state['done'] = True
        return actions

    return handler


def generate_launch_description():
    """Return the launch description of the m4k stack."""
    return LaunchDescription([
        DeclareLaunchArgument('config', default_value='',
                              description='user overlay YAML, as bringup --config'),
        DeclareLaunchArgument('bridge_params', default_value='',
                              description='extra ROS parameter files for m4k_bridge, '
                              'comma-separated, after the configuration (later files win)'),
        DeclareLaunchArgument('robot', default_value='',
                              description='one robot of several: namespace /ROBOT, tf on '
                              '/ROBOT/tf, frames unprefixed (recipes --robot ROBOT)'),
        DeclareLaunchArgument('namespace', default_value='',
                              description='ROS namespace of the bridge topics'),
        DeclareLaunchArgument('sim', default_value='auto',
                              description='auto | true | false: start the simulated robot'),
        DeclareLaunchArgument('robot_state_publisher', default_value='false',
                              description='start robot_state_publisher (full ROS install) '
                              'instead of the bridge publishing the static transforms'),
        DeclareLaunchArgument('foxglove', default_value='false',
                              description='serve the live view (Foxglove WebSocket, port 8765)'),
        DeclareLaunchArgument('foxglove_address', default_value='127.0.0.1',
                              description='address of the live view; 0.0.0.0 serves the LAN: '
                              'give it a token_file (foxglove_params) and firewall it'),
        DeclareLaunchArgument('foxglove_params', default_value='',
                              description='ROS parameter file of the live view (m4k_foxglove: '
                              'token_file, allowed_origins, nav_goals, ...)'),
        OpaqueFunction(function=_nodes),
    ])
