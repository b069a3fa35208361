import math

from fakeclock import FakeClock
import pytest

from m4k_drivers.handler import DeviceNotFoundError, State, Status
from m4k_drivers.motors import protocol as p
from m4k_drivers.motors.handler import MotorHandler, WheelCommand
from m4k_drivers.motors.real import open_real_bus
from m4k_drivers.motors.sim import open_sim_bus
from m4k_drivers.world import LEFT, RIGHT, World, WorldConfig
from m4k_rt.config import shipped_period_s
from m4k_rt.protocol import EncoderStatus

PERIOD_S = shipped_period_s('actuator')   # the actuator task's, as shipped


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
])
def test_encoder_status_bits_rejected(kw, match):
    with pytest.raises(p.EncoderFrameError, match=match):
        p.decode_encoder(p.encode_encoder(100, **kw))


@pytest.mark.parametrize('mag_inc, mag_dec', [(0, 0), (1, 0), (0, 1), (1, 1)])
def test_encoder_mag_bits_are_valid_data(mag_inc, mag_dec):
    # AS5045 datasheet Table 3: D11:D0 valid for OCF=1, COF=0, LIN=0 and any MagINC/MagDEC.
    f = p.decode_encoder(p.encode_encoder(100, mag_inc=bool(mag_inc), mag_dec=bool(mag_dec)))
    assert f.raw == 100
    assert p.mag_out_of_range(f) == bool(mag_inc and mag_dec)


@pytest.mark.parametrize('bad', [-1, 7, 24, True, 1.0])
def test_lead_bits_out_of_range_is_a_clear_error(bad):
    with pytest.raises(ValueError, match=r'lead_bits must be an int 0\.\.6'):
        p.decode_encoder(bytes(3), lead_bits=bad)


@pytest.mark.parametrize('lead', range(0, 7))
def test_every_valid_lead_bits_round_trips(lead):
    assert p.decode_encoder(p.encode_encoder(2345, lead_bits=lead), lead).raw == 2345


def test_dac_mapping_has_one_owner():
    # m4k_rt.control.dac computes WHEEL_CMD codes; the driver uses the very same functions.
    from m4k_rt.control import dac
    assert p.command_to_code is dac.command_to_code
    assert p.code_to_command is dac.code_to_command
    assert (p.DAC_ZERO, p.DAC_MAX, p.DAC_SPAN) == (dac.DAC_ZERO, dac.DAC_MAX, dac.DAC_SPAN)
    for code in range(1, 1024):
        assert p.command_to_code(p.code_to_command(code)) == code


@pytest.mark.parametrize('code, sign, trim, out', [
    (512, 1, 0, 512), (700, 1, 0, 700), (700, -1, 0, 324), (1, -1, 0, 1023),
    (512, 1, 5, 517), (512, -1, -7, 505), (1023, 1, 10, 1023), (1, 1, -10, 0)])
def test_trim_dac_code(code, sign, trim, out):
    assert p.trim_dac_code(code, sign, trim) == out


@pytest.mark.parametrize('raw, direction, zero, out', [
    (100, 1, 0, 100), (100, -1, 0, 3996), (100, 1, 100, 0), (50, 1, 100, 4046),
    (50, -1, 100, 50)])
def test_wheel_raw(raw, direction, zero, out):
    assert p.wheel_raw(raw, direction, zero) == out


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
def make_sim(world_cfg=None, **kw):
    clock = FakeClock()
    world = World(world_cfg or WorldConfig(), clock=clock, t0_ns=0)
    h = MotorHandler(lambda: open_sim_bus(world, noise_lsb=0.0), clock=clock,
                     **({'period_s': PERIOD_S} | kw))
    return h, world, clock


def test_mag_out_of_range_is_accepted_with_a_diagnostics_warning():
    h, world, clock = make_sim()
    h.configure()
    h.activate()
    h.bus.encoders[LEFT].dev.fault = {'mag_inc': True, 'mag_dec': True}
    for _ in range(3):
        clock.t += 10_000_000
        h.write(WheelCommand(600, 600, 1))
        r = h.read()
        assert r.status == Status.OK
        assert not r.value.status & (EncoderStatus.LEFT_FRAME | EncoderStatus.RIGHT_FRAME)
    assert r.value.left_angle > 0                       # the angle is used, the wheel moves
    assert h.mag_warnings == [3, 0]
    assert h.faults == 1 and h.status_level() == 1      # one warning per episode
    assert isinstance(h.last_exception, p.EncoderFieldWarning)
    assert 'magnet gap' in str(h.last_exception)
    h.shutdown()


def test_dac_sign_and_trim_reach_the_wires_and_the_wheel():
    h, world, clock = make_sim(dac_sign=(-1, 1), dac_zero_trim=(3, -2))
    h.configure()
    assert h.bus.dacs[LEFT].dev.last.code == 515 and h.bus.dacs[RIGHT].dev.last.code == 510
    h.activate()
    h.write(WheelCommand(700, 700, 1))
    assert h.codes == (700, 700)
    assert (h.bus.dacs[LEFT].dev.last.code, h.bus.dacs[RIGHT].dev.last.code) == (327, 698)
    clock.t += 200_000_000
    assert world.motor_voltage(LEFT) < 0 < world.motor_voltage(RIGHT)   # ground truth
    h.shutdown()


def test_encoder_direction_and_zero_give_forward_positive_angles():
    # The left encoder is mounted mirrored: -1 makes forward motion count up on both sides.
    h, world, clock = make_sim()
    h.configure()
    h.activate()
    first = h.read().value
    h.shutdown()
    h2, world2, clock2 = make_sim(enc_direction=(-1, 1), enc_zero=(first.left_raw, 0))
    h2.configure()
    h2.activate()
    r0 = h2.read().value
    assert r0.left_raw == 0                               # zero offset applied
    for _ in range(50):
        clock2.t += 10_000_000
        h2.write(WheelCommand(700, 700, 1))
        r = h2.read().value
    assert r.right_angle > 0 > r.left_angle               # sim wheel turns forward: mirrored
    h2.shutdown()


@pytest.mark.parametrize('kw, match', [
    ({'lead_bits': 7}, r'lead_bits: must be an int 0\.\.6'),
    ({'dac_sign': (1, 0)}, r'dac_sign: expected \[left, right\], each 1 or -1'),
    ({'dac_zero_trim': (0, 65)}, r'dac_zero_trim: .*-64\.\.64'),
    ({'enc_direction': (1,)}, r'enc_direction: expected \[left, right\]'),
    ({'enc_zero': (0, 4096)}, r'enc_zero: .*0\.\.4095'),
])
def test_handler_rejects_bad_trims(kw, match):
    with pytest.raises(ValueError, match=match):
        make_sim(**kw)


class _Spi:
    def __init__(self, log, name):
        self.log, self.name = log, name

    def transfer(self, data):
        self.log.append((self.name, bytes(data)))
        return p.encode_encoder(0) if self.name.endswith('_enc') else bytes(len(data))

    def close(self):
        pass


def _ports(log):
    from m4k_drivers.motors.real import SpiPort
    return [SpiPort(_Spi(log, n), n) for n in ('left_dac', 'right_dac', 'left_enc', 'right_enc')]


class _Ldac:
    def __init__(self, log):
        self.log = log

    def write(self, value):
        self.log.append(('ldac', value))

    def close(self):
        self.log.append(('ldac', 'closed'))


def test_driven_ldac_pulses_once_after_both_dac_words():
    from m4k_drivers.motors.real import MotorBus
    log = []
    bus = MotorBus(*_ports(log), ldac=_Ldac(log))
    h = MotorHandler(lambda: bus, clock=FakeClock(), period_s=PERIOD_S)
    h.configure()
    h.activate()
    log.clear()
    h.write(WheelCommand(600, 400, 1))
    assert [e[0] for e in log] == ['left_dac', 'right_dac', 'ldac', 'ldac']
    assert log[2:] == [('ldac', False), ('ldac', True)]        # low pulse after both words
    h.shutdown()
    assert ('ldac', 'closed') in log


def test_tied_low_ldac_needs_no_pulse():
    from m4k_drivers.motors.real import MotorBus
    log = []
    bus = MotorBus(*_ports(log))
    bus.latch()
    assert log == [] and bus.latches == 0


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
    assert r.status == Status.OK and not r.value.status & EncoderStatus.SAFE
    assert h.codes == (600, 600)
    clock.t += 60_000_000                           # 110 ms since the command > 100 ms
    r = h.read()
    assert r.value.status & EncoderStatus.SAFE
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
    assert r.value.status & EncoderStatus.RIGHT_FRAME
    assert not r.value.status & EncoderStatus.LEFT_FRAME
    assert h.faults == 1
    h.shutdown()


def test_configure_missing_spidev_names_the_path():
    h = MotorHandler(lambda: open_real_bus('/dev/spidev9.9', '/dev/spidev9.8',
                                           '/dev/spidev9.7', '/dev/spidev9.6'),
                     period_s=PERIOD_S)
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
                                           '/dev/spidev1.0', '/dev/spidev1.1'),
                     period_s=PERIOD_S)
    h.configure()
    h.activate()
    assert h.read().status == Status.OK
    h.shutdown()


def _late_left(h, clock, late_ns):
    """Return (the left encoder port, its transfer, that transfer returning ``late_ns`` late)."""
    left = h.bus.encoders[LEFT]
    transfer = left.transfer

    def late(data):
        out = transfer(data)
        clock.t += late_ns
        return out

    return left, transfer, late


def test_a_reading_returned_late_does_not_make_the_next_honest_step_a_jump():
    # The driver host is preempted right after a transfer (a busy machine): that reading's
    # clock is read 8 ms late. The wheel did not move faster for it, so the next reading one
    # period after the real transfer is an honest step, not an encoder jump.
    h, world, clock = make_sim()
    h.configure()
    h.activate()
    period = 10_000_000
    for _ in range(50):                        # 0.5 s at full forward: the wheels at speed
        clock.t += period
        h.write(WheelCommand(1023, 1023, 1))
        h.read()
    left, transfer, preempted_after = _late_left(h, clock, 8_000_000)
    left.transfer = preempted_after
    clock.t += period
    h.write(WheelCommand(1023, 1023, 1))
    assert not h.read().value.status & EncoderStatus.LEFT_JUMP
    left.transfer = transfer
    clock.t += period - 8_000_000              # one period after the late reading's transfer
    h.write(WheelCommand(1023, 1023, 1))
    r = h.read()
    assert not r.value.status & (EncoderStatus.LEFT_JUMP | EncoderStatus.RIGHT_JUMP), r
    assert h.unwrap[LEFT].rejected == 0
    h.shutdown()


def test_a_slow_first_transfer_does_not_read_as_a_turn():
    # An AS5045 latches its angle when its transfer starts. The driver host reads the left
    # encoder, then the right; when the left transfer returns 8 ms late (the host preempted,
    # or waiting for the GIL), the right wheel is latched 8 ms after the left. One reading has
    # one stamp, so its two angles must describe that one moment: the world drives straight,
    # and the readings must show no turn and both wheels where they were at the stamp.
    h, world, clock = make_sim()
    h.configure()
    h.activate()
    period = 10_000_000
    readings = []
    code = p.command_to_code(0.25 / 2.0)          # 0.25 m/s of 2 m/s full scale
    for _ in range(150):                       # 1.5 s: the wheels at a steady speed
        clock.t += period
        h.write(WheelCommand(code, code, 1))
        readings.append(h.read().value)
    left, transfer, slow = _late_left(h, clock, 8_000_000)
    for k in range(3):
        left.transfer = slow if k == 1 else transfer
        clock.t += period - (8_000_000 if k == 2 else 0)
        h.write(WheelCommand(code, code, 1))
        readings.append(h.read().value)
    h.shutdown()
    count = 2 * math.pi / p.ENC_COUNTS
    truth = world.state().wheel_speed
    assert truth[LEFT] == pytest.approx(truth[RIGHT], rel=1e-6)   # the world drove straight
    base = readings[-4]
    # the wheel speeds over 160 ms of steady driving before: far above the quantization
    old = readings[-20]
    speed = [(base.left_angle - old.left_angle) / (base.t_ns - old.t_ns),
             (base.right_angle - old.right_angle) / (base.t_ns - old.t_ns)]
    for r in readings[-3:]:
        # no turn: the wheels' angles keep their difference (a count of quantization)
        turn = (r.right_angle - r.left_angle) - (base.right_angle - base.left_angle)
        assert abs(turn) <= 1.01 * count, (r, turn / count)
        # and each angle is the wheel's at the reading's stamp
        for side, angle, a0 in ((LEFT, r.left_angle, base.left_angle),
                                (RIGHT, r.right_angle, base.right_angle)):
            expected = a0 + speed[side] * (r.t_ns - base.t_ns)
            assert abs(angle - expected) <= 1.5 * count, (side, r, (angle - expected) / count)
