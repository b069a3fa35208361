"""Runtime tests of timerfd, thread scheduling and RtTask (count events, never assert timing)."""

import errno
import threading

import pytest

from m4k_rt import sched, task, timerfd

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
    # The caller's own policy, whatever it is (SCHED_IDLE, say, where a thread without
    # CAP_SYS_NICE cannot go back to SCHED_OTHER).
    before = sched.thread_policy()

    def worker():
        try:
            sched.set_thread_fifo(10)
        except sched.SchedError as exc:
            seen['err'] = exc
        seen['policy'] = sched.thread_policy()
        if 'err' not in seen:
            sched.set_thread_other()

    th = threading.Thread(target=worker)
    th.start()
    th.join(5)
    if 'err' in seen:
        assert seen['err'].errno == errno.EPERM and 'RLIMIT_RTPRIO' in seen['err'].fix
        assert seen['policy'] == before
    else:
        assert seen['policy'] == ('SCHED_FIFO', 10)
    assert sched.thread_policy() == before


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


# --- RtTask ---

def _run_for(t, seconds):
    t.start()
    threading.Event().wait(seconds)
    t.stop()
    assert t.join(2.0), 'task did not stop within the bound'


def test_task_cycles_and_records_samples():
    seen = []
    t = task.RtTask('cyc', 20, 5 * MS, lambda ctx: seen.append(ctx.t_rel))
    _run_for(t, 0.3)
    assert t.cycles >= 20
    assert len(seen) >= t.cycles
    first, end, lost = t.ring.available(0)
    assert end == t.cycles and lost == 0
    rows = t.ring.rows(first, end)
    for (rel, start, stop, _exp), nxt in zip(rows, rows[1:], strict=False):
        assert rel <= start <= stop
        assert nxt[0] - rel == nxt[3] * 5 * MS   # releases advance by whole periods
    assert t.body_errors == 0 and not t.is_alive()


def test_task_runs_under_sched_fifo_or_reports_why():
    policy = {}
    t = task.RtTask('pol', 33, 5 * MS, lambda ctx: policy.setdefault('p', sched.thread_policy()))
    _run_for(t, 0.05)
    if t.fifo:
        assert policy['p'] == ('SCHED_FIFO', 33)
    else:
        assert 'RLIMIT_RTPRIO' in t.sched_error


def test_slow_body_overruns_are_counted_and_releases_skipped():
    def slow(ctx):
        if ctx.cycles % 4 == 1:
            timerfd_sleep(12 * MS)

    t = task.RtTask('slow', 20, 5 * MS, slow)
    _run_for(t, 0.3)
    rows = t.ring.rows(*t.ring.available(0)[:2])
    assert t.overruns >= 2
    assert t.overruns == sum(r[3] - 1 for r in rows)
    assert t.deadline_misses >= 1
    assert all(r[3] >= 1 for r in rows)


def timerfd_sleep(ns):
    # Busy-wait stand-in for work: time.sleep would be a forbidden call in a loop.
    end = timerfd.monotonic_ns() + ns
    while timerfd.monotonic_ns() < end:
        pass


def test_body_exception_is_counted_and_loop_continues():
    def flaky(ctx):
        if ctx.cycles % 2 == 0:
            raise ValueError('bad cycle %d' % ctx.cycles)

    t = task.RtTask('flaky', 20, 5 * MS, flaky)
    _run_for(t, 0.2)
    assert t.body_errors >= 5
    assert t.cycles > t.body_errors
    assert t.last_error.startswith('ValueError: bad cycle')
    assert t.last_error_site[0] == __file__


def test_stop_wakes_a_long_period_task_at_once():
    t = task.RtTask('long', 20, 10 * 10**9, lambda ctx: None)
    t.start()
    t.stop()
    assert t.join(1.0)


def test_paper_api_free_running_body_waits_period():
    counts = {'n': 0, 'ovr': 0}

    def body(ctx):
        while True:
            counts['ovr'] += task.pt_task_wait_period()
            counts['n'] += 1
            assert task.current_task() is ctx
            assert task.pt_timer_read() >= ctx.t_start

    t = task.pt_create_task_rt('paper', 20, 5 * MS, body, cyclic=False)
    threading.Event().wait(0.2)
    t.stop()
    assert t.join(2.0)
    assert counts['n'] >= 10 and t.cycles >= counts['n'] - 1
    assert t.body_errors == 0


def test_pt_task_wait_period_outside_task_fails():
    with pytest.raises(task.TaskError, match='outside'):
        task.pt_task_wait_period()


@pytest.mark.parametrize('kwargs, match', [
    ({'name': 'x' * 17, 'priority': 10, 'period_ns': MS}, 'name'),
    ({'name': 'a', 'priority': 0, 'period_ns': MS}, 'priority'),
    ({'name': 'a', 'priority': 10, 'period_ns': 0}, 'period_ns'),
    ({'name': 'a', 'priority': 10, 'period_ns': MS, 'cpu': -1}, 'cpu'),
])
def test_task_rejects_bad_parameters(kwargs, match):
    with pytest.raises(task.TaskError, match=match):
        task.RtTask(body=lambda ctx: None, **kwargs)


def test_rusage_counts_voluntary_switches_beyond_timer_wait():
    lock = threading.Event()

    def blocking(ctx):
        lock.wait(0.0005)   # blocks on something that is not the timer

    t = task.RtTask('blk', 20, 5 * MS, blocking)
    _run_for(t, 0.2)
    assert t.rusage.nvcsw_extra >= 1
    assert t.rusage.nvcsw >= t.cycles
