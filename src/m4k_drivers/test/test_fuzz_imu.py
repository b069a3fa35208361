"""Fuzz the myAHRS+ register decoding and the IMU handler's error paths.

Properties: any register contents decode to finite SI values in the ROS frame with a status
in {OK, NOT_READY, BAD_QUATERNION}; an OK sample has a unit quaternion and encodes into a
valid IMU datagram; wrong burst lengths, I2C errors and implausible samples (the handler's
plausibility check) are typed, counted errors -- never a value. Run with atheris (optional)
as a script::

    python src/m4k_drivers/test/test_fuzz_imu.py -atheris_runs=200000
"""

import ctypes
import errno
import math
import sys

from hypothesis import given, settings
from hypothesis import strategies as st

from m4k_drivers.handler import DeviceIOError, DeviceProtocolError, State, Status
from m4k_drivers.imu import protocol as p
from m4k_drivers.imu.handler import ImuHandler
from m4k_drivers.imu.real import I2cDevice
from m4k_rt import protocol as wire
from m4k_rt.protocol import ImuStatus
from m4k_testing import examples

STATUSES = {ImuStatus.OK, ImuStatus.NOT_READY, ImuStatus.BAD_QUATERNION}


def check_blocks(b1: bytes, b2: bytes, ready: bool) -> p.ImuSample | None:
    """Decode two bursts; check the invariants; return the sample (None if rejected)."""
    try:
        dev = p.decode_blocks(b1, b2)
    except DeviceProtocolError:
        assert (len(b1), len(b2)) != (p.BLOCK1_LEN, p.BLOCK2_LEN)
        return None
    s = p.to_ros(dev, ready)
    flat = [*s.orientation, *s.angular_velocity, *s.linear_acceleration, *s.rpy,
            s.temperature]
    assert all(math.isfinite(v) for v in flat), s
    assert s.status in STATUSES
    if not ready:
        assert s.status == ImuStatus.NOT_READY
    norm = math.sqrt(sum(q * q for q in s.orientation))
    if s.status == ImuStatus.OK:
        assert abs(norm - 1.0) < 1e-9
    assert norm == 0.0 or abs(norm - 1.0) < 1e-9  # renormalised, or all-zero (flagged)
    # What the driver host sends: it must always be a decodable IMU datagram.
    data = wire.encode(wire.Kind.IMU, 0, 0, *s.orientation, *s.angular_velocity,
                       *s.linear_acceleration, s.status)
    assert wire.decode(data)[1].status == s.status
    return s


@settings(max_examples=examples(200))
@given(st.binary(min_size=p.BLOCK1_LEN, max_size=p.BLOCK1_LEN),
       st.binary(min_size=p.BLOCK2_LEN, max_size=p.BLOCK2_LEN), st.booleans())
def test_any_register_contents_decode_to_finite_flagged_samples(b1, b2, ready):
    assert check_blocks(b1, b2, ready) is not None


@settings(max_examples=examples(200))
@given(st.binary(min_size=p.SAMPLE_LEN, max_size=p.SAMPLE_LEN))
def test_any_burst_the_handler_accepts_is_a_plausible_measurement(burst):
    s = p.decode_sample(burst)
    if p.implausible(s) is not None:
        return
    assert abs(math.sqrt(sum(q * q for q in s.quaternion)) - 1.0) <= p.QUAT_NORM_TOLERANCE
    assert max(abs(g) for g in s.gyro) < math.radians(2000.0)
    assert max(abs(a) for a in s.accel) < 16 * p.GRAVITY
    assert p.to_ros(s).status == ImuStatus.OK


@settings(max_examples=examples(200))
@given(st.binary(max_size=40), st.binary(max_size=40))
def test_wrong_burst_lengths_are_protocol_errors(b1, b2):
    check_blocks(b1, b2, True)


def test_zero_and_extreme_quaternions_are_flagged_not_published_as_ok():
    zero = bytes(p.BLOCK2_LEN)
    s = check_blocks(bytes(p.BLOCK1_LEN), zero, True)
    assert s.status == ImuStatus.BAD_QUATERNION
    extreme = b'\x00' * 6 + b'\xff\x7f' * 4  # |q| = 2
    assert check_blocks(bytes(p.BLOCK1_LEN), extreme, True).status == ImuStatus.BAD_QUATERNION


class FlakyBus:
    """A register-level myAHRS+ whose reads fail, return short blocks or garbage on demand."""

    def __init__(self, plan):
        self.plan = list(plan)   # per data read: 'ok', 'eio', 'eremoteio', 'short', 'garbage'
        self.regs = bytearray(p.REG_LAST + 1)
        self.regs[p.REG_WHO_AM_I] = p.WHO_AM_I_VALUE
        self.regs[p.REG_STATUS] = p.STATUS_READY
        b1, b2 = p.encode_blocks(p.DeviceSample((0.0, 0.0, -9.8), (0.0, 0.0, 0.0), (0, 0, 0),
                                                20.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)))
        self.regs[p.BLOCK1:p.BLOCK1 + p.BLOCK1_LEN] = b1
        self.regs[p.BLOCK2:p.BLOCK2 + p.BLOCK2_LEN] = b2
        self.closed = False

    def read_byte_data(self, addr, reg):
        return self.regs[reg]

    def i2c_rdwr(self, write, read):
        # One combined transaction per sample: pointer write, then the burst read.
        data = self.read_i2c_block_data(write.addr, bytes(write)[0], read.len)
        ctypes.memmove(read.buf, bytes(data), len(data))
        read.len = len(data)            # a transfer cut short delivers fewer bytes

    def read_i2c_block_data(self, addr, reg, length):
        what = self.plan.pop(0) if self.plan else 'ok'
        if what == 'eio':
            raise OSError(errno.EIO, 'Input/output error')
        if what == 'eremoteio':
            raise OSError(errno.EREMOTEIO, 'Remote I/O error')
        data = list(self.regs[reg:reg + length])
        if what == 'short':
            return data[:length // 2]
        if what == 'garbage':
            return [0xFF] * length
        return data

    def write_byte_data(self, addr, reg, value):
        pass

    def close(self):
        self.closed = True


def test_i2c_errors_and_short_reads_are_counted_and_never_a_value():
    # One burst transaction per sample.
    plan = ['ok', 'eio', 'short', 'eremoteio', 'ok', 'garbage']
    bus = FlakyBus(plan)
    h = ImuHandler(lambda: I2cDevice(bus, p.ADDRESS, 'flaky:i2c'))
    h.configure()
    h.activate()
    results = [h.read() for _ in range(6)]
    assert [r.status for r in results] == [Status.OK, Status.ERROR, Status.ERROR, Status.ERROR,
                                           Status.OK, Status.ERROR]
    assert all(r.value is None for r in results if r.status == Status.ERROR)
    assert isinstance(results[1].error, DeviceIOError) and 'errno 5' in str(results[1].error)
    assert isinstance(results[2].error, DeviceProtocolError)
    assert 'flaky:i2c@0x20' in str(results[3].error)
    assert h.faults == 4 and h.state == State.ACTIVE and h.status_level() == 1
    # 0xFF everywhere (nothing drives SDA) decodes, but its |q| = 6e-5: rejected, counted.
    assert isinstance(results[5].error, DeviceProtocolError)
    assert 'quaternion_norm' in str(results[5].error) and h.rejected == {'quaternion_norm': 1}
    assert h.read().value.status == ImuStatus.OK   # recovered without a reconfigure
    h.shutdown()
    assert bus.closed


def atheris_main() -> None:  # pragma: no cover -- run by hand
    """Coverage-guided fuzzing of the register decoding with atheris."""
    import atheris

    def one(data: bytes) -> None:
        fdp = atheris.FuzzedDataProvider(data)
        n1 = p.BLOCK1_LEN if fdp.ConsumeBool() else fdp.ConsumeIntInRange(0, 40)
        n2 = p.BLOCK2_LEN if fdp.ConsumeBool() else fdp.ConsumeIntInRange(0, 40)
        check_blocks(fdp.ConsumeBytes(n1), fdp.ConsumeBytes(n2), fdp.ConsumeBool())
    atheris.instrument_all()
    atheris.Setup(sys.argv, one)
    atheris.Fuzz()


if __name__ == '__main__':
    atheris_main()
