"""Real-time hardening of the RT process: SCHED_FIFO, affinity, mlockall, cpu_dma_latency, GC.

Every step may fail on an unprivileged or containerised host. Nothing here hides a failure:
each one lands in the :class:`Hardening` report with errno, strerror and the fix an operator
needs, the report says ``degraded``, and ``--require-rt`` turns a degraded report into
:class:`RtHardeningError`.

``os.sched_setscheduler(0, ...)`` and ``os.sched_setaffinity(0, ...)`` act on the *calling
thread* on Linux, which is what a task thread wants for itself.
"""

import ctypes
import ctypes.util
import dataclasses
import errno as _errno
import gc
import os
import resource
import struct
import sys

__all__ = [
    'Hardening', 'HardeningFailure', 'RtHardeningError', 'SchedError', 'explain',
    'freeze_gc', 'harden', 'set_thread_affinity', 'set_thread_fifo', 'thread_policy',
]

MCL_CURRENT = 1
MCL_FUTURE = 2
DMA_LATENCY_PATH = '/dev/cpu_dma_latency'
RT_RUNTIME_PATH = '/proc/sys/kernel/sched_rt_runtime_us'


class SchedError(OSError):
    """A scheduling or memory-locking call failed; ``fix`` says how to allow it."""

    def __init__(self, err: int | None, message: str, fix: str = '') -> None:
        """Keep errno, the message and the operator fix."""
        super().__init__(err, message)
        self.fix = fix


@dataclasses.dataclass
class HardeningFailure:
    """One hardening step that did not work."""

    step: str
    errno: int
    strerror: str
    fix: str

    def __str__(self) -> str:
        """Format as 'step: strerror [errno] -> fix'."""
        code = _errno.errorcode.get(self.errno, str(self.errno))
        return '{}: {} [{}] -> {}'.format(self.step, self.strerror, code, self.fix)


class RtHardeningError(RuntimeError):
    """Raised by ``require()`` when real-time hardening is degraded."""

    def __init__(self, report: 'Hardening') -> None:
        """Keep the report; the message lists every failure."""
        super().__init__('real-time hardening degraded: ' + '; '.join(
            str(f) for f in report.failures))
        self.report = report


@dataclasses.dataclass
class Hardening:
    """What the RT process obtained from the OS, and what it did not."""

    policy: str = 'SCHED_OTHER'
    priority: int = 0
    mem_locked: bool = False
    dma_latency_held: bool = False
    switch_interval_s: float = 0.0
    gc_frozen: bool = False
    rlimit_rtprio: tuple[int, int] = (0, 0)
    rlimit_memlock: tuple[int, int] = (0, 0)
    sched_rt_runtime_us: int | None = None
    failures: list[HardeningFailure] = dataclasses.field(default_factory=list)
    _dma_fd: int = dataclasses.field(default=-1, repr=False)

    @property
    def degraded(self) -> bool:
        """Tell whether any hardening step failed."""
        return bool(self.failures)

    def fail(self, step: str, err: int | None, fix: str) -> None:
        """Record a failed step (``err`` None: an OSError without errno, recorded as 0)."""
        code = err or 0
        self.failures.append(HardeningFailure(step, code, os.strerror(code), fix))

    def require(self) -> None:
        """Raise :class:`RtHardeningError` when degraded (the ``--require-rt`` semantic)."""
        if self.degraded:
            raise RtHardeningError(self)

    def lines(self) -> list[str]:
        """Return the report as human-readable lines (for stderr at start-up)."""
        def lim(v: int) -> str:
            return 'unlimited' if v == resource.RLIM_INFINITY else str(v)
        out = [
            'rt hardening: {} (policy {} prio {}, mlockall {}, cpu_dma_latency {}, '
            'switch interval {:g} s, gc frozen {})'.format(
                'DEGRADED' if self.degraded else 'ok', self.policy, self.priority,
                'yes' if self.mem_locked else 'no', 'held' if self.dma_latency_held else 'no',
                self.switch_interval_s, 'yes' if self.gc_frozen else 'no'),
            '  RLIMIT_RTPRIO {}/{}, RLIMIT_MEMLOCK {}/{}, sched_rt_runtime_us {}'.format(
                lim(self.rlimit_rtprio[0]), lim(self.rlimit_rtprio[1]),
                lim(self.rlimit_memlock[0]), lim(self.rlimit_memlock[1]),
                self.sched_rt_runtime_us),
        ]
        out.extend('  failed ' + str(f) for f in self.failures)
        return out

    def close(self) -> None:
        """Release /dev/cpu_dma_latency (the kernel drops the request when the fd closes)."""
        if self._dma_fd >= 0:
            fd, self._dma_fd = self._dma_fd, -1
            os.close(fd)
            self.dma_latency_held = False


def explain(step: str, err: int | None, priority: int = 0) -> str:
    """Return the operator fix for a failed hardening step."""
    if step == 'sched_fifo':
        if err == _errno.EPERM:
            return ('needs CAP_SYS_NICE or RLIMIT_RTPRIO >= {} '
                    '(ulimit -r / limits.conf rtprio)'.format(priority))
        if err == _errno.EINVAL:
            return 'priority must be within 1..99 for SCHED_FIFO, got {!r}'.format(priority)
    if step == 'mlockall':
        if err in (_errno.EPERM, _errno.ENOMEM):
            return 'needs CAP_IPC_LOCK or RLIMIT_MEMLOCK unlimited (ulimit -l / limits.conf)'
    if step == 'cpu_dma_latency':
        if err in (_errno.EACCES, _errno.EPERM):
            return 'needs write access to {} (root or a udev rule)'.format(DMA_LATENCY_PATH)
        if err == _errno.ENOENT:
            return 'kernel without PM QoS ({} missing); ignore on VMs'.format(DMA_LATENCY_PATH)
    if step == 'affinity' and err == _errno.EINVAL:
        return 'CPU not in this process cpuset (see taskset -p / cgroup cpuset)'
    if step == 'sched_rt_runtime':
        return ('RT throttling leaves CPU to others every second; '
                'echo -1 > {} to disable'.format(RT_RUNTIME_PATH))
    return 'see {}'.format(step)


def set_thread_fifo(priority: int) -> None:
    """Put the calling thread under SCHED_FIFO at ``priority`` (1..99); SchedError on failure."""
    if not isinstance(priority, int) or isinstance(priority, bool) or not 1 <= priority <= 99:
        raise ValueError('priority must be an int in 1..99, got {!r}'.format(priority))
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as exc:
        raise SchedError(exc.errno, 'sched_setscheduler(SCHED_FIFO, {}): {}'.format(
            priority, exc.strerror), explain('sched_fifo', exc.errno, priority)) from exc


def set_thread_other() -> None:
    """Put the calling thread back under SCHED_OTHER.

    Always allowed from SCHED_FIFO; from SCHED_IDLE only with CAP_SYS_NICE or an RLIMIT_NICE
    that allows the thread's nice value.
    """
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


def thread_policy() -> tuple[str, int]:
    """Return the calling thread's (policy name, priority)."""
    pol = os.sched_getscheduler(0)
    names = {os.SCHED_FIFO: 'SCHED_FIFO', os.SCHED_RR: 'SCHED_RR', os.SCHED_OTHER: 'SCHED_OTHER',
             os.SCHED_BATCH: 'SCHED_BATCH', os.SCHED_IDLE: 'SCHED_IDLE'}
    return names.get(pol, str(pol)), os.sched_getparam(0).sched_priority


def set_thread_affinity(cpus: int | set[int]) -> None:
    """Pin the calling thread to ``cpus`` (an index or a set); SchedError on failure."""
    cpuset = {cpus} if isinstance(cpus, int) else set(cpus)
    if not cpuset or any(not isinstance(c, int) or c < 0 for c in cpuset):
        raise ValueError('cpus must be CPU indices >= 0, got {!r}'.format(cpus))
    try:
        os.sched_setaffinity(0, cpuset)
    except OSError as exc:
        raise SchedError(exc.errno, 'sched_setaffinity({}): {}'.format(
            sorted(cpuset), exc.strerror), explain('affinity', exc.errno)) from exc


def _mlockall() -> int:
    lib = ctypes.CDLL(ctypes.util.find_library('c') or 'libc.so.6', use_errno=True)
    if lib.mlockall(MCL_CURRENT | MCL_FUTURE) != 0:
        return ctypes.get_errno()
    return 0


def munlockall() -> None:
    """Undo ``mlockall`` (tests and orderly shutdown)."""
    ctypes.CDLL(ctypes.util.find_library('c') or 'libc.so.6').munlockall()


def _read_rt_runtime() -> int | None:
    try:
        with open(RT_RUNTIME_PATH, 'rb') as f:
            return int(f.read().strip())
    except (OSError, ValueError):
        return None


def harden(*, priority: int = 0, mlockall: bool = True, cpu_dma_latency: bool = True,
           switch_interval_s: float | None = 1e-4) -> Hardening:
    """Apply the process-wide hardening once, at start-up, and report what was obtained.

    ``priority`` > 0 probes SCHED_FIFO at that priority on the calling thread and puts the
    thread back to SCHED_OTHER (task threads set their own policy); the probe is what tells
    an operator before the tasks start that their priorities will not be granted.
    """
    rep = Hardening()
    rep.rlimit_rtprio = resource.getrlimit(resource.RLIMIT_RTPRIO)
    rep.rlimit_memlock = resource.getrlimit(resource.RLIMIT_MEMLOCK)
    rep.sched_rt_runtime_us = _read_rt_runtime()
    if priority:
        try:
            set_thread_fifo(priority)
        except SchedError as exc:
            rep.fail('sched_fifo', exc.errno, exc.fix)
        else:
            rep.policy, rep.priority = 'SCHED_FIFO', priority
            set_thread_other()
    if mlockall:
        err = _mlockall()
        if err:
            rep.fail('mlockall', err, explain('mlockall', err))
        else:
            rep.mem_locked = True
    if cpu_dma_latency:
        try:
            fd = os.open(DMA_LATENCY_PATH, os.O_WRONLY | os.O_CLOEXEC)
        except OSError as exc:
            # A VM without PM QoS is not a degraded RT setup: note it, do not fail on it.
            if exc.errno != _errno.ENOENT:
                rep.fail('cpu_dma_latency', exc.errno, explain('cpu_dma_latency', exc.errno))
        else:
            try:
                os.write(fd, struct.pack('<i', 0))
            except OSError as exc:
                os.close(fd)
                rep.fail('cpu_dma_latency', exc.errno, explain('cpu_dma_latency', exc.errno))
            else:
                rep._dma_fd = fd
                rep.dma_latency_held = True
    if switch_interval_s is not None:
        sys.setswitchinterval(switch_interval_s)
    rep.switch_interval_s = sys.getswitchinterval()
    return rep


def freeze_gc(report: Hardening | None = None) -> None:
    """Collect once, move every object to the permanent generation and disable the GC.

    Called after start-up (bodies built, sockets bound) so no collection pause can hit a task.
    """
    gc.collect()
    gc.freeze()
    gc.disable()
    if report is not None:
        report.gc_frozen = True


def unfreeze_gc() -> None:
    """Re-enable the GC (tests, shutdown)."""
    gc.unfreeze()
    gc.enable()
