"""The consumers of the recipes, and the graph they form with the m4k bridge, resolved for real.

Each consumer is a node the stock launch files start: its name, its namespace, the remaps the
launch file gives its process and, per endpoint, where the topic name comes from (a parameter
with the upstream default, or a name fixed in the code) with the message type and the QoS the
upstream source subscribes or publishes with (the file named beside each entry, navigation2
``jazzy``, slam_toolbox, robot_localization, twist_mux; docs/nav2.md "Checked against upstream").

:func:`graph` builds the endpoints as the nodes would: for every consumer a real rclpy node is
created in its own ``Context`` whose arguments are the launch file's (``--params-file`` the
recipe, the remaps), with the consumer's node name and namespace. rcl then parses the file
with ``rcl_yaml_param_parser`` and picks the node's section by its fully qualified name (as the
C++ node's rcl does), and ``resolve_topic_name`` expands and remaps each name with rcl's rules.
The result goes to :func:`m4k_bridge.graphcheck.check`, the check ``doctor`` runs live.
"""

import dataclasses
import os
import tempfile

import rclpy
from rclpy.node import Node
import yaml

from m4k_bridge import params as bridge_params
from m4k_bridge.graphcheck import Endpoint

LASER, RANGE = 'sensor_msgs/msg/LaserScan', 'sensor_msgs/msg/Range'
IMU, ODOM = 'sensor_msgs/msg/Imu', 'nav_msgs/msg/Odometry'
TWIST, BOOL = 'geometry_msgs/msg/Twist', 'std_msgs/msg/Bool'
COSTMAP, POLYGON = 'nav2_msgs/msg/Costmap', 'geometry_msgs/msg/PolygonStamped'
# (reliable, transient_local)
SENSOR, RELIABLE, LATCHED = (False, False), (True, False), (True, True)

# navigation_launch.py (Jazzy): every node gets these; the controller, the behavior server
# and the velocity smoother also cmd_vel:=cmd_vel_nav.
NAV_REMAPS = [('/tf', 'tf'), ('/tf_static', 'tf_static')]
CMD_VEL_NAV = [('cmd_vel', 'cmd_vel_nav')]


@dataclasses.dataclass
class Ep:
    """One endpoint: a topic from a parameter (param set) or fixed in the code (param None)."""

    kind: str
    default: str                 # the upstream default (or the fixed name)
    type: str
    qos: tuple
    param: str | None = None     # dotted parameter name, '[]' suffix: a list of names
    external: bool = False       # fed by something outside the checked graph (joystick, map)


@dataclasses.dataclass
class Consumer:
    """A node as the stock launch file starts it."""

    name: str
    ns: str                      # relative to the robot's namespace ('' or 'local_costmap')
    remaps: list
    endpoints: list
    section: tuple               # its path in the parameter file


def _costmap(name, remaps, sources):
    eps = [Ep('sub', s, LASER, SENSOR, 'obstacle_layer.{}.topic'.format(s)) for s in sources]
    eps += [Ep('pub', 'costmap_raw', COSTMAP, LATCHED),           # costmap_2d_publisher.cpp
            Ep('pub', 'published_footprint', POLYGON, RELIABLE)]  # costmap_2d_ros.cpp
    return Consumer(name, name, remaps, eps, (name, name))


def nav2_consumers(doc):
    """Return Nav2's consumers of one generated Nav2 parameter file ``doc``."""
    local = _costmap('local_costmap', NAV_REMAPS + CMD_VEL_NAV,
                     doc['local_costmap']['local_costmap']['ros__parameters']['obstacle_layer']
                     ['observation_sources'].split())
    # range_sensor_layer.cpp: topics (no default), SensorDataQoS
    local.endpoints.append(Ep('sub', '', RANGE, SENSOR, 'range_layer.topics[]'))
    glob = _costmap('global_costmap', NAV_REMAPS,
                    doc['global_costmap']['global_costmap']['ros__parameters']['obstacle_layer']
                    ['observation_sources'].split())
    cm = doc['collision_monitor']['ros__parameters']
    cm_eps = [
        # collision_monitor_node.cpp: TwistSubscriber / TwistPublisher with QoS depth 1
        Ep('sub', 'cmd_vel_smoothed', TWIST, RELIABLE, 'cmd_vel_in_topic'),
        Ep('pub', 'cmd_vel', TWIST, RELIABLE, 'cmd_vel_out_topic'),
    ]
    for p in cm['polygons']:      # polygon.cpp: footprint_topic, SystemDefaultsQoS
        cm_eps.append(Ep('sub', 'local_costmap/published_footprint', POLYGON, RELIABLE,
                         p + '.footprint_topic'))
    for s in cm['observation_sources']:    # scan.cpp, range.cpp: SensorDataQoS
        kind = cm[s].get('type', 'scan')
        cm_eps.append(Ep('sub', '', LASER if kind == 'scan' else RANGE, SENSOR, s + '.topic'))
    beh_eps = [Ep('sub', d, t, q, k) for k, d, t, q in (
        # behavior_server.cpp: the costmap subscribers (CostmapSubscriber: transient local)
        ('local_costmap_topic', 'local_costmap/costmap_raw', COSTMAP, LATCHED),
        ('global_costmap_topic', 'global_costmap/costmap_raw', COSTMAP, LATCHED),
        ('local_footprint_topic', 'local_costmap/published_footprint', POLYGON, RELIABLE),
        ('global_footprint_topic', 'global_costmap/published_footprint', POLYGON, RELIABLE))]
    return [
        local, glob,
        # controller_server.cpp: OdomSubscriber(odom_topic), TwistPublisher("cmd_vel", 1)
        Consumer('controller_server', '', NAV_REMAPS + CMD_VEL_NAV, [
            Ep('sub', 'odom', ODOM, RELIABLE, 'odom_topic'),
            Ep('pub', 'cmd_vel', TWIST, RELIABLE)], ('controller_server',)),
        # velocity_smoother.cpp: TwistSubscriber("cmd_vel"), TwistPublisher("cmd_vel_smoothed"),
        # OdomSmoother(odom_topic) only with feedback CLOSED_LOOP
        Consumer('velocity_smoother', '', NAV_REMAPS + CMD_VEL_NAV, [
            Ep('sub', 'cmd_vel', TWIST, RELIABLE),
            Ep('pub', 'cmd_vel_smoothed', TWIST, RELIABLE)], ('velocity_smoother',)),
        Consumer('collision_monitor', '', NAV_REMAPS, cm_eps, ('collision_monitor',)),
        Consumer('behavior_server', '', NAV_REMAPS + CMD_VEL_NAV, beh_eps,
                 ('behavior_server',)),
        # bt_navigator.cpp: odom_topic (OdomSmoother, SystemDefaultsQoS)
        Consumer('bt_navigator', '', NAV_REMAPS, [
            Ep('sub', 'odom', ODOM, RELIABLE, 'odom_topic')], ('bt_navigator',)),
        # opennav_docking controller.cpp: controller.costmap_topic / footprint_topic
        Consumer('docking_server', '', NAV_REMAPS, [
            Ep('sub', 'local_costmap/costmap_raw', COSTMAP, LATCHED,
               'controller.costmap_topic'),
            Ep('sub', 'local_costmap/published_footprint', POLYGON, RELIABLE,
               'controller.footprint_topic')], ('docking_server',)),
        # no topic from their parameters; here so rcl hands them their sections too
        Consumer('planner_server', '', NAV_REMAPS, [], ('planner_server',)),
        Consumer('smoother_server', '', NAV_REMAPS, [], ('smoother_server',)),
        Consumer('waypoint_follower', '', NAV_REMAPS, [], ('waypoint_follower',)),
        # amcl_node.cpp: scan_topic, SensorDataQoS (localization_launch.py: same remaps)
        Consumer('amcl', '', NAV_REMAPS, [
            Ep('sub', 'scan', LASER, SENSOR, 'scan_topic')], ('amcl',)),
    ]


def other_consumers(kind, doc):
    """Return the consumers of the twist_mux, slam_toolbox or EKF recipe."""
    if kind == 'twist_mux':
        p = doc['twist_mux']['ros__parameters']
        # twist_mux.cpp: topics reliable depth 1 (Twist with use_stamped false), locks Bool
        # default QoS; the output cmd_vel_out remapped to cmd_vel as the recipe says
        eps = [Ep('sub', '', TWIST, RELIABLE, 'topics.{}.topic'.format(k),
                  external=(k != 'navigation')) for k in p['topics']]
        eps += [Ep('sub', '', BOOL, RELIABLE, 'locks.{}.topic'.format(k)) for k in p['locks']]
        eps.append(Ep('pub', 'cmd_vel_out', TWIST, RELIABLE))
        return [Consumer('twist_mux', '', [('cmd_vel_out', 'cmd_vel')], eps, ('twist_mux',))]
    if kind == 'slam_toolbox':
        # slam_toolbox_common.cpp: scan_topic default /scan, rmw_qos_profile_sensor_data
        return [Consumer('slam_toolbox', '', [], [
            Ep('sub', '/scan', LASER, SENSOR, 'scan_topic')], ('slam_toolbox',))]
    if kind == 'ekf':
        # ros_filter.cpp: odomN / imuN, SensorDataQoS(KeepLast(queue_size))
        return [Consumer('ekf_filter_node', '', [], [
            Ep('sub', '', ODOM, SENSOR, 'odom0'), Ep('sub', '', IMU, SENSOR, 'imu0')],
            ('ekf_filter_node',))]
    raise ValueError(kind)


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


def _wrapped(doc, robot):
    """Return the parameter file the launch file hands the node: RewrittenYaml nests the
    document under the namespace (root_key) when one is given."""
    return {robot: doc} if robot else doc


def resolve(consumers, doc, robot=''):
    """Return (endpoints, overrides by node): every consumer endpoint resolved by rcl."""
    out, seen = [], {}
    fd, path = tempfile.mkstemp(prefix='m4k-recipe-', suffix='.yaml')
    try:
        with os.fdopen(fd, 'w', encoding='utf-8') as f:
            yaml.safe_dump(_wrapped(doc, robot), f)
        for c in consumers:
            ns = '/'.join(x for x in ('', robot, c.ns) if x) or '/'
            ctx, node = _ctx_node(c.name, ns, _launch_args(path, c.remaps))
            try:
                overrides = {k: _plain(v.value)
                             for k, v in node._parameter_overrides.items()}
                seen[node.get_fully_qualified_name()] = overrides
                for ep in c.endpoints:
                    names = [ep.default]
                    if ep.param and ep.param.endswith('[]'):
                        names = list(overrides.get(ep.param[:-2], []))
                    elif ep.param:
                        names = [overrides.get(ep.param, ep.default)]
                    for raw in names:
                        assert raw, '{}: {} has no topic'.format(c.name, ep.param)
                        out.append(Endpoint(
                            node.get_fully_qualified_name(), ep.kind,
                            node.resolve_topic_name(raw), ep.type, ep.qos[0], ep.qos[1],
                            external=ep.external))
            finally:
                _close(ctx, node)
    finally:
        os.unlink(path)
    return out, seen


def bridge_endpoints(robot='', bridge_doc=None):
    """Return the bridge's endpoints, resolved as the bridge node in the robot's namespace."""
    ctx, node = _ctx_node(bridge_params.NODE_NAME, '/' + robot if robot else '/',
                          ['--ros-args'])
    try:
        out = []
        for key, kind, typ, qos in BRIDGE:
            name = str(bridge_params.spec('topics.' + key).default)
            out.append(Endpoint(node.get_fully_qualified_name(), kind,
                                node.resolve_topic_name(name), typ, qos[0], qos[1], m4k=True))
        return out
    finally:
        _close(ctx, node)
