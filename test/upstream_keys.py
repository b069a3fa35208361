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
        'scan_topic': STR, 'laser_max_range': FLOAT, 'laser_min_range': FLOAT}
# nav2_bt_navigator/src/bt_navigator.cpp
BT_NAVIGATOR = {'global_frame': STR, 'robot_base_frame': STR, 'odom_topic': STR,
                'transform_tolerance': FLOAT}
# nav2_collision_monitor/src/collision_monitor_node.cpp (getParameters)
COLLISION_MONITOR = {'base_frame_id': STR, 'odom_frame_id': STR, 'cmd_vel_in_topic': STR,
                     'cmd_vel_out_topic': STR, 'transform_tolerance': FLOAT}
# nav2_velocity_smoother/src/velocity_smoother.cpp: [x, y, theta] each
VELOCITY_SMOOTHER = {'smoothing_frequency': FLOAT, 'max_velocity': FLOATS,
                     'min_velocity': FLOATS, 'max_accel': FLOATS, 'max_decel': FLOATS,
                     'odom_topic': STR}
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

FLAT = {'amcl': AMCL, 'bt_navigator': BT_NAVIGATOR, 'collision_monitor': COLLISION_MONITOR,
        'velocity_smoother': VELOCITY_SMOOTHER, 'slam_toolbox': SLAM_TOOLBOX}


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
    for key, group in params.items():
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


def problems(node, params):
    """Return what upstream would not read (or read as another type) in one node's params."""
    found = []
    base = node.split('/')[-1]
    if base in FLAT:
        _against(FLAT[base], params, node, found)
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
