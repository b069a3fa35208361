"""Per-task cycle breakdown, measured inside the loop: where a task's CPU per cycle goes.

Switched on for a whole RT process before its tasks and bodies are built (``rt_core
--cycle-profile FILE`` or ``$M4K_CYCLE_PROFILE=FILE``); off, nothing here runs in a loop. On,
every task keeps one :class:`CycleProfile` (plain int accumulators, no allocation beyond the
ints) and the parts of each cycle are timed with the vDSO clock:

* ``drain`` -- :class:`~m4k_rt.tasks.portio.PortReader` ``next``/``discard``: the receive
  system calls and the decode of what arrived (timed readers, see ``portio``);
* ``send`` -- :class:`~m4k_rt.tasks.portio.PortWriter` ``send``/``forward``: encode + send;
* ``control`` -- the rest of the body (body time minus drain and send);
* ``record`` -- :meth:`RtTask.wait_period`'s bookkeeping after the body: timing ring record,
  deadline check, counters;
* ``rusage`` -- the getrusage refresh (every ``task.RUSAGE_EVERY`` cycles), per cycle;
* ``wake`` -- the thread's CPU per cycle (``CLOCK_THREAD_CPUTIME_ID``, read only at the
  rusage refreshes) minus the parts above: the timerfd wait's system call, the switch in and
  out, taking the GIL back and the loop's own lines -- what the Python floor pays too.

The parts are wall-clock times of code that does not block, so they are CPU time unless the
thread was preempted; ``wake`` is derived from measured thread CPU, so the parts add up to the
thread's CPU per cycle. A profiled cycle costs a few clock reads more than an unprofiled one
(``overhead_us``: the profile's own clock reads, timed at start-up, so the reader can subtract
it).
"""

from __future__ import annotations

import os
import threading
import time
from typing import Any

__all__ = ['ENV', 'PARTS', 'CycleProfile', 'bind', 'current', 'enable', 'enabled',
           'env_path']

ENV = 'M4K_CYCLE_PROFILE'
PARTS = ('wake', 'drain', 'control', 'send', 'record', 'rusage')

_enabled = False
_tls = threading.local()


def enable(on: bool = True) -> None:
    """Switch profiling on (or off) for tasks, readers and writers built from now on."""
    global _enabled
    _enabled = bool(on)


def enabled() -> bool:
    """Tell whether tasks, readers and writers built now are profiled."""
    return _enabled


def env_path() -> str | None:
    """Return the profile output path from ``$M4K_CYCLE_PROFILE`` (None when unset/empty)."""
    return os.environ.get(ENV) or None


def bind(profile: CycleProfile | None) -> None:
    """Make ``profile`` the calling thread's (timed readers and writers add to it)."""
    _tls.profile = profile


def current() -> CycleProfile | None:
    """Return the calling thread's profile, or None."""
    return getattr(_tls, 'profile', None)


def _clock_cost_ns(n: int = 2000) -> float:
    clock = time.monotonic_ns
    t0 = clock()
    for _ in range(n):
        clock()
    return (clock() - t0) / n


class CycleProfile:
    """Accumulated part times (ns) of one task's cycles."""

    __slots__ = ('drain_ns', 'drain_calls', 'send_ns', 'send_calls', 'body_ns', 'record_ns',
                 'rusage_ns', 'cycles', 'cpu_first_ns', 'cpu_last_ns', 'cpu_first_cycle',
                 'cpu_last_cycle', 'clock_ns')

    def __init__(self) -> None:
        """Start empty; time the clock once (the profile's own cost per reading)."""
        self.drain_ns = 0
        self.drain_calls = 0
        self.send_ns = 0
        self.send_calls = 0
        self.body_ns = 0
        self.record_ns = 0
        self.rusage_ns = 0
        self.cycles = 0
        self.cpu_first_ns = -1
        self.cpu_last_ns = 0
        self.cpu_first_cycle = 0
        self.cpu_last_cycle = 0
        self.clock_ns = _clock_cost_ns()

    def cpu_mark(self, cycles: int) -> None:
        """Read the thread's CPU time after ``cycles`` cycles (from the task thread)."""
        now = time.thread_time_ns()
        if self.cpu_first_ns < 0:
            self.cpu_first_ns, self.cpu_first_cycle = now, cycles
        self.cpu_last_ns, self.cpu_last_cycle = now, cycles

    def summary(self) -> dict[str, Any]:
        """Return µs per cycle of every part, the thread CPU per cycle and the counts."""
        n = self.cycles
        out: dict[str, Any] = {'cycles': n, 'drain_calls': self.drain_calls,
                               'send_calls': self.send_calls,
                               'overhead_us': self.clock_ns * 1e-3}
        if n <= 0:
            return out
        per = 1e-3 / n
        parts = {'drain': self.drain_ns * per, 'send': self.send_ns * per,
                 'control': max(0, self.body_ns - self.drain_ns - self.send_ns) * per,
                 'record': max(0, self.record_ns - self.rusage_ns) * per,
                 'rusage': self.rusage_ns * per}
        ncpu = self.cpu_last_cycle - self.cpu_first_cycle
        cpu = None
        if ncpu > 0:
            cpu = (self.cpu_last_ns - self.cpu_first_ns) * 1e-3 / ncpu
            parts['wake'] = max(0.0, cpu - sum(parts.values()))
        out['parts_us'] = {p: parts[p] for p in PARTS if p in parts}
        out['body_us'] = self.body_ns * per
        out['thread_cpu_per_cycle_us'] = cpu
        return out
