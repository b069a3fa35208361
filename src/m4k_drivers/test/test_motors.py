import math

import pytest

from m4k_drivers.handler import DeviceNotFoundError, State, Status
from m4k_drivers.motors import protocol as p
from m4k_drivers.motors.handler import MotorHandler, WheelCommand
from m4k_drivers.motors.real import open_real_bus
from m4k_drivers.motors.sim import open_sim_bus
from m4k_drivers.world import LEFT, RIGHT, World, WorldConfig


# -- MCP4911 frames (hand-computed: bit15 /A-B=0, bit14 BUF, bit13 /GA, bit12 /SHDN, D9..D0<<2)
@pytest.mark.parametrize('code, kw, frame', [
    (512, {}, b'\x38\x00'),                       # 0x2000 | 0x1000 | 512 << 2
    (0, {}, b'\x30\x00'),
    (1023, {}, b'\x3f\xfc'),
    (1, {}, b'\x30\x04'),
    (512, {'buffered': True}, b'\x78\x00'),
    (512, {'active': False}, b'\x28\x00'),
    (512, {'gain1x': False}, b'\x18\x00'),
])
def test_dac_frame_encodes_hand_computed_bytes(code, kw, frame):
    assert p.encode_dac(code, **kw) == frame
    dec = p.decode_dac(frame)
    assert dec.code == code and dec.write


@pytest.mark.parametrize('bad', [-1, 1024, 512.0, True, None])
def test_dac_frame_rejects_bad_code(bad):
    with pytest.raises(ValueError, match='DAC code'):
        p.encode_dac(bad)


def test_dac_code_voltage_command_mapping():
    assert p.code_to_volts(512, 3.3) == pytest.approx(1.65)
    assert p.code_to_volts(1023, 3.3) == pytest.approx(3.3 * 1023 / 1024)
    assert p.volts_to_code(1.65, 3.3) == 512
    assert p.code_to_command(512) == 0.0
    assert p.code_to_command(1023) == 1.0
    assert p.code_to_command(1) == -1.0
    assert p.code_to_command(0) == -1.0          # clamped
    assert p.command_to_code(0.125) == 576       # 512 + round(63.875)
    assert p.command_to_code(-2.0) == 1
    assert p.command_to_code(math.nan) == 512


# -- AS5045 frames: 1 lead bit, 18-bit frame D11..D0 OCF COF LIN INC DEC PAR, MSB first.
@pytest.mark.parametrize('raw, data', [
    (0, b'\x00\x04\x20'),        # bits17 = 0x10 (OCF) -> parity 1 -> 0x21 << 5
    (1, b'\x00\x0c\x00'),        # bits17 = 0x30 -> parity 0 -> 0x60 << 5
    (4095, b'\x7f\xfc\x20'),     # 13 ones -> parity 1 -> 0x3FFE1 << 5
    (2048, b'\x40\x04\x00'),     # 0x10010 -> parity 0 -> 0x20020 << 5
])
def test_encoder_frame_hand_computed(raw, data):
    assert p.encode_encoder(raw) == data
    assert p.decode_encoder(data).raw == raw


def test_encoder_frame_parity_error_rejected():
    bad = bytes([0x00, 0x04, 0x00])              # raw 0, OCF, parity bit cleared -> odd
    with pytest.raises(p.EncoderFrameError, match='parity'):
        p.decode_encoder(bad)


@pytest.mark.parametrize('kw, match', [
    ({'ocf': False}, 'OCF=0'),
    ({'cof': True}, 'COF=1'),
    ({'lin': True}, 'LIN=1'),
    ({'mag_inc': True, 'mag_dec': True}, 'magnetic field'),
])
def test_encoder_status_bits_rejected(kw, match):
    with pytest.raises(p.EncoderFrameError, match=match):
        p.decode_encoder(p.encode_encoder(100, **kw))


@pytest.mark.parametrize('data, level', [(b'\x00\x00\x00', 'low'), (b'\xff\xff\xff', 'high')])
def test_encoder_stuck_miso_named(data, level):
    with pytest.raises(p.EncoderFrameError, match=f'stuck {level}'):
        p.decode_encoder(data)


def test_unwrap_across_4095_to_0_both_directions():
    u = p.Unwrapper(max_rate=20000)
    ms = 1_000_000
    assert u.update(4094, 0) == 4094
    assert u.update(1, 10 * ms) == 4097          # +3 through the wrap
    assert u.update(4093, 20 * ms) == 4093       # -4 back through the wrap
    assert u.update(4000, 30 * ms) == 4000
    assert u.angle == pytest.approx(4000 * 2 * math.pi / 4096)


def test_unwrap_rejects_impossible_jump_then_resyncs():
    u = p.Unwrapper(max_rate=20000, slack=8, resync_after=3)
    ms = 1_000_000
    u.update(100, 0)
    assert u.limit(0.01) == 208
    with pytest.raises(p.EncoderJumpError, match='100 -> 1100'):
        u.update(1100, 10 * ms)
    assert u.count == 100 and u.rejected == 1
    with pytest.raises(p.EncoderJumpError):
        u.update(1101, 11 * ms)
    assert u.update(1102, 12 * ms) == 1102       # third in a row: accepted, resync counted
    assert u.resyncs == 1


# -- handler on the simulated bus --------------------------------------------------------
class Clock:
    def __init__(self):
        self.t = 0

    def __call__(self):
        return self.t


def make_sim(world_cfg=None, **kw):
    clock = Clock()
    world = World(world_cfg or WorldConfig(), clock=clock, t0_ns=0)
    h = MotorHandler(lambda: open_sim_bus(world, noise_lsb=0.0), clock=clock, **kw)
    return h, world, clock


def test_lifecycle_deactivate_leaves_motors_at_zero():
    h, world, clock = make_sim()
    h.configure()
    assert h.state == State.INACTIVE
    h.activate()
    assert h.write(WheelCommand(700, 700, 1)) == Status.OK
    dac = h.bus.dacs[LEFT].dev
    assert dac.last.code == 700
    clock.t += 200_000_000
    assert world.motor_voltage(LEFT) > 0
    h.deactivate()
    assert h.state == State.INACTIVE
    assert h.bus.dacs[LEFT].dev.last.code == 512 and h.bus.dacs[RIGHT].dev.last.code == 512
    assert h.bus.dacs[LEFT].dev.last.active       # safe is mid-scale, never /SHDN
    assert world.motor_voltage(LEFT) == 0.0 and world.motor_voltage(RIGHT) == 0.0
    assert h.write(WheelCommand(700, 700, 1)) == Status.ERROR   # not active: refused
    h.shutdown()
    assert h.state == State.FINALIZED and h.bus is None


def test_enable_zero_writes_zero_codes():
    h, world, clock = make_sim()
    h.configure()
    h.activate()
    h.write(WheelCommand(900, 100, 0))
    assert h.codes == (512, 512)
    h.shutdown()


def test_bad_wheel_cmd_code_is_counted_not_written():
    h, world, clock = make_sim()
    h.configure()
    h.activate()
    assert h.write(WheelCommand(2000, 512, 1)) == Status.ERROR
    assert h.faults == 1 and h.codes == (512, 512)
    h.shutdown()


def test_watchdog_makes_outputs_safe_until_fresh_command():
    h, world, clock = make_sim(period_s=0.01, watchdog_periods=10)
    h.configure()
    h.activate()
    h.write(WheelCommand(600, 600, 1))
    clock.t += 50_000_000
    r = h.read()
    assert r.status == Status.OK and not r.value.status & p.STATUS_SAFE
    assert h.codes == (600, 600)
    clock.t += 60_000_000                           # 110 ms since the command > 100 ms
    r = h.read()
    assert r.value.status & p.STATUS_SAFE
    assert h.codes == (512, 512) and h.watchdog_trips == 1
    clock.t += 100_000_000
    assert not h.poll_watchdog()                    # stays safe, no repeated trips
    h.write(WheelCommand(600, 600, 1))
    assert h.codes == (600, 600) and not h.safe
    h.shutdown()


def test_encoder_frame_fault_sets_status_bit_keeps_angle():
    h, world, clock = make_sim()
    h.configure()
    h.activate()
    h.bus.encoders[RIGHT].dev.fault = {'cof': True}
    r = h.read()
    assert r.status == Status.OK
    assert r.value.status & p.STATUS_RIGHT_FRAME and not r.value.status & p.STATUS_LEFT_FRAME
    assert h.faults == 1
    h.shutdown()


def test_configure_missing_spidev_names_the_path():
    h = MotorHandler(lambda: open_real_bus('/dev/spidev9.9', '/dev/spidev9.8',
                                           '/dev/spidev9.7', '/dev/spidev9.6'))
    with pytest.raises(DeviceNotFoundError, match=r'/dev/spidev9\.9: No such file or directory '
                                                  r'\(errno 2\)'):
        h.configure()
    assert h.state == State.ERROR and h.faults == 1


def test_drive_straight_through_dac_frames_encoders_match_pose():
    h, world, clock = make_sim()
    h.configure()
    h.activate()
    code = p.command_to_code(0.25 / 2.0)          # 0.25 m/s of 2 m/s full scale
    r = world.robot.wheel_radius_m
    dist = 0.0
    for _ in range(2000):
        clock.t += 10_000_000
        h.write(WheelCommand(code, code, 1))
        reading = h.read().value
        dist = (reading.left_angle + reading.right_angle) / 2 * r
        if dist >= 1.0:
            break
    h.write(WheelCommand(512, 512, 1))
    for _ in range(100):
        clock.t += 10_000_000
        reading = h.read().value
    dist = (reading.left_angle + reading.right_angle) / 2 * r
    pose = world.pose()
    assert 1.0 <= dist < 1.1
    assert pose.x == pytest.approx(dist, abs=2 * 2 * math.pi * r / 4096)   # 2 counts
    assert abs(pose.y) < 1e-9 and abs(pose.yaw) < 1e-9
    h.shutdown()


@pytest.mark.hardware
def test_real_motor_bus_configures():
    h = MotorHandler(lambda: open_real_bus('/dev/spidev0.0', '/dev/spidev0.1',
                                           '/dev/spidev1.0', '/dev/spidev1.1'))
    h.configure()
    h.activate()
    assert h.read().status == Status.OK
    h.shutdown()
