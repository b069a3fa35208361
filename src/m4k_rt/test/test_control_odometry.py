import math

import pytest

from m4k_rt.control.diffdrive import DiffDrive
from m4k_rt.control.odometry import normalize_angle, Odometry

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


def test_normalize_angle():
    assert normalize_angle(math.pi) == pytest.approx(math.pi)
    assert normalize_angle(-math.pi) == pytest.approx(math.pi)
    assert normalize_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
