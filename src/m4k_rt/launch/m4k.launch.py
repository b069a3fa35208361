"""Launch the m4k stack with ros2 launch (needs a full ROS 2 install: launch is not on PyPI).

    ros2 launch m4k_rt m4k.launch.py [config:=/path/overlay.yaml] [namespace:=robot1]

Starts sim_robot (the simulated robot; ``sim:=false`` on the real M4K), rt_core, driver_host
and the bridge (node m4k_bridge) with the configuration installed in share/m4k_rt/config.
``config`` is the same user overlay as ``bringup --config``: rt_core gets it as ``--config``,
sim_robot and driver_host as ``--overlay``; bridge parameters in it are NOT
extracted here -- pass them as a ROS parameter file with ``bridge_params:=FILE``. For
supervision with restarts and the live status line use ``bringup`` instead.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def _nodes(context, *args, **kwargs):
    """Build the three actions once the launch arguments are known."""
    share = get_package_share_directory('m4k_rt')
    overlay = LaunchConfiguration('config').perform(context)
    bridge_params = LaunchConfiguration('bridge_params').perform(context)
    namespace = LaunchConfiguration('namespace').perform(context)
    rt_args = ['--config', overlay] if overlay else []
    host_args = ['--overlay', overlay] if overlay else []
    params = [os.path.join(share, 'config', 'bridge.yaml')]
    if bridge_params:
        params.append(bridge_params)
    sim = LaunchConfiguration('sim').perform(context).lower() in ('true', '1', 'yes')
    robot = [Node(package='m4k_drivers', executable='sim_robot', name='sim_robot',
                  arguments=host_args, output='screen', respawn=True, respawn_delay=1.0)]
    return robot * sim + [
        Node(package='m4k_rt', executable='rt_core', name='rt_core', arguments=rt_args,
             output='screen', respawn=True, respawn_delay=1.0),
        Node(package='m4k_drivers', executable='driver_host', name='driver_host',
             arguments=host_args, output='screen', respawn=True, respawn_delay=1.0),
        Node(package='m4k_rt', executable='bridge', name='m4k_bridge', namespace=namespace,
             parameters=params, output='screen', respawn=True, respawn_delay=1.0),
    ]


def generate_launch_description():
    """Return the launch description of the m4k stack."""
    return LaunchDescription([
        DeclareLaunchArgument('config', default_value='',
                              description='user overlay YAML for rt_core and driver_host'),
        DeclareLaunchArgument('bridge_params', default_value='',
                              description='extra ROS parameter file for m4k_bridge'),
        DeclareLaunchArgument('sim', default_value='true',
                              description='start sim_robot (false: real devices only)'),
        DeclareLaunchArgument('namespace', default_value='',
                              description='ROS namespace of the bridge topics'),
        OpaqueFunction(function=_nodes),
    ])
