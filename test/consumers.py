"""The consumers of the recipes, and the graph they form with the m4k bridge, resolved for real.

The input is the documented command: ``m4k_bringup.fleet.nodes`` is every node
``m4k_nav2.launch.py`` starts (name, namespace, remaps, parameter files -- the list the launch
file turns into ``Node`` actions, checked against the real launch by
``tools/verify_nav2_launch.py``), and the bridge as ``m4k.launch.py robot:=NAME
bridge_params:=...`` runs it. What this module adds is upstream knowledge: per node, where each
topic name comes from (a parameter with the upstream default, or a name fixed in the code,
``/tf`` and ``/tf_static`` included), with the message type and QoS the upstream source uses
(the file named beside each entry, navigation2 ``jazzy``, slam_toolbox, robot_localization,
twist_mux; docs/nav2.md "Checked against upstream"), and the costmap nodes the controller and
planner servers create in ``<ns>/local_costmap`` and ``<ns>/global_costmap`` (they take the
process's remaps: rcl's global arguments).

:func:`graph` builds the endpoints as the nodes would: for every consumer a real rclpy node is
created in its own ``Context`` whose arguments are the launch file's (``--params-file`` each
recipe file, the remaps), with the node's name and namespace. rcl then parses the file
with ``rcl_yaml_param_parser`` and picks the node's section by its fully qualified name (as the
C++ node's rcl does), and ``resolve_topic_name`` expands and remaps each name with rcl's rules.
The result goes to :func:`m4k_bridge.graphcheck.check`, the check ``doctor`` runs live.
"""

import dataclasses

import rclpy
from rclpy.node import Node

from m4k_bridge import params as bridge_params
from m4k_bridge.graphcheck import Endpoint
from m4k_bringup import robots

LASER, RANGE = 'sensor_msgs/msg/LaserScan', 'sensor_msgs/msg/Range'
IMU, ODOM = 'sensor_msgs/msg/Imu', 'nav_msgs/msg/Odometry'
TWIST, BOOL = 'geometry_msgs/msg/Twist', 'std_msgs/msg/Bool'
COSTMAP, POLYGON = 'nav2_msgs/msg/Costmap', 'geometry_msgs/msg/PolygonStamped'
TF = 'tf2_msgs/msg/TFMessage'
# (reliable, transient_local)
SENSOR, RELIABLE, LATCHED = (False, False), (True, False), (True, True)


@dataclasses.dataclass
class Ep:
    """One endpoint: a topic from a parameter (param set) or fixed in the code (param None)."""

    kind: str
    default: str                 # the upstream default (or the fixed name)
    type: str
    qos: tuple
    param: str | None = None     # dotted parameter name, '[]' suffix: a list of names
    external: bool = False       # fed by something outside the checked graph (joystick, map)
    when: str | None = None      # only when this bool parameter is true (publish_tf)


# tf2_ros: TransformListener subscribes /tf (reliable, depth 100) and /tf_static (transient
# local); TransformBroadcaster publishes /tf. Absolute: only a remap moves them.
TF_LISTENER = [Ep('sub', '/tf', TF, RELIABLE), Ep('sub', '/tf_static', TF, LATCHED)]


@dataclasses.dataclass
class Consumer:
    """A node as the launch file starts it, and how its endpoints follow from its parameters."""

    name: str
    ns: str                      # absolute
    remaps: list
    params_files: tuple
    endpoints: object            # callable(parameters as rcl handed them) -> [Ep]


def _costmap_eps(p):
    # obstacle_layer.cpp: each observation source's topic, SensorDataQoS; range layer:
    # topics (no default); costmap_2d_publisher.cpp, costmap_2d_ros.cpp
    eps = [Ep('sub', '', LASER, SENSOR, 'obstacle_layer.{}.topic'.format(s))
           for s in str(p.get('obstacle_layer.observation_sources', '')).split()]
    if 'range_layer' in p.get('plugins', []):
        eps.append(Ep('sub', '', RANGE, SENSOR, 'range_layer.topics[]'))
    return eps + [Ep('pub', 'costmap_raw', COSTMAP, LATCHED),
                                Ep('pub', 'published_footprint', POLYGON, RELIABLE)]


def _monitor_eps(p):
    # collision_monitor_node.cpp: TwistSubscriber / TwistPublisher, depth 1; polygon.cpp
    # footprint_topic (SystemDefaultsQoS); scan.cpp / range.cpp: SensorDataQoS
    eps = [Ep('sub', 'cmd_vel_smoothed', TWIST, RELIABLE, 'cmd_vel_in_topic'),
           Ep('pub', 'cmd_vel', TWIST, RELIABLE, 'cmd_vel_out_topic')]
    eps += [Ep('sub', 'local_costmap/published_footprint', POLYGON, RELIABLE,
               poly + '.footprint_topic') for poly in p.get('polygons', [])]
    eps += [Ep('sub', 'scan', LASER if p.get(s + '.type', 'scan') == 'scan' else RANGE, SENSOR,
               s + '.topic') for s in p.get('observation_sources', [])]
    return eps + TF_LISTENER


_BEHAVIOR = [Ep('sub', d, t, q, k) for k, d, t, q in (
    # behavior_server.cpp: the costmap subscribers (CostmapSubscriber: transient local)
    ('local_costmap_topic', 'local_costmap/costmap_raw', COSTMAP, LATCHED),
    ('global_costmap_topic', 'global_costmap/costmap_raw', COSTMAP, LATCHED),
    ('local_footprint_topic', 'local_costmap/published_footprint', POLYGON, RELIABLE),
    ('global_footprint_topic', 'global_costmap/published_footprint', POLYGON, RELIABLE))]

# node name -> its endpoints from its parameters (upstream Jazzy sources)
ENDPOINTS = {
    # controller_server.cpp: OdomSubscriber(odom_topic), TwistPublisher("cmd_vel", 1)
    'controller_server': lambda p: [Ep('sub', 'odom', ODOM, RELIABLE, 'odom_topic'),
                                    Ep('pub', 'cmd_vel', TWIST, RELIABLE)] + TF_LISTENER,
    # velocity_smoother.cpp: TwistSubscriber("cmd_vel"), TwistPublisher("cmd_vel_smoothed");
    # OdomSmoother(odom_topic) only with feedback CLOSED_LOOP
    'velocity_smoother': lambda p: [Ep('sub', 'cmd_vel', TWIST, RELIABLE),
                                    Ep('pub', 'cmd_vel_smoothed', TWIST, RELIABLE)],
    'collision_monitor': _monitor_eps,
    # behaviors publish cmd_vel (TwistPublisher) from the behavior server
    'behavior_server': lambda p: _BEHAVIOR + [Ep('pub', 'cmd_vel', TWIST, RELIABLE)]
    + TF_LISTENER,
    # bt_navigator.cpp: odom_topic (OdomSmoother, SystemDefaultsQoS)
    'bt_navigator': lambda p: [Ep('sub', 'odom', ODOM, RELIABLE, 'odom_topic')] + TF_LISTENER,
    # opennav_docking: controller.costmap_topic / footprint_topic; docking_server.cpp
    # TwistPublisher("cmd_vel", 1) -- unremapped upstream
    'docking_server': lambda p: [
        Ep('sub', 'local_costmap/costmap_raw', COSTMAP, LATCHED, 'controller.costmap_topic'),
        Ep('sub', 'local_costmap/published_footprint', POLYGON, RELIABLE,
           'controller.footprint_topic'),
        Ep('pub', 'cmd_vel', TWIST, RELIABLE)] + TF_LISTENER,
    # route_server.cpp / CostmapScorer: costmap_topic (CostmapSubscriber)
    'route_server': lambda p: [Ep('sub', 'global_costmap/costmap_raw', COSTMAP, LATCHED,
                                  'costmap_topic')] + TF_LISTENER,
    'planner_server': lambda p: TF_LISTENER,
    'smoother_server': lambda p: TF_LISTENER,
    'waypoint_follower': lambda p: TF_LISTENER,
    'lifecycle_manager_navigation': lambda p: [],
    'lifecycle_manager_slam': lambda p: [],
    'lifecycle_manager_localization': lambda p: [],
    # map_server.cpp: map (transient local)
    'map_server': lambda p: [Ep('pub', 'map', 'nav_msgs/msg/OccupancyGrid', LATCHED)],
    # amcl_node.cpp: scan_topic SensorDataQoS, map transient local, broadcasts map -> odom
    'amcl': lambda p: [Ep('sub', 'scan', LASER, SENSOR, 'scan_topic'),
                       Ep('sub', 'map', 'nav_msgs/msg/OccupancyGrid', LATCHED, 'map_topic'),
                       Ep('pub', '/tf', TF, RELIABLE, when='tf_broadcast')] + TF_LISTENER,
    # slam_toolbox_common.cpp: scan_topic (default /scan), rmw_qos_profile_sensor_data;
    # broadcasts map -> odom
    'slam_toolbox': lambda p: [Ep('sub', '/scan', LASER, SENSOR, 'scan_topic'),
                               Ep('pub', '/tf', TF, RELIABLE)] + TF_LISTENER,
    # ros_filter.cpp: odomN / imuN SensorDataQoS; publish_tf broadcasts world -> base
    'ekf_filter_node': lambda p: [Ep('sub', '', ODOM, SENSOR, 'odom0'),
                                  Ep('sub', '', IMU, SENSOR, 'imu0'),
                                  Ep('pub', '/tf', TF, RELIABLE, when='publish_tf')]
    + TF_LISTENER,
    # twist_mux.cpp: topics reliable depth 1 (Twist with use_stamped false), locks Bool
    # default QoS, output cmd_vel_out
    'twist_mux': lambda p: [
        Ep('sub', '', TWIST, RELIABLE, 'topics.{}.topic'.format(k), external=(k != 'navigation'))
        for k in sorted({key.split('.')[1] for key in p if key.startswith('topics.')})] + [
        Ep('sub', '', BOOL, RELIABLE, 'locks.{}.topic'.format(k))
        for k in sorted({key.split('.')[1] for key in p if key.startswith('locks.')})] + [
        Ep('pub', 'cmd_vel_out', TWIST, RELIABLE)],
}
# parameters the upstream node declares with a default the endpoints depend on
DEFAULTS = {'amcl': {'tf_broadcast': True}, 'ekf_filter_node': {'publish_tf': True}}


def consumers_of(specs):
    """Return the consumers of fleet node specs: each node, and the costmap nodes the
    controller and planner servers create (costmap_2d_ros.cpp: ``<ns>/local_costmap``)."""
    out = []
    for s in specs:
        out.append(Consumer(s.name, s.namespace, list(s.remaps), s.params_files,
                            ENDPOINTS[s.name]))
        child = {'controller_server': 'local_costmap', 'planner_server': 'global_costmap'}
        if s.name in child:
            c = child[s.name]
            out.append(Consumer(c, s.namespace.rstrip('/') + '/' + c, list(s.remaps),
                                s.params_files, _costmap_eps))
            # costmap_2d_ros.cpp: TransformListener(*tf_buffer_) without a node makes its own
            # node, in the process's namespace (the launch's __ns), with its remaps
            out.append(Consumer('transform_listener_impl_' + c, s.namespace, list(s.remaps),
                                (), lambda p: TF_LISTENER))
    return out


# The bridge's own endpoints: topics.<key>, kind, type, QoS (m4k_bridge.node, .safety, .tf).
BRIDGE = [
    ('odom', 'pub', ODOM, RELIABLE), ('imu', 'pub', IMU, SENSOR),
    ('scan', 'pub', LASER, SENSOR), ('sonar', 'pub', RANGE, SENSOR),
    ('cmd_vel', 'sub', TWIST, SENSOR), ('e_stop', 'sub', BOOL, RELIABLE),
    ('e_stop_state', 'pub', BOOL, LATCHED),
]


def _plain(value):
    # rclpy hands arrays as array.array or lists: compare as lists
    return value if isinstance(value, (str, bool, int, float)) else list(value)


def _ctx_node(name, namespace, args):
    ctx = rclpy.Context()
    rclpy.init(context=ctx, args=args)
    return ctx, Node(name, namespace=namespace or '/', context=ctx)


def _close(ctx, node):
    node.destroy_node()
    rclpy.try_shutdown(context=ctx)


def _launch_args(params_file, remaps):
    args = ['--ros-args']
    if params_file:
        args += ['--params-file', params_file]
    for a, b in remaps:
        args += ['-r', '{}:={}'.format(a, b)]
    return args


def resolve(consumers):
    """Return (endpoints, overrides by node): every consumer endpoint resolved by rcl."""
    out, seen = [], {}
    for c in consumers:
        args = ['--ros-args']
        for f in c.params_files:
            args += ['--params-file', f]
        for a, b in c.remaps:
            args += ['-r', '{}:={}'.format(a, b)]
        ctx, node = _ctx_node(c.name, c.ns, args)
        try:
            overrides = {k: _plain(v.value) for k, v in node._parameter_overrides.items()}
            fqn = node.get_fully_qualified_name()
            seen[fqn] = overrides
            params = {**DEFAULTS.get(c.name, {}), **overrides}
            for ep in c.endpoints(params):
                if ep.when and not params.get(ep.when):
                    continue
                names = [ep.default]
                if ep.param and ep.param.endswith('[]'):
                    names = list(params.get(ep.param[:-2], []))
                elif ep.param:
                    names = [params.get(ep.param, ep.default)]
                for raw in names:
                    assert raw, '{}: {} has no topic'.format(c.name, ep.param)
                    out.append(Endpoint(fqn, ep.kind, node.resolve_topic_name(raw), ep.type,
                                        ep.qos[0], ep.qos[1], external=ep.external))
        finally:
            _close(ctx, node)
    return out, seen


def bridge_endpoints(robot='', bridge_files=()):
    """Return the bridge's endpoints as ``m4k.launch.py robot:=NAME bridge_params:=FILES``
    runs it: its namespace, its tf mode (robots.robot_settings), its topics resolved by rcl."""
    ns, values = robots.robot_settings(robot) if robot else ('/', {})
    values = robots.effective_bridge_values(values, list(bridge_files))
    ctx, node = _ctx_node(bridge_params.NODE_NAME, ns, ['--ros-args'])
    try:
        out = []
        for key, kind, typ, qos in BRIDGE:
            name = str(bridge_params.spec('topics.' + key).default)
            out.append(Endpoint(node.get_fully_qualified_name(), kind,
                                node.resolve_topic_name(name), typ, qos[0], qos[1], m4k=True))
        # m4k_bridge.tf: tf always (wheel joints; odom -> base_footprint with publish_tf),
        # tf_static transient local; relative when tf_namespaced
        rel = values.get('tf_namespaced', bridge_params.spec('tf_namespaced').default)
        for name, qos in (('tf', RELIABLE), ('tf_static', LATCHED)):
            out.append(Endpoint(node.get_fully_qualified_name(), 'pub',
                                node.resolve_topic_name(name if rel else '/' + name), TF,
                                qos[0], qos[1], m4k=True))
        return out
    finally:
        _close(ctx, node)
