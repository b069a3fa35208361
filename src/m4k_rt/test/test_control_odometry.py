import math

import pytest

from m4k_rt.control.diffdrive import DiffDrive
from m4k_rt.control.odometry import AngleHistory, normalize_angle, Odometry

R = 0.1016
L = 0.40
NS = 1_000_000_000


def _drive(odom, kin, v, w, seconds, step_s, t0_ns=0, angles=(0.0, 0.0)):
    wl, wr = kin.inverse(v, w)
    left, right = angles
    n = round(seconds / step_s)
    odom.update(left, right, t0_ns)
    for i in range(1, n + 1):
        odom.update(left + wl * step_s * i, right + wr * step_s * i,
                    t0_ns + round(i * step_s * NS))
    return left + wl * seconds, right + wr * seconds


@pytest.mark.parametrize('step_s', [0.01, 0.25, 1.0])
def test_arc_matches_closed_form_circle(step_s):
    kin = DiffDrive(R, L)
    odom = Odometry(R, L)
    radius, v = 1.0, 0.25
    w = v / radius
    t = 4.0
    _drive(odom, kin, v, w, t, step_s)
    # closed form for a circle of radius 1 m started at the origin heading +x
    assert odom.x == pytest.approx(radius * math.sin(w * t), abs=1e-9)
    assert odom.y == pytest.approx(radius * (1 - math.cos(w * t)), abs=1e-9)
    assert odom.yaw == pytest.approx(w * t, abs=1e-12)
    assert odom.v == pytest.approx(v, abs=1e-9)
    assert odom.w == pytest.approx(w, abs=1e-9)


def test_euler_would_be_wrong_on_the_same_arc():
    # Guard the test above: with 1 s steps a naive Euler integration misses by centimetres.
    x = y = yaw = 0.0
    v, w = 0.25, 0.25
    for _ in range(4):
        x += v * math.cos(yaw)
        y += v * math.sin(yaw)
        yaw += w
    assert abs(y - (1 - math.cos(1.0))) > 0.02


def test_straight_line_and_wheel_speeds_use_encoder_stamps():
    odom = Odometry(R, L)
    odom.update(0.0, 0.0, 0)
    # 15 ms between samples though the task period is 10 ms: speed from the stamps
    assert odom.update(0.15, 0.15, 15_000_000)
    assert odom.left_speed == pytest.approx(10.0)
    assert odom.v == pytest.approx(10.0 * R)
    assert odom.x == pytest.approx(0.15 * R)
    assert odom.y == 0.0


def test_full_turn_in_place_returns_to_origin_with_wrapped_yaw():
    kin = DiffDrive(R, L)
    odom = Odometry(R, L)
    _drive(odom, kin, 0.0, math.pi / 2, 4.0, 0.01)   # 2 pi in 4 s
    assert odom.x == pytest.approx(0.0, abs=1e-12)
    assert odom.y == pytest.approx(0.0, abs=1e-12)
    assert abs(normalize_angle(odom.yaw)) < 1e-9


def test_duplicate_stamp_is_counted_not_integrated_as_infinite_speed():
    odom = Odometry(R, L)
    odom.update(0.0, 0.0, 10)
    assert not odom.update(0.1, 0.1, 10)
    assert odom.bad_intervals == 1
    assert odom.x == 0.0
    assert math.isfinite(odom.v)


def test_jump_rebaselines_instead_of_teleporting():
    odom = Odometry(R, L, max_wheel_speed=30.0)
    odom.update(0.0, 0.0, 0)
    odom.update(0.2, 0.2, 10_000_000)
    x = odom.x
    assert not odom.update(500.0, 500.0, 20_000_000)   # driver restart / glitch
    assert odom.jumps == 1
    assert odom.x == x
    assert odom.update(500.2, 500.2, 30_000_000)
    assert odom.x == pytest.approx(x + 0.2 * R)


def test_wheel_positions_are_continuous_across_jumps_rebases_and_resets():
    # joint_states positions: the integrated angle steps, never the encoders' origin.
    odom = Odometry(R, L, max_wheel_speed=30.0)
    odom.update(1.0, -2.0, 0)                            # first sample: a baseline only
    odom.update(1.2, -2.1, 10_000_000)
    assert (odom.left_position, odom.right_position) == pytest.approx((0.2, -0.1))
    odom.update(500.0, 500.0, 20_000_000)                # jump: origin moved, wheels did not
    odom.update(500.1, 500.0, 30_000_000)
    odom.rebase()
    odom.update(7.0, 7.0, 40_000_000)
    odom.update(7.1, 7.2, 50_000_000)
    odom.reset()                                         # moves the pose, not the wheels
    assert (odom.left_position, odom.right_position) == pytest.approx((0.4, 0.1))


def test_normalize_angle():
    assert normalize_angle(math.pi) == pytest.approx(math.pi)
    assert normalize_angle(-math.pi) == pytest.approx(math.pi)
    assert normalize_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)


MS = 1_000_000
COUNT = 2 * math.pi / 4096          # one 12-bit encoder count, rad


def test_angle_history_rates_over_a_window_hand_computed():
    h = AngleHistory(8)
    assert not h.rates(1)                       # nothing to difference yet
    for t_ms, left, right in ((0, 0.0, 0.0), (10, 0.01, 0.02), (20, 0.03, 0.03),
                              (30, 0.045, 0.05)):
        h.push(t_ms * MS, left, right)
    assert h.rates(1)
    assert (h.left_rate, h.right_rate) == pytest.approx((1.5, 2.0))    # 0.015, 0.02 / 10 ms
    assert h.baseline_ns == 10 * MS
    assert h.rates(3)
    assert (h.left_rate, h.right_rate) == pytest.approx((1.5, 0.05 / 0.03))
    assert h.rates(5)                           # more than held: the oldest sample
    assert h.baseline_ns == 30 * MS


def test_angle_history_stretches_a_too_short_baseline_past_a_burst():
    # Queued replies after a driver stall: 10 ms, then two samples 60 us apart; the newest one
    # saw one more count. Over 60 us that count alone would read 25.6 rad/s.
    h = AngleHistory(8)
    h.push(0, 0.0, 0.0)
    h.push(10 * MS, 0.0246, 0.0246)
    h.push(10 * MS + 60_000, 0.0246 + COUNT, 0.0246)
    assert h.rates(1)
    assert h.left_rate == pytest.approx(COUNT / 60e-6)          # what the old code used
    assert h.rates(1, min_baseline_ns=5 * MS)
    assert h.baseline_ns == 10 * MS + 60_000
    assert h.left_rate == pytest.approx((0.0246 + COUNT) / 0.01006)   # 2.598 rad/s
    assert h.right_rate == pytest.approx(0.0246 / 0.01006)


def test_angle_history_ring_wraps_and_clears():
    h = AngleHistory(3)
    for i in range(5):                          # keeps samples 2, 3, 4
        h.push(i * 10 * MS, 0.1 * i, 0.0)
    assert h.count == 3
    assert h.rates(10)
    assert h.baseline_ns == 20 * MS and h.left_rate == pytest.approx(10.0)
    h.clear()
    assert h.count == 0 and not h.rates(1) and h.left_rate == 0.0
    with pytest.raises(ValueError, match='capacity'):
        AngleHistory(1)


def test_windowed_twist_is_the_angle_difference_over_the_baseline():
    odom = Odometry(R, L, velocity_window=2)
    odom.update(0.0, 0.0, 0)
    odom.update(0.1, 0.1, 10 * MS)
    odom.update(0.3, 0.1, 20 * MS)
    # left 0.3 rad and right 0.1 rad over 20 ms: 15 and 5 rad/s, not the last step's 20 and 0
    assert (odom.left_speed, odom.right_speed) == pytest.approx((15.0, 5.0))
    assert odom.v == pytest.approx(0.5 * R * 20.0)
    assert odom.w == pytest.approx(R * (5.0 - 15.0) / L)


def test_windowed_twist_of_a_quantized_encoder_at_cruise():
    # 0.25 m/s = 2.4606 rad/s = 16.04 counts per 10 ms: single differences flip between 16
    # and 17 counts (0.2493 / 0.2649 m/s); over 5 samples, 80 or 81 counts (0.2493 / 0.2524).
    wheel = 0.25 / R
    single = Odometry(R, L)
    window = Odometry(R, L, velocity_window=5, sample_period=0.01)
    v1, v5 = [], []
    for k in range(200):
        a = math.floor(wheel * 0.01 * k / COUNT + 0.3) * COUNT
        for odom, out in ((single, v1), (window, v5)):
            if odom.update(a, a, k * 10 * MS) and k > 5:
                out.append(odom.v)
    one = COUNT / 0.01 * R                   # 0.0156 m/s: one count per 10 ms
    assert max(v1) - min(v1) == pytest.approx(one, rel=1e-6)
    assert max(v5) - min(v5) == pytest.approx(one / 5, rel=1e-6)
    assert all(abs(v - 0.25) <= one / 5 for v in v5)
    assert window.x == pytest.approx(single.x)     # the pose does not depend on the window


def test_min_baseline_is_half_the_window_span():
    odom = Odometry(R, L, velocity_window=1, sample_period=0.01)
    assert odom.min_baseline_ns == 5 * MS
    odom.update(0.0, 0.0, 0)
    odom.update(0.0246, 0.0246, 10 * MS)
    odom.update(0.0246 + COUNT, 0.0246 + COUNT, 10 * MS + 60_000)
    assert odom.v == pytest.approx((0.0246 + COUNT) / 0.01006 * R)
    assert odom.x == pytest.approx((0.0246 + COUNT) * R)


def test_jump_and_rebase_restart_the_speed_window():
    odom = Odometry(R, L, max_wheel_speed=30.0, velocity_window=5)
    for k in range(6):
        odom.update(0.1 * k, 0.1 * k, k * 10 * MS)
    assert odom.left_speed == pytest.approx(10.0)
    odom.update(500.0, 500.0, 60 * MS)          # jump: the window must not span it
    odom.update(500.05, 500.05, 70 * MS)
    assert odom.left_speed == pytest.approx(5.0)
    odom.rebase()
    assert odom.history.count == 0 and odom.v == 0.0


@pytest.mark.parametrize('kw,match', [
    ({'velocity_window': 0}, 'velocity_window'),
    ({'velocity_window': 2.0}, 'velocity_window'),
    ({'sample_period': 0.0}, 'sample_period'),
    ({'velocity_window': 5, 'history': 5}, 'history'),
])
def test_bad_window_arguments_are_named(kw, match):
    with pytest.raises(ValueError, match=match):
        Odometry(R, L, **kw)
