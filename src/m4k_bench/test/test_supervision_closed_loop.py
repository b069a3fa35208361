"""Wheel supervision and category-1 stops in the closed loop, judged on ground truth.

The RT controller drives the simulated base in virtual time (m4k_bench.virtualbase: the motor
handler over the simulated SPI DACs and AS5045s, the IMU handler over the myAHRS+ registers
with the simulator's noise and bias, the heartbeat monostable, the drive physics). A fault is
injected once the robot runs at its speed (the simulator's own fault kinds: the encoders keep
sending valid frames); the supervision must latch within 0.3 s of the onset, and the robot
must come to rest on ground truth. A wheel driven at a zero command is judged by the speed
still test with the standstill hold off, and by the standstill window with it on (as
shipped): held inside it, or latched as it leaves; its fault stop cuts the power once the
zero word does not slow it. Faults there from the very start at a creep latch within 0.3 s of
the first command, on a calibrated base, one whose zero trims calibrate left 2 codes low, and
an uncalibrated one (dead band, offsets). Healthy drives on the same bases, at a
creep, with starts, stops, turns and reversals, and at top speed with turns, must latch
nothing. Deterministic: fixed seeds, no wall clock.
"""

import pytest

from m4k_bench.latch import (
    BASES,
    from_the_start,
    HOLD_OFF,
    hold_offset,
    still_after_stop,
    turn_after_guard_stops,
)
from m4k_bench.virtualbase import VirtualBase
from m4k_rt.control.params import SupervisionParams
from m4k_rt.control.supervision import cause_text, COUNT

LATCH_S = 0.3
WINDOW = SupervisionParams().standstill_window     # counts (the shipped default)


def _at_speed(v, w, faults=(), robot=None, seed=3):
    vb = VirtualBase(world={'seed': seed, 'robot': robot or {}})
    ramp = max(abs(v) / 0.37, abs(w) / 1.85) + 0.5
    assert vb.run(ramp, v, w, until=vb.faulted) is None, cause_text(vb.ctl.supervisor.cause)
    for kind, wheel in faults:
        vb.world.set_fault(kind, wheel)
    return vb


@pytest.mark.parametrize('kind, wheel', [('encoder_frozen', 'left'), ('encoder_sign_flip', 'left'),
                                         ('wheel_stall', 'left'), ('encoder_frozen', 'right')])
@pytest.mark.parametrize('v, w', [(0.02, 0.0), (0.02, 0.05), (0.0, 0.1)],
                         ids=['creep-straight', 'creep-turning', 'creep-in-place'])
def test_a_fault_at_a_creep_latches_within_0_3_s_and_the_robot_stops(kind, wheel, v, w):
    vb = _at_speed(v, w, [(kind, wheel)])
    try:
        dt = vb.run(1.0, v, w, until=vb.faulted)
        assert dt is not None and dt <= LATCH_S, (dt, cause_text(vb.ctl.supervisor.cause))
        assert vb.run(2.0, v, w, until=vb.at_rest) is not None
        assert vb.world.peak_speed < 0.1                 # no runaway on ground truth
    finally:
        vb.close()


@pytest.mark.parametrize('v, w', [(0.02, 0.05), (0.0, 0.1), (0.25, 0.4), (0.0, 0.8)],
                         ids=['creep-turning', 'creep-in-place', 'cruise-turning',
                              'cruise-in-place'])
def test_swapped_encoder_channels_latch_within_0_3_s_when_the_wheels_differ(v, w):
    vb = _at_speed(v, w)
    vb.world.set_fault('encoder_swap')
    try:
        dt = vb.run(1.0, v, w, until=vb.faulted)
        assert dt is not None and dt <= LATCH_S, (dt, cause_text(vb.ctl.supervisor.cause))
    finally:
        vb.close()


def test_with_the_hold_off_a_wheel_driven_at_a_zero_command_latches():
    # an amplifier input offset of 1 V: the left wheel turns with the DAC at zero volts; the
    # speed still test judges it (with the hold on, the hold holds it: the next tests)
    vb = VirtualBase(world={'seed': 1, 'robot': {'amp_offset_left_v': 1.0}}, control=HOLD_OFF)
    try:
        dt = vb.run(1.0, 0.0, 0.0, until=vb.faulted)
        assert dt is not None and dt <= LATCH_S
        assert 'commanded still' in cause_text(vb.ctl.supervisor.cause)
    finally:
        vb.close()


@pytest.mark.parametrize('v', [0.02, 0.05])
def test_an_encoder_frozen_from_the_start_at_a_creep_never_runs_away(v):
    vb = VirtualBase(world={'seed': 1, 'faults': [{'at_s': 0.0, 'kind': 'encoder_frozen',
                                                     'wheel': 'left'}]})
    try:
        assert vb.run(1.0, v, 0.0, until=vb.faulted) is not None
        vb.run(3.0, v, 0.0)
        # Until the latch the PI's break-away boost drives the wheel whose encoder never
        # moves up to pi.breakaway_effort (0.15 of full scale: 0.3 m/s at its rim), the body
        # at about half that; the runaway of issue 39 reached 2.0 m/s.
        assert vb.world.peak_speed < 0.25 and vb.world.travelled < 0.05
    finally:
        vb.close()


_CREEPS = [(0.02, 0.0), (-0.02, 0.0), (0.02, 0.05), (0.0, 0.1)]


@pytest.mark.parametrize('base', list(BASES))
@pytest.mark.parametrize('kind', ['encoder_frozen', 'wheel_stall', 'encoder_sign_flip'])
@pytest.mark.parametrize('wheel', ['left', 'right'])
@pytest.mark.parametrize('v, w', _CREEPS, ids=['straight', 'reverse', 'turning', 'in-place'])
def test_a_fault_from_the_very_start_at_a_creep_latches_within_0_3_s_of_the_first_command(
        base, kind, wheel, v, w):
    # the docking case: the fault is there before the first command; a dead band and a
    # trim left low (or none: uncalibrated) hold healthy wheels at rest too, so the
    # supervision judges the break-away effort, the other wheel and the gyro
    seed = 1 + (_CREEPS.index((v, w)) + len(base)) % 3
    latched, _ = from_the_start(kind, wheel, v, w, seed, BASES[base], limit_s=1.0)
    assert latched is not None and latched <= LATCH_S, latched


@pytest.mark.parametrize('base, v, w', [('calibrated', 0.02, 0.05), ('trim -2 codes', 0.02, 0.05),
                                         ('calibrated', 0.0, 0.1), ('uncalibrated', 0.0, 0.1),
                                         ('uncalibrated', 0.0, -0.1),
                                         ('uncalibrated', 0.02, 0.05),
                                         ('uncalibrated', -0.02, 0.05)])
def test_channels_crossed_from_the_start_at_a_creep_latch_within_0_3_s(base, v, w):
    # Uncalibrated and turning at a creep, both wheels' setpoints one way, the wheels' turn
    # differs from the gyro's by about the per-cycle yaw test's tolerance: that test took
    # 0.26-0.37 s forward and 0.25-0.92 s backward (seeds 1-3); the heading integrated over
    # a window (supervision.YAW_WINDOW) takes 0.20-0.25 s
    for seed in (1, 2, 3):
        latched, _ = from_the_start('encoder_swap', None, v, w, seed, BASES[base], limit_s=1.0)
        assert latched is not None and latched <= LATCH_S, (seed, latched)


@pytest.mark.parametrize('v, w, guard', [(0.25, 0.0, False), (0.0, 0.8, False),
                                         (1.0, 0.0, True), (0.25, 0.4, True)],
                         ids=['ramped-stop', 'ramped-stop-in-place', 'guard-stop-1mps',
                              'guard-stop-turning'])
def test_with_the_hold_off_a_wheel_driven_after_a_stop_latches_within_0_3_s_of_when_it_should_rest(
        v, w, guard):
    # a 1 V amplifier offset on the left: the PI holds it while driving, the zero word does
    # not. It should rest once its setpoint is zero, and not before the drive has braked it
    # from speed: judged against the healthy right wheel reaching rest on ground truth.
    after_zero, after_rest = still_after_stop(v, w, guard, seed=2, control=HOLD_OFF)
    assert after_zero is not None
    assert after_rest is not None and after_rest <= LATCH_S, (after_zero, after_rest)
    if not guard:
        assert after_zero <= LATCH_S


@pytest.mark.parametrize('v, w, guard', [(0.25, 0.0, False), (0.0, 0.8, False),
                                         (1.0, 0.0, True), (0.25, 0.4, True)],
                         ids=['ramped-stop', 'ramped-stop-in-place', 'guard-stop-1mps',
                              'guard-stop-turning'])
@pytest.mark.parametrize('seed', [1, 2])
def test_a_wheel_driven_beyond_the_hold_after_a_stop_latches_within_0_3_s_of_when_it_should_rest(
        v, w, guard, seed):
    # the hold as shipped, an 8 V offset on the left (0.33 of full scale, beyond hold.limit:
    # up to it the hold brakes the wheel it finds pulled to rest and holds it there, a safe
    # operating stop): latched before the healthy right wheel reaches rest (None) or within
    # 0.3 s after
    after_zero, after_rest = still_after_stop(v, w, guard, seed=seed, offset_v=8.0)
    assert after_zero is not None
    assert after_rest is None or after_rest <= LATCH_S, (after_zero, after_rest)


@pytest.mark.parametrize('v, w, guard', [(0.25, 0.0, False), (1.0, 0.0, True), (0.25, 0.4, True)],
                         ids=['ramped-stop', 'guard-stop-1mps', 'guard-stop-turning'])
def test_a_wheel_driven_within_the_hold_after_a_stop_is_held_at_rest_or_latched(v, w, guard):
    # a 4 V offset (within hold.limit): after the stop the left wheel rests on ground truth
    # and stays at rest (held), unless the fault latched
    vb = VirtualBase(world={'seed': 1, 'robot': {'amp_offset_left_v': 4.0}})
    try:
        vb.run(max(abs(v) / 0.37, abs(w) / 1.85) + 0.5, v, w)
        kw = {'forward_cap': 0.0, 'guard_active': True} if guard else {}
        vb.run(1.5, 0.0, 0.0, **kw)
        start = vb.world.state().wheel_angle[0]
        vb.run(2.0, 0.0, 0.0, **kw)
        turned = abs(vb.world.state().wheel_angle[0] - start) / COUNT
        # held on ground truth: the hold may hunt a count or two, never rolls on
        assert vb.faulted() or turned < 3.0, turned
    finally:
        vb.close()


@pytest.mark.parametrize('offset_v', [1.0, 2.0, 3.0, 4.0, 6.0])
@pytest.mark.parametrize('seed', [1, 2, 3])
def test_a_held_wheel_never_turns_beyond_the_standstill_window_unlatched(offset_v, seed):
    # from rest on the level, never commanded, the hold as shipped: whatever drives the wheel,
    # it is held inside the window or the fault latches as it leaves (a safe operating stop);
    # an offset that makes the hold hold more than the level allows (2 V and more: the IMU
    # says there is no slope to hold) latches within 0.3 s (measured 0.10 s)
    turned, latched = hold_offset(offset_v, seed)
    assert turned <= WINDOW, (turned, latched)
    if offset_v >= 2.0:
        assert latched is not None and latched <= LATCH_S, (turned, latched)
    else:
        assert latched is None, (turned, latched)     # 1 V: held, a safe operating stop


@pytest.mark.parametrize('offset_v', [2.0, 3.0])
def test_without_the_imu_a_held_offset_is_bounded_by_the_window_alone(offset_v):
    # the negative control: the IMU unplugged, nothing says the floor is level -- the 2-3 V
    # offsets the level test latches at 0.10 s creep to the window's edge (or are held in it)
    # and latch later, if at all; the window still bounds them
    runs = [hold_offset(offset_v, seed, imu=False) for seed in (1, 2, 3)]
    assert all(turned <= WINDOW for turned, _ in runs), runs
    assert all(latched is None or latched > 0.15 for _, latched in runs), runs
    assert any(turned > 0.75 * WINDOW for turned, _ in runs), runs


def test_a_fault_stop_brakes_with_the_drive_then_drops_the_enable():
    vb = _at_speed(1.0, 0.0, [('encoder_frozen', 'left')])
    try:
        assert vb.run(1.0, 1.0, until=vb.faulted) is not None
        ctl = vb.ctl
        assert (ctl.left_code, ctl.right_code, ctl.enable) == (512, 512, 1)
        assert vb.world.drive_enabled()                  # category 1: the drive brakes
        assert vb.run(1.0, 1.0, until=vb.at_rest) is not None
        # the peak braking is the drive's (current limit), not coasting's friction
        assert vb.world.peak_decel > 3.0 * vb.world.robot.coast_decel_mps2
        bound = vb.params.linear.max_velocity / vb.params.guard.brake_deceleration
        vb.run(bound, 1.0)
        assert ctl.enable == 0 and not vb.world.drive_enabled()   # then power is cut
    finally:
        vb.close()


@pytest.mark.parametrize('kind, v, w', [('encoder_frozen', 1.0, 0.0), ('encoder_frozen', 2.0, 0.0),
                                     ('encoder_sign_flip', 1.0, 0.0),
                                     ('encoder_sign_flip', 2.0, 0.0),
                                     ('encoder_sign_flip', 0.5, 0.8)])
def test_a_fault_stop_at_speed_keeps_braking_with_the_drive_until_the_robot_rests(kind, v, w):
    # the zero word slows a braked wheel however its encoder reads it: the enable stays on
    # until the robot is at rest on ground truth (not cut early as a wheel driven at zero)
    vb = _at_speed(v, w, [(kind, 'left')])
    try:
        assert vb.run(1.0, v, w, until=vb.faulted) is not None
        while not vb.at_rest():
            assert vb.ctl.enable == 1 and vb.world.drive_enabled(), f'cut at {vb.t:.2f} s'
            vb.cycle(v, w)
    finally:
        vb.close()


@pytest.mark.parametrize('hold, offset_v', [(HOLD_OFF, 1.0), (HOLD_OFF, 4.0), (HOLD_OFF, 6.0),
                                            (None, 4.0), (None, 6.0)],
                         ids=['hold-off-1V', 'hold-off-4V', 'hold-off-6V', 'hold-4V', 'hold-6V'])
def test_a_fault_stop_cuts_the_power_to_a_wheel_the_zero_word_drives(hold, offset_v):
    # (with the hold as shipped a 1 V offset is held inside the standstill window: no fault)
    # an amplifier offset drives the left wheel at the zero word: once the still fault has
    # latched, the zero word is no brake -- the enable drops within 0.15 s, not after the
    # braking time bound (1.33 s) with the wheel driven all along
    vb = VirtualBase(world={'seed': 2, 'robot': {'amp_offset_left_v': offset_v}}, control=hold)
    try:
        assert vb.run(2.0, 0.0, 0.0, until=vb.faulted) is not None
        assert 'commanded still' in cause_text(vb.ctl.supervisor.cause)
        cut = vb.run(0.15, 0.0, 0.0, until=lambda: not vb.world.drive_enabled())
        assert cut is not None, 'the drive still powered 0.15 s after the latch'
    finally:
        vb.close()


@pytest.mark.parametrize('seed', [1, 2])
@pytest.mark.parametrize('base', list(BASES) + ['uncalibrated, worst dead band'])
def test_healthy_creeping_starts_stops_and_turns_latch_nothing(seed, base):
    # the worst dead band the supervision allows for: 2.4 V (offset -1.2 V, band 1.2 V)
    robot = BASES.get(base, {'amp_offset_left_v': -1.2, 'amp_offset_right_v': 0.3,
                             'deadband_v': 1.2})
    vb = VirtualBase(world={'seed': seed, 'robot': robot})
    segments = [(0.01, 0.0, 0.8), (0.0, 0.0, 0.4), (0.02, 0.0, 0.8), (0.0, 0.0, 0.4),
                (0.02, 0.05, 0.8), (0.0, 0.1, 0.8), (0.0, -0.2, 0.8), (0.05, 0.0, 0.8),
                (-0.05, 0.0, 0.8), (0.0, 0.0, 0.5), (0.08, 0.0, 0.8), (0.0, 0.0, 0.5),
                (0.03, 0.0, 0.5), (0.0, 0.0, 0.3), (0.01, 0.1, 0.6), (0.0, 0.0, 0.3),
                (0.25, 0.4, 1.5), (0.25, -0.4, 1.0), (0.0, 0.0, 1.0)]
    try:
        for v, w, t in segments:
            assert vb.run(t, v, w, until=vb.faulted) is None, \
                (v, w, cause_text(vb.ctl.supervisor.cause))
    finally:
        vb.close()


@pytest.mark.parametrize('base', list(BASES))
def test_healthy_guard_stop_from_speed_reversal_in_place_and_top_speed_turns_latch_nothing(
        base):
    vb = VirtualBase(world={'seed': 1 + len(base) % 3, 'robot': BASES[base]})
    try:
        assert vb.run(3.5, 1.0, 0.0, until=vb.faulted) is None
        assert vb.run(1.0, 1.0, 0.0, until=vb.faulted, forward_cap=0.0,
                      guard_active=True) is None
        for w in (1.5, -1.5, 0.0):
            assert vb.run(1.5, 0.0, w, until=vb.faulted) is None, \
                cause_text(vb.ctl.supervisor.cause)
        # top speed, then turns there (an uncalibrated wheel saturates short of its setpoint)
        for v, w, t in ((2.0, 0.0, 6.0), (2.0, 0.6, 2.0), (1.5, -0.6, 2.0), (0.0, 0.0, 2.0)):
            assert vb.run(t, v, w, until=vb.faulted) is None, \
                (v, w, cause_text(vb.ctl.supervisor.cause))
    finally:
        vb.close()


_ARCS = [(0.5, 0.5), (0.5, -0.5), (0.25, 0.5), (1.0, 0.5), (0.1, 0.2), (2.0, 1.0)]


@pytest.mark.parametrize('base', list(BASES))
@pytest.mark.parametrize('lag, jitter', [(0.0, 0.0), (0.02, 0.0), (0.05, 0.03)],
                         ids=['gyro-in-step', 'gyro-20ms-late', 'gyro-50-80ms-late'])
def test_healthy_arcs_from_rest_latch_nothing_when_the_gyro_comes_late(base, lag, jitter):
    # v ramps at 0.37 m/s^2 and w at 1.85 rad/s^2, so an arc from rest pivots on its inner
    # wheel, still below break-away, while the outer wheel turns the body: the gyro, a hop
    # behind the encoders, must be compared with them at its own instant (issue 39: a
    # healthy wheel latched frozen at the start of arc_leg_outside_0_5 under load)
    for seed in (1, 2):
        for v, w in _ARCS:
            vb = VirtualBase(world={'seed': seed, 'robot': BASES[base]}, imu_lag_s=lag,
                             imu_jitter_s=jitter)
            try:
                assert vb.run(1.5, v, w, until=vb.faulted) is None, \
                    (seed, v, w, cause_text(vb.ctl.supervisor.cause))
            finally:
                vb.close()


@pytest.mark.parametrize('kind', ['encoder_frozen', 'wheel_stall', 'encoder_sign_flip'])
@pytest.mark.parametrize('v, w', [(0.02, 0.0), (0.02, 0.05), (0.0, 0.1)],
                         ids=['straight', 'turning', 'in-place'])
def test_a_fault_from_the_start_latches_within_0_3_s_with_the_gyro_30_ms_late(kind, v, w):
    for wheel in ('left', 'right'):
        latched, _ = from_the_start(kind, wheel, v, w, 2, BASES['uncalibrated'], limit_s=1.0,
                                    imu_lag_s=0.03)
        assert latched is not None and latched <= LATCH_S, (wheel, latched)


@pytest.mark.parametrize('base', list(BASES))
@pytest.mark.parametrize('v, w', [(2.0, 0.5), (1.0, 0.5), (2.0, -0.5)])
def test_a_guard_stop_released_mid_brake_with_a_turn_held_latches_nothing(base, v, w):
    # the guard stops an arc (v cut to 0 at once, w held) and releases to a creep while the
    # robot still rolls at speed: the inner wheel's setpoint reverses while it rolls forward
    # and the PI brakes it at full effort. Seen on the stack in arc_leg_inside_top: a wrong-way
    # latch 0.1 s after the release; with that fixed, a stall latch on the braking effort
    vb = VirtualBase(world={'seed': 2, 'robot': BASES[base]}, imu_lag_s=0.02)
    try:
        assert vb.run(max(v / 0.37, 0.5) + 1.0, v, w, until=vb.faulted) is None
        assert vb.run(0.25, v, w, until=vb.faulted, forward_cap=0.0, guard_active=True) is None
        assert vb.run(2.0, v, w, until=vb.faulted, forward_cap=0.022) is None, \
            cause_text(vb.ctl.supervisor.cause)
    finally:
        vb.close()


@pytest.mark.parametrize('base', list(BASES))
@pytest.mark.parametrize('lag', [0.0, 0.03], ids=['gyro-in-step', 'gyro-30ms-late'])
def test_guard_stops_then_a_slow_turn_in_place_latch_nothing(base, lag):
    # wall.*.turning and wheel_leg.slow.turning of the envelope: an arc, the guard stopping and
    # releasing to a creep three times, then a slow turn in place. Three things read a healthy
    # wheel as frozen: its roll-down after a release counted as "seen following" (it then stops
    # by itself below the break-away, and got no boost); the guard's "still braking forward"
    # re-armed on a pivot's one-wheel speed and reset both PIs every few cycles; and the
    # unseen-motion window, read at the gyro's aligned (older) instant, counted the wheel's
    # last motion before it stopped as unseen. Before the fix: 30 of these 72 runs latched.
    latched = [(s, w, t) for s in (1, 2, 3) for w in (0.02, 0.057, 0.1, -0.057)
               if (t := turn_after_guard_stops(w, s, BASES[base], lag)) is not None]
    assert latched == []


@pytest.mark.parametrize('kind, wheel', [('encoder_frozen', 'left'), ('wheel_stall', 'left'),
                                         ('encoder_sign_flip', 'right'),
                                         ('encoder_frozen', 'right')])
@pytest.mark.parametrize('base', list(BASES))
def test_a_fault_as_the_guard_releases_to_a_creep_latches_within_0_3_s(kind, wheel, base):
    # The roll-down after a release is no evidence the wheel follows, so a fault there is
    # judged on the effort (the break-away boost), the gyro and the other wheel: still 0.3 s.
    vb = VirtualBase(world={'seed': 2, 'robot': BASES[base]}, imu_lag_s=0.03)
    try:
        assert vb.run(2.0, 0.25, 0.1, until=vb.faulted) is None
        assert vb.run(0.1, 0.25, 0.1, until=vb.faulted, forward_cap=0.0,
                      guard_active=True) is None
        vb.world.set_fault(kind, wheel)
        dt = vb.run(1.0, 0.25, 0.1, until=vb.faulted, forward_cap=0.05)
        assert dt is not None and dt <= LATCH_S, (dt, cause_text(vb.ctl.supervisor.cause))
        assert vb.run(2.0, 0.0, 0.0, until=vb.at_rest) is not None
    finally:
        vb.close()
