import math

import pytest

from m4k_rt.control.dac import code_to_command, command_to_code
from m4k_rt.control.diffdrive import DiffDrive, KinematicsError

R = 0.1016
L = 0.40


def test_inverse_straight_line_hand_computed():
    kin = DiffDrive(R, L, 12)
    left, right = kin.inverse(0.25, 0.0)
    assert left == pytest.approx(2.460629921, abs=1e-9)   # 0.25 / 0.1016
    assert right == pytest.approx(2.460629921, abs=1e-9)


def test_inverse_turn_hand_computed():
    kin = DiffDrive(R, L)
    # v = 0.2, w = 1.0: left = (0.2 - 1.0 * 0.2) / r = 0, right = 0.4 / r = 3.937007874
    left, right = kin.inverse(0.2, 1.0)
    assert left == pytest.approx(0.0, abs=1e-12)
    assert right == pytest.approx(3.937007874, abs=1e-9)
    # spin in place: w = 0.5 -> wheels +-0.1 / r = +-0.984251969
    left, right = kin.inverse(0.0, 0.5)
    assert (left, right) == pytest.approx((-0.984251969, 0.984251969), abs=1e-9)


def test_forward_inverts_inverse():
    kin = DiffDrive(R, L)
    for v, w in ((0.25, 0.0), (-0.3, 0.7), (0.0, -1.5), (1.9, 0.1)):
        assert kin.forward(*kin.inverse(v, w)) == pytest.approx((v, w), abs=1e-12)
    # hand computed: wheels (1, 3) rad/s -> v = r * 2 = 0.2032, w = r * 2 / L = 0.508
    assert kin.forward(1.0, 3.0) == pytest.approx((0.2032, 0.508), abs=1e-12)


def test_gear_ratio_maps_wheel_to_motor():
    kin = DiffDrive(R, L, 12)
    assert kin.wheel_to_motor(2.0) == 24.0
    assert kin.motor_to_wheel(24.0) == 2.0


def test_saturate_keeps_curvature():
    left, right, sat = DiffDrive.saturate(10.0, 30.0, 15.0)
    assert sat
    assert (left, right) == pytest.approx((5.0, 15.0))
    assert DiffDrive.saturate(-3.0, 2.0, 15.0) == (-3.0, 2.0, False)


@pytest.mark.parametrize('field,args', [
    ('wheel_radius', (0.0, L)), ('track_width', (R, -1.0)), ('track_width', (R, math.nan)),
    ('gear_ratio', (R, L, math.inf)),
])
def test_bad_parameters_name_the_field(field, args):
    with pytest.raises(KinematicsError, match=field):
        DiffDrive(*args)


def test_dac_mapping_zero_full_scale_and_clamp():
    assert command_to_code(0.0) == 512
    assert command_to_code(1.0) == 1023
    assert command_to_code(-1.0) == 1
    assert command_to_code(5.0) == 1023
    assert command_to_code(-5.0) == 1
    assert command_to_code(math.nan) == 512
    assert command_to_code(0.5) == 512 + 256   # round(255.5) -> 256 (banker's: even)
    assert code_to_command(1023) == 1.0
    assert code_to_command(0) == -1.0
    assert code_to_command(512) == 0.0
    for code in range(1, 1024):
        assert command_to_code(code_to_command(code)) == code
    with pytest.raises(ValueError, match='1024'):
        code_to_command(1024)
