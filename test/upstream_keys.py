"""What the ROS 2 Jazzy nodes our recipes configure really read: key names and value types.

Written by hand from the upstream sources (docs/nav2.md, "Checked against upstream", lists the
repositories, branches and commits; each table names the file it comes from). Only the keys our
recipes set, their close relatives and the structure around them (plugin namespaces, sensor
indices, analyzer sections) are here: a key the table does not know is a key nobody reads.

Types are the ROS parameter types the node declares. rclcpp refuses an override of another
type (an integer for a double, ``timeout: 0`` for ``0.0``), and the file then fails to load or
the node throws while configuring, so the types are checked as strictly as names.
"""

import re

STR, FLOAT, INT, BOOL = 'str', 'float', 'int', 'bool'
STRS, FLOATS, BOOLS = 'str[]', 'float[]', 'bool[]'

# nav2_amcl/src/amcl_node.cpp (declared with add_parameter, read in initParameters)
AMCL = {'base_frame_id': STR, 'odom_frame_id': STR, 'global_frame_id': STR,
        'scan_topic': STR, 'laser_max_range': FLOAT, 'laser_min_range': FLOAT,
        'robot_model_type': STR}
# nav2_bt_navigator/src/bt_navigator.cpp
BT_NAVIGATOR = {'global_frame': STR, 'robot_base_frame': STR, 'odom_topic': STR,
                'transform_tolerance': FLOAT, 'navigators': STRS}
# bt_navigator.cpp: <navigator id>.plugin for each of navigators (no further keys read there)
BT_NAVIGATORS = {'nav2_bt_navigator::NavigateToPoseNavigator': {},
                 'nav2_bt_navigator::NavigateThroughPosesNavigator': {}}
# nav2_collision_monitor/src/collision_monitor_node.cpp (getParameters)
COLLISION_MONITOR = {'base_frame_id': STR, 'odom_frame_id': STR, 'cmd_vel_in_topic': STR,
                     'cmd_vel_out_topic': STR, 'transform_tolerance': FLOAT,
                     'state_topic': STR, 'source_timeout': FLOAT, 'base_shift_correction': BOOL,
                     'stop_pub_timeout': FLOAT, 'polygons': STRS, 'observation_sources': STRS}
# nav2_collision_monitor/src/polygon.cpp getCommonParameters/getParameters: <polygon>.<key>
COLLISION_POLYGON = {'type': STR, 'action_type': STR, 'enabled': BOOL, 'min_points': INT,
                     'slowdown_ratio': FLOAT, 'linear_limit': FLOAT, 'angular_limit': FLOAT,
                     'time_before_collision': FLOAT, 'simulation_time_step': FLOAT,
                     'visualize': BOOL, 'polygon_pub_topic': STR, 'footprint_topic': STR,
                     'polygon_sub_topic': STR, 'points': STR, 'sources_names': STRS}
COLLISION_POLYGON_TYPES = ('polygon', 'circle', 'velocity_polygon')
# source.cpp (topic, enabled, source_timeout), scan.cpp (no more), range.cpp (obstacles_angle),
# pointcloud.cpp (min_height, max_height): <source>.<key>
COLLISION_SOURCE = {'type': STR, 'topic': STR, 'enabled': BOOL, 'source_timeout': FLOAT,
                    'obstacles_angle': FLOAT, 'min_height': FLOAT, 'max_height': FLOAT}
COLLISION_SOURCE_TYPES = ('scan', 'pointcloud', 'range', 'polygon')
# nav2_velocity_smoother/src/velocity_smoother.cpp: [x, y, theta] each
VELOCITY_SMOOTHER = {'smoothing_frequency': FLOAT, 'max_velocity': FLOATS,
                     'min_velocity': FLOATS, 'max_accel': FLOATS, 'max_decel': FLOATS,
                     'odom_topic': STR, 'feedback': STR, 'odom_duration': FLOAT,
                     'velocity_timeout': FLOAT, 'scale_velocities': BOOL}
# nav2_controller/src/controller_server.cpp (and nav_2d_utils' OdomSubscriber: odom_topic)
CONTROLLER_SERVER = {'controller_frequency': FLOAT, 'odom_topic': STR,
                     'progress_checker_plugins': STRS, 'goal_checker_plugins': STRS,
                     'controller_plugins': STRS, 'failure_tolerance': FLOAT,
                     'costmap_update_timeout': FLOAT, 'min_x_velocity_threshold': FLOAT,
                     'min_y_velocity_threshold': FLOAT, 'min_theta_velocity_threshold': FLOAT}
# nav2_controller/plugins/simple_progress_checker.cpp, simple_goal_checker.cpp;
# nav2_mppi_controller/src/optimizer.cpp, controller.cpp, critic_manager.cpp (plugin name.)
CONTROLLER_PLUGINS = {
    'nav2_controller::SimpleProgressChecker': {'required_movement_radius': FLOAT,
                                               'movement_time_allowance': FLOAT},
    'nav2_controller::SimpleGoalChecker': {'xy_goal_tolerance': FLOAT,
                                           'yaw_goal_tolerance': FLOAT, 'stateful': BOOL},
    'nav2_mppi_controller::MPPIController': {
        'model_dt': FLOAT, 'time_steps': INT, 'batch_size': INT, 'iteration_count': INT,
        'temperature': FLOAT, 'gamma': FLOAT, 'vx_max': FLOAT, 'vx_min': FLOAT,
        'vy_max': FLOAT, 'wz_max': FLOAT, 'ax_max': FLOAT, 'ax_min': FLOAT, 'ay_max': FLOAT,
        'ay_min': FLOAT, 'az_max': FLOAT, 'vx_std': FLOAT, 'vy_std': FLOAT, 'wz_std': FLOAT,
        'motion_model': STR, 'critics': STRS, 'visualize': BOOL},
}
MPPI_CRITICS = ('ConstraintCritic', 'CostCritic', 'GoalCritic', 'GoalAngleCritic',
                'PathAlignCritic', 'PathFollowCritic', 'PathAngleCritic',
                'PreferForwardCritic', 'ObstaclesCritic', 'TwirlingCritic',
                'VelocityDeadbandCritic')
# nav2_planner/src/planner_server.cpp; nav2_navfn_planner/src/navfn_planner.cpp
PLANNER_SERVER = {'planner_plugins': STRS, 'expected_planner_frequency': FLOAT,
                  'costmap_update_timeout': FLOAT}
PLANNER_PLUGINS = {'nav2_navfn_planner::NavfnPlanner': {'tolerance': FLOAT, 'use_astar': BOOL,
                                                        'allow_unknown': BOOL}}
# nav2_smoother/src/nav2_smoother.cpp; nav2_smoother/src/simple_smoother.cpp
SMOOTHER_SERVER = {'smoother_plugins': STRS, 'transform_tolerance': FLOAT}
SMOOTHER_PLUGINS = {'nav2_smoother::SimpleSmoother': {'tolerance': FLOAT, 'max_its': INT,
                                                      'do_refinement': BOOL}}
# nav2_behaviors/src/behavior_server.cpp; plugins/spin.cpp (the rotational limits, declared
# on the server node, not under the plugin name)
BEHAVIOR_SERVER = {'local_costmap_topic': STR, 'global_costmap_topic': STR,
                   'local_footprint_topic': STR, 'global_footprint_topic': STR,
                   'cycle_frequency': FLOAT, 'behavior_plugins': STRS, 'local_frame': STR,
                   'global_frame': STR, 'robot_base_frame': STR, 'transform_tolerance': FLOAT,
                   'max_rotational_vel': FLOAT, 'min_rotational_vel': FLOAT,
                   'rotational_acc_lim': FLOAT, 'simulate_ahead_time': FLOAT}
BEHAVIOR_PLUGINS = {'nav2_behaviors::Spin': {}, 'nav2_behaviors::BackUp': {},
                    'nav2_behaviors::DriveOnHeading': {}, 'nav2_behaviors::Wait': {},
                    'nav2_behaviors::AssistedTeleop': {}}
# nav2_waypoint_follower/src/waypoint_follower.cpp; plugins/wait_at_waypoint.cpp
WAYPOINT_FOLLOWER = {'loop_rate': INT, 'stop_on_failure': BOOL,
                     'waypoint_task_executor_plugin': STR}
WAYPOINT_PLUGINS = {'nav2_waypoint_follower::WaitAtWaypoint': {
    'enabled': BOOL, 'waypoint_pause_duration': INT}}
# nav2_docking/opennav_docking/src/docking_server.cpp, dock_database.cpp (dock_plugins),
# controller.cpp (controller.<key>)
DOCKING_SERVER = {'controller_frequency': FLOAT, 'base_frame': STR, 'fixed_frame': STR,
                  'dock_backwards': BOOL, 'dock_plugins': STRS, 'max_retries': INT}
DOCKING_CONTROLLER = {'k_phi': FLOAT, 'k_delta': FLOAT, 'v_linear_min': FLOAT,
                      'v_linear_max': FLOAT, 'use_collision_detection': BOOL,
                      'costmap_topic': STR, 'footprint_topic': STR,
                      'transform_tolerance': FLOAT}
# simple_charging_dock.cpp: use_battery_status (default true subscribes battery_state)
DOCK_PLUGINS = {'opennav_docking::SimpleChargingDock': {'use_battery_status': BOOL}}
# nav2_route/src/route_server.cpp (route_frame, base_frame, global_frame, max_planning_time,
# costmap_topic), graph_loader.cpp (graph_filepath, graph_file_loader)
ROUTE_SERVER = {'route_frame': STR, 'base_frame': STR, 'global_frame': STR,
                'max_planning_time': FLOAT, 'costmap_topic': STR, 'graph_filepath': STR,
                'graph_file_loader': STR}
# nav2_costmap_2d/src/costmap_2d_ros.cpp (constructor's declare_parameter list)
COSTMAP = {'global_frame': STR, 'robot_base_frame': STR, 'footprint': STR, 'plugins': STRS,
           'robot_radius': FLOAT, 'rolling_window': BOOL, 'width': INT, 'height': INT,
           'resolution': FLOAT, 'update_frequency': FLOAT, 'publish_frequency': FLOAT,
           'transform_tolerance': FLOAT, 'track_unknown_space': BOOL}
# costmap_2d_ros.cpp: with exactly this plugins list a missing <layer>.plugin is defaulted
COSTMAP_DEFAULT_PLUGINS = ['static_layer', 'obstacle_layer', 'inflation_layer']
# nav2_costmap_2d/plugins/*.cpp onInitialize(): keys under <layer name>. (plus 'plugin')
LAYERS = {
    'nav2_costmap_2d::ObstacleLayer': {
        'enabled': BOOL, 'footprint_clearing_enabled': BOOL, 'min_obstacle_height': FLOAT,
        'max_obstacle_height': FLOAT, 'combination_method': INT, 'observation_sources': STR},
    'nav2_costmap_2d::RangeSensorLayer': {
        'enabled': BOOL, 'phi': FLOAT, 'inflate_cone': FLOAT, 'no_readings_timeout': FLOAT,
        'clear_threshold': FLOAT, 'mark_threshold': FLOAT, 'clear_on_max_reading': BOOL,
        'topics': STRS, 'input_sensor_type': STR},
    'nav2_costmap_2d::InflationLayer': {
        'enabled': BOOL, 'inflation_radius': FLOAT, 'cost_scaling_factor': FLOAT,
        'inflate_unknown': BOOL, 'inflate_around_unknown': BOOL},
    'nav2_costmap_2d::StaticLayer': {'enabled': BOOL, 'map_subscribe_transient_local': BOOL},
}
# obstacle_layer.cpp: keys under <layer>.<source>. for each name in observation_sources.
# Jazzy's default max_obstacle_height of a source is 0.0 (not the layer's 2.0), and
# observation_buffer.cpp keeps only points with min <= z <= max in the costmap's frame.
OBSERVATION_SOURCE = {
    'topic': STR, 'sensor_frame': STR, 'observation_persistence': FLOAT,
    'expected_update_rate': FLOAT, 'data_type': STR, 'min_obstacle_height': FLOAT,
    'max_obstacle_height': FLOAT, 'inf_is_valid': BOOL, 'marking': BOOL, 'clearing': BOOL,
    'obstacle_max_range': FLOAT, 'obstacle_min_range': FLOAT, 'raytrace_max_range': FLOAT,
    'raytrace_min_range': FLOAT}
SOURCE_DEFAULT_MAX_OBSTACLE_HEIGHT = 0.0
DATA_TYPES = ('LaserScan', 'PointCloud2')

# slam_toolbox src/slam_toolbox_common.cpp, src/slam_mapper.cpp (Karto's setters),
# src/laser_utils.cpp (max_laser_range), solvers/ceres_solver.cpp (mode)
SLAM_TOOLBOX = {'mode': STR, 'odom_frame': STR, 'map_frame': STR, 'base_frame': STR,
                'scan_topic': STR, 'max_laser_range': FLOAT, 'resolution': FLOAT,
                'minimum_travel_distance': FLOAT, 'minimum_travel_heading': FLOAT,
                'map_update_interval': FLOAT, 'transform_publish_period': FLOAT,
                'use_scan_matching': BOOL, 'throttle_scans': INT, 'transform_timeout': FLOAT,
                'tf_buffer_duration': FLOAT}
SLAM_MODES = ('mapping', 'localization')

# twist_mux src/twist_mux.cpp getTopicHandles: for every <name> listed under topics. and
# locks., fetch_param(<name>.topic / .timeout / .priority) with get_value<T>: string, double,
# int (clamped to 0..255 in topic_handle.hpp).
TWIST_MUX_GROUPS = ('topics', 'locks')
TWIST_MUX_ENTRY = {'topic': STR, 'timeout': FLOAT, 'priority': INT}
# twist_mux 4.4.0 (Jazzy 2024-10, ros/rosdistro#43002; twist_mux#50): fetch_param(use_stamped)
# with no default -- the node aborts without it ("could not load parameter 'use_stamped'",
# twist_mux#53, #57); true: TwistStamped in and out, false: Twist.
TWIST_MUX = {'use_stamped': BOOL}

# robot_localization src/ros_filter.cpp loadParams
EKF = {'frequency': FLOAT, 'two_d_mode': BOOL, 'publish_tf': BOOL, 'map_frame': STR,
       'odom_frame': STR, 'base_link_frame': STR, 'world_frame': STR,
       'sensor_timeout': FLOAT, 'print_diagnostics': BOOL}
# <kind><N>[suffix]: the sensor topic, then its options (N counts up from 0 without gaps)
EKF_SENSOR = re.compile(r'^(odom|imu)(\d+)(.*)$')
EKF_SENSOR_KEYS = {
    'odom': {'': STR, '_config': BOOLS, '_differential': BOOL, '_relative': BOOL,
             '_queue_size': INT},
    'imu': {'': STR, '_config': BOOLS, '_differential': BOOL, '_relative': BOOL,
            '_queue_size': INT, '_remove_gravitational_acceleration': BOOL},
}
# filter_common.hpp StateMembers: x y z, roll pitch yaw, vx vy vz, vroll vpitch vyaw, ax ay az
EKF_STATE = ('x', 'y', 'z', 'roll', 'pitch', 'yaw', 'vx', 'vy', 'vz',
             'vroll', 'vpitch', 'vyaw', 'ax', 'ay', 'az')

# diagnostic_aggregator src/aggregator.cpp (node 'analyzers', top-level keys),
# src/analyzer_group.cpp (<name>.type and <name>.path create an analyzer),
# src/generic_analyzer.cpp (its keys), plugin_description.xml (the types)
AGGREGATOR = {'path': STR, 'pub_rate': FLOAT, 'other_as_errors': BOOL,
              'history_depth': INT, 'critical': BOOL}
GENERIC_ANALYZER = {'type': STR, 'path': STR, 'find_and_remove_prefix': STRS,
                    'remove_prefix': STRS, 'startswith': STRS, 'contains': STRS,
                    'expected': STRS, 'regex': STRS, 'timeout': FLOAT, 'num_items': INT,
                    'discard_stale': BOOL}
ANALYZER_TYPES = ('diagnostic_aggregator/GenericAnalyzer',
                  'diagnostic_aggregator/DiscardAnalyzer',
                  'diagnostic_aggregator/IgnoreAnalyzer',
                  'diagnostic_aggregator/AnalyzerGroup')

FLAT = {'amcl': AMCL, 'velocity_smoother': VELOCITY_SMOOTHER, 'slam_toolbox': SLAM_TOOLBOX,
        'route_server': ROUTE_SERVER}
# plugin servers: node -> (its own keys, {plugin list key or single-plugin key: plugin types})
PLUGIN_SERVERS = {
    'bt_navigator': (BT_NAVIGATOR, {'navigators': BT_NAVIGATORS}),
    'controller_server': (CONTROLLER_SERVER, {'progress_checker_plugins': CONTROLLER_PLUGINS,
                                              'goal_checker_plugins': CONTROLLER_PLUGINS,
                                              'controller_plugins': CONTROLLER_PLUGINS}),
    'planner_server': (PLANNER_SERVER, {'planner_plugins': PLANNER_PLUGINS}),
    'smoother_server': (SMOOTHER_SERVER, {'smoother_plugins': SMOOTHER_PLUGINS}),
    'behavior_server': (BEHAVIOR_SERVER, {'behavior_plugins': BEHAVIOR_PLUGINS}),
    'waypoint_follower': (WAYPOINT_FOLLOWER, {'waypoint_task_executor_plugin':
                                              WAYPOINT_PLUGINS}),
    'docking_server': (DOCKING_SERVER, {'dock_plugins': DOCK_PLUGINS}),
}


def type_of(value):
    """Return the ROS parameter type a YAML value loads as ('mixed[]' for what none is)."""
    if isinstance(value, bool):
        return BOOL
    if isinstance(value, int):
        return INT
    if isinstance(value, float):
        return FLOAT
    if isinstance(value, str):
        return STR
    if isinstance(value, list) and value:
        kinds = {type_of(v) for v in value}
        return kinds.pop() + '[]' if len(kinds) == 1 else 'mixed[]'
    return type(value).__name__


def _against(table, params, where, problems, skip=()):
    """Append a problem for each key of params not in table or of another type."""
    for key, value in params.items():
        if key in skip:
            continue
        if key not in table:
            problems.append('{}.{}: not read upstream'.format(where, key))
        elif type_of(value) != table[key]:
            problems.append('{}.{}: {} where upstream declares {}'.format(
                where, key, type_of(value), table[key]))


def _costmap(params, where, problems):
    plugins = params.get('plugins', COSTMAP_DEFAULT_PLUGINS)
    layers = {k for k, v in params.items() if isinstance(v, dict)}
    _against(COSTMAP, params, where, problems, skip=layers)
    for name in sorted(layers - set(plugins)):
        problems.append('{}.{}: a layer not in plugins'.format(where, name))
    for name in plugins:
        layer = params.get(name, {})
        kind = layer.get('plugin')
        if kind is None:
            if plugins != COSTMAP_DEFAULT_PLUGINS:
                problems.append('{}.{}.plugin: missing'.format(where, name))
            continue
        if kind not in LAYERS:
            problems.append('{}.{}.plugin: unknown layer {}'.format(where, name, kind))
            continue
        sources = str(layer.get('observation_sources', '')).split()
        _against(LAYERS[kind], layer, '{}.{}'.format(where, name), problems,
                 skip={'plugin'} | set(sources))
        for src in sources:
            _against(OBSERVATION_SOURCE, layer.get(src, {}),
                     '{}.{}.{}'.format(where, name, src), problems)
            if layer.get(src, {}).get('data_type', 'LaserScan') not in DATA_TYPES:
                problems.append('{}.{}.{}.data_type: not {}'.format(
                    where, name, src, DATA_TYPES))


def _twist_mux(params, where, problems):
    if 'use_stamped' not in params:
        problems.append('{}.use_stamped: missing (twist_mux >= 4.4.0 aborts)'.format(where))
    for key, group in params.items():
        if key in TWIST_MUX:
            _against(TWIST_MUX, {key: group}, where, problems)
            continue
        if key not in TWIST_MUX_GROUPS or not isinstance(group, dict):
            problems.append('{}.{}: not read upstream'.format(where, key))
            continue
        for name, entry in group.items():
            _against(TWIST_MUX_ENTRY, entry, '{}.{}.{}'.format(where, key, name), problems)
            for need in TWIST_MUX_ENTRY:
                if need not in entry:   # fetch_param throws: twist_mux does not start
                    problems.append('{}.{}.{}.{}: missing'.format(where, key, name, need))


def _ekf(params, where, problems):
    sensors = {}
    for key, value in params.items():
        m = EKF_SENSOR.match(key)
        if key in EKF or not m or m.group(3) not in EKF_SENSOR_KEYS[m.group(1)]:
            _against(EKF, {key: value}, where, problems)
            continue
        kind, index, suffix = m.group(1), int(m.group(2)), m.group(3)
        _against({key: EKF_SENSOR_KEYS[kind][suffix]}, {key: value}, where, problems)
        sensors.setdefault(kind, set()).add(index)
        if suffix == '_config' and len(value) != len(EKF_STATE):
            problems.append('{}.{}: {} entries, the state has {}'.format(
                where, key, len(value), len(EKF_STATE)))
    for kind, indices in sensors.items():
        if sorted(indices) != list(range(len(indices))):    # loadParams stops at a gap
            problems.append('{}: {} indices {} have a gap'.format(where, kind, sorted(indices)))
        for i in indices:
            if '{}{}'.format(kind, i) not in params:
                problems.append('{}.{}{}: options without the topic'.format(where, kind, i))


def _aggregator(params, where, problems):
    analyzers = {k for k, v in params.items() if isinstance(v, dict)}
    _against(AGGREGATOR, params, where, problems, skip=analyzers)
    for name in analyzers:
        a = params[name]
        _against(GENERIC_ANALYZER, a, '{}.{}'.format(where, name), problems)
        if a.get('type') not in ANALYZER_TYPES or 'path' not in a:  # both make an analyzer
            problems.append('{}.{}: needs a known type and a path'.format(where, name))


def _plugin_server(params, where, problems, own, lists):
    named = {}
    for key, types in lists.items():
        names = params.get(key, [])
        for name in [names] if isinstance(names, str) else names:
            named[name] = types
    subs = {k for k, v in params.items() if isinstance(v, dict)}
    _against(own, params, where, problems, skip=subs)
    for name in sorted(subs):
        sub = params[name]
        if name == 'controller' and own is DOCKING_SERVER:
            _against(DOCKING_CONTROLLER, sub, where + '.controller', problems)
            continue
        if name not in named:
            problems.append('{}.{}: a plugin not in any plugin list'.format(where, name))
            continue
        kind = sub.get('plugin')
        if kind not in named[name]:
            problems.append('{}.{}.plugin: unknown plugin {}'.format(where, name, kind))
            continue
        _against(named[name][kind], sub, '{}.{}'.format(where, name), problems, skip={'plugin'})
        for critic in sub.get('critics', []):
            if critic not in MPPI_CRITICS:
                problems.append('{}.{}.critics: unknown critic {}'.format(where, name, critic))
    for name in sorted(set(named) - subs):
        problems.append('{}.{}: listed plugin without its section'.format(where, name))


def _collision_monitor(params, where, problems):
    polygons, sources = params.get('polygons', []), params.get('observation_sources', [])
    _against(COLLISION_MONITOR, params, where, problems, skip=set(polygons) | set(sources))
    if not polygons or not sources:     # declared without default: configure fails
        problems.append('{}: needs polygons and observation_sources'.format(where))
    for name in polygons:
        p = params.get(name, {})
        _against(COLLISION_POLYGON, p, '{}.{}'.format(where, name), problems)
        if p.get('type') not in COLLISION_POLYGON_TYPES or 'action_type' not in p:
            problems.append('{}.{}: needs a type of {} and an action_type'.format(
                where, name, COLLISION_POLYGON_TYPES))
    for name in sources:
        src = params.get(name, {})
        _against(COLLISION_SOURCE, src, '{}.{}'.format(where, name), problems)
        if src.get('type', 'scan') not in COLLISION_SOURCE_TYPES:
            problems.append('{}.{}.type: not {}'.format(where, name, COLLISION_SOURCE_TYPES))


def problems(node, params):
    """Return what upstream would not read (or read as another type) in one node's params."""
    found = []
    base = node.split('/')[-1]
    if base in FLAT:
        _against(FLAT[base], params, node, found)
    elif base in PLUGIN_SERVERS:
        _plugin_server(params, node, found, *PLUGIN_SERVERS[base])
    elif base == 'collision_monitor':
        _collision_monitor(params, node, found)
    elif base in ('local_costmap', 'global_costmap'):
        _costmap(params, node, found)
    elif base == 'twist_mux':
        _twist_mux(params, node, found)
    elif base == 'ekf_filter_node':
        _ekf(params, node, found)
    elif base == 'analyzers':
        _aggregator(params, node, found)
    else:
        found.append('{}: no upstream table for this node'.format(node))
    return found
