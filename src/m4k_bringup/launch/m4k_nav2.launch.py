"""Nav2 (Jazzy) for one m4k robot of a fleet, exactly as the recipes expect it.

    ros2 run m4k_bringup recipes --robot r1 --out DIR        # the robot's recipes, once
    ros2 launch m4k_bringup m4k_nav2.launch.py robot:=r1 recipes:=DIR [twist_mux:=true]
        [ekf:=true] [slam:=true | slam:=false map:=FILE] [use_sim_time:=false]

Starts every node of ``m4k_bringup.fleet.nodes`` -- the Nav2 servers and their lifecycle
manager, slam_toolbox (or map_server + AMCL), the EKF and twist_mux -- in ``/r1`` with ``/tf``
and ``/tf_static`` remapped into the namespace, the robot's recipe files as parameters. This
file only turns that list into ``Node`` actions (docs/nav2.md, "Several robots"); without
``robot`` the nodes run in the root namespace on the shipped recipes of config/.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

_TRUE = ('true', '1', 'yes', 'on')
_FALSE = ('false', '0', 'no', 'off')


def _flag(context, name):
    value = LaunchConfiguration(name).perform(context).strip().lower()
    if value in _TRUE:
        return True
    if value in _FALSE:
        return False
    raise RuntimeError('{}:={!r}: expected true or false'.format(name, value))


def _nodes(context):
    from m4k_bringup import fleet
    from m4k_rt import config
    robot = LaunchConfiguration('robot').perform(context).strip()
    recipes = LaunchConfiguration('recipes').perform(context).strip()
    if not recipes:
        if robot:
            raise RuntimeError('robot:={} needs recipes:=DIR, written by `ros2 run m4k_bringup '
                               'recipes --robot {} --out DIR`'.format(robot, robot))
        recipes = config.find_config_dir()
    specs = fleet.nodes(robot, recipes, mux=_flag(context, 'twist_mux'),
                        ekf=_flag(context, 'ekf'), slam=_flag(context, 'slam'),
                        map_file=LaunchConfiguration('map').perform(context).strip(),
                        use_sim_time=_flag(context, 'use_sim_time'))
    return [Node(package=s.package, executable=s.executable, name=s.name,
                 namespace=s.namespace, remappings=list(s.remaps),
                 parameters=[*s.params_files, dict(s.values)], output='screen')
            for s in specs]


def generate_launch_description():
    """Return the launch description: the arguments, then the nodes of the robot."""
    return LaunchDescription([
        DeclareLaunchArgument('robot', default_value='',
                              description='robot name: namespace /NAME, its own tf tree'),
        DeclareLaunchArgument('recipes', default_value='',
                              description='directory `recipes --robot NAME --out` wrote'),
        DeclareLaunchArgument('twist_mux', default_value='false',
                              description='twist_mux in front of the bridge (e-stop lock)'),
        DeclareLaunchArgument('ekf', default_value='false',
                              description='robot_localization EKF owns odom -> base_footprint'),
        DeclareLaunchArgument('slam', default_value='true',
                              description='slam_toolbox maps (false: map:= with AMCL)'),
        DeclareLaunchArgument('map', default_value='', description='map yaml for map_server'),
        DeclareLaunchArgument('use_sim_time', default_value='false'),
        OpaqueFunction(function=_nodes),
    ])
