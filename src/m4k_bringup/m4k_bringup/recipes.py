"""Generate the recipes for the stack around the base from ``config/`` (``recipes`` script).

The Nav2, twist_mux, slam_toolbox, robot_localization and RViz files under ``config/<tool>/``
are not written by hand: they are this module's output for the layered configuration
(``robot.yaml``'s body and sensor frames, ``control.yaml``'s velocity and acceleration limits)
and the bridge's parameter defaults (frames, topic names, sonar range). Change ``control.yaml``
and every recipe follows; ``recipes --check`` (and ``test/test_recipes.py``) fails while a
shipped file differs from what the configuration generates.

Names are written the way the consumer resolves them correctly (docs/nav2.md, "Names"):
every topic a Nav2 node reads from a parameter is absolute, because Jazzy's costmap layers
pass the parameter straight to the subscription of a node living in ``/local_costmap`` or
``/global_costmap`` (navigation2 #5745: ``scan`` there is ``/local_costmap/scan``). With a
robot name (``--robot r1``) the topics get the robot's namespace (``/r1/scan``), every section
but the bridge's is nested under ``r1`` (rcl matches ``/r1/<node>``), frames stay unprefixed
(each robot's tree is on its own ``/r1/tf``), and the headers give the exact commands
(``m4k_bringup.fleet``: ``m4k_nav2.launch.py robot:=r1 recipes:=DIR``).

The Nav2 file is complete: ``navigation_launch.py`` takes ONE ``params_file``, so it carries a
section for every node that launch file (and ``localization_launch.py``'s AMCL) starts, with the
plugin lists the Jazzy stock ``nav2_params.yaml`` uses and m4k's values; what it leaves out
each node defaults itself (``test/upstream_keys.py`` lists what every key is read as).
"""

from __future__ import annotations

import argparse
import difflib
import math
import os
import sys
import types
from typing import Any, Mapping, Sequence

import yaml

from m4k_bridge import params as bridge_params
from m4k_bringup import fleet
from m4k_drivers.lrf.sim import URG04LX_PP
from m4k_rt import config as rt_config
from m4k_rt.control import guard
from m4k_rt.control.footprint import outline_of
from m4k_rt.control.guard import front_offset
from m4k_rt.control.params import control_params
from m4k_rt.tasks.actuator import guard_plan

# The laser's range as the URG-04LX reports it in PP (DMIN, DMAX; mm): 0.02 .. 5.6 m.
LASER_MIN_RANGE = int(URG04LX_PP['DMIN']) / 1000.0
LASER_MAX_RANGE = int(URG04LX_PP['DMAX']) / 1000.0

# the generated files, under config/
FILES = ('nav2/nav2_params.yaml', 'nav2/nav2_params_twist_mux.yaml', 'twist_mux/twist_mux.yaml',
         'slam_toolbox/mapper_params_online_async.yaml', 'robot_localization/ekf.yaml',
         'rviz/m4k.rviz')
# Nav2's final velocity output when twist_mux sits in front of the bridge: the collision
# monitor publishes here and twist_mux reads it (never cmd_vel_nav, the controller's raw output
# before the smoother and the collision monitor).
NAV2_MUX_INPUT = 'cmd_vel_nav2'
# the installed config/ as the shipped headers name it
SHIPPED_DIR = '$(ros2 pkg prefix m4k_bringup)/share/m4k_bringup/config'


class Names:
    """Topic names and frame ids of one robot (``robot`` '' = the single robot in the root).

    Nav2's multi-robot layout: topics in the robot's namespace (``/r1/scan``), each robot's
    tree on its own ``/r1/tf`` and ``/r1/tf_static``, frames unprefixed (``odom``), so stock
    namespaced RViz, map_server and route_server find the frames they default to.
    """

    def __init__(self, robot: str = '') -> None:
        """Derive the namespace '/r1' from the robot name."""
        if robot and not robot.replace('_', 'a').isalnum() or robot[:1].isdigit():
            raise ValueError('robot name must be a ROS name token ([a-zA-Z_][a-zA-Z0-9_]*), '
                             'got {!r}'.format(robot))
        self.robot = robot
        self.ns = '/' + robot if robot else ''

    def topic(self, relative: str) -> str:
        """Return the absolute name of one of the robot's relative topics."""
        return '{}/{}'.format(self.ns, relative.lstrip('/'))

    def bridge_topic(self, key: str) -> str:
        """Return the absolute name of the bridge's topic ``topics.<key>``."""
        name = str(bridge_params.spec('topics.' + key).default)
        return name if name.startswith('/') else self.topic(name)

    @staticmethod
    def frame(key: str) -> str:
        """Return the bridge's frame ``<key>`` (e.g. 'odom_frame'): the same in every tree."""
        return str(bridge_params.spec(key).default)


# Nav2's loop rates: each adds its period to the time between a scan and a brake command.
LOCAL_COSTMAP_HZ = 5.0        # local costmap update_frequency
CONTROLLER_HZ = 10.0          # controller_frequency (>= 2 Hz: the RT cmd_vel timeout)
SMOOTHER_HZ = 20.0            # velocity smoother
# The laser's marking range: the URG-04LX's 5.6 m less its last 0.6 m, where the part's
# accuracy degrades (datasheet: +-3 % beyond 1 m) and low-reflectance returns drop out.
LASER_MARKING_MAX = 5.0
STOCK_MARKING_M = 2.5         # Nav2's stock obstacle_max_range: never mark less
MIN_HORIZON_S = 2.8           # Nav2's stock MPPI horizon (56 x 0.05 s): never plan shorter


def _limits(layered: Mapping[str, Any]) -> dict[str, float]:
    """Return the velocity and acceleration limits Nav2 plans with, and what they rest on.

    Forward: the RT collision guard's top speed (control.linear.max_velocity, or less when
    the laser cannot see far enough for the guard to stop from it), and no more than Nav2
    itself can stop from, braking at control.yaml's (comfortable) deceleration, inside its
    marking range: d_nav(v) = v t_nav + v^2 / (2 a_decel) + margin, with t_nav the guard's
    t_react (sensor and actuation) plus one period of the local costmap, the controller and
    the smoother. Backwards the guard's reverse creep (no rear sensor); with the guard off,
    control.linear.max_velocity both ways. Accelerations and the turn rate are control.yaml's.
    From the speed follow the marking range (what stopping from it needs), the MPPI horizon
    (the time to stop, so the controller sees the end of its own stop) and the collision
    monitor's time before collision (its approach keeps that much time to any obstacle:
    t_mon + v / (2 a) covers the stop at a_decel with the monitor's latency t_mon).
    """
    control = layered['control']
    lin, ang = control['linear'], control['angular']
    cfg = rt_config.parse(layered)
    shared = types.SimpleNamespace(config=cfg)
    robot = layered.get('robot')
    params = control_params(control)
    plan = guard_plan(params, cfg.task('actuator').period_ns * 1e-9, shared, robot)
    top = float(lin['max_velocity'])
    dx = float(lin['max_deceleration'] or lin['max_acceleration'])
    margin = params.guard.stop_distance
    t_nav = plan.reaction_time + 1.0 / LOCAL_COSTMAP_HZ + 1.0 / CONTROLLER_HZ + 1.0 / SMOOTHER_HZ
    ahead = front_offset(robot, 'laser')
    nav_top = guard.speed_for_distance(LASER_MARKING_MAX - ahead, t_nav, dx, margin)
    vx = math.floor(100.0 * min(top, plan.top_speed, nav_top)) / 100.0   # down: never faster
    marking = min(LASER_MARKING_MAX, max(STOCK_MARKING_M, math.ceil(
        10.0 * (guard.stop_distance(vx, t_nav, dx, margin) + ahead)) / 10.0))
    t_mon = plan.reaction_time + 1.0 / SMOOTHER_HZ
    return {
        'vx': vx,
        'vx_rev': min(top, plan.reverse_creep),
        'wz': float(ang['max_velocity']),
        'ax': float(lin['max_acceleration']),
        'dx': dx,
        'az': float(ang['max_acceleration']),
        'dz': float(ang['max_deceleration'] or ang['max_acceleration']),
        't_nav': t_nav, 'nav_top': nav_top, 'guard_top': plan.top_speed,
        'marking': marking,
        'horizon': max(MIN_HORIZON_S, t_nav + vx / dx),
        'time_before_collision': math.ceil(10.0 * (t_mon + vx / (2.0 * dx))) / 10.0,
    }


def _footprint(layered: Mapping[str, Any]) -> str:
    """Nav2's footprint: the robot's outline, the drive wheels outside the body included."""
    c = control_params(layered.get('control'))
    pts = outline_of(layered['robot'], c.track_width, c.wheel_radius)
    return '[' + ', '.join('[{:g}, {:g}]'.format(round(x, 4), round(y, 4)) for x, y in pts) + ']'


INFLATION_RADIUS_M = 0.45
MAP_FRAME = 'map'        # slam_toolbox's and AMCL's global frame, unprefixed


def local_window_m(lim: Mapping[str, float], length_m: float, laser_max_m: float) -> int:
    """Return the side of the local costmap (m): it reaches as far as Nav2 needs to stop.

    From the planned top speed at control.yaml's deceleration, plus half the body and the
    inflation, in whole metres both ways (Nav2's stock 3 m at least); never beyond what the
    laser sees (a window past its range holds nothing the controller could use). Planning at
    2 m/s inside the stock 3 m window would aim the controller at space it cannot see the end
    of the stop in (5.4 m at 0.37 m/s^2).
    """
    reach = lim['vx'] ** 2 / (2.0 * lim['dx']) + length_m / 2.0 + INFLATION_RADIUS_M
    return int(min(max(3, 2 * math.ceil(reach)), 2 * math.ceil(laser_max_m)))


def _scan_source(n: Names, max_range: float, marking: float) -> dict[str, Any]:
    return {
        'topic': n.bridge_topic('scan'),
        'data_type': 'LaserScan',
        'marking': True,
        'clearing': True,
        'inf_is_valid': True,               # URG "nothing within range" is +inf (REP-117)
        'raytrace_max_range': max_range,
        'obstacle_max_range': marking,      # _limits: what stopping from the top speed needs
        # Jazzy's per-source default is 0.0 and the buffer drops every point above it
        'max_obstacle_height': 2.0,
    }


def nav2(layered: Mapping[str, Any], n: Names, *, mux: bool = False) -> dict[str, Any]:
    """Return the complete Nav2 parameter file (one params_file for navigation_launch.py)."""
    lim = _limits(layered)
    foot = _footprint(layered)
    laser_max = LASER_MAX_RANGE
    odom, base, footprint = n.frame('odom_frame'), n.frame('base_frame'), \
        n.frame('footprint_frame')
    map_frame = MAP_FRAME

    def ros(p: dict[str, Any]) -> dict[str, Any]:
        return {'ros__parameters': p}

    scan = _scan_source(n, laser_max, lim['marking'])
    window = local_window_m(lim, float(layered['robot']['body']['length']), laser_max)
    local = {
        'update_frequency': LOCAL_COSTMAP_HZ, 'publish_frequency': 2.0,
        'global_frame': odom, 'robot_base_frame': base,
        'rolling_window': True, 'width': window, 'height': window, 'resolution': 0.05,
        'footprint': foot,
        'plugins': ['obstacle_layer', 'range_layer', 'inflation_layer'],
        'obstacle_layer': {'plugin': 'nav2_costmap_2d::ObstacleLayer', 'enabled': True,
                           'observation_sources': 'scan', 'scan': dict(scan)},
        'range_layer': {'plugin': 'nav2_costmap_2d::RangeSensorLayer', 'enabled': True,
                        'topics': [n.bridge_topic('sonar')],
                        'clear_on_max_reading': True},   # with sonar_no_echo: max_range
        'inflation_layer': {'plugin': 'nav2_costmap_2d::InflationLayer',
                            'inflation_radius': INFLATION_RADIUS_M, 'cost_scaling_factor': 3.0},
    }
    glob = {
        'update_frequency': 1.0, 'publish_frequency': 1.0,
        'global_frame': map_frame, 'robot_base_frame': base,
        'resolution': 0.05, 'track_unknown_space': True,
        'footprint': foot,
        'plugins': ['static_layer', 'obstacle_layer', 'inflation_layer'],
        'static_layer': {'plugin': 'nav2_costmap_2d::StaticLayer',
                         'map_subscribe_transient_local': True},
        'obstacle_layer': {'plugin': 'nav2_costmap_2d::ObstacleLayer', 'enabled': True,
                           'observation_sources': 'scan', 'scan': dict(scan)},
        'inflation_layer': {'plugin': 'nav2_costmap_2d::InflationLayer',
                            'inflation_radius': 0.45, 'cost_scaling_factor': 3.0},
    }
    mppi = {
        'plugin': 'nav2_mppi_controller::MPPIController',
        'motion_model': 'DiffDrive',
        # the horizon covers the stop from vx_max (_limits); model_dt = the control period
        'time_steps': math.ceil(round(lim['horizon'] * CONTROLLER_HZ, 6)),
        'model_dt': 1.0 / CONTROLLER_HZ, 'batch_size': 2000,
        'vx_max': lim['vx'], 'vx_min': -lim['vx_rev'], 'vy_max': 0.0, 'wz_max': lim['wz'],
        'ax_max': lim['ax'], 'ax_min': -lim['dx'], 'az_max': lim['az'],
        'critics': ['ConstraintCritic', 'CostCritic', 'GoalCritic', 'GoalAngleCritic',
                    'PathAlignCritic', 'PathFollowCritic', 'PathAngleCritic',
                    'PreferForwardCritic'],
    }
    doc: dict[str, Any] = {
        # also a bridge_params:= file: the sonar's "no echo" as max_range, which the range
        # layer's clear_on_max_reading clears with (it drops +inf)
        'm4k_bridge': ros({'sonar_no_echo': 'max_range'}),
        'amcl': ros({
            'base_frame_id': footprint, 'odom_frame_id': odom, 'global_frame_id': map_frame,
            'scan_topic': n.bridge_topic('scan'),
            'laser_max_range': laser_max, 'laser_min_range': LASER_MIN_RANGE,
            'robot_model_type': 'nav2_amcl::DifferentialMotionModel'}),
        'bt_navigator': ros({
            'global_frame': map_frame, 'robot_base_frame': base,
            'odom_topic': n.bridge_topic('odom'),
            'navigators': ['navigate_to_pose', 'navigate_through_poses'],
            'navigate_to_pose': {'plugin': 'nav2_bt_navigator::NavigateToPoseNavigator'},
            'navigate_through_poses': {
                'plugin': 'nav2_bt_navigator::NavigateThroughPosesNavigator'}}),
        'controller_server': ros({
            # >= 2 Hz: the RT actuator brakes after control.cmd_vel_timeout without cmd_vel
            'controller_frequency': CONTROLLER_HZ,
            'odom_topic': n.bridge_topic('odom'),
            'progress_checker_plugins': ['progress_checker'],
            'goal_checker_plugins': ['general_goal_checker'],
            'controller_plugins': ['FollowPath'],
            'progress_checker': {'plugin': 'nav2_controller::SimpleProgressChecker'},
            'general_goal_checker': {'plugin': 'nav2_controller::SimpleGoalChecker',
                                     'xy_goal_tolerance': 0.25, 'yaw_goal_tolerance': 0.25},
            'FollowPath': mppi}),
        'local_costmap': {'local_costmap': ros(local)},
        'global_costmap': {'global_costmap': ros(glob)},
        'planner_server': ros({
            'planner_plugins': ['GridBased'],
            'GridBased': {'plugin': 'nav2_navfn_planner::NavfnPlanner', 'tolerance': 0.5,
                          'use_astar': False, 'allow_unknown': True}}),
        'smoother_server': ros({
            'smoother_plugins': ['simple_smoother'],
            'simple_smoother': {'plugin': 'nav2_smoother::SimpleSmoother'}}),
        'behavior_server': ros({
            'local_costmap_topic': n.topic('local_costmap/costmap_raw'),
            'global_costmap_topic': n.topic('global_costmap/costmap_raw'),
            'local_footprint_topic': n.topic('local_costmap/published_footprint'),
            'global_footprint_topic': n.topic('global_costmap/published_footprint'),
            'local_frame': odom, 'global_frame': map_frame, 'robot_base_frame': base,
            'behavior_plugins': ['spin', 'backup', 'drive_on_heading', 'wait'],
            'spin': {'plugin': 'nav2_behaviors::Spin'},
            'backup': {'plugin': 'nav2_behaviors::BackUp'},
            'drive_on_heading': {'plugin': 'nav2_behaviors::DriveOnHeading'},
            'wait': {'plugin': 'nav2_behaviors::Wait'},
            'max_rotational_vel': lim['wz'], 'min_rotational_vel': min(0.4, lim['wz']),
            'rotational_acc_lim': lim['az']}),
        'waypoint_follower': ros({
            'waypoint_task_executor_plugin': 'wait_at_waypoint',
            'wait_at_waypoint': {'plugin': 'nav2_waypoint_follower::WaitAtWaypoint'}}),
        'velocity_smoother': ros({
            'smoothing_frequency': SMOOTHER_HZ,
            'feedback': 'OPEN_LOOP',
            'odom_topic': n.bridge_topic('odom'),
            # [x, y, theta]: within control.yaml, so the RT limiter never clamps what Nav2 plans
            'max_velocity': [lim['vx'], 0.0, lim['wz']],
            'min_velocity': [-lim['vx_rev'], 0.0, -lim['wz']],
            'max_accel': [lim['ax'], 0.0, lim['az']],
            'max_decel': [-lim['dx'], 0.0, -lim['dz']]}),
        'collision_monitor': ros({
            'base_frame_id': footprint, 'odom_frame_id': odom,
            'cmd_vel_in_topic': n.topic('cmd_vel_smoothed'),
            'cmd_vel_out_topic': n.topic(NAV2_MUX_INPUT) if mux else n.bridge_topic('cmd_vel'),
            'polygons': ['FootprintApproach'],
            'FootprintApproach': {
                'type': 'polygon', 'action_type': 'approach',
                'footprint_topic': n.topic('local_costmap/published_footprint'),
                'time_before_collision': lim['time_before_collision'],
                'simulation_time_step': 0.1,
                'min_points': 6, 'enabled': True},
            # The laser only. Jazzy's Range source reads the bridge's default "no echo" (+inf)
            # as invalid, and an invalid source is a STOP while source_timeout is set; one
            # reading makes too few points for min_points anyway (graphcheck.range_points).
            # The sonar stops the robot in the RT guard and marks the costmap's range layer.
            'observation_sources': ['scan'],
            'scan': {'type': 'scan', 'topic': n.bridge_topic('scan'), 'enabled': True}}),
        # navigation_launch.py (Jazzy) starts it: graph_filepath '' loads no graph at
        # configure; give one with the set_route_graph service (or an overlay's
        # graph_filepath). Its costmap scorer reads the global costmap, absolute like the rest.
        'route_server': ros({
            'route_frame': MAP_FRAME, 'global_frame': MAP_FRAME, 'base_frame': base,
            'graph_filepath': '',
            'costmap_topic': n.topic('global_costmap/costmap_raw')}),
        'docking_server': ros({
            'base_frame': base, 'fixed_frame': odom,
            'dock_plugins': ['simple_charging_dock'],
            # use_battery_status (default true) subscribes battery_state, which the M4K has
            # no gauge for and nothing publishes: "charging" is then never true. false:
            # docked means charging (the dock's contacts), as Nav2's stock file ships it.
            'simple_charging_dock': {'plugin': 'opennav_docking::SimpleChargingDock',
                                     'use_battery_status': False},
            'controller': {
                'costmap_topic': n.topic('local_costmap/costmap_raw'),
                'footprint_topic': n.topic('local_costmap/published_footprint')}}),
    }
    return doc


def twist_mux(n: Names, stamped: bool = False) -> dict[str, Any]:
    """Return twist_mux's parameters: Nav2's final output and a joystick, locked by e-stop."""
    return {'twist_mux': {'ros__parameters': {
        # twist_mux >= 4.4.0 (Jazzy since 2024-10) aborts without it; false: Twist in and out,
        # as Nav2 Jazzy publishes and the bridge's enable_stamped_cmd_vel: false subscribes
        'use_stamped': stamped,
        'topics': {
            'navigation': {'topic': n.topic(NAV2_MUX_INPUT), 'timeout': 0.5, 'priority': 10},
            'joystick': {'topic': n.topic('cmd_vel_joy'), 'timeout': 0.5, 'priority': 100},
        },
        'locks': {
            # twist_mux subscribes locks volatile, so the bridge repeats e_stop_state at 1 Hz;
            # with a timeout an unheard lock counts as engaged (docs/nav2.md)
            'e_stop': {'topic': n.bridge_topic('e_stop_state'), 'timeout': 2.5,
                       'priority': 255},
        },
    }}}


def slam_toolbox(n: Names) -> dict[str, Any]:
    """Return slam_toolbox's online-async parameters for the URG-04LX."""
    return {'slam_toolbox': {'ros__parameters': {
        'mode': 'mapping',
        'odom_frame': n.frame('odom_frame'), 'map_frame': MAP_FRAME,
        'base_frame': n.frame('footprint_frame'),
        'scan_topic': n.bridge_topic('scan'),
        'max_laser_range': LASER_MAX_RANGE,
        'resolution': 0.05,
        'minimum_travel_distance': 0.2, 'minimum_travel_heading': 0.2,
        'map_update_interval': 5.0, 'transform_publish_period': 0.02,
        'use_scan_matching': True,
    }}}


def ekf(n: Names) -> dict[str, Any]:
    """Return the 2-D EKF: wheel vx, vy and yaw rate, IMU yaw rate.

    vy is fused as the zero a differential drive measures, with the odometry's own variance
    (the bridge's odom_twist_covariance_diagonal); the EKF owns odom -> base_footprint, so the
    file's m4k_bridge section turns the bridge's transform off.
    """
    return {
        'm4k_bridge': {'ros__parameters': {'publish_tf': False}},
        'ekf_filter_node': {'ros__parameters': {
            'frequency': 30.0, 'two_d_mode': True, 'publish_tf': True,
            'map_frame': MAP_FRAME, 'odom_frame': n.frame('odom_frame'),
            'base_link_frame': n.frame('footprint_frame'), 'world_frame': n.frame('odom_frame'),
            'odom0': n.bridge_topic('odom'),
            # x y z, roll pitch yaw, vx vy vz, vroll vpitch vyaw, ax ay az
            'odom0_config': [False, False, False, False, False, False,
                             True, True, False, False, False, True,
                             False, False, False],
            'imu0': n.bridge_topic('imu'),
            'imu0_config': [False, False, False, False, False, False,
                            False, False, False, False, False, True,
                            False, False, False],
            'imu0_remove_gravitational_acceleration': True,
        }},
    }


def _topic(value: str, reliability: str, durability: str = 'Volatile',
           depth: int = 5) -> dict[str, Any]:
    return {'Value': value, 'Depth': depth, 'Durability Policy': durability,
            'History Policy': 'Keep Last', 'Reliability Policy': reliability}


def rviz(n: Names) -> dict[str, Any]:
    """Return the RViz 2 layout: the base's displays with the QoS m4k publishes with."""
    return {
        'Panels': [{'Class': 'rviz_common/Displays', 'Name': 'Displays'}],
        'Visualization Manager': {
            'Class': '',
            'Displays': [
                {'Class': 'rviz_default_plugins/Grid', 'Name': 'Grid', 'Enabled': True,
                 'Reference Frame': '<Fixed Frame>'},
                {'Class': 'rviz_default_plugins/RobotModel', 'Name': 'RobotModel',
                 'Enabled': True, 'Description Source': 'Topic',
                 'Description Topic': _topic(n.bridge_topic('robot_description'), 'Reliable',
                                             'Transient Local', 1)},
                {'Class': 'rviz_default_plugins/TF', 'Name': 'TF', 'Enabled': True,
                 'Show Names': True},
                {'Class': 'rviz_default_plugins/LaserScan', 'Name': 'LaserScan',
                 'Enabled': True, 'Topic': _topic(n.bridge_topic('scan'), 'Best Effort')},
                {'Class': 'rviz_default_plugins/Range', 'Name': 'Range', 'Enabled': True,
                 'Topic': _topic(n.bridge_topic('sonar'), 'Best Effort')},
                # imu_tools' rviz_imu_plugin (apt ros-jazzy-rviz-imu-plugin)
                {'Class': 'rviz_imu_plugin/Imu', 'Name': 'Imu', 'Enabled': True,
                 'Topic': _topic(n.bridge_topic('imu'), 'Best Effort')},
                {'Class': 'rviz_default_plugins/Odometry', 'Name': 'Odometry',
                 'Enabled': True, 'Topic': _topic(n.bridge_topic('odom'), 'Reliable'),
                 'Keep': 100},
            ],
            'Enabled': True,
            'Global Options': {'Fixed Frame': n.frame('odom_frame'), 'Frame Rate': 30},
            'Name': 'root',
            'Tools': [{'Class': 'rviz_default_plugins/MoveCamera'},
                      {'Class': 'rviz_default_plugins/Select'},
                      {'Class': 'rviz_default_plugins/SetInitialPose'},
                      {'Class': 'rviz_default_plugins/SetGoal'}],
            'Views': {'Current': {'Class': 'rviz_default_plugins/Orbit', 'Distance': 6.0,
                                  'Target Frame': '<Fixed Frame>'}},
        },
    }


def _headers(robot: str, recipes_dir: str) -> dict[str, str]:
    """Return each recipe's header: what it is for and the exact commands that use it."""
    nav = fleet.command(robot, recipes_dir)
    base = fleet.bridge_command(robot, recipes_dir)
    tf = (' --ros-args -r /tf:=/{0}/tf -r /tf_static:=/{0}/tf_static'.format(robot)
          if robot else '')
    return {
        'nav2/nav2_params.yaml':
            'Nav2 (Jazzy), complete, with SLAM or AMCL: ' + nav + '\nand the base: ' + base +
            "\n(its m4k_bridge section). The collision monitor drives the bridge's cmd_vel.",
        'nav2/nav2_params_twist_mux.yaml':
            'Nav2 (Jazzy) with twist_mux in front of the bridge: ' + nav + ' twist_mux:=true'
            "\nThe collision monitor publishes Nav2's final output on {} (twist_mux's "
            '"navigation" input).'.format(NAV2_MUX_INPUT),
        'twist_mux/twist_mux.yaml':
            'twist_mux (Jazzy, >= 4.4.0), remapped cmd_vel_out:=cmd_vel: ' + nav +
            ' twist_mux:=true',
        'slam_toolbox/mapper_params_online_async.yaml':
            'slam_toolbox (Jazzy, online async, lifecycle-managed): ' + nav,
        'robot_localization/ekf.yaml':
            'robot_localization EKF (Jazzy): ' + nav + ' ekf:=true\nand the base: ' +
            fleet.bridge_command(robot, recipes_dir, ekf=True) +
            '\n(the EKF publishes odom -> base_footprint, the bridge does not).',
        'rviz/m4k.rviz':
            'RViz 2 (Jazzy): rviz2 -d ' + os.path.join(recipes_dir, 'rviz/m4k.rviz') + tf +
            '\nSensors best effort (sensor-data QoS), robot_description transient local.',
    }


class _Dumper(yaml.SafeDumper):
    pass


def _list(dumper: yaml.SafeDumper, data: list[Any]) -> yaml.Node:
    flow = all(not isinstance(v, (dict, list)) for v in data)
    return dumper.represent_sequence('tag:yaml.org,2002:seq', data, flow_style=flow)


_Dumper.add_representer(list, _list)


def render(rel: str, doc: Mapping[str, Any], robot: str = '', header: str = '') -> str:
    """Return the text of one recipe: a generated-file header, then the YAML.

    For a robot, every section but the bridge's goes under the robot's namespace key: rcl
    hands a section to the node whose fully qualified name it spells (``/r1/controller_server``),
    and a bare ``controller_server`` is ``/controller_server``. The bridge's section stays bare:
    m4k.launch.py's ``bridge_params`` rewrites it for the bridge's namespace.
    """
    head = ['# GENERATED by `ros2 run m4k_bringup recipes` from config/ (robot.yaml, '
            'control.yaml) and', "# the bridge's defaults: edit those and regenerate, not "
            'this file (docs/nav2.md).']
    if robot:
        head.append('# Robot {!r}: namespace /{}, its tree on /{}/tf, frames unprefixed.'
                    .format(robot, robot, robot))
    head += ['# ' + line for line in header.split('\n') if line]
    if robot and not rel.endswith('.rviz'):
        inner = {k: v for k, v in doc.items() if k != bridge_params.NODE_NAME}
        doc = {**({bridge_params.NODE_NAME: doc[bridge_params.NODE_NAME]}
                  if bridge_params.NODE_NAME in doc else {}), robot: inner}
    body = yaml.dump(dict(doc), Dumper=_Dumper, sort_keys=False, default_flow_style=False,
                     width=99)
    return '\n'.join(head) + '\n' + body


def generate(layered: Mapping[str, Any] | None = None, robot: str = '',
             recipes_dir: str = '') -> dict[str, str]:
    """Return every recipe (path under config/ -> text) for the configuration and robot.

    ``recipes_dir``: where the files will live, for the commands in their headers (default:
    the shipped config/ for the root robot, ``DIR`` for a named one).
    """
    layered = layered if layered is not None else rt_config.load_layered()
    n = Names(robot)
    docs = {
        'nav2/nav2_params.yaml': nav2(layered, n),
        'nav2/nav2_params_twist_mux.yaml': nav2(layered, n, mux=True),
        'twist_mux/twist_mux.yaml': twist_mux(n),
        'slam_toolbox/mapper_params_online_async.yaml': slam_toolbox(n),
        'robot_localization/ekf.yaml': ekf(n),
        'rviz/m4k.rviz': rviz(n),
    }
    heads = _headers(robot, recipes_dir or ('DIR' if robot else SHIPPED_DIR))
    return {rel: render(rel, docs[rel], robot, heads[rel]) for rel in FILES}


def stale(config_dir: str, texts: Mapping[str, str]) -> list[str]:
    """Return a unified diff per recipe under config_dir that differs from texts."""
    out = []
    for rel, text in texts.items():
        path = os.path.join(config_dir, rel)
        try:
            with open(path, encoding='utf-8') as f:
                have = f.read()
        except OSError as exc:
            out.append('{}: cannot read ({})'.format(path, exc.strerror))
            continue
        if have != text:
            out.append(''.join(difflib.unified_diff(
                have.splitlines(True), text.splitlines(True), path, 'generated')))
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Write (or with --check compare) the recipes; exit 1 when --check finds a stale one."""
    ap = argparse.ArgumentParser(prog='recipes', description=__doc__.split('\n')[0])
    ap.add_argument('--config-dir', default=None,
                    help='the config/ to read (default: as the stack finds it)')
    ap.add_argument('--out', default=None,
                    help='directory to write <tool>/<file> into (default: --config-dir)')
    ap.add_argument('--robot', default='', help="robot name: namespace /NAME, frames 'NAME/'")
    ap.add_argument('--check', action='store_true',
                    help='compare instead of writing; exit 1 and show the diff when stale')
    a = ap.parse_args(argv)
    config_dir = a.config_dir or rt_config.find_config_dir()
    try:
        texts = generate(rt_config.load_layered(config_dir=config_dir), a.robot,
                         os.path.abspath(a.out) if a.out and a.robot else '')
    except (ValueError, KeyError) as exc:
        print('recipes: {}'.format(exc), file=sys.stderr)
        return 2
    out = a.out or config_dir
    if a.check:
        diffs = stale(out, texts)
        for d in diffs:
            print(d)
        if diffs:
            print('recipes: {} stale recipe(s) under {}: run `recipes` to regenerate'.format(
                len(diffs), out), file=sys.stderr)
            return 1
        return 0
    for rel, text in texts.items():
        path = os.path.join(out, rel)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(path, 'w', encoding='utf-8') as f:
            f.write(text)
        print(path)
    return 0


if __name__ == '__main__':
    sys.exit(main())
