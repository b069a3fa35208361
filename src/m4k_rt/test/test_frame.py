"""The frame executive's schedule and its counting: pure, driven frame by frame (no thread).

The frames are run by calling the executive's frame body with the runner's release fields
set by hand, as its timerfd loop would (``expirations`` > 1: frames skipped by an overrun).
"""

import pytest

from m4k_rt.frame import frame_order, FrameExecutive, releases, schedule
from m4k_rt.schema import ConfigError
from m4k_rt.task import RtTask

MS = 1_000_000


def test_members_run_in_rate_monotonic_order_actuator_first():
    # config order scrambled: sonar 30 ms, led 20 ms, imu 10 ms (85), actuator 10 ms (90)
    assert frame_order([30 * MS, 20 * MS, 10 * MS, 10 * MS], [75, 80, 85, 90]) == [3, 2, 1, 0]


def test_the_harmonic_schedule_of_the_paper_task_set():
    # actuator 10, imu 10, led 20, sonar 30 ms in a 10 ms frame
    got = schedule([1, 1, 2, 3], 7)
    assert got == [[0, 1, 2, 3], [0, 1], [0, 1, 2], [0, 1, 3], [0, 1, 2], [0, 1], [0, 1, 2, 3]]
    # per second: 100 + 100 + 50 + 34 task cycles from 100 wakes (the frame's)
    per_s = schedule([1, 1, 2, 3], 100)
    assert sum(len(f) for f in per_s) == 100 + 100 + 50 + 34


def test_releases_in_a_window_of_frames():
    assert releases(-1, 0, 3) == (1, 0)          # the common release
    assert releases(0, 1, 3) == (0, 0)
    assert releases(2, 3, 3) == (1, 3)
    assert releases(0, 7, 3) == (2, 6)           # frames 3 and 6 in the window: one skipped
    assert releases(5, 6, 1) == (1, 6)


class _Rec:
    def __init__(self, log, name, slow=None):
        self.log, self.name, self.slow = log, name, slow

    def __call__(self, task):
        self.log.append((self.name, task.t_rel, task.expirations))
        if self.slow is not None:
            raise self.slow


def _exe(log, fail=None):
    specs = [('sonar', 30, 75), ('led', 20, 80), ('imu', 10, 85), ('actuator', 10, 90)]
    members = [RtTask(n, prio, p * MS, _Rec(log, n, fail if n == 'led' else None), index=i)
               for i, (n, p, prio) in enumerate(specs)]
    return FrameExecutive(members), {m.name: m for m in members}


def _run(exe, t_rel, exp=1):
    exe.runner.t_rel, exe.runner.expirations = t_rel, exp
    exe._frame(exe.runner)


def test_each_member_is_released_at_its_own_ideal_time_in_order():
    log = []
    exe, m = _exe(log)
    assert exe.frame_ns == 10 * MS and [t.name for t in exe.members] == [
        'actuator', 'imu', 'led', 'sonar']
    for k in range(4):
        _run(exe, 1000 * MS + k * 10 * MS)
    names = [n for n, _, _ in log]
    assert names == ['actuator', 'imu', 'led', 'sonar', 'actuator', 'imu',
                     'actuator', 'imu', 'led', 'actuator', 'imu', 'sonar']
    assert [t for n, t, _ in log if n == 'sonar'] == [1000 * MS, 1030 * MS]
    assert (m['actuator'].cycles, m['imu'].cycles, m['led'].cycles, m['sonar'].cycles) == (
        4, 4, 2, 2)
    assert m['sonar'].ring.total == 2 and not any(t.overruns for t in m.values())


def test_an_overrun_frame_counts_each_members_own_skipped_releases():
    log = []
    exe, m = _exe(log)
    _run(exe, 0)                                  # frame 0: all four
    _run(exe, 70 * MS, exp=7)                     # frames 1..6 skipped, frame 7 runs
    # actuator/imu: releases 1..7 -> runs once late, 6 skipped; led: 2, 4, 6 -> 2 skipped
    # (6 is its last release, run now, late); sonar: 3, 6 -> 1 skipped
    assert (m['actuator'].overruns, m['imu'].overruns, m['led'].overruns,
            m['sonar'].overruns) == (6, 6, 2, 1)
    led, sonar = [(t, e) for n, t, e in log if n == 'led'][-1], [
        (t, e) for n, t, e in log if n == 'sonar'][-1]
    assert led == (60 * MS, 3) and sonar == (60 * MS, 2)     # their own ideal release


def test_a_failing_member_is_counted_and_the_frame_goes_on():
    log = []
    exe, m = _exe(log, fail=ValueError('boom'))
    _run(exe, 0)
    assert m['led'].body_errors == 1 and m['led'].last_error == 'ValueError: boom'
    assert [n for n, _, _ in log] == ['actuator', 'imu', 'led', 'sonar']


def test_a_frame_needs_harmonic_cyclic_members():
    a = RtTask('actuator', 90, 10 * MS, lambda t: None)
    with pytest.raises(ConfigError, match='not a whole multiple'):
        FrameExecutive([a, RtTask('odd', 80, 15 * MS, lambda t: None)])
    with pytest.raises(ConfigError, match='not cyclic'):
        FrameExecutive([a, RtTask('free', 80, 20 * MS, lambda t: None, cyclic=False)])
    with pytest.raises(ConfigError, match='no task'):
        FrameExecutive([])
