"""Pure loop-timing arithmetic, per-task sample rings, statistics and schedulability tests.

Definitions (design.md, "Timing, as the paper measures it"), per cycle i:

* ``t_rel`` ideal release, ``t_start`` after the wait, ``t_end`` after the last command,
  ``expirations`` as read from the timerfd;
* period = t_start[i] - t_start[i-1]; periodicity jitter = |period - nominal|;
* release latency = t_start - the first release the cycle serves: ``t_rel`` is the latest
  release, so after an overrun (``expirations`` > 1) the latency counts from the earliest
  missed one, ``t_rel - (expirations - 1) * period`` -- cyclictest's metric;
  response time = t_end - t_start;
* overruns = expirations - 1; deadline miss = t_end > t_rel + nominal period.

The release arithmetic mirrors an absolute periodic timerfd: a late wake-up reports every
release that passed, the task runs once for the latest one (skip ahead, never burst).

Only :class:`SampleRing` runs inside RT loops (``record`` is a handful of array stores); the
statistics use numpy and belong to NRT code.
"""

from array import array
import dataclasses
import math
from typing import NamedTuple, Sequence

import numpy as np
import numpy.typing as npt

__all__ = [
    'RtaResult', 'RtaTask', 'SampleRing', 'Stats', 'TaskTiming', 'UtilizationResult',
    'advance_release', 'analyze', 'deadline_missed', 'describe', 'expirations_at',
    'first_release', 'liu_layland_bound', 'overruns', 'release_latency',
    'response_time_analysis',
    'utilization_test',
]


# --- release arithmetic -------------------------------------------------------------------

def first_release(now_ns: int, period_ns: int, start_ns: int | None = None,
                  lead_ns: int = 0) -> int:
    """Return the first release time.

    ``start_ns`` in the future is taken as is (tasks sharing it start in phase, the critical
    instant of RM analysis); otherwise the first multiple of ``period_ns`` at or after
    ``now_ns + lead_ns``, so harmonic tasks started separately still release together.
    """
    if period_ns <= 0:
        raise ValueError('period_ns must be > 0, got {!r}'.format(period_ns))
    if start_ns is not None and start_ns > now_ns:
        return start_ns
    t = now_ns + lead_ns
    return -(-t // period_ns) * period_ns


def expirations_at(next_release_ns: int, period_ns: int, now_ns: int) -> int:
    """Return how many releases a periodic timer has passed at ``now_ns`` (0 = not yet)."""
    if now_ns < next_release_ns:
        return 0
    return (now_ns - next_release_ns) // period_ns + 1


def advance_release(release_ns: int, period_ns: int, expirations: int) -> int:
    """Return the release the task now runs for, after ``expirations`` from the timer.

    ``release_ns`` is the previous cycle's release (or first release minus one period).
    With 3 expirations the task skips two releases and serves the latest one.
    """
    return release_ns + expirations * period_ns


def overruns(expirations: int) -> int:
    """Return the releases skipped in a cycle (expirations beyond one)."""
    return expirations - 1 if expirations > 1 else 0


def deadline_missed(t_rel_ns: int, t_end_ns: int, period_ns: int) -> bool:
    """Tell whether a cycle ended after its implicit deadline (release + period)."""
    return t_end_ns > t_rel_ns + period_ns


# --- the per-task sample ring ---------------------------------------------------------------

class SampleRing:
    """Fixed-capacity ring of (t_rel, t_start, t_end, expirations), preallocated arrays.

    One writer (the task thread) calls :meth:`record`; readers take ranges of sequence
    numbers (``0 .. total``) with :meth:`rows`. A row is complete once ``total`` counts it,
    because ``record`` publishes by incrementing ``total`` last.
    """

    __slots__ = ('capacity', 't_rel', 't_start', 't_end', 'expirations', 'total')

    def __init__(self, capacity: int = 4096) -> None:
        """Preallocate ``capacity`` rows."""
        if not isinstance(capacity, int) or capacity < 2:
            raise ValueError('ring capacity must be an int >= 2, got {!r}'.format(capacity))
        self.capacity = capacity
        self.t_rel = array('q', bytes(8 * capacity))
        self.t_start = array('q', bytes(8 * capacity))
        self.t_end = array('q', bytes(8 * capacity))
        self.expirations = array('L', bytes(array('L').itemsize * capacity))
        self.total = 0

    def record(self, t_rel: int, t_start: int, t_end: int, expirations: int) -> None:
        """Store one cycle (O(1), no allocation beyond the ints passed in)."""
        i = self.total % self.capacity
        self.t_rel[i] = t_rel
        self.t_start[i] = t_start
        self.t_end[i] = t_end
        self.expirations[i] = expirations
        self.total += 1

    def available(self, cursor: int) -> tuple[int, int, int]:
        """Return (first, end, lost) for a reader that has consumed up to ``cursor``.

        Rows ``first .. end-1`` are still in the ring; ``lost`` were overwritten unread.
        """
        end = self.total
        first = max(cursor, end - self.capacity)
        return first, end, first - cursor

    def row(self, seq: int) -> tuple[int, int, int, int]:
        """Return the row with sequence number ``seq`` (must still be in the ring)."""
        i = seq % self.capacity
        return self.t_rel[i], self.t_start[i], self.t_end[i], self.expirations[i]

    def rows(self, first: int, end: int) -> list[tuple[int, int, int, int]]:
        """Return rows ``first .. end-1`` (NRT use; allocates)."""
        return [self.row(s) for s in range(first, end)]

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Return the rows still held, oldest first, as int64 numpy arrays (NRT use)."""
        first, end, _ = self.available(0)
        idx = np.arange(first, end, dtype=np.int64) % self.capacity
        t_rel, t_start, t_end, expirations = (
            np.frombuffer(a, dtype=np.int64 if a.typecode == 'q' else np.uint64)[idx]
            .astype(np.int64) for a in (self.t_rel, self.t_start, self.t_end, self.expirations))
        return t_rel, t_start, t_end, expirations


# --- statistics -------------------------------------------------------------------------------

class Stats(NamedTuple):
    """Summary of one timing metric (ns); NaN fields when there were no values."""

    n: int
    avg: float
    max: float
    min: float
    std: float
    p50: float
    p99: float
    p999: float


def describe(values: Sequence[float] | np.ndarray) -> Stats:
    """Return avg, max, min, population std and p50/p99/p99.9 of ``values``."""
    a = np.asarray(values, dtype=np.float64)
    if a.size == 0:
        nan = math.nan
        return Stats(0, nan, nan, nan, nan, nan, nan, nan)
    p50, p99, p999 = np.percentile(a, [50.0, 99.0, 99.9])
    return Stats(int(a.size), float(a.mean()), float(a.max()), float(a.min()), float(a.std()),
                 float(p50), float(p99), float(p999))


def release_latency(t_rel: npt.ArrayLike, t_start: npt.ArrayLike, expirations: npt.ArrayLike,
                    period_ns: int) -> np.ndarray:
    """Return t_start minus the earliest release each cycle serves (ns, int64).

    ``t_rel`` is the latest release the timer reported; with ``expirations`` > 1 the cycle
    also answers the ``expirations - 1`` releases before it, and its latency is measured from
    the first of them -- the release it missed -- as cyclictest measures a late wake-up.
    """
    rel = np.asarray(t_rel, dtype=np.int64)
    missed = np.clip(np.asarray(expirations, dtype=np.int64) - 1, 0, None)
    return np.asarray(t_start, dtype=np.int64) - (rel - missed * int(period_ns))


@dataclasses.dataclass
class TaskTiming:
    """Timing analysis of one task's samples (all times in ns)."""

    name: str
    period_ns: int
    cycles: int
    period: Stats
    jitter: Stats
    latency: Stats
    response: Stats
    overruns: int
    deadline_misses: int

    @property
    def wcrt_ns(self) -> float:
        """Return the measured worst-case response time (max response), NaN when empty."""
        return self.response.max


def analyze(t_rel: Sequence[int], t_start: Sequence[int], t_end: Sequence[int],
            expirations: Sequence[int], period_ns: int, name: str = '') -> TaskTiming:
    """Compute the paper's per-task metrics from samples in cycle order.

    A period is only measured between two cycles known to be consecutive (their releases
    differ by ``expirations * period``), so samples lost in transit do not show up as jitter.
    """
    if period_ns <= 0:
        raise ValueError('period_ns must be > 0, got {!r}'.format(period_ns))
    rel = np.asarray(t_rel, dtype=np.int64)
    start = np.asarray(t_start, dtype=np.int64)
    end = np.asarray(t_end, dtype=np.int64)
    exp = np.asarray(expirations, dtype=np.int64)
    if not rel.size == start.size == end.size == exp.size:
        raise ValueError('sample arrays differ in length: {}'.format(
            (rel.size, start.size, end.size, exp.size)))
    if rel.size > 1:
        consecutive = np.diff(rel) == exp[1:] * period_ns
        periods = np.diff(start)[consecutive]
    else:
        periods = np.empty(0, dtype=np.int64)
    return TaskTiming(
        name=name, period_ns=period_ns, cycles=int(rel.size),
        period=describe(periods), jitter=describe(np.abs(periods - period_ns)),
        latency=describe(release_latency(rel, start, exp, period_ns)),
        response=describe(end - start),
        overruns=int(np.clip(exp - 1, 0, None).sum()),
        deadline_misses=int((end > rel + period_ns).sum()))


# --- schedulability ----------------------------------------------------------------------------

def liu_layland_bound(n: int) -> float:
    """Return the Liu-Layland RM utilization bound n(2^(1/n) - 1) (0.743 for n = 5)."""
    if not isinstance(n, int) or n < 1:
        raise ValueError('task count must be an int >= 1, got {!r}'.format(n))
    return n * (math.pow(2.0, 1.0 / n) - 1.0)  # math.pow: float (float ** may be complex)


@dataclasses.dataclass
class UtilizationResult:
    """Utilization test of a task set from measured worst-case response times."""

    per_task: dict[str, float]
    total: float
    bound: float
    verdict: str  # 'schedulable', 'inconclusive' (bound < U <= 1), 'overloaded' (U > 1)

    @property
    def passes(self) -> bool:
        """Tell whether the sufficient Liu-Layland test passes."""
        return self.verdict == 'schedulable'


def utilization_test(tasks: Sequence[tuple[str, float, float]]) -> UtilizationResult:
    """Run the Liu-Layland test on (name, wcet_ns, period_ns) triples.

    The bound is sufficient, not necessary: above it, use :func:`response_time_analysis`.
    """
    if not tasks:
        raise ValueError('utilization test needs at least one task')
    per = {}
    for name, c, t in tasks:
        if not t > 0 or not c >= 0:
            raise ValueError('task {!r}: need wcet >= 0 and period > 0, got {!r}, {!r}'.format(
                name, c, t))
        per[name] = float(c) / float(t)
    total = sum(per.values())
    bound = liu_layland_bound(len(per))
    verdict = 'schedulable' if total <= bound else (
        'inconclusive' if total <= 1.0 else 'overloaded')
    return UtilizationResult(per, total, bound, verdict)


class RtaTask(NamedTuple):
    """A task for response-time analysis; higher ``priority`` preempts lower."""

    name: str
    wcet_ns: float
    period_ns: float
    priority: int
    deadline_ns: float | None = None  # None: implicit deadline = period
    jitter_ns: float = 0.0            # release jitter J: worst release latency (wake-up delay)


class RtaResult(NamedTuple):
    """Worst-case response time of one task (None when it diverged past the deadline)."""

    name: str
    response_ns: float | None
    deadline_ns: float
    schedulable: bool
    iterations: int


def response_time_analysis(tasks: Sequence[RtaTask],
                           max_iterations: int = 1000) -> list[RtaResult]:
    """Worst-case response per task, in input order, with release jitter (Audsley et al. 1993).

    w = C_i + sum over higher-priority j of ceil((w + J_j) / T_j) * C_j, iterated to a fixed
    point; R_i = J_i + w. J is the release jitter: how late a task may start after its
    release (its worst measured release latency), so a late wake-up of task j can put one
    more of its jobs in the window, and task i's own late start adds to its response. With
    every J = 0 this is the classic R = C + sum(ceil(R / Tj) * Cj).

    Tasks of equal priority count as interference for each other (SCHED_FIFO runs a
    same-priority task to completion, whichever was released first), which is the safe side.
    """
    out = []
    for task in tasks:
        if not task.period_ns > 0 or not task.wcet_ns >= 0 or not task.jitter_ns >= 0:
            raise ValueError('task {!r}: need wcet >= 0, jitter >= 0 and period > 0'.format(
                task.name))
        deadline = task.period_ns if task.deadline_ns is None else task.deadline_ns
        hp = [j for j in tasks if j is not task and j.priority >= task.priority]
        w = task.wcet_ns + sum(j.wcet_ns for j in hp)
        iterations = 0
        result: float | None = None
        while iterations < max_iterations:
            iterations += 1
            if task.jitter_ns + w > deadline:
                break
            nxt = task.wcet_ns + sum(math.ceil((w + j.jitter_ns) / j.period_ns) * j.wcet_ns
                                     for j in hp)
            if nxt == w:
                result = task.jitter_ns + w
                break
            w = nxt
        out.append(RtaResult(task.name, result, deadline, result is not None, iterations))
    return out
