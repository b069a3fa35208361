"""The frame executive: one SCHED_FIFO thread on one timerfd runs several tasks back to back.

ros2_control's answer to "one thread per device" (the paper's executive, :mod:`m4k_rt.task`):
one update loop at one rate. Here: the frame is the shortest period among ``runtime.frame_tasks``
(the actuator's 10 ms); in every frame the thread runs, in rate-monotonic order (period, then
priority: the actuator first), each member whose release falls in it -- IMU every frame, LED
every 2nd, sonar every 3rd. One wake per frame instead of one per task cycle.

Every member stays an :class:`~m4k_rt.task.RtTask` that is never started: its ring, counters,
rusage and profile are filled by the frame thread, so TASK_STATS / rt_stat see the same tasks
with the same meaning. A member's release is its own ideal release (the frame in which it is
due), so its release latency includes the members run before it in that frame -- what it
really waits. Skipped frames (the frame thread's timerfd expired more than once: a frame
overran) count, per member, the releases of its own that were skipped, exactly as a task's own
timerfd would (:func:`releases`), and the member runs once, late.

What it trades (docs/design-notes.md §11): a member that overruns delays every member after it
and the next frame's actuator, where one thread per task lets the actuator's higher priority
preempt it (between two bytecodes, under the GIL's switch interval).
"""

from typing import Any, Sequence

from m4k_rt import cycleprof, modeswitch
from m4k_rt.schema import ConfigError
from m4k_rt.task import RtTask
from m4k_rt.timerfd import monotonic_ns

__all__ = ['FrameExecutive', 'frame_order', 'releases', 'schedule']


def frame_order(periods_ns: Sequence[int], priorities: Sequence[int]) -> list[int]:
    """Return the members' indices in rate-monotonic order: period, then priority (high first)."""
    return sorted(range(len(periods_ns)), key=lambda i: (periods_ns[i], -priorities[i], i))


def releases(k_prev: int, k_now: int, divisor: int) -> tuple[int, int]:
    """Return (releases in frames ``k_prev`` < k <= ``k_now``, the last one's frame index).

    A member with ``divisor`` d is released in every frame k with k % d == 0 (frame 0 is the
    common release). No release in the window: (0, the last earlier one).
    """
    last = (k_now // divisor) * divisor
    return k_now // divisor - k_prev // divisor, last


def schedule(divisors: Sequence[int], frames: int) -> list[list[int]]:
    """Return, for frames 0 .. frames-1 run one after the other, the members due in each."""
    return [[i for i, d in enumerate(divisors) if releases(k - 1, k, d)[0]]
            for k in range(frames)]


class FrameExecutive:
    """Run ``members`` (RtTasks, not started) from one thread; ``runner`` is that thread's task."""

    def __init__(self, members: Sequence[RtTask], *, start_ns: int | None = None,
                 ring_capacity: int = 64) -> None:
        """Order the members, check the periods are harmonic to the frame, build the thread."""
        if not members:
            raise ConfigError('runtime.frame_tasks', 'no task to run in the frame', [])
        order = frame_order([m.period_ns for m in members], [m.priority for m in members])
        self.members = [members[i] for i in order]
        frame_ns = self.members[0].period_ns
        for m in self.members:
            if m.period_ns % frame_ns:
                raise ConfigError('runtime.frame_tasks', 'task {} period {} ms is not a whole '
                                  'multiple of the frame ({} ms)'.format(
                                      m.name, m.period_ns / 1e6, frame_ns / 1e6), m.name)
            if not m.cyclic:
                raise ConfigError('runtime.frame_tasks', 'task {} runs its own loop (not '
                                  'cyclic): it cannot share a frame'.format(m.name), m.name)
        self.frame_ns = frame_ns
        self.divisors = [m.period_ns // frame_ns for m in self.members]
        self.k = -1                      # the last frame run (-1: none yet)
        first = self.members[0]
        self.runner = _Runner(self, 'frame', first.priority, frame_ns, self._frame,
                              cpu=first.cpu, start_ns=start_ns, ring_capacity=ring_capacity,
                              index=first.index)

    def _start_members(self, runner: RtTask) -> None:
        for m in self.members:
            m.fifo, m.sched_error, m.affinity_error = (runner.fifo, runner.sched_error,
                                                       runner.affinity_error)
            m.rusage.start()             # the frame thread's counters, from now on
            m.waits_of = runner          # ... and its timer waits (one per frame)

    def _frame(self, runner: RtTask) -> None:
        k_prev = self.k
        if k_prev < 0:
            self._start_members(runner)
            k_now = 0
        else:
            k_now = k_prev + runner.expirations
        t_frame = runner.t_rel
        frame_ns = self.frame_ns
        for m, d in zip(self.members, self.divisors, strict=True):
            n, last = releases(k_prev, k_now, d)
            if not n:
                continue
            m.open_cycle(t_frame - (k_now - last) * frame_ns, monotonic_ns(), n)
            modeswitch.enter_rt(m.sites)
            cycleprof.bind(m.profile)
            try:
                m.body(m)
            except Exception as exc:  # noqa: BLE001 -- counted on the member, frame goes on
                m._body_failed(exc)
            m.close_cycle(monotonic_ns())
        modeswitch.enter_rt(runner.sites)
        cycleprof.bind(runner.profile)
        self.k = k_now


class _Runner(RtTask):
    """The frame thread's task: also reads its members' rusage once more when the loop ends."""

    def __init__(self, frame: FrameExecutive, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.frame = frame

    def _run(self) -> None:
        try:
            super()._run()
        finally:
            for m in self.frame.members:      # in the frame thread: RUSAGE_THREAD is its own
                m.rusage.update(self.cycles)
