import math

import pytest

from m4k_rt.control.limiter import LimiterError, SpeedLimiter

DT = 0.01


def test_velocity_is_clamped_both_ways():
    lim = SpeedLimiter(max_velocity=2.0)
    assert lim.step(3.0, DT) == 2.0
    assert lim.clamped
    assert lim.step(-5.0, DT) == -2.0
    assert lim.step(1.0, DT) == 1.0
    assert not lim.clamped


def test_acceleration_ramp_matches_table2_limit():
    lim = SpeedLimiter(max_velocity=2.0, max_acceleration=0.37)
    out = [lim.step(0.25, DT) for _ in range(100)]
    assert out[0] == pytest.approx(0.0037)
    assert out[9] == pytest.approx(0.037)
    # 0.25 / 0.37 = 0.6757 s -> reached on the 68th cycle, not before
    assert out[66] < 0.25
    assert out[67] == pytest.approx(0.25)
    assert out[-1] == 0.25


def test_deceleration_has_its_own_limit_and_crosses_zero():
    lim = SpeedLimiter(max_acceleration=0.5, max_deceleration=2.0)
    lim.reset(1.0)
    assert lim.step(0.0, DT) == pytest.approx(0.98)      # decelerating: 2.0 m/s^2
    lim.reset(0.0)
    assert lim.step(-1.0, DT) == pytest.approx(-0.005)   # accelerating in reverse: 0.5
    lim.reset(-1.0)
    assert lim.step(0.0, DT) == pytest.approx(-0.98)


def test_jerk_limits_change_of_acceleration():
    lim = SpeedLimiter(max_acceleration=1.0, max_jerk=10.0)
    # first step: a0 = 0, a may grow by jerk*dt = 0.1 m/s^2 -> v = 0.001
    v1 = lim.step(1.0, DT)
    assert v1 == pytest.approx(0.001)
    v2 = lim.step(1.0, DT)
    assert (v2 - v1) / DT == pytest.approx(0.2)
    for _ in range(20):
        lim.step(1.0, DT)
    # after 10 steps the acceleration has reached the 1.0 limit and stays there
    v_prev = lim.value
    assert (lim.step(1.0, DT) - v_prev) / DT == pytest.approx(1.0)


def test_override_bypasses_ramp_and_continues_from_there():
    lim = SpeedLimiter(max_acceleration=0.37)
    for _ in range(50):
        lim.step(0.25, DT)
    lim.override(0.0)
    assert lim.value == 0.0
    assert lim.step(0.25, DT) == pytest.approx(0.0037)


def test_zero_dt_only_clamps_value():
    lim = SpeedLimiter(max_velocity=1.0, max_acceleration=0.1)
    assert lim.step(5.0, 0.0) == 1.0


@pytest.mark.parametrize('kwargs,field', [
    ({'max_velocity': 0.0}, 'max_velocity'),
    ({'max_acceleration': -1.0}, 'max_acceleration'),
    ({'max_deceleration': math.nan}, 'max_deceleration'),
    ({'max_jerk': 0}, 'max_jerk'),
    ({'min_velocity': 0.5}, 'min_velocity'),
])
def test_bad_limits_are_rejected_naming_the_field(kwargs, field):
    with pytest.raises(LimiterError, match=field):
        SpeedLimiter(**kwargs)
