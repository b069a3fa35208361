import math

import pytest

from m4k_rt.control.pid import PidError, WheelSpeedPI

DT = 0.01


def test_feed_forward_alone_gives_the_open_loop_command():
    pi = WheelSpeedPI(kp=0.0, ki=0.0, kff=1 / 20.0)
    assert pi.update(10.0, 0.0, DT) == pytest.approx(0.5)


def test_proportional_and_integral_hand_computed():
    pi = WheelSpeedPI(kp=0.1, ki=2.0, kff=0.0)
    # e = 1: p = 0.1, i = 2 * 1 * 0.01 = 0.02
    assert pi.update(1.0, 0.0, DT) == pytest.approx(0.12)
    assert pi.update(1.0, 0.0, DT) == pytest.approx(0.14)
    assert pi.integral == pytest.approx(0.04)


def _saturate_then_recover(mode: str) -> tuple[WheelSpeedPI, int]:
    pi = WheelSpeedPI(kp=0.05, ki=5.0, kff=0.05, anti_windup=mode)
    for _ in range(200):   # 2 s demanding 40 rad/s of a plant that can reach 20: saturated
        assert pi.update(40.0, 20.0, DT) == 1.0
    assert pi.saturated
    # now the setpoint drops below what is measured: how many cycles until the output leaves 1?
    for n in range(1, 1000):
        if pi.update(10.0, 20.0, DT) < 1.0:
            return pi, n
    return pi, 1000


def test_clamping_keeps_integrator_bounded_and_unsaturates_at_once():
    pi, n = _saturate_then_recover('clamping')
    assert n == 1


def test_back_calculation_unwinds_fast():
    pi, n = _saturate_then_recover('back_calculation')
    assert n <= 2


def test_without_anti_windup_the_same_case_would_stay_saturated_long():
    # Reference: a plain PI (huge limit, then clipped by hand) keeps winding up.
    pi = WheelSpeedPI(kp=0.05, ki=5.0, kff=0.05, limit=1e9)
    for _ in range(200):
        pi.update(40.0, 20.0, DT)
    n = next(n for n in range(1, 10000) if min(pi.update(10.0, 20.0, DT), 1.0) < 1.0)
    assert n > 100


def test_integrator_still_works_when_error_pulls_out_of_saturation():
    pi = WheelSpeedPI(kp=0.0, ki=1.0, kff=0.0, anti_windup='clamping')
    pi.integral = 0.99
    assert pi.update(5.0, 0.0, DT) == 1.0   # pushes further: frozen
    assert pi.integral == 0.99
    # the wheel still rolling backwards (the setpoint's way): the integrator unwinds freely
    assert pi.update(-5.0, -1.0, DT) == pytest.approx(0.95)


@pytest.mark.parametrize('sign', [1.0, -1.0])
def test_a_wheel_at_rest_is_never_pushed_against_its_setpoint(sign):
    """The end of a deceleration ramp: the wheel has stopped while the setpoint is still a
    few mrad/s its way and the integrator holds the ramp's braking torque. The output is zero,
    not that torque (it drove a stopped robot backwards), and no reverse torque stays stored."""
    pi = WheelSpeedPI(kp=0.03, ki=0.4, kff=0.05)
    pi.integral = -0.04 * sign
    assert pi.update(0.01 * sign, 0.0, DT) == 0.0
    assert pi.update(0.005 * sign, 0.0, DT) == 0.0
    # the stored torque is gone: a fresh setpoint its way drives the wheel its way at once
    assert sign * pi.update(1.0 * sign, 0.0, DT) > 0.0
    # a wheel rolling the other way (pushed, on a slope) is driven the setpoint's way
    pi.integral = -0.04 * sign
    assert sign * pi.update(0.5 * sign, -2.0 * sign, DT) > 0.0


@pytest.mark.parametrize('sign', [1.0, -1.0])
def test_a_wheel_faster_than_its_setpoint_is_still_braked(sign):
    pi = WheelSpeedPI(kp=0.1, ki=0.4, kff=0.05)
    assert sign * pi.update(1.0 * sign, 6.0 * sign, DT) < 0.0     # braking torque, its sign
    pi.integral = -0.05 * sign
    assert sign * pi.update(0.01 * sign, 0.3 * sign, DT) < 0.0    # still turning its way


def test_reset_clears_integral():
    pi = WheelSpeedPI(kp=0.1, ki=1.0)
    pi.update(1.0, 0.0, DT)
    pi.reset()
    assert pi.integral == 0.0


@pytest.mark.parametrize('kwargs,field', [
    ({'kp': -1.0, 'ki': 0.0}, 'kp'), ({'kp': 1.0, 'ki': float('nan')}, 'ki'),
    ({'kp': 1.0, 'ki': 1.0, 'limit': 0.0}, 'limit'),
    ({'kp': 1.0, 'ki': 1.0, 'anti_windup': 'none'}, 'anti_windup'),
])
def test_bad_gains_are_rejected(kwargs, field):
    with pytest.raises(PidError, match=field):
        WheelSpeedPI(**kwargs)


def test_the_integral_band_leaves_transients_to_p_and_feed_forward():
    pi = WheelSpeedPI(0.02, 0.4, 0.05, band=1.5)
    pi.update(0.0, 9.0, 0.01)             # braking from 9 rad/s: |error| 9 > 1.5
    assert pi.integral == 0.0
    pi.update(0.0, 1.0, 0.01)             # within the band: integrates
    assert pi.integral == pytest.approx(0.4 * -1.0 * 0.01)
    pi.reset()
    pi.update(3.0, 0.0, 0.01)             # underspeed (a stalled wheel): integrates
    assert pi.integral == pytest.approx(0.4 * 3.0 * 0.01)
    for bad in (0.0, -1.0, math.nan, True):
        with pytest.raises(PidError, match='band'):
            WheelSpeedPI(0.02, 0.4, band=bad)


def test_break_away_raises_the_integral_at_its_rate_up_to_its_effort_while_starting():
    # a creep setpoint on a wheel at rest: ki alone winds up at 0.4 * 0.2 = 0.08/s
    pi = WheelSpeedPI(0.02, 0.4, 0.05, breakaway_rate=2.0, breakaway_effort=0.15)
    u = [pi.update(0.2, 0.0, 0.01, starting=True) for _ in range(5)]
    assert u[-1] == pytest.approx(0.05 * 0.2 + 0.02 * 0.2 + 2.0 * 0.05)
    u = [pi.update(0.2, 0.0, 0.01, starting=True) for _ in range(2)]
    assert u[-1] == pytest.approx(0.15)                 # the boost stops at breakaway_effort
    # beyond it only ki integrates, starting or not
    assert pi.update(0.2, 0.0, 0.01, starting=True) == pytest.approx(0.15 + 0.4 * 0.2 * 0.01)


@pytest.mark.parametrize('measured, starting', [(0.0, False), (-0.5, True), (0.153, True)])
def test_break_away_does_not_act_once_started_or_while_the_wheel_reads_motion(measured,
                                                                                   starting):
    plain = WheelSpeedPI(0.02, 0.4, 0.05)
    boost = WheelSpeedPI(0.02, 0.4, 0.05, breakaway_rate=2.0, breakaway_effort=0.15,
                         breakaway_still=0.1)
    for _ in range(5):
        assert boost.update(-0.2, -measured, 0.01, starting) == \
            pytest.approx(plain.update(-0.2, -measured, 0.01))
