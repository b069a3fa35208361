"""Pure conversions of the bridge: datagram payloads <-> ROS message fields (no rclpy)."""

import math

from hypothesis import given
from hypothesis import strategies as st
import pytest
from sensor_msgs.msg import Range

from m4k_bridge import convert
from m4k_rt import protocol


def test_ros_stamp_subtracts_datagram_age():
    assert convert.ros_stamp_ns(1_000, 1_500, 10_000_000) == 10_000_000 - 500


def test_ros_stamp_from_the_future_is_clamped_to_now():
    assert convert.ros_stamp_ns(2_000, 1_500, 10_000_000) == 10_000_000


def test_time_msg_splits_seconds_and_nanoseconds():
    t = convert.time_msg(3_000_000_007)
    assert (t.sec, t.nanosec) == (3, 7)


@given(st.floats(-math.pi, math.pi))
def test_yaw_quaternion_is_unit_and_round_trips(yaw):
    x, y, z, w = convert.quaternion_rpy(0.0, 0.0, yaw)
    assert x == 0.0 and y == 0.0
    assert math.isclose(x * x + y * y + z * z + w * w, 1.0)
    assert math.isclose(math.atan2(2 * w * z, 1 - 2 * z * z), yaw, abs_tol=1e-9)


def test_roll_quaternion_rotates_about_x():
    x, y, z, w = convert.quaternion_rpy(math.pi / 2, 0.0, 0.0)
    assert math.isclose(x, math.sqrt(0.5)) and math.isclose(w, math.sqrt(0.5))
    assert y == pytest.approx(0.0) and z == pytest.approx(0.0)


def test_covariance_diagonals_land_on_the_diagonal():
    c = convert.covariance6([1, 2, 3, 4, 5, 6])
    assert [c[i * 7] for i in range(6)] == [1, 2, 3, 4, 5, 6]
    assert sum(c) == 21
    c3 = convert.covariance3([7, 8, 9])
    assert (c3[0], c3[4], c3[8], sum(c3)) == (7, 8, 9, 24)
    with pytest.raises(ValueError, match='6 variances'):
        convert.covariance6([1, 2])


def test_odometry_message_has_pose_twist_frames_and_covariance():
    odom = protocol.Odometry(1.5, -0.5, math.pi / 2, 0.25, 0.1, 2.4, 2.6, 3.0, 3.5, 0)
    msg = convert.odometry_msg(odom, 5_000_000_000, 'odom', 'base_link',
                               [1, 2, 3, 4, 5, 6], [6, 5, 4, 3, 2, 1])
    assert msg.header.frame_id == 'odom' and msg.child_frame_id == 'base_link'
    assert msg.header.stamp.sec == 5
    assert (msg.pose.pose.position.x, msg.pose.pose.position.y) == (1.5, -0.5)
    q = msg.pose.pose.orientation
    assert math.isclose(q.z, math.sqrt(0.5)) and math.isclose(q.w, math.sqrt(0.5))
    assert msg.twist.twist.linear.x == 0.25 and msg.twist.twist.angular.z == 0.1
    assert msg.pose.covariance[0] == 1 and msg.pose.covariance[35] == 6
    assert msg.twist.covariance[0] == 6


def test_odom_transform_matches_the_odometry_pose():
    odom = protocol.Odometry(1.0, 2.0, 0.3, 0, 0, 0, 0, 0, 0, 0)
    t = convert.odom_transform(odom, 0, 'odom', 'base_link')
    assert (t.header.frame_id, t.child_frame_id) == ('odom', 'base_link')
    assert (t.transform.translation.x, t.transform.translation.y) == (1.0, 2.0)
    assert math.isclose(t.transform.rotation.z, math.sin(0.15))


def test_static_transform_from_pose_list():
    t = convert.static_transform('base_link', 'laser', [0.1, 0.0, 0.2, 0.0, 0.0, math.pi], 0)
    assert (t.header.frame_id, t.child_frame_id) == ('base_link', 'laser')
    assert t.transform.translation.z == 0.2
    assert math.isclose(abs(t.transform.rotation.z), 1.0)
    with pytest.raises(ValueError, match='roll, pitch, yaw'):
        convert.static_transform('a', 'b', [0.0], 0)


def _imu(status=0):
    return protocol.Imu(0.0, 0.0, 0.0, 1.0, 0.1, 0.2, 0.3, 0.0, 0.0, 9.81, status)


def test_imu_message_follows_rep_145():
    msg = convert.imu_msg(_imu(), 10, 'imu_link', [1, 1, 2], [3, 3, 3], [4, 4, 4])
    assert msg.header.frame_id == 'imu_link'
    assert msg.orientation.w == 1.0
    assert msg.angular_velocity.z == 0.3 and msg.linear_acceleration.z == 9.81
    assert msg.orientation_covariance[8] == 2 and msg.angular_velocity_covariance[0] == 3
    assert msg.linear_acceleration_covariance[4] == 4


def test_imu_with_bad_quaternion_marks_orientation_absent():
    msg = convert.imu_msg(_imu(protocol.ImuStatus.BAD_QUATERNION), 0, 'imu_link', [1] * 3, [1] * 3,
                          [1] * 3)
    assert msg.orientation_covariance[0] == -1.0
    assert msg.angular_velocity.x == 0.1  # the rest is still published


def test_imu_not_ready_is_not_published():
    assert convert.imu_msg(_imu(protocol.ImuStatus.NOT_READY), 0, 'i', [1] * 3, [1] * 3,
                           [1] * 3) is None


@pytest.mark.parametrize('mm, expected', [
    (20, 0.02), (1500, 1.5), (5600, 5.6), (0, math.inf)])
def test_urg_ranges_and_far_codes(mm, expected):
    assert convert.urg_range_m(mm) == pytest.approx(expected)


@pytest.mark.parametrize('code', [1, 2, 5, 6, 7, 16, 19])
def test_urg_error_codes_are_nan(code):
    assert math.isnan(convert.urg_range_m(code))


def test_every_urg_code_but_no_object_in_range_is_invalid():
    # SCIP 2.0 spec C-42-03320B Table 3: only code 0 ("possibly at 22 m") says "nothing in
    # range"; code 6 is "Others". The driver names codes from this same table.
    assert set(protocol.SCAN_ERROR_CODES) == set(range(protocol.SCAN_ERROR_CODE_MAX + 1))
    for code in protocol.SCAN_ERROR_CODES:
        value = convert.urg_range_m(code)
        assert (value == math.inf) if code == 0 else math.isnan(value), code


def test_scan_message_geometry_from_the_datagram():
    inc = math.radians(360 / 1024)
    ranges = (1500, 0, 19, 2000)
    scan = protocol.LaserScan(-0.5, inc, 0.02, 5.6, 0.1, 0.1 / 1024, 123, ranges)
    msg = convert.scan_msg(scan, 0, 'laser')
    assert msg.header.frame_id == 'laser'
    assert msg.angle_min == pytest.approx(-0.5)
    assert msg.angle_max == pytest.approx(-0.5 + 3 * inc)
    assert msg.angle_increment == pytest.approx(inc)
    assert (msg.range_min, msg.range_max) == (pytest.approx(0.02), pytest.approx(5.6))
    assert msg.scan_time == pytest.approx(0.1)
    assert msg.ranges[0] == pytest.approx(1.5) and msg.ranges[3] == pytest.approx(2.0)
    assert math.isinf(msg.ranges[1]) and math.isnan(msg.ranges[2])


def test_sonar_ok_no_echo_and_fault():
    args = ('sonar_link', 0.26, 0.02, 4.5)
    ok = convert.sonar_msg(protocol.Sonar(1.25, protocol.SONAR_OK), 0, *args)
    assert ok.radiation_type == Range.ULTRASOUND and ok.range == pytest.approx(1.25)
    assert ok.field_of_view == pytest.approx(0.26) and ok.max_range == pytest.approx(4.5)
    far = convert.sonar_msg(protocol.Sonar(0.0, protocol.SONAR_NO_ECHO), 0, *args)
    assert math.isinf(far.range) and far.range > 0
    at_max = convert.sonar_msg(protocol.Sonar(0.0, protocol.SONAR_NO_ECHO), 0, *args,
                               no_echo='max_range')
    assert at_max.range == pytest.approx(4.5) == at_max.max_range
    # Never NaN on /sonar: a fault, a timeout or a non-finite 'ok' range is not published.
    for status in (protocol.SONAR_TIMEOUT, protocol.SONAR_FAULT):
        assert convert.sonar_msg(protocol.Sonar(0.0, status), 0, *args) is None
    assert convert.sonar_msg(protocol.Sonar(math.nan, protocol.SONAR_OK), 0, *args) is None
    assert convert.sonar_msg(protocol.Sonar(math.inf, protocol.SONAR_OK), 0, *args) is None


def test_velocity_within_limits_passes_unchanged():
    assert convert.velocity_command(0.25, -0.1, 2.0, 1.5) == (0.25, -0.1, False)


def test_velocity_beyond_limits_is_clamped_and_flagged():
    assert convert.velocity_command(3.0, -2.0, 2.0, 1.5) == (2.0, -1.5, True)


@pytest.mark.parametrize('bad', [math.nan, math.inf, -math.inf])
def test_command_with_nan_or_inf_is_rejected(bad):
    with pytest.raises(convert.NonFiniteCommand, match='non-finite'):
        convert.velocity_command(bad, 0.0, 2.0, 1.5)
    with pytest.raises(convert.NonFiniteCommand):
        convert.velocity_command(0.0, bad, 2.0, 1.5)


@given(st.floats(allow_nan=False, allow_infinity=False),
       st.floats(allow_nan=False, allow_infinity=False))
def test_clamped_velocity_is_always_encodable_and_bounded(v, w):
    lv, aw, _ = convert.velocity_command(v, w, 2.0, 1.5)
    assert abs(lv) <= 2.0 and abs(aw) <= 1.5
    protocol.decode(protocol.encode(protocol.Kind.VELOCITY_CMD, 0, 0, lv, aw))


def test_led_colour_becomes_an_override():
    assert convert.led_command(1.0, 0.5, 0.0, 1.0) == (255, 128, 0, 255, 1)
    assert convert.led_command(2.0, -1.0, 0.0, 0.5) == (255, 0, 0, 128, 1)


def test_led_alpha_zero_releases_the_override():
    fields = convert.led_command(1.0, 1.0, 1.0, 0.0)
    assert fields == (0, 0, 0, 0, 0)
    protocol.decode(protocol.encode(protocol.Kind.LED, 0, 0, *fields))


def test_led_nan_is_rejected():
    with pytest.raises(convert.NonFiniteCommand):
        convert.led_command(math.nan, 0, 0, 1)
