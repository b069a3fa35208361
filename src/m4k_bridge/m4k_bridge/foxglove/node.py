"""foxglove: serve the robot's ROS graph to Foxglove over the WebSocket protocol (v1).

``ros2 run m4k_bridge foxglove [--ros-args -p port:=8765 -p address:=127.0.0.1]`` (node
``m4k_foxglove``; ``bringup --foxglove``, ``ros2 launch m4k_bringup m4k.launch.py
foxglove:=true``). Every topic of the graph that matches ``topic_whitelist`` is subscribed
as soon as it has a publisher, with the publishers' QoS (reliable only when every publisher
is, transient local only when every one is: sensors best effort, ``tf_static`` and
``robot_description`` latched), and served as a ``cdr`` channel with the ``ros2msg`` schema
the MCAP recorder writes (:mod:`m4k_bridge.bag.msgdef`): serialized CDR as received, never
decoded. The last messages of latched topics are kept and sent to a client when it
subscribes, so a late joiner gets the TF tree and the URDF.

Capabilities: ``clientPublish`` (CDR) on the topics of ``client_topics`` only (default the
bridge's inputs ``cmd_vel``, ``e_stop``, ``led``): Foxglove's teleop panel drives the robot;
when the driving client's Twist channel goes away (unadvertised, disconnected) one zero Twist
follows, so the robot does not coast on the last command until the command timeout.
``parameters`` (read-only): the parameters of the bridge node (``bridge_node``) and this
node, named ``<node>.<parameter>``. ``services``: the services matching ``service_whitelist``
(default the bridge's own; :mod:`.services`).

Rights (:mod:`.rights`): each client has view, drive or safety, from the token it presents
(``rights``, ``drive_token_file``, ``safety_token_file``). A view client is offered neither
``clientPublish`` nor ``services``. Motion (cmd_vel, led, goals) is published for one driver
at a time (``driver_idle_timeout``), each client channel is rate limited
(``max_publish_rate``), and an ``e_stop`` true is published at once from the server thread on
the node's own e-stop publisher: never behind the request queue, never limited, never
dropped. ``e_stop`` false needs safety.

Security: the protocol has no authentication: anyone who reaches the port sees the robot and,
with ``clientPublish``, drives it. The server therefore listens on 127.0.0.1 by default; reach
it with an SSH tunnel (``ssh -L 8765:localhost:8765 robot``). Web pages in the operator's
browser can reach that tunnel too: the handshake's ``Origin`` must be on ``allowed_origins``
(the Foxglove and Lichtblick apps and localhost pages by default) or it gets HTTP 403 before
anything is served. ``address:=0.0.0.0`` serves the LAN -- with ``token_file`` (clients add
``?token=...`` to the URL) and behind a firewall that admits the operators' machines.
``max_clients`` and ``max_client_channels`` bound what clients can make the node allocate.
Parameters: :data:`m4k_bridge.foxglove.params.SPECS` (all read-only).

Diagnostics (``m4k_foxglove: server`` on ``diagnostics``, each ``diagnostics_period``):
clients, messages sent and dropped (each client's data queue is bounded by
``max_queue_messages`` and ``max_queue_bytes``; the oldest frame is dropped and counted when a
client reads slower than the data comes), WARN while a client is dropping.
"""

from __future__ import annotations

import collections
import os
import re
import sys
import threading
import time
from typing import Any, Callable, Sequence

from diagnostic_msgs.msg import DiagnosticArray
import rclpy
from rclpy.duration import Duration
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.parameter import parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from std_msgs.msg import Bool

from m4k_bridge.bag.msgdef import message_definition, MsgDefError
from m4k_bridge.descriptors import descriptor
from m4k_bridge.diagnostics import make_status
from m4k_bridge.foxglove import params as fparams
from m4k_bridge.foxglove import protocol as fp
from m4k_bridge.foxglove.access import (
    AccessError,
    Credentials,
    OriginPolicy,
    read_token_file,
    tls_context,
)
from m4k_bridge.foxglove.rights import at_least, DriverLock, TokenBucket
from m4k_bridge.foxglove.server import Server
from m4k_bridge.foxglove.services import ServiceSide
from m4k_bridge.foxglove.writes import ClientWrites
from m4k_bridge.interfaces import interface_class
from m4k_bridge.safety import E_STOP_QOS
from m4k_bridge.shutdown import spin_until_shutdown, stop_aware_start
from m4k_rt import yamlload
from m4k_rt.stopsignals import StopSignals

__all__ = ['FoxgloveNode', 'descriptor', 'main', 'subscription_qos']

NODE_NAME = fparams.NODE_NAME
# A client's type name, checked before anything is imported by it.
_TYPE_NAME = re.compile(r'[A-Za-z][A-Za-z0-9_]*/msg/[A-Za-z][A-Za-z0-9_]*')
_TOPIC_NAME = re.compile(r'~?/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*')
_ACTIONS_MAX = 1000          # client requests waiting for the ROS thread
_BOOL = 'std_msgs/msg/Bool'
_TWISTS = ('geometry_msgs/msg/Twist', 'geometry_msgs/msg/TwistStamped')
# A publisher destroyed right after its last message can take that message with it: a reliable
# writer's unacknowledged samples die with the writer (ros2cli's `topic pub` keeps its node
# alive 0.1 s after the last message for the same reason). A dropped client's publisher is
# therefore kept until every reader acknowledged the zero Twist, or this long at most.
_RETIRE_S = 5.0


def subscription_qos(profiles: Sequence[Any]) -> QoSProfile:
    """Return the QoS to subscribe with, from the publishers' (as rosbag2 does).

    Reliable only when every publisher offers it (a reliable reader does not match a
    best-effort writer); transient local only when every one offers it.
    """
    reliable = bool(profiles) and all(
        q.reliability == ReliabilityPolicy.RELIABLE for q in profiles)
    latched = bool(profiles) and all(
        q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in profiles)
    return QoSProfile(
        depth=10 if latched else 20,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


def full_type(name: str, kind: str = 'msg') -> str:
    """Return ``pkg/<kind>/Name`` for ``pkg/Name`` or ``pkg/<kind>/Name``."""
    parts = name.split('/')
    if len(parts) == 2:
        return '{}/{}/{}'.format(parts[0], kind, parts[1])
    if len(parts) == 3 and parts[1] == kind:
        return name
    raise ValueError('not a {} type name: {!r}'.format(kind, name))


class FoxgloveNode(ClientWrites, ServiceSide, Node):
    """The rclpy side: graph discovery, subscriptions, client publishers, services."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        p = fparams.validate({s.name: self.declare_parameter(s.name, s.default,
                                                             descriptor(s)).value
                              for s in fparams.SPECS})
        self.address = str(p['address'])
        self.topic_whitelist = [re.compile(x) for x in p['topic_whitelist']]
        self.service_whitelist = [re.compile(x) for x in p['service_whitelist']]
        self.client_topics = {self.resolve_topic_name(t) for t in p['client_topics']}
        self.nav_goals = bool(p['nav_goals'])
        self._nav_topics = {self.resolve_topic_name(t): tname
                            for t, tname in fparams.NAV_TOPICS.items()}
        tokens = {k: read_token_file(p[k]) if p[k] else None
                  for k in ('token_file', 'drive_token_file', 'safety_token_file')}
        credentials = Credentials(p['rights'], tokens['token_file'],
                                  tokens['drive_token_file'], tokens['safety_token_file'])
        token = tokens['token_file']
        tls = tls_context(p['tls_cert_file'], p['tls_key_file'])
        self.service_timeout = float(p['service_timeout'])
        self.max_publish_rate = float(p['max_publish_rate'])
        self.max_service_rate = float(p['max_service_rate'])
        self.lock = DriverLock(float(p['driver_idle_timeout']))
        self._buckets: dict[tuple[int, int], TokenBucket] = {}
        self._lock_refused: set[tuple[int, int]] = set()
        self.refused_rights = 0
        self.throttled = 0
        self.e_stop_engages = 0
        self._estop_keys: set[tuple[int, int]] = set()
        self._estop_topic = self.resolve_topic_name('e_stop')
        # The engage path of every client: made now, so an engage never waits for one.
        self._estop_pub = self.create_publisher(Bool, self._estop_topic, E_STOP_QOS)
        bridge = str(p['bridge_node'])
        self._bridge_fqn = bridge if bridge.startswith('/') else '{}/{}'.format(
            self.get_namespace().rstrip('/'), bridge)
        self._init_services()
        graph_period = float(p['graph_period'])
        diag_period = float(p['diagnostics_period'])
        self._inert: set[tuple[int, int]] = set()    # nav channels while nav_goals is false
        self.inert_messages = 0
        self._subs: dict[str, tuple[int, Any, str]] = {}   # topic -> (channel, sub, type)
        self._skipped: set[str] = set()
        self._pubs: dict[tuple[int, int], tuple[Any, Any, str]] = {}
        self._retiring: list[tuple[float, Any]] = []    # (monotonic deadline, publisher)
        self._actions: collections.deque[Callable[[], None]] = collections.deque()
        self._actions_lock = threading.Lock()
        self.actions_dropped = 0
        self.bad_client_messages = 0
        self._last_dropped = 0
        self._bridge_params = AsyncParameterClient(self, str(p['bridge_node']))
        self._wake = self.create_guard_condition(self._run_actions)
        self._diag_pub = self.create_publisher(DiagnosticArray, 'diagnostics', 10)
        self.server = Server(self, self.address, int(p['port']),
                             name='m4k ' + self.get_fully_qualified_name(),
                             capabilities=('clientPublish', 'parameters', 'services'),
                             encodings=('cdr',), max_queue_messages=p['max_queue_messages'],
                             max_queue_bytes=p['max_queue_bytes'],
                             origins=OriginPolicy(p['allowed_origins']),
                             credentials=credentials, tls=tls,
                             max_clients=p['max_clients'],
                             max_client_channels=p['max_client_channels'],
                             # As foxglove_bridge: the apps then take the source as ROS 2
                             # (their publish tools use ROS 2 type names and definitions).
                             metadata={'ROS_DISTRO': os.environ.get('ROS_DISTRO') or 'jazzy'})
        self.server.start()
        local = self.address in ('127.0.0.1', 'localhost', '::1')
        self.get_logger().info('Foxglove WebSocket server on {}://{}:{} ({}; {})'.format(
            'wss' if tls else 'ws', self.address, self.server.port,
            'localhost only; use an SSH tunnel' if local else 'serving the network',
            'token required' if token else (
                'no token' if local else 'NO TOKEN: anyone on this network can drive the '
                'robot')))
        self.poll_graph()
        self.create_timer(graph_period, self.poll_graph)
        self.create_timer(diag_period, self.publish_diagnostics)
        self.create_timer(0.1, self._tick)

    def destroy_node(self) -> None:
        """Stop the server (closing every connection), then the node.

        The connections' last requests still run here -- the zero Twist of every client that
        was driving -- and the node waits (bounded) for its readers to acknowledge it.
        """
        self.server.stop()
        self._run_actions()
        for _, pub in self._retiring:
            pub.wait_for_all_acked(Duration(seconds=0.5))
        self._retiring.clear()
        super().destroy_node()

    # --- graph -> channels -------------------------------------------------------------------
    def poll_graph(self) -> None:
        """Serve new topics and services of the graph; unadvertise topics that have gone."""
        types = dict(self.get_topic_names_and_types())
        for topic in list(self._subs):
            if topic not in types:
                channel, sub, _ = self._subs.pop(topic)
                self.destroy_subscription(sub)
                self.server.remove_channel(channel)
        for topic, names in types.items():
            if topic in self._subs or topic in self._skipped or not names:
                continue
            if not any(p.fullmatch(topic) for p in self.topic_whitelist):
                continue
            infos = self.get_publishers_info_by_topic(topic)
            if infos:
                self._serve_topic(topic, names[0], [i.qos_profile for i in infos])
        self._poll_services()

    def _serve_topic(self, topic: str, type_name: str, profiles: list[Any]) -> None:
        try:
            cls = interface_class(full_type(type_name))
            schema = message_definition(type_name)
        except (MsgDefError, ImportError, AttributeError, ValueError) as exc:
            self._skipped.add(topic)
            self.get_logger().warning('not serving {}: {}'.format(topic, exc))
            return
        qos = subscription_qos(profiles)
        latched = qos.durability == DurabilityPolicy.TRANSIENT_LOCAL
        channel = self.server.add_channel(topic, full_type(type_name), schema)

        def forward(data: bytes) -> None:
            self.server.publish(channel, data, latched=latched)

        sub = self.create_subscription(cls, topic, forward, qos, raw=True)
        self._subs[topic] = (channel, sub, full_type(type_name))

    # --- what clients send (server thread -> ROS thread) -------------------------------------
    def _post(self, action: Callable[[], None], critical: bool = False, front: bool = False,
              client: int | None = None) -> None:
        # ``critical``: never dropped for the bound (a client's channel going away: its zero
        # Twist; an e-stop engage call); one per channel or engage, so the queue stays bounded.
        # ``front``: ahead of everything queued (an e-stop engage call).
        with self._actions_lock:
            full = len(self._actions) >= _ACTIONS_MAX and not critical
            if full:
                self.actions_dropped += 1
            elif front:
                self._actions.appendleft(action)
            else:
                self._actions.append(action)
        if full:
            if client is not None:
                self.server.send_text(client, fp.status(1, (
                    'request dropped: {} requests of all clients wait for the ROS side'
                    .format(_ACTIONS_MAX))))
            return
        self._wake.trigger()

    def _run_actions(self) -> None:
        while True:
            with self._actions_lock:
                if not self._actions:
                    return
                action = self._actions.popleft()
            action()

    def on_client_advertise(self, client: int, channel: dict[str, Any]) -> str | None:
        """Accept a CDR channel on an allowed topic; the publisher is made on the ROS thread.

        The topic is checked against ``client_topics`` (and the 3D panel's nav topics) first,
        then the type name's form and the graph's type: a client's type is imported only for
        a topic it may publish on.
        """
        name = channel.get('topic')
        if not at_least(self.server.client_right(client) or 'view', 'drive'):
            self.refused_rights += 1
            return '{}: publishing needs the drive right'.format(name)
        if not isinstance(name, str) or not _TOPIC_NAME.fullmatch(name):
            return '{!r}: not a valid topic name'.format(name)
        topic = self.resolve_topic_name(name)
        nav = self._nav_topics.get(topic)
        if topic not in self.client_topics and nav is None:
            return '{}: clients may publish only on {}'.format(
                topic, ', '.join(sorted(self.client_topics)) or 'nothing (view only)')
        try:
            tname = full_type(str(channel['schemaName']))
        except (KeyError, ValueError) as exc:
            return '{}: cannot publish: {}'.format(topic, exc)
        if not _TYPE_NAME.fullmatch(tname):
            return '{}: {!r} is not a message type name'.format(topic, tname)
        key = (client, int(channel['id']))
        if nav is not None and topic not in self.client_topics:
            if tname != nav:
                return '{}: expects {}, not {}'.format(topic, nav, tname)
            if not self.nav_goals:
                self._inert.add(key)      # the 3D panel advertises it on every layout load
                return None
        if topic == self._estop_topic:
            if tname != _BOOL:
                return '{}: the e-stop is {}, not {}'.format(topic, _BOOL, tname)
            self._estop_keys.add(key)
        graph = dict(self.get_topic_names_and_types()).get(topic, [])
        if graph and tname not in graph:
            return '{}: the graph has it as {}, not {}'.format(topic, graph[0], tname)
        try:
            cls = interface_class(tname)
        except (ImportError, AttributeError, ValueError) as exc:
            return '{}: cannot publish {}: {}'.format(topic, tname, exc)
        self._post(lambda: self._make_publisher(key, topic, cls, tname))
        return None

    def _make_publisher(self, key: tuple[int, int], topic: str, cls: Any, tname: str) -> None:
        # Reliable matches every reader; transient local only when a reader asks for it.
        latched = any(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
                      for i in self.get_subscriptions_info_by_topic(topic))
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL if latched
                         else DurabilityPolicy.VOLATILE)
        self._pubs[key] = (self.create_publisher(cls, topic, qos), cls, tname)
        self.get_logger().info('client {} publishes {} on {}'.format(key[0], tname, topic))

    def on_client_unadvertise(self, client: int, channel_id: int) -> None:
        """Destroy the client's publisher (after one zero Twist if it was driving)."""
        key = (client, channel_id)
        self._inert.discard(key)
        self._estop_keys.discard(key)
        self._buckets.pop(key, None)
        self._lock_refused.discard(key)
        # Only the driver's going away stops the robot: another client's would stop the
        # robot someone else drives.
        driver = self.lock.owner == client
        self._post(lambda: self._drop_publisher(key, driver), critical=True)

    def on_client_gone(self, client: int) -> None:
        """Free the driver lock if the client held it."""
        self._forget_client_calls(client)
        if self.lock.release(client):
            self.server.broadcast_status(0, 'nobody drives now (the driver left)')

    def _drop_publisher(self, key: tuple[int, int], driver: bool = True) -> None:
        entry = self._pubs.pop(key, None)
        if entry is None:
            return
        pub, cls, tname = entry
        if tname not in _TWISTS or not driver:
            self.destroy_publisher(pub)
            return
        pub.publish(cls())          # zero velocity: the robot stops with its client
        self._retiring.append((time.monotonic() + _RETIRE_S, pub))

    def _tick(self) -> None:
        """Fail service calls past their timeout; retire dropped clients' publishers."""
        self._expire_calls(time.monotonic())
        self._retire()

    def _retire(self) -> None:
        """Destroy dropped clients' publishers once their zero Twist is acknowledged."""
        if not self._retiring:
            return
        now = time.monotonic()
        keep = []
        for deadline, pub in self._retiring:
            if now < deadline and not pub.wait_for_all_acked(Duration(seconds=0)):
                keep.append((deadline, pub))
            else:
                self.destroy_publisher(pub)
        self._retiring = keep

    def _publish(self, key: tuple[int, int], payload: bytes) -> None:
        entry = self._pubs.get(key)
        if entry is None:
            return
        pub, cls, tname = entry
        try:
            msg = deserialize_message(payload, cls)
        except Exception as exc:  # noqa: BLE001 -- rclpy raises a private error type
            self.bad_client_messages += 1
            self.server.send_text(key[0], fp.status(2, 'not a CDR {}: {}'.format(tname, exc)))
            return
        pub.publish(msg)

    def on_get_parameters(self, client: int, names: list[str], request_id: str | None) -> None:
        """Reply with the bridge's and this node's parameters (``names`` empty: all)."""
        self._post(lambda: self._get_parameters(client, names, request_id))

    def _get_parameters(self, client: int, names: list[str], request_id: str | None) -> None:
        own = [('{}.{}'.format(self.get_fully_qualified_name(), n), self.get_parameter(n).value)
               for n in sorted(self.list_parameters([], 0).names)]
        bridge = self._bridge_params.remote_node_name
        prefix = bridge if bridge.startswith('/') else '{}/{}'.format(
            self.get_namespace().rstrip('/'), bridge)

        def reply(values: list[tuple[str, Any]]) -> None:
            out = [(n, v) for n, v in own + values if not names or n in names]
            self.server.send_text(client, fp.parameter_values(out, request_id))

        if not self._bridge_params.services_are_ready():
            reply([])
            return

        def got_list(fut: Any) -> None:
            listed = sorted(fut.result().result.names) if fut.result() else []
            if not listed:
                reply([])
                return

            def got_values(fut2: Any) -> None:
                res = fut2.result()
                vals = [parameter_value_to_python(v) for v in res.values] if res else []
                reply([('{}.{}'.format(prefix, n), v) for n, v in zip(listed, vals, strict=False)])

            self._bridge_params.get_parameters(listed).add_done_callback(got_values)

        self._bridge_params.list_parameters().add_done_callback(got_list)

    # --- diagnostics -------------------------------------------------------------------------
    def publish_diagnostics(self) -> None:
        """Publish the server's status: clients, sent, queued and dropped messages."""
        stats = self.server.stats()
        dropped = self.server.dropped_departed + sum(s.dropped for s in stats)
        values: dict[str, Any] = {
            'address': '{}:{}'.format(self.address, self.server.port), 'clients': len(stats),
            'clients_total': self.server.clients_total, 'channels': len(self._subs),
            'dropped_total': dropped, 'client_requests_dropped': self.actions_dropped,
            'bad_client_messages': self.bad_client_messages,
            'refused_origin': self.server.refused['origin'],
            'refused_token': self.server.refused['token'],
            'refused_max_clients': self.server.refused['clients'],
            'nav_messages_not_published': self.inert_messages,
            'driver': self.lock.owner_name or 'nobody', 'driver_changes': self.lock.changes,
            'refused_rights': self.refused_rights, 'throttled_messages': self.throttled,
            'refused_calls': self.calls_refused, 'service_timeouts': self.service_timeouts,
            'e_stop_engages': self.e_stop_engages,
            'max_queue_messages': self.server.max_queue_messages,
            'max_queue_bytes': self.server.max_queue_bytes}
        for s in stats:
            values['client {} ({})'.format(s.id, s.address)] = (
                'right {} subscriptions {} sent {} dropped {} queued {} ({} bytes)'.format(
                    s.right, s.subscriptions, s.sent, s.dropped, s.queued, s.queued_bytes))
        dropping = dropped > self._last_dropped
        self._last_dropped = dropped
        msg = '{} client(s){}'.format(len(stats), '; a client reads slower than the data '
                                      'comes: dropping' if dropping else '')
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [make_status('m4k_foxglove: server', 1 if dropping else 0, msg, values,
                                  hardware_id='m4k_foxglove')]
        self._diag_pub.publish(arr)


def _check_param_files(argv: Sequence[str]) -> None:
    for i, a in enumerate(argv[:-1]):
        if a == '--params-file':
            path = argv[i + 1]
            with open(path, encoding='utf-8') as f:
                try:
                    doc = yamlload.load(f)
                except yamlload.yaml.YAMLError as exc:
                    raise ValueError('{}: {}'.format(path, str(exc).replace('\n', ' '))) \
                        from None
            fparams.check_param_file(doc, path)


def main(args: Sequence[str] | None = None) -> int:
    """Run the Foxglove server node until SIGINT/SIGTERM; exit code 1 if it cannot listen."""
    stop = StopSignals().install()
    argv = list(sys.argv if args is None else args)
    try:
        _check_param_files(argv)
    except (OSError, ValueError) as exc:   # unreadable, not YAML, duplicate or unknown key
        sys.stderr.write('{}: {}\n'.format(NODE_NAME, exc))
        stop.restore()
        return 2
    rclpy.init(args=argv)
    node = None
    try:
        try:
            if not stop.stopping:
                node = stop_aware_start(FoxgloveNode, stop)
        except OSError as exc:
            sys.stderr.write('{}: cannot listen: {}\n'.format(NODE_NAME, exc))
            return 1
        except (AccessError, ParameterException, ValueError) as exc:
            sys.stderr.write('{}: {}\n'.format(NODE_NAME, exc))
            return 2
        if node is not None and not stop.stopping:
            spin_until_shutdown(lambda: rclpy.spin(node), node.context)
    except KeyboardInterrupt:
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        stop.restore()
    return 0


if __name__ == '__main__':
    sys.exit(main())
