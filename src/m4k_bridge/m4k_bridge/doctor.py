"""Inspect the live ROS graph around the m4k base and name what a Nav2 user would hit.

    ros2 run m4k_bridge doctor [--duration 3.0] [--config-dir DIR]

One line per problem, each with its fix; exit status 1 when there is any problem, 0 when none
(2 on a usage error). What it looks at (docs/nav2.md, "doctor"):

* names, types and QoS of every topic (:mod:`m4k_bridge.graphcheck`): a subscription with no
  publisher whose name is an m4k topic up to the namespace (a costmap layer on
  ``/local_costmap/scan``), a ``cmd_vel`` publisher of the other type (Twist against
  TwistStamped), a publisher that cannot serve a subscription (reliability, durability);
* the TF tree over ``--duration`` seconds: split into several trees, a frame with two parents
  or two static publishers, transforms on a namespaced ``tf`` topic, dynamic transforms whose
  stamps lag the clock;
* the rates of the base's topics against the configured task periods (far: a factor of 3);
* ``use_sim_time`` differing between nodes, and a twist_mux without ``use_stamped`` (both read
  through the nodes' parameter services);
* a DDS graph open to the subnet (:mod:`m4k_bridge.exposure`).
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

from m4k_bridge import exposure, params
from m4k_bridge.graphcheck import check, Endpoint
from m4k_bridge.interfaces import interface_class

__all__ = ['Doctor', 'main']

NODE_NAME = '_m4k_doctor'          # hidden: not part of the graph it inspects
TF_TYPE = 'tf2_msgs/msg/TFMessage'
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
        self.tf: list[tuple[str, bool, Any]] = []     # (topic, static, TFMessage)
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
            self.tf.append((topic, static, msg))
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
        """Return the TF tree's problems seen while listening."""
        out = []
        for t in sorted({e.topic for e in eps if e.type == TF_TYPE and e.kind == 'pub'}):
            if t not in ('/tf', '/tf_static'):
                nodes = sorted({e.node for e in eps if e.topic == t and e.kind == 'pub'})
                out.append('transforms on {} (from {}), not /tf or /tf_static: tf listeners '
                           'that read /tf see a split tree; use one mode for the whole robot '
                           "(the bridge's tf_namespaced, robot_state_publisher's /tf remap, "
                           "Nav2's namespaced launch)".format(t, ', '.join(nodes)))
        parents: dict[str, set[str]] = {}
        static_samples: dict[str, int] = {}
        latest: dict[str, float] = {}
        for topic, static, msg in self.tf:
            if topic not in ('/tf', '/tf_static'):
                continue
            for tr in msg.transforms:
                child, parent = tr.child_frame_id.lstrip('/'), tr.header.frame_id.lstrip('/')
                parents.setdefault(child, set()).add(parent)
                if static:
                    static_samples[child] = static_samples.get(child, 0) + 1
                else:
                    stamp = tr.header.stamp.sec + tr.header.stamp.nanosec * 1e-9
                    latest[child] = max(latest.get(child, 0.0), stamp)
        for child, ps in sorted(parents.items()):
            if len(ps) > 1:
                out.append('frame {} has {} parents ({}): two publishers disagree; keep one '
                           "(the bridge's publish_tf / publish_robot_state, the EKF's "
                           'publish_tf, robot_state_publisher)'.format(
                               child, len(ps), ', '.join(sorted(ps))))
        static_pubs = sorted({e.node for e in eps if e.topic == '/tf_static' and e.kind == 'pub'})
        if len(static_pubs) > 1:
            for child, n in sorted(static_samples.items()):
                if n > 1:
                    out.append('frame {} is published on /tf_static by more than one of {}: '
                               "turn one off (robot_state_publisher:=true turns the bridge's "
                               'publish_robot_state off)'.format(child, ', '.join(static_pubs)))
        frames = set(parents) | {p for ps in parents.values() for p in ps}
        roots = sorted(f for f in frames if f not in parents)
        if len(roots) > 1:
            out.append('the TF tree is split into {} trees with roots {}: a transform between '
                       'them is missing or published elsewhere (frame_prefix, a namespaced tf '
                       'topic, a node not running)'.format(len(roots), ', '.join(roots)))
        now = self.node.get_clock().now().nanoseconds * 1e-9
        for child, stamp in sorted(latest.items()):
            if now - stamp > STALE_TF_S:
                out.append('transform to {} is stamped {:.1f} s behind this clock: its '
                           'publisher is stalled or on another clock (use_sim_time, NTP)'
                           .format(child, now - stamp))
        return out

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

    def parameter_problems(self, timeout: float = 2.0) -> list[str]:
        """Return use_sim_time disagreements and a twist_mux without use_stamped."""
        from rcl_interfaces.msg import ParameterType
        from rcl_interfaces.srv import GetParameters
        me = self.node.get_fully_qualified_name()
        pending = {}
        for name, ns in self.node.get_node_names_and_namespaces():
            fqn = _fqn(ns, name)
            if fqn == me:
                continue
            cli = self.node.create_client(GetParameters, fqn + '/get_parameters')
            if not cli.wait_for_service(timeout_sec=timeout):
                self.node.destroy_client(cli)
                continue
            wanted = ['use_sim_time'] + (['use_stamped'] if 'twist_mux' in name else [])
            pending[fqn] = (cli, wanted, cli.call_async(GetParameters.Request(names=wanted)))
        end = time.monotonic() + timeout
        while time.monotonic() < end and not all(f.done() for _, _, f in pending.values()):
            rclpy.spin_once(self.node, timeout_sec=0.05)
        sim: dict[str, bool] = {}
        out = []
        for fqn, (cli, wanted, fut) in sorted(pending.items()):
            if fut.done() and fut.result() is not None:
                values = dict(zip(wanted, fut.result().values, strict=False))
                v = values.get('use_sim_time')
                if v is not None and v.type == ParameterType.PARAMETER_BOOL:
                    sim[fqn] = v.bool_value
                s = values.get('use_stamped')
                if 'use_stamped' in wanted and (s is None
                                                or s.type != ParameterType.PARAMETER_BOOL):
                    out.append('{} has no use_stamped parameter: twist_mux >= 4.4.0 aborts '
                               'without it and older ones mux Twist only; set use_stamped: '
                               'false (Twist, as Nav2 Jazzy and the bridge by default) or true '
                               '(TwistStamped) in its parameter file'.format(fqn))
            self.node.destroy_client(cli)
        if len(set(sim.values())) > 1:
            on = sorted(k for k, v in sim.items() if v)
            off = sorted(k for k, v in sim.items() if not v)
            few, many, state = (on, off, 'true') if len(on) <= len(off) else (off, on, 'false')
            out.append('use_sim_time is {} on {} but {} on {}: one clock for all nodes (set it '
                       'the same everywhere; with a simulator, true; with the robot, false)'
                       .format(state, ', '.join(few), 'false' if state == 'true' else 'true',
                               ', '.join(many)))
        return out

    def problems(self, duration: float) -> list[str]:
        """Return every problem of the live graph (one line each, with its fix)."""
        eps = self.endpoints()
        out = check(eps, unfed='m4k')
        if not any(e.m4k for e in eps):
            out.append('no m4k_bridge node in this graph (ROS_DOMAIN_ID, '
                       'ROS_AUTOMATIC_DISCOVERY_RANGE, the network): start the base or run '
                       'doctor where it can see it')
        self.listen(eps, duration)
        out += self.tf_problems(eps)
        out += self.rate_problems(eps)
        out += self.parameter_problems()
        return out + exposure.graph_problems()   # an open DDS graph (m4k_bridge.exposure)


def discover(node: Node, limit: float, settle: float = 2.0) -> None:
    """Spin until the graph (nodes, topics, endpoints) has not changed for settle seconds.

    Two seconds: on a loaded host DDS discovery announces participants more than a second
    apart, and a graph read in such a gap is missing the base (seen: "no m4k_bridge node").
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
        elif now[0] > 1 and time.monotonic() - changed >= settle:
            return


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
