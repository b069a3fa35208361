"""record: write ROS 2 topics to a rosbag2 MCAP directory that survives a crash.

``ros2 run m4k_bridge record [TOPIC ...] [-o DIR] [--duration S]`` (or ``python -m
m4k_bridge.bag.record``); ``record --recover DIR`` makes a crashed bag whole. Without topics
it records every m4k topic: the bridge's (``config/bridge.yaml`` names), ``tf``,
``tf_static``, ``joint_states``, ``robot_description`` and the planner's ``planner_state``. A
topic is subscribed as soon as the graph shows a publisher of it (so the recorder may start
before the robot), with the publisher's reliability and durability (``tf_static`` and
``robot_description`` are transient local, the sensors best effort), and its messages are
stored as received: serialized CDR, no decoding and re-encoding.

The file follows the MCAP ``ros2`` profile as rosbag2 (Jazzy) writes it: profile ``ros2``,
schemas ``ros2msg`` with the nested definitions (:mod:`m4k_bridge.bag.msgdef`), channels ``cdr``
with the ``offered_qos_profiles`` and ``topic_type_hash`` metadata, and a summary. It goes to
``DIR/<DIR name>_0.mcap`` with ``DIR/metadata.yaml`` (rosbag2 format 9,
:mod:`m4k_bridge.bag.metadata`): the directory is a bag that ``ros2 bag info DIR``, ``ros2 bag
play DIR`` and rosbags take as it is. DIR defaults to ``m4k_<UTC time>`` (``-2``, ``-3``, ...
appended if that exists); a DIR given with ``-o`` that exists is refused (exit 2): a recording
never overwrites another.

Crash safety (:mod:`m4k_bridge.bag.writer`): the bag is written as ``DIR.partial`` and renamed
to ``DIR`` when the recording ends, so a bag under the name asked for is always whole. Once a
second the messages so far are appended as an indexed chunk with a fresh footer behind them
(the old one retired, never overwritten; the summary comes with the last sync) and fsynced,
and metadata.yaml is replaced atomically to match, so after ``kill -9`` or a power cut
``DIR.partial`` is a complete bag of everything but the last second (``--recover DIR``
checks it, repairs a torn last write, indexes it, and renames it to ``DIR``). The bag records
the commit of the code that wrote it (``m4k.commit``). SIGINT / SIGTERM (or ``--duration``)
end the recording cleanly. Exit codes: 0 done,
1 the bag could not be created or a sync failed (e.g. disk full: the recording stops there,
what was synced stays readable), 2 bad arguments (an existing ``-o`` DIR among them).
"""

from __future__ import annotations

import argparse
import datetime
import os
import signal
import sys
import time
from typing import Any, Sequence

import rclpy
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from m4k_bridge import params as bridge_params
from m4k_bridge.bag.metadata import qos_entries
from m4k_bridge.bag.msgdef import message_definition, MsgDefError, split_type, type_hash
from m4k_bridge.bag.recover import recover
from m4k_bridge.bag.writer import BagError, BagExistsError, BagWriter, partial_directory
from m4k_bridge.interfaces import interface_class
from m4k_bridge.provenance import COMMIT_KEY, commit_text

__all__ = ['DEFAULT_TOPICS', 'Recorder', 'SYNC_PERIOD_S', 'main', 'qos_yaml']

# Everything the m4k stack publishes or takes (relative names: the recorder's namespace applies).
DEFAULT_TOPICS = tuple(bridge_params.spec('topics.' + role).default
                       for role in bridge_params.TOPIC_ROLES) + (
    '/tf', '/tf_static', 'joint_states', 'robot_description', 'planner_state')
_GRAPH_PERIOD_S = 0.5
_DEPTH = 100
# How much a crash may lose: the bag is synced (written, fsynced, metadata replaced) this often.
SYNC_PERIOD_S = 1.0


def qos_yaml(profiles: Sequence[Any]) -> str:
    """Return rosbag2's ``offered_qos_profiles`` YAML for the publishers' QoS profiles."""
    out = []
    for q in profiles:
        out.append(
            '- history: {}\n  depth: {}\n  reliability: {}\n  durability: {}\n'
            '  deadline:\n    sec: {}\n    nsec: {}\n  lifespan:\n    sec: {}\n    nsec: {}\n'
            '  liveliness: {}\n  liveliness_lease_duration:\n    sec: {}\n    nsec: {}\n'
            '  avoid_ros_namespace_conventions: {}'.format(
                int(q.history), q.depth, int(q.reliability), int(q.durability),
                *_sec_nsec(q.deadline), *_sec_nsec(q.lifespan), int(q.liveliness),
                *_sec_nsec(q.liveliness_lease_duration),
                'true' if q.avoid_ros_namespace_conventions else 'false'))
    return '\n'.join(out) + '\n' if out else '[]'


def _sec_nsec(duration: Any) -> tuple[int, int]:
    ns = int(duration.nanoseconds)
    return ns // 1_000_000_000, ns % 1_000_000_000


def _message_class(type_name: str) -> Any:
    package, name = split_type(type_name)       # MsgDefError for a name that is no message
    return interface_class('{}/msg/{}'.format(package, name))


def _subscription_qos(profiles: Sequence[Any]) -> QoSProfile:
    # Like rosbag2: reliable only when every publisher offers it (a reliable subscription
    # does not match a best-effort publisher), transient local only when every one offers it.
    reliable = bool(profiles) and all(
        q.reliability == ReliabilityPolicy.RELIABLE for q in profiles)
    latched = bool(profiles) and all(
        q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in profiles)
    return QoSProfile(
        depth=_DEPTH,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=(DurabilityPolicy.TRANSIENT_LOCAL if latched
                    else DurabilityPolicy.VOLATILE))


class Recorder:
    """Subscribe to topics as they appear and write their serialized messages to a bag."""

    def __init__(self, node: Any, directory: str, topics: Sequence[str],
                 sync_period: float = SYNC_PERIOD_S) -> None:
        """Create the bag ``directory`` (:class:`BagExistsError` if it exists) and subscribe."""
        self.node = node
        self.topics = [node.resolve_topic_name(t) for t in topics]
        self.bag = BagWriter(directory, library='m4k_bridge record',
                             custom_data={COMMIT_KEY: commit_text()})
        self.path = self.bag.path
        self._channels: dict[str, int] = {}
        self.counts: dict[str, int] = {}
        self.skipped: dict[str, str] = {}
        self._subs: list[Any] = []
        self._finished = False
        self.poll_graph()
        self._timer = node.create_timer(_GRAPH_PERIOD_S, self.poll_graph)
        self.error: BagError | None = None
        self._sync_timer = node.create_timer(sync_period, self._sync)

    def poll_graph(self) -> None:
        """Subscribe to every wanted topic that now has a publisher of a known type."""
        types = dict(self.node.get_topic_names_and_types())
        for topic in self.topics:
            if topic in self._channels or topic in self.skipped or topic not in types:
                continue
            infos = self.node.get_publishers_info_by_topic(topic)
            if not infos:
                continue
            type_name = types[topic][0]
            try:
                self._subscribe(topic, type_name, infos)
            except (MsgDefError, ImportError, AttributeError, ValueError) as exc:
                self.skipped[topic] = str(exc)
                self.node.get_logger().warning('not recording {}: {}'.format(topic, exc))

    def _subscribe(self, topic: str, type_name: str, infos: Sequence[Any]) -> None:
        msg_type = _message_class(type_name)
        profiles = [i.qos_profile for i in infos]
        hashes = {str(i.topic_type_hash) for i in infos}
        digest = hashes.pop() if len(hashes) == 1 else type_hash(type_name)
        digest = digest if digest.startswith('RIHS') else ''
        self._channels[topic] = self.bag.add_topic(
            topic, type_name, message_definition(type_name), digest, qos_entries(profiles),
            qos_yaml(profiles))
        self.counts[topic] = 0
        self._subs.append(self.node.create_subscription(
            msg_type, topic, lambda data, t=topic: self._write(t, data),
            _subscription_qos(profiles), raw=True))
        self.node.get_logger().info('recording {} ({})'.format(topic, type_name))

    def _sync(self) -> None:
        try:
            self.bag.sync()
        except BagError as exc:         # e.g. disk full: stop, say why (main exits 1)
            self.error = exc
            self._finished = True

    def _write(self, topic: str, data: bytes) -> None:
        if self._finished:
            return
        seq = self.counts[topic]
        self.bag.write(self._channels[topic], time.time_ns(), data, seq)
        self.counts[topic] = seq + 1

    def finish(self) -> None:
        """Write what is buffered and close the bag (idempotent; a failed sync is kept)."""
        if self._timer.is_canceled():
            return
        self._finished = True
        self._timer.cancel()
        self._sync_timer.cancel()
        try:
            self.bag.close()
        except BagError as exc:
            self.error = self.error or exc


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='record', description=__doc__.split('\n\n')[0])
    ap.add_argument('topics', nargs='*', help='topics to record (default: every m4k topic)')
    ap.add_argument('-o', '--output',
                    help='output directory; must not exist (default: m4k_<UTC time>)')
    ap.add_argument('--duration', type=float, default=0.0,
                    help='stop after this many seconds (default: until SIGINT/SIGTERM)')
    ap.add_argument('--recover', metavar='DIR',
                    help='make the crashed bag DIR (left as DIR.partial) whole (MCAP index and '
                         'summary, metadata.yaml), name it DIR and exit')
    return ap


def default_output(now: datetime.datetime | None = None) -> str:
    """Return ``m4k_<UTC time>``, with ``-2``, ``-3``, ... appended while that name exists."""
    base = 'm4k_' + (now or datetime.datetime.now(datetime.timezone.utc)).strftime(
        '%Y_%m_%d-%H_%M_%S')
    name, n = base, 1
    while os.path.lexists(name) or os.path.lexists(partial_directory(name)):
        n += 1
        name = '{}-{}'.format(base, n)
    return name


def _recover(directory: str) -> int:
    try:
        r = recover(directory)
    except (BagError, OSError) as exc:
        print('record: cannot recover {!r}: {}'.format(directory, exc), file=sys.stderr)
        return 1
    state = 'complete' if r.complete else 'cut short ({} bytes of a torn record dropped)'.format(
        r.dropped_bytes)
    print('record: {}: MCAP {}; {} messages ({}); {}'.format(
        r.directory, state, r.messages, ', '.join('{} {}'.format(t, n)
                                                 for t, n in sorted(r.counts.items())),
        'rewritten' if r.rewritten else 'metadata already matches, nothing to do'),
        file=sys.stderr)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Record until SIGINT/SIGTERM or ``--duration``; return the exit code."""
    args_all = list(sys.argv if argv is None else ['record', *argv])
    ros_args = rclpy.utilities.remove_ros_args(args_all)[1:]
    args = _parser().parse_args(ros_args)
    if args.recover:
        return _recover(args.recover)
    if not args.duration >= 0.0:
        print('record: --duration must be >= 0, got {!r}'.format(args.duration),
              file=sys.stderr)
        return 2
    out_dir = args.output or default_output()
    for taken in (out_dir, partial_directory(out_dir)):
        if os.path.lexists(taken):
            print('record: output directory {!r} exists: a recording never overwrites one '
                  '(choose another -o, or omit -o for a new m4k_<UTC time>; a crashed bag is '
                  'made whole with --recover)'.format(taken), file=sys.stderr)
            return 2
    stop = []
    previous = {sig: signal.signal(sig, lambda signum, frame: stop.append(signum))
                for sig in (signal.SIGINT, signal.SIGTERM)}
    rclpy.init(args=args_all, signal_handler_options=SignalHandlerOptions.NO)
    node = rec = None
    try:
        node = rclpy.create_node('m4k_record')
        try:
            rec = Recorder(node, out_dir, args.topics or DEFAULT_TOPICS)
        except BagExistsError as exc:
            print('record: {}'.format(exc), file=sys.stderr)
            return 2
        except BagError as exc:
            print('record: {}'.format(exc), file=sys.stderr)
            return 1
        node.get_logger().info('writing {}'.format(rec.path))
        end = time.monotonic() + args.duration if args.duration else None
        while not stop and rec.error is None and (end is None or time.monotonic() < end):
            rclpy.spin_once(node, timeout_sec=0.1)
    finally:
        if rec is not None:
            rec.finish()
            total = sum(rec.counts.values())
            print('record: {} messages on {} topics -> {}'.format(
                total, len(rec.counts), rec.bag.path), file=sys.stderr)
            if rec.error is not None:
                print('record: stopped: {}'.format(rec.error), file=sys.stderr)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 1 if rec is not None and rec.error is not None else 0


if __name__ == '__main__':
    sys.exit(main())
