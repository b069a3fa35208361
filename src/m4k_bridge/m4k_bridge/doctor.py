"""Inspect the live ROS graph around the m4k base (one robot or a fleet) and name what is wrong.

    ros2 run m4k_bridge doctor [--duration 3.0] [--config-dir DIR]

One line per problem, each with its fix; exit status 1 when there is any problem, 0 when none
(2 on a usage error). What it looks at (docs/nav2.md, "doctor"):

* names, types and QoS of every topic (:mod:`m4k_bridge.graphcheck`): a subscription with no
  publisher whose name is an m4k topic up to the namespace (a costmap layer on
  ``/local_costmap/scan``), a ``cmd_vel`` publisher of the other type, two types on one topic,
  a publisher that cannot serve a subscription (reliability, durability), more than one
  writer on an m4k input (``cmd_vel``, ``e_stop``: an unremapped docking server);
* each robot's TF tree on its own topics (``/tf``, or ``/r1/tf`` for robot ``r1``, Nav2's
  multi-robot layout; :mod:`m4k_bridge.fleetcheck`): split, a frame with two parents or two
  static publishers, stale stamps, one edge claimed by two nodes (read from their
  ``publish_tf``-style parameters), a node publishing into another robot's tree, frame
  parameters naming frames the node's tree does not have;
* the rates of the base's topics against the configured task periods (far: a factor of 3);
* parameters read through the nodes' services: ``use_sim_time`` differing, or true with no
  ``/clock``; a twist_mux without ``use_stamped``; a collision monitor's Range source on the
  m4k sonar that stops the robot on "no echo" or can never trigger;
* lifecycle nodes that are not active;
* a DDS graph open to the subnet (:mod:`m4k_bridge.exposure`).

Each check is one entry of :attr:`Doctor.checks` (a method returning lines), so a new check
is one more method there.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any, Callable, Sequence

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from m4k_bridge import exposure, fleetcheck, params
from m4k_bridge.fleetcheck import TF_TYPE, TfSample
from m4k_bridge.graphcheck import check, Endpoint
from m4k_bridge.interfaces import interface_class

__all__ = ['Doctor', 'main']

RETRY_S = 1.0                      # a service request unanswered this long is sent again
NODE_NAME = '_m4k_doctor'          # hidden: not part of the graph it inspects
RATE_FACTOR = 3.0                  # a rate beyond configured / 3 .. configured * 3 is "far"
STALE_TF_S = 1.0                   # a dynamic transform this far behind the clock is stale
_SKIP_TOPICS = ('/rosout', '/parameter_events')
_TF_STATIC_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.TRANSIENT_LOCAL)
_ANY_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)


def _fqn(ns: str, name: str) -> str:
    return ns.rstrip('/') + '/' + name


def expected_rates(config_dir: str | None = None) -> dict[str, float]:
    """Return topic key -> configured rate [Hz] of the base's periodic topics."""
    from m4k_rt import config
    cfg = config.load(config_dir=config_dir)
    doc = config.load_layered(config_dir=config_dir)
    every = int(doc['control'].get('odom_every_n', 1))

    def hz(task: str, n: int = 1) -> float:
        return 1e9 / (cfg.task(task).period_ns * n)

    return {'odom': hz('actuator', every), 'imu': hz('imu'), 'sonar': hz('sonar'),
            'scan': hz('lrf')}


class Doctor:
    """Collect the graph, TF and rates through one hidden node; :meth:`problems` judges."""

    def __init__(self, node: Node, rates: dict[str, float]) -> None:
        """Use node (already in the graph's context) and the configured rates."""
        self.node = node
        self.rates = rates
        self.tf: list[TfSample] = []
        self.params: dict[str, dict[str, Any]] = {}   # node -> parameters it answered
        self.sources: dict[str, dict[str, Any]] = {}  # collision monitor -> source params
        self.counts: dict[str, int] = {}
        self.subs: list[Any] = []

    # --- the graph ------------------------------------------------------------------------
    def endpoints(self) -> list[Endpoint]:
        """Return every publisher and subscription of the graph but the doctor's own."""
        out = []
        me = self.node.get_fully_qualified_name()
        for topic, _types in self.node.get_topic_names_and_types():
            if topic in _SKIP_TOPICS:
                continue
            for kind, infos in (('pub', self.node.get_publishers_info_by_topic(topic)),
                                ('sub', self.node.get_subscriptions_info_by_topic(topic))):
                for i in infos:
                    fqn = _fqn(i.node_namespace, i.node_name)
                    if fqn == me:
                        continue
                    q = i.qos_profile
                    out.append(Endpoint(
                        fqn, kind, topic, i.topic_type,
                        q.reliability == ReliabilityPolicy.RELIABLE,
                        q.durability == DurabilityPolicy.TRANSIENT_LOCAL,
                        m4k=i.node_name == params.NODE_NAME))
        return out

    def listen(self, eps: Sequence[Endpoint], duration: float) -> None:
        """Subscribe TF and the base's periodic topics and spin for duration seconds."""
        from tf2_msgs.msg import TFMessage
        tf_topics = sorted({e.topic for e in eps if e.type == TF_TYPE and e.kind == 'pub'})
        for t in tf_topics:
            static = t.endswith('tf_static')
            self.subs.append(self.node.create_subscription(
                TFMessage, t, self._tf_callback(t, static),
                _TF_STATIC_QOS if static else _ANY_QOS))
        for _key, topic, typ in self._rated(eps):
            self.counts[topic] = 0
            cls = interface_class(typ)
            self.subs.append(self.node.create_subscription(
                cls, topic, self._count_callback(topic), _ANY_QOS))
        self._t0 = time.monotonic()
        end = self._t0 + duration
        while time.monotonic() < end:
            rclpy.spin_once(self.node, timeout_sec=0.05)
        self._elapsed = time.monotonic() - self._t0

    def _tf_callback(self, topic: str, static: bool) -> Callable[[Any], None]:
        def on_tf(msg: Any) -> None:
            for tr in msg.transforms:
                self.tf.append(TfSample(
                    topic, static, tr.header.frame_id.lstrip('/'), tr.child_frame_id.lstrip('/'),
                    tr.header.stamp.sec + tr.header.stamp.nanosec * 1e-9))
        return on_tf

    def _count_callback(self, topic: str) -> Callable[[Any], None]:
        def on_msg(_msg: Any) -> None:
            self.counts[topic] += 1
        return on_msg

    def _rated(self, eps: Sequence[Endpoint]) -> list[tuple[str, str, str]]:
        out = []
        for e in eps:
            if e.m4k and e.kind == 'pub':
                for key in self.rates:
                    name = str(params.spec('topics.' + key).default)
                    if e.topic.rsplit('/', 1)[-1] == name.rsplit('/', 1)[-1]:
                        out.append((key, e.topic, e.type))
        return sorted(set(out))

    # --- judgements -----------------------------------------------------------------------
    def tf_problems(self, eps: Sequence[Endpoint]) -> list[str]:
        """Return each robot's TF tree problems seen while listening."""
        now = self.node.get_clock().now().nanoseconds * 1e-9
        return (fleetcheck.wrong_tree_publishers(eps)
                + fleetcheck.tree_problems(self.tf, eps, now, STALE_TF_S)
                + fleetcheck.duplicate_edges(eps, self.params)
                + fleetcheck.frame_parameter_problems(eps, self.params, self.tf))

    def rate_problems(self, eps: Sequence[Endpoint]) -> list[str]:
        """Return the base's topics whose rate is far from the configured one."""
        out = []
        for key, topic, _typ in self._rated(eps):
            want = self.rates[key]
            got = self.counts.get(topic, 0) / max(self._elapsed, 1e-9)
            if got < want / RATE_FACTOR or got > want * RATE_FACTOR:
                out.append('{} arrives at {:.1f} Hz, configured {:.1f} Hz: check the device and '
                           'its RT task (rt_status, diagnostics) or the network between here and '
                           'the robot'.format(topic, got, want))
        return out

    def _call(self, srv: Any, suffix: str, requests: dict[str, Any],
              timeout: float) -> dict[str, Any]:
        """Call service fqn + suffix on each node at once; return fqn -> response."""
        pending = {}
        for fqn, req in requests.items():
            cli = self.node.create_client(srv, fqn + suffix)
            if not cli.wait_for_service(timeout_sec=timeout):
                self.node.destroy_client(cli)
                continue
            pending[fqn] = (cli, cli.call_async(req))
        # Fast DDS may answer a request before the server has met this client's response
        # reader, and that answer is lost: ask again, every RETRY_S, until the timeout.
        end = time.monotonic() + timeout
        again = time.monotonic() + RETRY_S
        while time.monotonic() < end and not all(f.done() for _, f in pending.values()):
            rclpy.spin_once(self.node, timeout_sec=0.05)
            if time.monotonic() >= again:
                again = time.monotonic() + RETRY_S
                for fqn, (cli, fut) in list(pending.items()):
                    if not fut.done():
                        cli.remove_pending_request(fut)
                        pending[fqn] = (cli, cli.call_async(requests[fqn]))
        out = {}
        for fqn, (cli, fut) in pending.items():
            if fut.done() and fut.result() is not None:
                out[fqn] = fut.result()
            self.node.destroy_client(cli)
        return out

    def _ask(self, wanted: dict[str, list[str]], timeout: float) -> dict[str, dict[str, Any]]:
        """Return node -> {parameter: value} for the wanted parameters each node declares.

        Listed first: rclpy answers get_parameters with nothing at all when one name is not
        declared (rclcpp with NOT_SET for that one).
        """
        from rcl_interfaces.msg import ParameterType
        from rcl_interfaces.srv import GetParameters, ListParameters
        listed = self._call(ListParameters, '/list_parameters',
                            {f: ListParameters.Request() for f in wanted}, timeout)
        names = {f: [n for n in wanted[f] if n in set(r.result.names)]
                 for f, r in listed.items()}
        answers = self._call(GetParameters, '/get_parameters',
                             {f: GetParameters.Request(names=n) for f, n in names.items() if n},
                             timeout)
        fields = {ParameterType.PARAMETER_BOOL: 'bool_value',
                  ParameterType.PARAMETER_INTEGER: 'integer_value',
                  ParameterType.PARAMETER_DOUBLE: 'double_value',
                  ParameterType.PARAMETER_STRING: 'string_value',
                  ParameterType.PARAMETER_STRING_ARRAY: 'string_array_value'}
        out: dict[str, dict[str, Any]] = {fqn: {} for fqn in names}
        for fqn, res in answers.items():
            for name, v in zip(names[fqn], res.values, strict=False):
                if v.type in fields:
                    value = getattr(v, fields[v.type])
                    out[fqn][name] = list(value) if \
                        v.type == ParameterType.PARAMETER_STRING_ARRAY else value
        return out

    def collect_parameters(self, timeout: float = 2.0) -> None:
        """Read every node's known parameters, then each collision monitor's sources."""
        me = self.node.get_fully_qualified_name()
        nodes = [_fqn(ns, name) for name, ns in self.node.get_node_names_and_namespaces()]
        self.params = self._ask({n: list(fleetcheck.PARAMS) for n in nodes if n != me},
                                timeout)
        more = {}
        for fqn, p in self.params.items():
            if isinstance(p.get('observation_sources'), list):
                more[fqn] = [s + k for s in p['observation_sources'] for k in (
                    '.type', '.topic', '.obstacles_angle', '.source_timeout')] + [
                    poly + '.min_points' for poly in p.get('polygons') or []]
        self.sources = self._ask(more, timeout) if more else {}

    def parameter_problems(self, eps: Sequence[Endpoint]) -> list[str]:
        """Return clock problems, a twist_mux without use_stamped, a sonar source that fails."""
        out = []
        for fqn, p in sorted(self.params.items()):
            if 'twist_mux' in fqn.rsplit('/', 1)[-1] and not isinstance(p.get('use_stamped'),
                                                                         bool):
                out.append('{} has no use_stamped parameter: twist_mux >= 4.4.0 aborts '
                           'without it and older ones mux Twist only; set use_stamped: '
                           'false (Twist, as Nav2 Jazzy and the bridge by default) or true '
                           '(TwistStamped) in its parameter file'.format(fqn))
        return (out + fleetcheck.sim_time_problems(eps, self.params)
                + fleetcheck.sonar_source_problems(eps, self.params, self.sources))

    def lifecycle_problems(self, timeout: float = 2.0) -> list[str]:
        """Return lifecycle nodes (those serving get_state) that are not active."""
        from lifecycle_msgs.srv import GetState
        nodes = []
        for name, ns in self.node.get_node_names_and_namespaces():
            fqn = _fqn(ns, name)
            services = dict(self.node.get_service_names_and_types_by_node(name, ns))
            if fqn + '/get_state' in services:
                nodes.append(fqn)
        got = self._call(GetState, '/get_state', {f: GetState.Request() for f in nodes},
                         timeout)
        states = {f: got[f].current_state.label if f in got else 'not answering'
                  for f in nodes}
        return fleetcheck.lifecycle_problems(states)

    def problems(self, duration: float) -> list[str]:
        """Return every problem of the live graph (one line each, with its fix)."""
        eps = self.endpoints()
        out = check(eps, unfed='m4k')
        if not any(e.m4k for e in eps):
            out.append('no m4k_bridge node in this graph (ROS_DOMAIN_ID, '
                       'ROS_AUTOMATIC_DISCOVERY_RANGE, the network): start the base or run '
                       'doctor where it can see it')
        self.collect_parameters()
        self.listen(eps, duration)
        for judge in self.checks():
            out += judge(eps)
        return out

    def checks(self) -> list[Callable[[Sequence[Endpoint]], list[str]]]:
        """Return the checks run after listening, each endpoints -> lines."""
        return [self.tf_problems, self.rate_problems, self.parameter_problems,
                lambda _eps: self.lifecycle_problems(),
                lambda _eps: exposure.graph_problems()]   # an open DDS graph


def discover(node: Node, limit: float, settle: float = 2.0) -> None:
    """Spin until the graph (nodes, topics, endpoints) has not changed for settle seconds.

    Two seconds: on a loaded host DDS discovery announces participants more than a second
    apart, and a graph read in such a gap is missing the base (seen: "no m4k_bridge node").
    A settled graph with no base in it is waited on to the limit: the base is what doctor
    checks, and other nodes (a teleop) can settle before it is discovered (seen in CI).
    """
    start = time.monotonic()
    last, changed = None, start
    while time.monotonic() - start < limit:
        rclpy.spin_once(node, timeout_sec=0.05)
        topics = node.get_topic_names_and_types()
        now = (len(node.get_node_names_and_namespaces()), len(topics),
               sum(node.count_publishers(t) + node.count_subscribers(t) for t, _ in topics))
        if now != last:
            last, changed = now, time.monotonic()
        elif bridge_seen(node) and time.monotonic() - changed >= settle:
            return


def bridge_seen(node: Node) -> bool:
    """Return whether the graph holds an m4k_bridge node (any namespace): until then, wait."""
    return any(name == params.NODE_NAME for name, _ in node.get_node_names_and_namespaces())


def main(argv: Sequence[str] | None = None) -> int:
    """Run the checks once; print one line per problem; exit 1 when there is any."""
    args = list(sys.argv[1:] if argv is None else argv)
    ros_args = args[args.index('--ros-args'):] if '--ros-args' in args else []
    ap = argparse.ArgumentParser(prog='doctor', description=__doc__.split('\n')[0])
    ap.add_argument('--duration', type=float, default=3.0,
                    help='seconds to watch TF and the topic rates (default 3)')
    ap.add_argument('--discovery', type=float, default=6.0,
                    help='at most this many seconds for discovery to settle (default 6)')
    ap.add_argument('--config-dir', default=None, help='the configuration of the base')
    a = ap.parse_args(args[:len(args) - len(ros_args)])
    rates = expected_rates(a.config_dir)
    rclpy.init(args=['doctor'] + ros_args)
    node = Node(NODE_NAME)
    try:
        discover(node, a.discovery)
        found = Doctor(node, rates).problems(a.duration)
    except (KeyboardInterrupt, ExternalShutdownException):
        return 130
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    for line in found:
        print(line)
    print('doctor: {} problem(s)'.format(len(found)) if found else 'doctor: no problem found',
          file=sys.stderr)
    return 1 if found else 0


if __name__ == '__main__':
    sys.exit(main())
