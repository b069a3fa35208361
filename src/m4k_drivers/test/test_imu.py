import ctypes
import errno
import math

import pytest

from m4k_drivers.handler import (
    DeviceIdentityError,
    DeviceIOError,
    DeviceNotFoundError,
    State,
    Status,
)
from m4k_drivers.imu import protocol as p
from m4k_drivers.imu.handler import ImuHandler
from m4k_drivers.imu.real import I2cDevice, open_real_i2c
from m4k_drivers.imu.sim import FakeMyAhrsBus, GARBLES
from m4k_drivers.world import World, WorldConfig
from m4k_rt.protocol import ImuStatus

# Hand-made registers 0x22..0x35: acc (2048, 0, -2048), gyro (0, 0, 1638), magnet
# (100, -200, 300), temperature 4096 -- all int16 little-endian.
BLOCK1 = bytes([0x00, 0x08, 0x00, 0x00, 0x00, 0xF8,
                0x00, 0x00, 0x00, 0x00, 0x66, 0x06,
                0x64, 0x00, 0x38, 0xFF, 0x2C, 0x01,
                0x00, 0x10])
# 0x36..0x43: roll 0, pitch 0, yaw 16384, quaternion (0, 0, 23170, 23170).
BLOCK2 = bytes([0x00, 0x00, 0x00, 0x00, 0x00, 0x40,
                0x00, 0x00, 0x00, 0x00, 0x82, 0x5A, 0x82, 0x5A])


def test_register_map_addresses():
    assert (p.ADDRESS, p.REG_WHO_AM_I, p.WHO_AM_I_VALUE, p.REG_STATUS) == (0x20, 0x01, 0xB1, 0x04)
    assert (p.BLOCK1, p.BLOCK1_LEN, p.BLOCK2, p.BLOCK2_LEN) == (0x22, 20, 0x36, 14)
    assert p.REG_C_GYRO_X == 0x28 and p.REG_TEMPERATURE == 0x34 and p.REG_QUATERNION_X == 0x3C


def test_decode_hand_made_registers_scales():
    s = p.decode_blocks(BLOCK1, BLOCK2)
    g = 2048 * 16 / 32767 * 9.80665                         # 1.00003 g in m/s^2
    assert s.accel == pytest.approx((g, 0.0, -g))
    assert s.gyro[2] == pytest.approx(math.radians(1638 * 2000 / 32767))   # 99.98 dps
    assert s.magnet == (100, -200, 300)
    assert s.temperature == pytest.approx(4096 * 200 / 32767)              # 25.0 degC
    assert s.euler[2] == pytest.approx(math.radians(16384 * 180 / 32767))  # 90.0 deg
    assert s.quaternion == pytest.approx((0, 0, 23170 / 32767, 23170 / 32767))


def test_to_ros_flips_y_and_z():
    r = p.to_ros(p.decode_blocks(BLOCK1, BLOCK2))
    g = 2048 * 16 / 32767 * 9.80665
    assert r.linear_acceleration == pytest.approx((g, 0.0, g))     # REP-145: +g up at rest
    assert r.angular_velocity[2] == pytest.approx(-math.radians(1638 * 2000 / 32767))
    assert r.rpy[2] == pytest.approx(-math.radians(16384 * 180 / 32767))
    qx, qy, qz, qw = r.orientation
    assert (qx, qy) == (0.0, 0.0)
    assert qz == pytest.approx(-math.sqrt(0.5)) and qw == pytest.approx(math.sqrt(0.5))
    # the quaternion and the Euler yaw describe the same heading
    assert 2 * math.atan2(qz, qw) == pytest.approx(r.rpy[2], abs=1e-3)
    assert r.status == ImuStatus.OK


def test_to_ros_flags_bad_quaternion_and_not_ready():
    bad = BLOCK2[:6] + bytes(8)                       # quaternion all zero
    assert p.to_ros(p.decode_blocks(BLOCK1, bad)).status == ImuStatus.BAD_QUATERNION
    assert p.to_ros(p.decode_blocks(BLOCK1, BLOCK2), ready=False).status == ImuStatus.NOT_READY


def _with(block, offset, count):
    """Return ``block`` with the int16 at byte ``offset`` replaced by ``count``."""
    return block[:offset] + count.to_bytes(2, 'little', signed=True) + block[offset + 2:]


def test_implausible_quaternion_norm_from_the_register_scaling():
    assert p.implausible(p.decode_blocks(BLOCK1, BLOCK2)) is None           # |q| = 1.00001
    zero = BLOCK2[:6] + bytes(8)
    assert p.implausible(p.decode_blocks(BLOCK1, zero)) == 'quaternion_norm'
    ones = b'\xff' * p.BLOCK2_LEN                                           # |q| = 6e-5
    assert p.implausible(p.decode_blocks(BLOCK1, ones)) == 'quaternion_norm'
    # 1 % off unit: 0.99 * 23170 * sqrt(2) -- just inside; 1.2 % -- outside
    inside = _with(_with(BLOCK2, 10, round(23170 * 0.991)), 12, round(23170 * 0.991))
    outside = _with(_with(BLOCK2, 10, round(23170 * 0.988)), 12, round(23170 * 0.988))
    assert p.implausible(p.decode_blocks(BLOCK1, inside)) is None
    assert p.implausible(p.decode_blocks(BLOCK1, outside)) == 'quaternion_norm'


def test_implausible_rates_and_accelerations_at_the_full_scale_rail():
    for offset, reason in ((6, 'gyro_full_scale'), (10, 'gyro_full_scale'),
                           (0, 'accel_full_scale'), (4, 'accel_full_scale')):
        for rail in (32767, -32767, -32768):
            s = p.decode_blocks(_with(BLOCK1, offset, rail), BLOCK2)
            assert p.implausible(s) == reason, (offset, rail)
        assert p.implausible(p.decode_blocks(_with(BLOCK1, offset, 32766), BLOCK2)) is None


def test_handler_rejects_implausible_sample_with_a_counted_reason():
    regs = _regs()
    regs[0x3C:0x44] = bytes(8)                       # quaternion registers cleared (a reset)
    bus = RegBus(regs)
    h = ImuHandler(lambda: I2cDevice(bus, 0x20, 'fake'))
    h.configure()
    h.activate()
    r = h.read()
    assert r.status == Status.ERROR and r.value is None
    assert 'sample rejected: quaternion_norm (|q|=0.0000' in str(r.error)
    assert h.rejected == {'quaternion_norm': 1} and h.faults == 1 and h.status_level() == 1
    regs[0x36:0x44] = BLOCK2
    assert h.read().status == Status.OK                # the next sound sample passes
    h.shutdown()


def test_sim_garble_modes_produce_what_the_plausibility_rules_reject():
    world = World(WorldConfig(), clock=lambda: 0, t0_ns=0)
    bus = FakeMyAhrsBus(world)
    dev = I2cDevice(bus, p.ADDRESS, 'sim')
    sound = p.decode_sample(dev.read_burst(p.SAMPLE, p.SAMPLE_LEN))
    assert p.implausible(sound) is None
    want = {'zeros': 'quaternion_norm', 'ones': 'quaternion_norm',
            'quaternion': 'quaternion_norm', 'gyro_rail': 'gyro_full_scale'}
    assert set(want) == set(GARBLES)
    for garble, reason in want.items():
        bus.garble = garble
        assert p.implausible(p.decode_sample(dev.read_burst(p.SAMPLE, p.SAMPLE_LEN))) == reason
    bus.garble = None
    assert p.decode_sample(dev.read_burst(p.SAMPLE, p.SAMPLE_LEN)) == sound


def test_decode_rejects_short_burst():
    with pytest.raises(p.DeviceProtocolError, match='20 \\+ 14'):
        p.decode_blocks(BLOCK1[:-1], BLOCK2)


def test_encode_blocks_round_trips_hand_made_bytes():
    assert p.encode_blocks(p.decode_blocks(BLOCK1, BLOCK2)) == (BLOCK1, BLOCK2)


class RegBus:
    """A plain register file with the smbus2 methods."""

    def __init__(self, regs, address=0x20):
        self.regs, self.address, self.closed = regs, address, False

    def read_byte_data(self, a, r):
        if a != self.address:
            raise OSError(errno.EREMOTEIO, 'Remote I/O error')
        return self.regs[r]

    def read_i2c_block_data(self, a, r, n):
        return [self.read_byte_data(a, r + i) for i in range(n)]

    def write_byte_data(self, a, r, v):
        self.regs[r] = v

    def i2c_rdwr(self, *msgs):
        self.transactions = getattr(self, 'transactions', 0) + 1
        pointer = 0
        for m in msgs:
            if m.addr != self.address:
                raise OSError(errno.EREMOTEIO, 'Remote I/O error')
            if m.flags & 1:
                ctypes.memmove(m.buf, bytes(self.regs[pointer:pointer + m.len]), m.len)
                pointer += m.len
            else:
                pointer = bytes(m)[0]

    def close(self):
        self.closed = True


def _regs(who=0xB1):
    regs = bytearray(0x44)
    regs[0x01], regs[0x04] = who, 0x80
    regs[0x22:0x36] = BLOCK1
    regs[0x36:0x44] = BLOCK2
    return regs


def test_handler_reads_sample_in_ros_frame():
    bus = RegBus(_regs())
    h = ImuHandler(lambda: I2cDevice(bus, 0x20, 'fake'))
    h.configure()
    h.activate()
    r = h.read()
    assert r.status == Status.OK
    assert r.value.linear_acceleration[2] == pytest.approx(2048 * 16 / 32767 * 9.80665)
    h.shutdown()
    assert bus.closed and h.state == State.FINALIZED


def test_configure_fails_with_wrong_who_am_i():
    bus = RegBus(_regs(who=0x68))
    h = ImuHandler(lambda: I2cDevice(bus, 0x20, '/dev/i2c-1'))
    with pytest.raises(DeviceIdentityError, match=r'/dev/i2c-1@0x20: WHO_AM_I is 0x68, '
                                                  r'expected 0xb1'):
        h.configure()
    assert h.state == State.ERROR and bus.closed


def test_configure_wrong_address_is_io_error_naming_address():
    bus = RegBus(_regs())
    sleeps = []
    h = ImuHandler(lambda: I2cDevice(bus, 0x21, '/dev/i2c-1'), sleep=sleeps.append)
    with pytest.raises(DeviceIOError, match=r'/dev/i2c-1@0x21: read 0x01: .*errno 121'):
        h.configure()
    assert sleeps == [0.02, 0.04]                   # retried with exponential backoff


def test_missing_i2c_bus_names_path():
    with pytest.raises(DeviceNotFoundError, match=r'/dev/i2c-97: No such file or directory'):
        open_real_i2c(97, 0x20)


def test_sim_registers_follow_world_at_rest():
    t = [0]
    world = World(clock=lambda: t[0], t0_ns=0)
    bus = FakeMyAhrsBus(world)
    h = ImuHandler(lambda: I2cDevice(bus, 0x20, 'sim'))
    h.configure()
    h.activate()
    before = bus.samples
    az, yaws, gz = [], [], []
    for _ in range(50):
        t[0] += 10_000_000
        s = h.read().value
        az.append(s.linear_acceleration[2])
        yaws.append(s.rpy[2])
        gz.append(s.angular_velocity[2])
    assert sum(az) / 50 == pytest.approx(9.80665, abs=0.02)
    assert max(abs(y) for y in yaws) < 0.01
    # gyro z = bias + noise: the mean of 50 is the bias within 4 sd + one 16-bit LSB
    lsb = math.radians(2000 / 32767)
    assert abs(bus.gyro_bias[2]) > 0
    assert sum(gz) / 50 == pytest.approx(bus.gyro_bias[2], abs=4 * 0.002428 / 50 ** 0.5 + lsb)
    assert bus.samples - before == 50                # one register refresh per 10 ms tick
    h.shutdown()


def test_sim_holds_sample_between_device_ticks():
    t = [0]
    world = World(clock=lambda: t[0], t0_ns=0)
    bus = FakeMyAhrsBus(world)
    a = bus.read_i2c_block_data(0x20, 0x22, 20)
    t[0] += 3_000_000                              # same 10 ms tick
    assert bus.read_i2c_block_data(0x20, 0x22, 20) == a
    t[0] += 10_000_000
    assert bus.read_i2c_block_data(0x20, 0x22, 20) != a


@pytest.mark.hardware
def test_real_myahrs_identifies():
    h = ImuHandler(lambda: open_real_i2c(1, 0x20))
    h.configure()
    assert h.read().status == Status.OK
    h.shutdown()


class UpdatingBus(RegBus):
    """Registers that change to a new sample after every transaction (worst-case timing)."""

    def __init__(self, regs, samples):
        super().__init__(regs)
        self.samples = list(samples)

    def _next(self):
        b1, b2 = p.encode_blocks(self.samples.pop(0))
        self.regs[p.BLOCK1:p.BLOCK1 + p.BLOCK1_LEN] = b1
        self.regs[p.BLOCK2:p.BLOCK2 + p.BLOCK2_LEN] = b2

    def i2c_rdwr(self, *msgs):
        super().i2c_rdwr(*msgs)
        self._next()

    def read_i2c_block_data(self, a, r, n):
        out = super().read_i2c_block_data(a, r, n)
        self._next()
        return out


def test_sample_is_one_transaction_and_never_mixes_two_updates():
    # The device updates between any two bus transactions: a two-burst read would pair the
    # accel of one sample with the quaternion of the next.
    still = p.DeviceSample((0.0, 0.0, -9.80665), (0.0,) * 3, (0, 0, 0), 20.0, (0.0,) * 3,
                           (0.0, 0.0, 0.0, 1.0))
    turned = p.DeviceSample((1.0, 0.0, -9.80665), (0.0,) * 3, (0, 0, 0), 20.0,
                            (0.0, 0.0, -math.pi / 2),
                            (0.0, 0.0, -math.sin(math.pi / 4), math.cos(math.pi / 4)))
    bus = UpdatingBus(_regs(), [still, turned, still, turned, still, turned])
    dev = I2cDevice(bus, 0x20, 'fake')
    for _ in range(4):
        s = p.decode_sample(dev.read_burst(p.SAMPLE, p.SAMPLE_LEN))
        moving = abs(s.accel[0]) > 0.5
        turned_q = abs(s.quaternion[2]) > 0.5
        assert moving == turned_q                      # both halves from the same update
    assert bus.transactions == 4


def test_sim_sample_is_read_in_one_i2c_transaction():
    world = World(WorldConfig(), clock=lambda: 0, t0_ns=0)
    bus = FakeMyAhrsBus(world)
    h = ImuHandler(lambda: I2cDevice(bus, p.ADDRESS, 'sim'))
    h.configure()
    h.activate()
    assert h.read().status == Status.OK
    assert bus.transactions == 1
    h.shutdown()


def _rotate(q, v):
    """Rotate v by the unit quaternion q = (x, y, z, w)."""
    x, y, z, w = q
    # v' = v + 2 w (u x v) + 2 u x (u x v), u = (x, y, z)
    cx, cy, cz = y * v[2] - z * v[1], z * v[0] - x * v[2], x * v[1] - y * v[0]
    dx, dy, dz = y * cz - z * cy, z * cx - x * cz, x * cy - y * cx
    return (v[0] + 2 * (w * cx + dx), v[1] + 2 * (w * cy + dy), v[2] + 2 * (w * cz + dz))


def _sample_at_rest(heading_deg, patch):
    """One noise-free sample of the simulated myAHRS+ on a robot at rest at the origin."""
    t = [0]
    cfg = WorldConfig.from_dict({'start': [0.0, 0.0, math.radians(heading_deg)],
                                 'obstacles': [], 'floor': [patch]})
    world = World(cfg, clock=lambda: t[0], t0_ns=0)
    bus = FakeMyAhrsBus(world, accel_sd=0.0, gyro_sd=0.0, orientation_sd=0.0)
    h = ImuHandler(lambda: I2cDevice(bus, 0x20, 'sim'))
    h.configure()
    h.activate()
    t[0] += 10_000_000
    s = h.read().value
    h.shutdown()
    return s


@pytest.mark.parametrize('heading_deg, roll_deg, pitch_deg', [
    (0.0, 0.0, 2.0),       # facing downhill: nose down (REP-103 pitch +)
    (180.0, 0.0, -2.0),    # facing uphill: nose up
    (90.0, 2.0, 0.0),      # downhill on the right: the left side up (roll +)
    (-90.0, -2.0, 0.0),
    (45.0, 1.414, 1.414),
])
def test_sim_on_a_ramp_reports_the_tilt_gravity_and_field_of_a_tilted_body(
        heading_deg, roll_deg, pitch_deg):
    # A 2 deg ramp falling toward world +x under a robot at rest (the drive train's friction
    # holds it there up to ~2.7 deg; steeper, it rolls and the accelerometer reads that
    # too): the myAHRS+ reads the slope -- its Euler angles, a quaternion that turns
    # base_link's z onto the slope's normal, the floor's push along the same axis, |g| kept.
    s = _sample_at_rest(heading_deg, {'rectangle': [-5.0, -5.0, 5.0, 5.0], 'mu': 0.6,
                                      'grade_deg': 2.0, 'downhill_deg': 0.0})
    g = math.radians(2.0)
    assert s.rpy[0] == pytest.approx(math.radians(roll_deg), abs=2e-3)
    assert s.rpy[1] == pytest.approx(math.radians(pitch_deg), abs=2e-3)
    assert s.rpy[2] == pytest.approx(math.radians(heading_deg), abs=2e-3)
    normal = (math.sin(g), 0.0, math.cos(g))          # the slope's normal leans downhill
    assert _rotate(s.orientation, (0.0, 0.0, 1.0)) == pytest.approx(normal, abs=2e-3)
    # at rest the accelerometer reads the floor's push: world up, in the body frame
    up_in_body = _rotate((-s.orientation[0], -s.orientation[1], -s.orientation[2],
                          s.orientation[3]), (0.0, 0.0, p.GRAVITY))
    assert s.linear_acceleration == pytest.approx(up_in_body, abs=0.01)
    assert math.hypot(*s.linear_acceleration) == pytest.approx(p.GRAVITY, abs=0.01)


def test_sim_off_the_ramp_is_level():
    s = _sample_at_rest(0.0, {'rectangle': [1.0, -5.0, 5.0, 5.0], 'mu': 0.6, 'grade_deg': 4.8})
    assert s.rpy[0] == pytest.approx(0.0, abs=1e-3) and s.rpy[1] == pytest.approx(0.0, abs=1e-3)
    assert s.linear_acceleration[0] == pytest.approx(0.0, abs=0.01)
    assert s.linear_acceleration[2] == pytest.approx(p.GRAVITY, abs=0.01)
