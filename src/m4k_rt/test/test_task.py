"""Runtime tests of timerfd, thread scheduling and RtTask (count events, never assert timing)."""

import errno
import threading

import pytest

from m4k_rt import sched, timerfd

MS = 1_000_000


def test_timerfd_counts_expirations_after_a_late_read():
    with timerfd.TimerFd() as tfd:
        now = timerfd.monotonic_ns()
        tfd.set_abs(now - 35 * MS, 10 * MS)   # four releases already passed
        assert tfd.read() >= 4


def test_timerfd_nonblocking_read_before_expiry_is_zero():
    with timerfd.TimerFd(nonblocking=True) as tfd:
        tfd.set_abs(timerfd.monotonic_ns() + 10**9, 10**9)
        assert tfd.read() == 0


def test_timerfd_rejects_bad_times_and_closed_use():
    tfd = timerfd.TimerFd()
    with pytest.raises(ValueError, match='first_ns'):
        tfd.set_abs(0, 10)
    with pytest.raises(ValueError, match='interval_ns'):
        tfd.set_abs(1, -1)
    tfd.close()
    assert tfd.closed and tfd.fileno() == -1
    with pytest.raises(OSError):
        tfd.set_abs(1, 1)


def test_set_thread_fifo_applies_to_calling_thread_only():
    seen = {}

    def worker():
        try:
            sched.set_thread_fifo(10)
        except sched.SchedError as exc:
            seen['err'] = exc
        seen['policy'] = sched.thread_policy()
        sched.set_thread_other()

    th = threading.Thread(target=worker)
    th.start()
    th.join(5)
    if 'err' in seen:
        assert seen['err'].errno == errno.EPERM and 'RLIMIT_RTPRIO' in seen['err'].fix
    else:
        assert seen['policy'] == ('SCHED_FIFO', 10)
    assert sched.thread_policy()[0] == 'SCHED_OTHER'


def test_set_thread_fifo_rejects_out_of_range_priority():
    with pytest.raises(ValueError, match='100'):
        sched.set_thread_fifo(100)


def test_explain_eperm_names_the_fix():
    fix = sched.explain('sched_fifo', errno.EPERM, 90)
    assert 'CAP_SYS_NICE' in fix and '>= 90' in fix
    assert 'CAP_IPC_LOCK' in sched.explain('mlockall', errno.EPERM)


def test_harden_reports_limits_and_require_raises_when_degraded():
    rep = sched.harden(priority=0, mlockall=False, cpu_dma_latency=False,
                       switch_interval_s=None)
    try:
        assert rep.sched_rt_runtime_us is None or rep.sched_rt_runtime_us >= -1
        assert len(rep.rlimit_rtprio) == 2
        assert not rep.degraded
        rep.require()
        rep.fail('sched_fifo', errno.EPERM, sched.explain('sched_fifo', errno.EPERM, 90))
        assert rep.degraded
        with pytest.raises(sched.RtHardeningError, match='EPERM'):
            rep.require()
        assert any('failed sched_fifo' in line for line in rep.lines())
    finally:
        rep.close()


def test_harden_holds_dma_latency_until_close():
    rep = sched.harden(priority=0, mlockall=False, cpu_dma_latency=True,
                       switch_interval_s=None)
    rep.close()
    assert not rep.dma_latency_held
    assert rep._dma_fd == -1
