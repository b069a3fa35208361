"""The wheel supervision's cross-checks, one at a time, on synthetic samples (pure).

Each check is fed what a fault makes the wheels, the PI and the gyro report, and what a healthy
base under the same command reports; the first must latch within the check's time (0.3 s at
most), the second never. Speeds in rad/s at the wheel, 10 ms cycles, one encoder sample each.
"""

import math

import pytest

from m4k_rt.control.params import control_params, SupervisionParams
from m4k_rt.control.supervision import COUNT, WheelSupervisor
from m4k_rt.protocol import FaultCause

DT = 0.01
P = control_params(None)
FF = P.feed_forward
R_OVER_T = P.wheel_radius / P.track_width


def sup(**kw):
    return WheelSupervisor(SupervisionParams(**kw), P.wheel_radius, P.track_width, FF)


class Wheels:
    """Angles integrated from the speeds each cycle; ``step`` feeds one cycle to ``s``."""

    def __init__(self, s):
        self.s = s
        self.angle = [0.0, 0.0]
        self.t = 0.0

    def step(self, sp, meas, u=None, yaw=math.nan, read=None, sat=(False, False), held=False,
             level_hold=None):
        """One cycle: the wheels turn at ``meas`` (``read``: what the encoders say instead)."""
        for k in (0, 1):
            self.angle[k] += meas[k] * DT
        shown = self.angle if read is None else read
        self.t += DT
        stamp = round(self.t * 1e9)
        self.s.encoders(shown[0], shown[1], stamp)
        if yaw == yaw:
            self.s.gyro(yaw, stamp)
        if u is None:
            u = (FF * sp[0], FF * sp[1])
        return self.s.step(DT, sp[0], sp[1], meas[0], meas[1], u[0], u[1], sat[0], sat[1], yaw,
                           (held, held), level_hold)

    def run(self, seconds, *args, **kw):
        """Run; return the time into the run at which the fault latched (None: never)."""
        for k in range(round(seconds / DT)):
            if self.step(*args, **kw):
                return (k + 1) * DT
        return None


def test_the_supervisor_takes_its_settings_from_their_one_declaration():
    params = SupervisionParams()
    s = WheelSupervisor(params, P.wheel_radius, P.track_width, FF)
    assert s.p is params and s.enabled == params.enabled


def test_a_wheel_driven_while_commanded_still_latches():
    w = Wheels(sup())
    dt = w.run(1.0, (0.0, 0.0), (0.5, 0.0))            # the left wheel creeps at 5 cm/s
    assert dt is not None and dt <= 0.3
    assert w.s.cause == FaultCause.LEFT_STILL


def test_a_wheel_braking_down_at_a_zero_setpoint_is_still_healthy():
    w = Wheels(sup())
    speed = 19.0                                        # a guard stop from top speed
    for _ in range(100):
        speed = max(speed - 28.0 * DT, 0.0)             # the drive's braking: ~28 rad/s^2
        assert not w.step((0.0, 0.0), (speed, speed))
    assert not w.s.latched


def test_encoder_noise_at_rest_is_not_motion():
    # +/-1 count flicker at rest, read as the speed it implies over the 20 ms feedback window
    s = sup()
    last = 0.0
    for k in range(300):
        flick = COUNT * (1, -1, 0)[k % 3]
        speed = (flick - last) / (2 * DT)
        last = flick
        s.encoders(flick, -flick, (k + 1) * 10_000_000)
        assert not s.step(DT, 0.0, 0.0, speed, -speed, 0.0, 0.0, False, False, 0.0)


def test_wheels_describing_a_turn_the_gyro_does_not_see_latch():
    # the left encoder flipped at 4 cm/s: the wheels say a spin, the body drives straight
    w = Wheels(sup())
    dt = w.run(1.0, (0.4, 0.4), (-0.4, 0.4), yaw=0.0, u=(FF * 0.4, FF * 0.4))
    assert dt is not None and dt <= 0.3
    # from a start, the counts-against test (the same gyro, integrated) names the wheel first
    assert w.s.cause & (FaultCause.YAW | FaultCause.LEFT_WRONG_WAY)


@pytest.mark.parametrize('slip', [0.0, 0.2])
def test_the_gyro_agreeing_within_slip_does_not_latch(slip):
    w = Wheels(sup())
    wl, wr = 2.0, 4.0                                   # a turn at 0.3 m/s
    yaw = R_OVER_T * (wr - wl) * (1.0 - slip)           # the body turns less when tyres slip
    assert w.run(2.0, (wl, wr), (wl, wr), yaw=yaw) is None


def test_a_creep_turn_the_gyro_sees_the_other_way_latches_on_the_integrated_heading():
    # crossed channels in a creep turn: the wheels describe +0.04 rad/s, the body turns
    # -0.04 -- a per-cycle difference (0.08) inside that test's tolerance (0.08 + a quarter
    # of the rate), 0.012 rad of heading over the window, beyond its 8 counts
    w = Wheels(sup())
    dr = 0.04 / R_OVER_T
    sp = (0.2, 0.2 + dr)
    dt = w.run(1.0, sp, sp, yaw=-0.04)
    assert dt is not None and dt <= 0.3 and w.s.cause == FaultCause.YAW


def test_a_reversal_in_place_the_gyro_follows_within_slip_does_not_latch():
    # 1.5 rad/s one way, then the other, the wheels' rate ramping through zero at 12 rad/s^2
    # of body yaw; the body turns a fifth less (slip) and the gyro says so
    # (the angles integrated as the gyro's heading is, sample to sample: a wheel's angle is
    # the true integral of its speed, not the last speed times the period)
    w = Wheels(sup())
    rate = 0.0
    angle = [0.0, 0.0]
    for k in range(300):
        target = 1.5 if (k // 100) % 2 == 0 else -1.5
        last = rate
        rate += max(-0.12, min(0.12, target - rate))
        dw = rate / R_OVER_T / 2.0
        half = 0.5 * (rate + last) / R_OVER_T / 2.0 * DT
        angle = [angle[0] - half, angle[1] + half]
        assert not w.step((-dw, dw), (-dw, dw), yaw=0.8 * rate, read=angle), (k, w.s.cause)


def test_no_gyro_sample_means_no_yaw_test():
    w = Wheels(sup())
    assert w.run(1.0, (0.2, 0.2), (-0.2, 0.2), yaw=math.nan) is None


def test_effort_without_motion_is_a_stall_below_saturation():
    w = Wheels(sup())
    still = [0.0, 0.0]
    # the PI drives the left wheel at a free-running 5 rad/s, the encoder flickers at rest
    dt = None
    for k in range(40):
        still[0] = COUNT * (k % 2)
        if w.step((0.3, 0.3), (0.0, 0.3), u=(5.0 * FF, 0.3 * FF), read=[still[0], w.angle[1]]):
            dt = w.t
            break
    assert dt is not None and dt <= 0.3
    assert w.s.cause & (FaultCause.LEFT_STALL | FaultCause.LEFT_FROZEN)


def test_a_wheel_that_followed_then_froze_latches_at_a_creep():
    w = Wheels(sup())
    assert w.run(1.0, (0.2, 0.2), (0.2, 0.2)) is None     # 2 cm/s, both healthy
    frozen = w.angle[0]
    dt = None
    for k in range(100):
        if w.step((0.2, 0.2), (0.2, 0.2), read=[frozen, w.angle[1] + 0.2 * DT]):
            dt = (k + 1) * DT
            break
    assert dt is not None and dt <= 0.3
    assert w.s.cause & FaultCause.LEFT_FROZEN


def test_a_wheel_not_yet_broken_away_under_a_small_effort_is_not_frozen():
    # an uncalibrated amplifier: the left wheel needs more than the feed-forward to start
    w = Wheels(sup())
    assert w.run(1.0, (0.3, 0.3), (0.0, 0.3), u=(0.05, 0.3 * FF), yaw=R_OVER_T * 0.3) is None


def test_a_still_reading_wheel_the_gyro_shows_turning_unseen_latches():
    # frozen from the start: both wheels turn, the left encoder reads nothing, the body
    # drives straight although the encoders describe a pivot
    w = Wheels(sup())
    dt = None
    for k in range(100):
        if w.step((0.2, 0.2), (0.0, 0.2), u=(0.02, 0.2 * FF), yaw=0.0,
                  read=[0.0, w.angle[1] + 0.2 * DT]):
            dt = (k + 1) * DT
            break
    assert dt is not None and dt <= 0.3


def test_a_still_reading_wheel_turning_unseen_in_place_latches_and_is_flagged_unseen():
    # in place at a creep: the left encoder frozen while the wheel turns backwards as told;
    # the gyro shows the whole turn, the encoders half of it
    w = Wheels(sup())
    dt = None
    for k in range(100):
        if w.step((-0.3, 0.3), (-0.3, 0.3), u=(-0.02, 0.3 * FF), yaw=R_OVER_T * 0.6,
                  read=[0.0, w.angle[1] + 0.3 * DT]):
            dt = (k + 1) * DT
            break
    assert dt is not None and dt <= 0.3
    assert w.s.cause & FaultCause.LEFT_FROZEN and w.s.unseen[0]


def test_gyro_bias_over_a_slow_start_is_not_unseen_motion():
    # the left wheel held by its dead band for 0.3 s under a small effort, the gyro's bias
    # 2.5 sd (0.005 rad/s) the wrong way: its drift is no motion of the still wheel
    w = Wheels(sup())
    assert w.run(0.3, (0.3, 0.3), (0.0, 0.3), u=(0.05, 0.3 * FF),
                 yaw=R_OVER_T * 0.3 - 0.005) is None
    assert not w.s.unseen[0]


def test_supervision_off_latches_nothing():
    w = Wheels(sup(enabled=False))
    assert w.run(1.0, (0.0, 0.0), (3.0, -3.0), yaw=0.0) is None


def test_a_reversal_braking_the_wheel_is_not_wrong_way_but_one_that_does_not_slow_is():
    # forward at 9 rad/s, then the setpoint -1 (a guard released mid-brake with a turn held):
    # braked at 28 rad/s^2 the wheel is no fault, nor is the full backward effort a stall
    w = Wheels(sup())
    assert w.run(1.0, (9.0, 9.0), (9.0, 9.0)) is None
    speed = 9.0
    for _ in range(60):
        speed = max(speed - 28.0 * DT, -1.0)
        braking = speed > -1.0                   # full effort back until it gets there
        assert not w.step((-1.0, 1.0), (speed, 1.0), u=(-1.0 if braking else -FF, FF),
                          sat=(braking, False))
    # the same reversal with a wheel that keeps rolling forward (its encoder or drive lies)
    w = Wheels(sup())
    assert w.run(1.0, (9.0, 9.0), (9.0, 9.0)) is None
    dt = w.run(2.0, (-1.0, 1.0), (9.0, 1.0), u=(-1.0, FF), sat=(True, False))
    assert dt is not None and dt <= 0.3 + 9.0 / P.supervision.still_deceleration


def test_a_held_wheel_is_judged_by_its_standstill_window_not_its_speed():
    # zero setpoints, the hold holding: a wheel still taking a ramp's load rolls slowly for
    # longer than still_time (0.2 rad/s for 0.4 s: 52 counts) -- no fault; the same roll
    # with no hold is the speed still test's symptom
    window = SupervisionParams().standstill_window
    roll = (0.2, 0.0)
    assert 0.2 * 0.4 / COUNT < window
    assert Wheels(sup()).run(0.4, (0.0, 0.0), roll, u=(0.05, 0.0), held=True) is None
    assert Wheels(sup()).run(0.4, (0.0, 0.0), roll, u=(0.0, 0.0)) is not None


@pytest.mark.parametrize('k', [0, 1])
@pytest.mark.parametrize('direction', [1.0, -1.0])
def test_a_held_wheel_leaving_its_standstill_window_latches_at_once(k, direction):
    window = SupervisionParams().standstill_window
    s = sup()
    w = Wheels(s)
    meas = [0.0, 0.0]
    meas[k] = direction * 0.05      # slow: 0.33 counts a cycle, never the still test's speed
    assert not w.step((0.0, 0.0), meas, u=(0.0, 0.0), held=True)
    origin = w.angle[k]             # where the hold began: the first held sample
    while not w.step((0.0, 0.0), meas, u=(0.0, 0.0), held=True):
        assert abs(w.angle[k] - origin) / COUNT <= window + 1e-9, 'outside the window, unlatched'
    assert abs(w.angle[k] - origin) / COUNT > window
    cause = FaultCause.LEFT_STILL if k == 0 else FaultCause.RIGHT_STILL
    assert s.cause == int(cause)


@pytest.mark.parametrize('k', [0, 1])
@pytest.mark.parametrize('sign', [1.0, -1.0])
def test_a_hold_holding_a_load_on_the_level_latches_at_once(k, sign):
    # the IMU says level: a hold integral beyond level_hold_effort is holding an amplifier
    # that drives the wheel -- latched in the cycle it passes, wherever the wheel is
    limit = SupervisionParams().level_hold_effort
    s = sup()
    w = Wheels(s)
    load = [0.0, 0.0]
    load[k] = sign * 0.9 * limit
    for _ in range(20):
        assert not w.step((0.0, 0.0), (0.0, 0.0), u=tuple(load), held=True, level_hold=load)
    load[k] = sign * 1.01 * limit
    assert w.step((0.0, 0.0), (0.0, 0.0), u=tuple(load), held=True, level_hold=load)
    cause = FaultCause.LEFT_STILL if k == 0 else FaultCause.RIGHT_STILL
    assert s.cause == int(cause)


def test_a_hold_load_off_the_level_while_driving_or_braking_is_no_symptom():
    # the same load with the IMU saying "a slope" (None) is a ramp the hold is for; a load
    # at a nonzero setpoint is not the hold's
    limit = SupervisionParams().level_hold_effort
    load = [2.0 * limit, 0.0]
    assert Wheels(sup()).run(1.0, (0.0, 0.0), (0.0, 0.0), u=tuple(load), held=True,
                             level_hold=None) is None
    assert Wheels(sup()).run(1.0, (1.0, 1.0), (1.0, 1.0), level_hold=load) is None
    # nor on a wheel the hold found pulled that has not read still yet: it still brakes from
    # speed (a late encoder sample makes a braking wheel read pulled, and the hold's integral
    # then brakes it harder -- no amplifier fault)
    assert Wheels(sup()).run(1.0, (0.0, 0.0), (0.0, 0.0), u=tuple(load), held=False,
                             level_hold=load) is None


def test_the_window_restarts_with_each_hold():
    # held, 40 counts away; the hold ends (a command) and a new one begins: measured afresh
    window = SupervisionParams().standstill_window
    s = sup()
    w = Wheels(s)
    creep = 0.05
    n = round(0.7 * window * COUNT / (creep * DT))
    for _ in range(n):
        assert not w.step((0.0, 0.0), (creep, 0.0), u=(0.0, 0.0), held=True)
    for _ in range(5):
        assert not w.step((1.0, 1.0), (1.0, 1.0))
    for _ in range(n):
        assert not w.step((0.0, 0.0), (creep, 0.0), u=(0.0, 0.0), held=True)
