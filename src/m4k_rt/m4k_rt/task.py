"""Periodic real-time tasks: one SCHED_FIFO thread per task, released by an absolute timerfd.

Each cycle, as the paper probes it: wait for the release -> ``t_start`` -> ``body(ctx)`` ->
``t_end`` -> record (t_rel, t_start, t_end, expirations) into the task's preallocated ring ->
every :data:`RUSAGE_EVERY` cycles (and when the loop ends), refresh the thread's rusage
counters: getrusage is a system call that allocates a result object, and the counters are
read by the monitor about once a second, so once per cycle was most of the timing record's
cost. A body exception is counted and kept, and the task keeps
cycling: for a robot task, stopping is worse than one bad cycle.

Paper-style API on top of :class:`RtTask`: :func:`pt_create_task_rt`,
:func:`pt_task_wait_period` (from inside a task thread) and :func:`pt_timer_read`.
"""

import signal
import threading
from typing import Callable

from m4k_rt import cycleprof, modeswitch, sched, timing
from m4k_rt.timerfd import monotonic_ns, TimerFd

__all__ = [
    'RUSAGE_EVERY', 'RtTask', 'TaskError', 'TaskStopped', 'current_task', 'pt_create_task_rt',
    'pt_task_wait_period', 'pt_timer_read',
]

Body = Callable[['RtTask'], object]

# Cycles between two rusage refreshes (a power of two: the test is one AND). At 100 Hz that is
# 0.64 s, below the monitor's 1 s batches; the last refresh runs when the loop ends.
RUSAGE_EVERY = 64
_RUSAGE_MASK = RUSAGE_EVERY - 1

_current = threading.local()


class TaskError(RuntimeError):
    """A task API was used wrongly (bad parameters, called outside a task thread)."""


class TaskStopped(BaseException):  # noqa: N818 -- a cancellation signal, not an error
    """Raised by ``wait_period`` once the task is asked to stop (a cancellation point).

    A BaseException so that a body's ``except Exception`` does not swallow it.
    """


class RtTask:
    """A periodic SCHED_FIFO task thread with timing samples and mode-switch counters."""

    def __init__(self, name: str, priority: int, period_ns: int, body: Body, *,
                 cpu: int | None = None, start_ns: int | None = None,
                 ring_capacity: int = 4096, index: int = 0, cyclic: bool = True,
                 site_capacity: int = 8, block_signals: bool = True) -> None:
        """Validate the parameters and preallocate the ring; ``start()`` runs the thread.

        ``cyclic``: the loop calls ``body(ctx)`` once per period. Otherwise ``body(ctx)`` is
        called once and runs its own loop around :func:`pt_task_wait_period`.
        """
        if not isinstance(name, str) or not name or len(name.encode()) > 16:
            raise TaskError('task name must be 1..16 bytes of text, got {!r}'.format(name))
        if not isinstance(priority, int) or isinstance(priority, bool) or not 1 <= priority <= 99:
            raise TaskError('task {!r}: priority must be an int in 1..99, got {!r}'.format(
                name, priority))
        if not isinstance(period_ns, int) or period_ns <= 0:
            raise TaskError('task {!r}: period_ns must be an int > 0, got {!r}'.format(
                name, period_ns))
        if not callable(body):
            raise TaskError('task {!r}: body must be callable, got {!r}'.format(name, body))
        if cpu is not None and (not isinstance(cpu, int) or cpu < 0):
            raise TaskError('task {!r}: cpu must be None or an int >= 0, got {!r}'.format(
                name, cpu))
        self.name = name
        self.priority = priority
        self.period_ns = period_ns
        self.body = body
        self.cpu = cpu
        self.index = index
        self.start_ns = start_ns
        self.cyclic = cyclic
        self.block_signals = block_signals
        self.ring = timing.SampleRing(ring_capacity)
        self.sites = modeswitch.SiteTable(site_capacity)
        self.rusage = modeswitch.ThreadRusage()
        # The cycle breakdown (m4k_rt.cycleprof), when profiling was switched on before.
        self.profile = cycleprof.CycleProfile() if cycleprof.enabled() else None
        self.cycles = 0
        self.waits_of: RtTask | None = None   # the frame runner whose thread runs this task
        self.overruns = 0
        self.deadline_misses = 0
        self.body_errors = 0
        self.last_error: str | None = None
        self.last_error_site: tuple[str, int] | None = None
        self.fifo = False
        self.sched_error: str | None = None
        self.affinity_error: str | None = None
        self.finished = False
        self.t_rel = 0
        self.t_start = 0
        self.expirations = 0
        self._open = False
        self._stop = False
        self._tfd: TimerFd | None = None
        self._tfd_lock = threading.Lock()
        self._ready = threading.Event()
        self._thread: threading.Thread | None = None

    # --- lifecycle (any thread) -------------------------------------------------------------

    def start(self) -> None:
        """Start the task thread; return once it has set its policy and armed its timer."""
        if self._thread is not None:
            raise TaskError('task {!r} already started'.format(self.name))
        self._thread = threading.Thread(target=self._run, name='rt:' + self.name, daemon=True)
        self._thread.start()
        self._ready.wait(5.0)

    def stop(self) -> None:
        """Ask the task to stop and wake it now (the timer is re-armed to fire at once)."""
        self._stop = True
        with self._tfd_lock:
            if self._tfd is not None and not self._tfd.closed:
                self._tfd.set_abs(monotonic_ns(), self.period_ns)

    def join(self, timeout: float | None = None) -> bool:
        """Wait for the thread to end; return True when it did within ``timeout``."""
        if self._thread is None:
            return True
        self._thread.join(timeout)
        return not self._thread.is_alive()

    def is_alive(self) -> bool:
        """Tell whether the task thread runs."""
        return self._thread is not None and self._thread.is_alive()

    @property
    def stop_requested(self) -> bool:
        """Tell whether ``stop()`` was called (for free-running bodies)."""
        return self._stop

    # --- the task thread --------------------------------------------------------------------

    def _run(self) -> None:
        _current.task = self
        if self.block_signals:
            # SIGINT/SIGTERM go to the main thread, which stops every task.
            signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
        try:
            sched.set_thread_fifo(self.priority)
            self.fifo = True
        except sched.SchedError as exc:
            self.sched_error = '{} ({})'.format(exc.strerror, exc.fix)
        if self.cpu is not None:
            try:
                sched.set_thread_affinity(self.cpu)
            except sched.SchedError as exc:
                self.affinity_error = '{} ({})'.format(exc.strerror, exc.fix)
        try:
            tfd = TimerFd()
            first = timing.first_release(monotonic_ns(), self.period_ns, self.start_ns)
            tfd.set_abs(first, self.period_ns)
        except OSError as exc:
            self.sched_error = 'timerfd: {}'.format(exc)
            self._ready.set()
            return
        with self._tfd_lock:
            self._tfd = tfd
        self.t_rel = first - self.period_ns
        self.rusage.start()
        cycleprof.bind(self.profile)
        self._ready.set()
        modeswitch.enter_rt(self.sites)
        try:
            if self.cyclic:
                self._loop_cyclic()
            else:
                self._loop_free()
        except TaskStopped:
            pass
        finally:
            self.rusage.update(self.cycles)
            if self.profile is not None:
                self.profile.cpu_mark(self.cycles)  # the last reading, for slow tasks too
            modeswitch.leave_rt()
            with self._tfd_lock:
                self._tfd = None
                tfd.close()
            _current.task = None

    def _loop_cyclic(self) -> None:
        body = self.body
        wait = self.wait_period
        while True:
            wait()
            try:
                body(self)
            except Exception as exc:  # noqa: BLE001 -- counted and reported, task keeps going
                self._body_failed(exc)

    def _loop_free(self) -> None:
        while True:
            try:
                self.body(self)
            except Exception as exc:  # noqa: BLE001 -- counted; re-enter the body next period
                self._body_failed(exc)
            else:
                self.finished = True
                return
            self.wait_period()

    def _body_failed(self, exc: Exception) -> None:
        # Only the failing cycle pays for this; the site comes from the traceback objects
        # without reading source lines (that would be file I/O in the loop).
        self.body_errors += 1
        self.last_error = '{}: {}'.format(type(exc).__name__, exc)
        tb = exc.__traceback__
        while tb is not None and tb.tb_next is not None:
            tb = tb.tb_next
        if tb is not None:
            self.last_error_site = (tb.tb_frame.f_code.co_filename, tb.tb_lineno)

    def wait_period(self) -> int:
        """Close the running cycle, wait for the next release and return the overruns.

        Raises :class:`TaskStopped` once the task was asked to stop.
        """
        t_end = monotonic_ns()
        if self._open:
            self.close_cycle(t_end)
        if self._stop:
            raise TaskStopped
        tfd = self._tfd
        if tfd is None:
            raise TaskError('wait_period() called outside the task loop of {!r}'.format(
                self.name))
        exp = tfd.read()
        t_start = monotonic_ns()
        if self._stop:
            raise TaskStopped
        return self.open_cycle(self.t_rel + exp * self.period_ns, t_start, exp)

    def open_cycle(self, t_rel: int, t_start: int, exp: int) -> int:
        """Start a cycle released (ideally) at ``t_rel``, begun at ``t_start``; return overruns.

        ``exp``: releases since the last cycle (more than one: skipped releases, counted).
        Also called by the frame executive (:mod:`m4k_rt.frame`) for the tasks it runs.
        """
        self.t_rel = t_rel
        self.t_start = t_start
        self.expirations = exp
        self._open = True
        if exp > 1:
            self.overruns += exp - 1
            return exp - 1
        return 0

    def close_cycle(self, t_end: int) -> None:
        """Record the open cycle ending at ``t_end``: ring, deadline, cycles, rusage, profile."""
        rel = self.t_rel
        self.ring.record(rel, self.t_start, t_end, self.expirations)
        if t_end > rel + self.period_ns:
            self.deadline_misses += 1
        self.cycles += 1
        if not self.cycles & _RUSAGE_MASK:
            self._refresh_rusage()
        self._open = False
        prof = self.profile
        if prof is not None:
            prof.body_ns += t_end - self.t_start
            prof.record_ns += monotonic_ns() - t_end
            prof.cycles += 1
            if self.cycles == 1:
                prof.cpu_mark(1)  # the first CPU reading: after the warm-up cycle

    def timer_waits(self) -> int:
        """Return the timer waits of this task's thread so far (for the extra-switch count).

        A task run by a frame (``waits_of``: the frame's runner) shares that thread's waits.
        """
        src = self.waits_of
        return self.cycles if src is None else src.cycles + 1

    def _refresh_rusage(self) -> None:
        prof = self.profile
        if prof is None:
            self.rusage.update(self.timer_waits())
            return
        t0 = monotonic_ns()
        self.rusage.update(self.timer_waits())
        prof.rusage_ns += monotonic_ns() - t0
        prof.cpu_mark(self.cycles)

    def counters(self) -> dict[str, object]:
        """Return a snapshot of the task's counters (NRT use)."""
        ru = self.rusage
        return {
            'name': self.name, 'index': self.index, 'priority': self.priority,
            'period_ns': self.period_ns, 'cpu': self.cpu, 'fifo': self.fifo,
            'cycles': self.cycles, 'overruns': self.overruns,
            'deadline_misses': self.deadline_misses, 'body_errors': self.body_errors,
            'last_error': self.last_error, 'last_error_site': self.last_error_site,
            'nvcsw': ru.nvcsw, 'nvcsw_extra': ru.nvcsw_extra, 'nivcsw': ru.nivcsw,
            'minflt': ru.minflt, 'majflt': ru.majflt, 'forbidden_calls': self.sites.total,
            'sched_error': self.sched_error, 'affinity_error': self.affinity_error,
        }


def current_task() -> RtTask | None:
    """Return the RtTask running the calling thread, or None outside task threads."""
    return getattr(_current, 'task', None)


def pt_create_task_rt(name: str, priority: int, period_ns: int, body: Body, *,
                      cpu: int | None = None, start_ns: int | None = None,
                      ring_capacity: int = 4096, cyclic: bool = True,
                      start: bool = True) -> RtTask:
    """Create (and by default start) a periodic RT task, as the paper's ``pt_create_task_rt``."""
    t = RtTask(name, priority, period_ns, body, cpu=cpu, start_ns=start_ns,
               ring_capacity=ring_capacity, cyclic=cyclic)
    if start:
        t.start()
    return t


def pt_task_wait_period() -> int:
    """Wait for the calling task's next release; return the overruns (skipped releases)."""
    t: RtTask | None = getattr(_current, 'task', None)
    if t is None:
        raise TaskError('pt_task_wait_period() called outside an RT task thread')
    return t.wait_period()


def pt_timer_read() -> int:
    """Return the RT clock (CLOCK_MONOTONIC) in nanoseconds."""
    return monotonic_ns()
