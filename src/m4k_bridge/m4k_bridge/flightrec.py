"""The flight recorder's parts that need no ROS: the bounded ring, the triggers, the dumps.

A flight recorder keeps the last seconds of what the robot was told and did, always, and
writes them to a bag when something goes wrong, so the question after an incident -- what
happened in the ten seconds before the robot stopped -- has an answer on disk. The ROS side
(:mod:`m4k_bridge.flightrec_ros`) feeds this module serialized messages and decoded RT
datagrams; this module decides and writes.

* :class:`Ring`: serialized messages ``(time, key, bytes)``, bounded twice: by age (``span``)
  and by bytes (``max_bytes``, counting each entry as its payload plus
  :data:`ENTRY_OVERHEAD` bytes). The byte bound is an invariant, checked on every add: the
  oldest entries go first, an entry larger than the whole cap is refused and counted.
* :class:`Triggers`: the rising edges that dump -- the e-stop latch engaging or the contact
  opening (``e_stop``), the collision guard stopping forward motion (``guard_stop``; its flag
  rising while the robot stands -- the fail-safe hold while a sensor has not reported yet at
  start-up, or an obstacle stepping into the zone of a robot at rest -- stopped nothing), the wheel
  supervisor's latched fault (``motor_fault``), a task cycle ending after its deadline
  (``deadline_miss``), a device entering ERROR (``device_fault``).
* :class:`RateLimit`: at most one dump per trigger kind per ``min_interval``.
* :class:`Dumper`: a background thread that waits ``post`` seconds after a trigger (so the
  stop itself is in the bag), copies the ring's window and writes it with the recorder's
  crash-safe writer (:class:`m4k_bridge.bag.writer.BagWriter`) as a rosbag2 MCAP directory
  whose ``metadata.yaml`` ``custom_data`` names the trigger. The bridge's callbacks only
  append to the ring and put a trigger on a queue: they never wait for a disk. After each dump
  (and at start) the directory is pruned to its disk cap and age limit
  (:func:`m4k_bridge.flightrec_store.prune`); a failed dump is counted and its reason kept
  (``failed``, ``last_error``) for the recorder's diagnostic.
"""

from __future__ import annotations

import collections
import dataclasses
import datetime
import os
import queue
import threading
import time
from typing import Any, Callable, Iterable, Mapping, Sequence

from m4k_bridge.bag.msgdef import message_definition, MsgDefError, type_hash
from m4k_bridge.bag.writer import BagError, BagWriter, partial_directory
from m4k_bridge.flightrec_store import prune, stamp, unused_path
from m4k_rt import protocol, timing

__all__ = ['ENTRY_OVERHEAD', 'KINDS', 'Dumper', 'RateLimit', 'Ring', 'TopicSpec', 'Trigger',
           'Triggers', 'default_directory']

# Bytes counted per ring entry beyond its payload: the tuple, the int, the bytes object's
# header and the deque slot in CPython 3.11 (about 56 + 32 + 33 + 8), rounded up.
ENTRY_OVERHEAD = 160
KINDS = ('e_stop', 'guard_stop', 'motor_fault', 'deadline_miss', 'device_fault')
_NS = 1_000_000_000


def default_directory(environ: Mapping[str, str] = os.environ) -> str:
    """Return where dumps go when no directory is configured: the XDG state directory."""
    base = environ.get('XDG_STATE_HOME') or os.path.join(
        environ.get('HOME') or os.path.expanduser('~'), '.local', 'state')
    return os.path.join(base, 'm4k', 'flight_recorder')


class Ring:
    """The last ``span_s`` seconds of serialized messages, never more than ``max_bytes``."""

    def __init__(self, span_s: float, max_bytes: int) -> None:
        if not span_s > 0 or max_bytes <= ENTRY_OVERHEAD:
            raise ValueError('ring needs span_s > 0 and max_bytes > {}, got {!r}, {!r}'.format(
                ENTRY_OVERHEAD, span_s, max_bytes))
        self.span_ns = int(span_s * _NS)
        self.max_bytes = int(max_bytes)
        self._q: collections.deque[tuple[int, str, bytes]] = collections.deque()
        self._lock = threading.Lock()
        self.bytes = 0
        self.peak_bytes = 0
        self.evicted_age = 0
        self.evicted_bytes = 0      # entries pushed out by the byte cap before their age
        self.refused = 0            # entries larger than the whole cap

    def __len__(self) -> int:
        return len(self._q)

    def add(self, t_ns: int, key: str, data: bytes) -> bool:
        """Append one message (time ns since the epoch); False when it alone exceeds the cap."""
        size = len(data) + ENTRY_OVERHEAD
        if size > self.max_bytes:
            self.refused += 1
            return False
        with self._lock:
            q = self._q
            horizon = t_ns - self.span_ns
            while q and q[0][0] < horizon:
                self.bytes -= len(q.popleft()[2]) + ENTRY_OVERHEAD
                self.evicted_age += 1
            while q and self.bytes + size > self.max_bytes:
                self.bytes -= len(q.popleft()[2]) + ENTRY_OVERHEAD
                self.evicted_bytes += 1
            q.append((t_ns, key, data))
            self.bytes += size
            if self.bytes > self.peak_bytes:
                self.peak_bytes = self.bytes
        return True

    def snapshot(self, since_ns: int = 0) -> list[tuple[int, str, bytes]]:
        """Return a copy of the entries at or after ``since_ns``, oldest first."""
        with self._lock:
            return [e for e in self._q if e[0] >= since_ns]


@dataclasses.dataclass(frozen=True)
class Trigger:
    """Why a dump is written: kind (one of :data:`KINDS`), detail, when (both clocks)."""

    kind: str
    detail: str
    wall_ns: int
    mono_ns: int


GUARD_MOVING_V = 0.02   # m/s: forward faster than this when the guard flag rises = a stop


class Triggers:
    """Turn decoded RT datagrams into triggers on their rising edges (pure)."""

    _FLAGS = ((protocol.OdomFlag.E_STOP, 'e_stop', 'e-stop latch engaged'),
              (protocol.OdomFlag.ESTOP_OPEN, 'e_stop', 'e-stop contact open'),
              (protocol.OdomFlag.GUARD, 'guard_stop', 'collision guard stopped forward motion'),
              (protocol.OdomFlag.MOTOR_FAULT, 'motor_fault', 'wheel supervisor latched a '
               'motor fault'))

    def __init__(self) -> None:
        self.flags: int | None = None
        self._levels: dict[str, int] = {}

    def on_odometry(self, flags: int, v: float | None = None) -> list[tuple[str, str]]:
        """Return (kind, detail) of every watched flag that rose since the last ODOMETRY.

        The first ODOMETRY after start (or after the RT process came back) only sets the
        reference: a latch already engaged then is a state, not an event. ``v`` is the
        ODOMETRY's forward speed (m/s): the guard flag rising while the robot is not moving
        forward (``v`` at most :data:`GUARD_MOVING_V`) stopped no motion -- every start-up
        raises it while the guard's sensors have not reported yet -- and dumps nothing.
        """
        prev, self.flags = self.flags, int(flags)
        if prev is None:
            return []
        rose = self.flags & ~prev
        if v is not None and not v > GUARD_MOVING_V:
            rose &= ~protocol.OdomFlag.GUARD
        return [(kind, '{} (flags 0x{:x})'.format(text, self.flags))
                for bit, kind, text in self._FLAGS if rose & bit]

    def on_task_stats(self, stats: Any) -> list[tuple[str, str]]:
        """Return a ``deadline_miss`` naming the task and the worst lateness, if any cycle."""
        worst = 0
        n = 0
        for s in stats.samples:
            if timing.deadline_missed(s.t_rel, s.t_end, stats.period_ns):
                n += 1
                worst = max(worst, s.t_end - s.t_rel - stats.period_ns)
        if not n:
            return []
        return [('deadline_miss', 'task {} missed {} deadline(s) of {:.1f} ms, worst by '
                 '{:.2f} ms'.format(stats.name, n, stats.period_ns / 1e6, worst / 1e6))]

    def on_device_status(self, st: Any) -> list[tuple[str, str]]:
        """Return a ``device_fault`` when a device's level becomes ERROR."""
        prev = self._levels.get(st.device)
        self._levels[st.device] = int(st.level)
        if int(st.level) == protocol.LEVEL_ERROR and prev is not None \
                and prev != protocol.LEVEL_ERROR:
            return [('device_fault', 'device {} in ERROR (faults {}, last error {})'.format(
                st.device, st.faults, st.last_error))]
        return []

    def reset(self) -> None:
        """Forget the reference flags (the RT process restarted)."""
        self.flags = None


class RateLimit:
    """At most one dump per kind per ``min_interval_s``; the rest are counted."""

    def __init__(self, min_interval_s: float) -> None:
        self.min_interval_ns = int(min_interval_s * _NS)
        self._last: dict[str, int] = {}
        self.suppressed: collections.Counter[str] = collections.Counter()

    def allow(self, kind: str, mono_ns: int) -> bool:
        """Tell whether a dump of ``kind`` may be written now (and note it if so)."""
        last = self._last.get(kind)
        if last is not None and mono_ns - last < self.min_interval_ns:
            self.suppressed[kind] += 1
            return False
        self._last[kind] = mono_ns
        return True


@dataclasses.dataclass(frozen=True)
class TopicSpec:
    """What a ring key is in a bag: topic, type and the QoS it is offered with."""

    topic: str
    type_name: str
    qos: list[dict[str, Any]]
    qos_text: str


class Dumper:
    """Write trigger windows of a :class:`Ring` as bags, in a thread of its own."""

    def __init__(self, ring: Ring, topics: Mapping[str, TopicSpec], directory: str,
                 pre_s: float, post_s: float,
                 log: Callable[[str, str], None] = lambda level, text: None,
                 share: Callable[[str], str] | None = None,
                 limits: tuple[int, float] | None = None,
                 provenance: Mapping[str, str] | None = None) -> None:
        # ``provenance``: more custom_data for every dump (the commit and the configuration
        # the bridge runs with).
        # ``limits``: (disk cap in bytes, age limit in s, 0 = none) of the dump directory;
        # None: never pruned (tests of the dump alone).
        self.ring = ring
        self.topics = dict(topics)
        self.directory = directory
        self.pre_ns = int(pre_s * _NS)
        self.post_ns = int(post_s * _NS)
        self._log = log
        self._share = share
        self._defs: dict[str, tuple[str, str]] = {}
        self._jobs: queue.Queue[Trigger | None] = queue.Queue()
        self._stop = threading.Event()
        self.written: list[str] = []
        self.failed = 0
        self.last_error = ''
        self.failing = False           # the last dump failed (cleared by the next good one)
        self.limits = limits
        self.provenance = dict(provenance or {})
        self.pruned = 0
        self.disk_bytes = 0
        self._thread = threading.Thread(target=self._run, name='flight_recorder', daemon=True)
        self._thread.start()

    def set_topics(self, topics: Mapping[str, TopicSpec]) -> None:
        """Replace what the ring keys are in a bag, as a new mapping.

        A dump in progress keeps the one it started with; ring entries of a key no longer
        listed are left out of later dumps.
        """
        self.topics = dict(topics)

    def submit(self, trigger: Trigger) -> None:
        """Queue a dump (returns at once)."""
        self._jobs.put(trigger)

    def close(self, timeout_s: float = 10.0) -> None:
        """Write the queued dumps without waiting out their post-trigger time, then stop."""
        self._stop.set()
        self._jobs.put(None)
        self._thread.join(timeout_s)

    def _prune(self, keep: str = '') -> None:
        if self.limits is None:
            return
        try:
            removed, self.disk_bytes = prune(self.directory, self.limits[0], self.limits[1],
                                             keep=keep)
        except OSError as exc:
            self._log('error', 'flight recorder: cannot prune {}: {}'.format(
                self.directory, exc))
            return
        self.pruned += len(removed)
        if removed:
            self._log('warning', 'flight recorder: removed {} old dump(s) to stay within {} '
                      'bytes / {:g} days: {}'.format(len(removed), self.limits[0],
                                                     self.limits[1] / 86400,
                                                     ', '.join(removed)))
        if self.disk_bytes > self.limits[0]:
            self._log('warning', 'flight recorder: the newest dump alone ({} bytes) is over '
                      'the disk cap of {} bytes; kept'.format(self.disk_bytes, self.limits[0]))

    def _fail(self, job: Trigger, why: str) -> None:
        self.failed += 1
        self.failing = True
        self.last_error = '{}: {}'.format(job.kind, why)
        self._log('error', 'flight recorder: dump for {} failed: {}'.format(job.kind, why))

    def _run(self) -> None:
        self._prune()
        while True:
            job = self._jobs.get()
            if job is None:
                return
            wait = (job.mono_ns + self.post_ns - time.monotonic_ns()) / _NS
            if wait > 0:
                self._stop.wait(wait)
            try:
                path = self.dump(job)
            except (BagError, OSError, MsgDefError, ValueError) as exc:
                self._fail(job, str(exc))
                continue
            except Exception as exc:  # noqa: BLE001 -- the thread must outlive one bad dump
                self._fail(job, repr(exc))
                continue
            self.written.append(path)
            self.failing = False
            self._prune(keep=path)

    def _definition(self, type_name: str) -> tuple[str, str]:
        if type_name not in self._defs:
            kw = {'share': self._share} if self._share else {}
            self._defs[type_name] = (message_definition(type_name, **kw),
                                     type_hash(type_name, **kw))
        return self._defs[type_name]

    def dump(self, trigger: Trigger) -> str:
        """Write the ring's window around ``trigger`` now; return the bag directory."""
        entries = self.ring.snapshot(trigger.wall_ns - self.pre_ns)
        topics = self.topics         # once: set_topics may replace it meanwhile
        base = os.path.join(self.directory, 'flight_{}_{}'.format(stamp(trigger.wall_ns),
                                                                  trigger.kind))
        path = unused_path(base, taken=lambda p: os.path.lexists(p)
                           or os.path.lexists(partial_directory(p)))
        custom = {
            'm4k.flight_recorder.trigger': trigger.kind,
            'm4k.flight_recorder.detail': trigger.detail,
            'm4k.flight_recorder.trigger_time_ns': str(trigger.wall_ns),
            'm4k.flight_recorder.trigger_time_utc': datetime.datetime.fromtimestamp(
                trigger.wall_ns / _NS, datetime.timezone.utc).isoformat(),
            'm4k.flight_recorder.pre_seconds': '{:g}'.format(self.pre_ns / _NS),
            'm4k.flight_recorder.post_seconds': '{:g}'.format(self.post_ns / _NS),
            'm4k.flight_recorder.ring_max_bytes': str(self.ring.max_bytes),
            'm4k.flight_recorder.ring_evicted_by_bytes': str(self.ring.evicted_bytes),
            **self.provenance,
        }
        os.makedirs(self.directory, exist_ok=True)
        # Written as <path>.partial and renamed to <path> once whole: a reader (or an rsync of
        # the dump directory) never finds a half dump under a dump's name.
        bag = BagWriter(path, library='m4k_bridge flight_recorder', custom_data=custom)
        complete = False
        try:
            channels: dict[str, int] = {}
            seq: collections.Counter[str] = collections.Counter()
            for key in _keys_in_order(entries, topics):
                spec = topics[key]
                msgdef, digest = self._definition(spec.type_name)
                channels[key] = bag.add_topic(spec.topic, spec.type_name, msgdef, digest,
                                              spec.qos, spec.qos_text)
            for t_ns, key, data in entries:
                if key in channels:
                    bag.write(channels[key], t_ns, data, seq[key])
                    seq[key] += 1
            complete = True
        finally:
            bag.close(complete)
        self._log('warning', 'flight recorder: {} ({}): {} messages of {:.1f} s before and '
                  '{:.1f} s after -> {}'.format(trigger.kind, trigger.detail,
                                                 bag.message_count, self.pre_ns / _NS,
                                                 self.post_ns / _NS, path))
        return path


def _keys_in_order(entries: Iterable[tuple[int, str, bytes]],
                   topics: Mapping[str, TopicSpec]) -> Sequence[str]:
    seen: dict[str, None] = {}
    for _, key, _ in entries:
        if key in topics:
            seen.setdefault(key)
    return list(seen)
