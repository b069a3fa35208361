"""myAHRS+ (WithRobot) I2C register map and decoding (pure: bytes in, SI units out).

Source of the register map and scale factors: WithRobot's own documentation, repository
``withrobot/myAHRS_plus``, ``tutorial/readme.md``, section "I2C Interface" ("I2C Register
description" and "Data transform formula").  7-bit slave address 0x20.  All data registers are
signed 16-bit little-endian (LOW register first)::

    0x01 WHO_AM_I      = 0xB1            0x04 STATUS   bit 7 = 1 when initialisation is done
    0x02 REV_ID_MAJOR  0x03 REV_ID_MINOR
    0x10..0x21  I_ACC/I_GYRO/I_MAGNET x,y,z   raw (uncompensated) counts; magnet uT = I * 0.3
    0x22..0x27  C_ACC x,y,z      g   = C * 16 / 32767
    0x28..0x2D  C_GYRO x,y,z     dps = C * 2000 / 32767
    0x2E..0x33  C_MAGNET x,y,z   calibrated, no physical unit
    0x34..0x35  TEMPERATURE      degC = T * 200 / 32767
    0x36..0x3B  ROLL, PITCH, YAW deg = E * 180 / 32767
    0x3C..0x43  QUATERNION x,y,z,w  = Q / 32767

A sample is ONE burst 0x22..0x43 (34 bytes: accel, gyro, magnet, temperature, Euler,
quaternion) in one I2C transaction (register write, repeated START, read; the pointer
auto-increments), so it cannot mix two of the device's 100 Hz updates.  SMBus block reads stop
at 32 bytes, hence a plain I2C_RDWR rather than read_i2c_block_data (``BLOCK1``/``BLOCK2``
name the two halves inside that burst).

Axes: the myAHRS+ board frame is x forward, y right, z down (its Euler angles are roll about x,
pitch about y, yaw about z-down, i.e. heading clockwise).  REP-103 wants x forward, y left,
z up, so y and z flip sign for vectors, the quaternion becomes (x, -y, -z, w) (a conjugation by
the 180 deg rotation about x) and pitch and yaw flip sign.  Yaw is relative to the device's
heading reference (magnetic north), not ENU east.  REP-145: the accelerometer at rest reads
+9.81 m/s^2 on z.
"""

from __future__ import annotations

import math
import struct
from typing import NamedTuple

from m4k_drivers.handler import DeviceProtocolError
from m4k_rt.protocol import ImuStatus

__all__ = [
    'ADDRESS', 'BLOCK1', 'BLOCK1_LEN', 'BLOCK2', 'BLOCK2_LEN', 'GRAVITY', 'REG_STATUS',
    'SAMPLE', 'SAMPLE_LEN', 'decode_sample',
    'REG_WHO_AM_I', 'STATUS_READY', 'WHO_AM_I_VALUE', 'DeviceSample', 'ImuSample',
    'QUAT_NORM_TOLERANCE', 'decode_blocks', 'encode_blocks', 'implausible', 'quaternion_norm',
    'to_ros',
]

ADDRESS = 0x20
REG_WHO_AM_I = 0x01
WHO_AM_I_VALUE = 0xB1
REG_REV_MAJOR = 0x02
REG_REV_MINOR = 0x03
REG_STATUS = 0x04
STATUS_READY = 0x80
REG_I_ACC_X = 0x10
REG_C_ACC_X = 0x22
REG_C_GYRO_X = 0x28
REG_C_MAGNET_X = 0x2E
REG_TEMPERATURE = 0x34
REG_ROLL = 0x36
REG_QUATERNION_X = 0x3C
REG_LAST = 0x43

BLOCK1, BLOCK1_LEN = REG_C_ACC_X, REG_ROLL - REG_C_ACC_X            # 0x22, 20 bytes
BLOCK2, BLOCK2_LEN = REG_ROLL, REG_LAST + 1 - REG_ROLL             # 0x36, 14 bytes
SAMPLE, SAMPLE_LEN = BLOCK1, BLOCK1_LEN + BLOCK2_LEN                # 0x22, 34 bytes, one read

GRAVITY = 9.80665
FULL = 32767.0
ACC_G = 16.0 / FULL
GYRO_DPS = 2000.0 / FULL
TEMP_C = 200.0 / FULL
EULER_DEG = 180.0 / FULL
QUAT = 1.0 / FULL

# Plausibility (see :func:`implausible`).  The firmware's EKF outputs a unit quaternion; the
# registers round each component to 1/32767, so |q| of a sound sample is 1 within
# sqrt(4) * 0.5 / 32767 = 3.1e-5.  0.01 (328 LSB) is 300 times that: room for a firmware that
# normalises loosely, while all-zero (a reset in progress), all-0xFF (nothing drives SDA:
# |q| = 6e-5) and a corrupted high byte of a large component (>= 256 LSB) fall outside.
QUAT_NORM_TOLERANCE = 0.01
# A calibrated accel/gyro register at the rail (|count| >= 32767: +-16 g, +-2000 dps, the
# stated full scale) is clipped -- the true value is at or beyond the range, so the number is
# wrong.  Half an LSB below the rail, so the rail itself counts.
ACC_LIMIT = (FULL - 0.5) * ACC_G * GRAVITY                    # m/s^2
GYRO_LIMIT = math.radians((FULL - 0.5) * GYRO_DPS)        # rad/s

class DeviceSample(NamedTuple):
    """One sample in the myAHRS+ board frame (x fwd, y right, z down), SI units."""

    accel: tuple[float, float, float]      # m/s^2
    gyro: tuple[float, float, float]       # rad/s
    magnet: tuple[int, int, int]           # calibrated, unitless
    temperature: float                     # degC
    euler: tuple[float, float, float]      # roll, pitch, yaw, rad
    quaternion: tuple[float, float, float, float]   # x, y, z, w


class ImuSample(NamedTuple):
    """One sample in the ROS frame (REP-103/145), what the IMU datagram carries."""

    orientation: tuple[float, float, float, float]   # x, y, z, w
    angular_velocity: tuple[float, float, float]     # rad/s
    linear_acceleration: tuple[float, float, float]  # m/s^2
    rpy: tuple[float, float, float]                  # roll, pitch, yaw (rad)
    temperature: float
    status: int


_B1 = struct.Struct('<3h3h3hh')
_B2 = struct.Struct('<3h4h')


def decode_blocks(block1: bytes | bytearray, block2: bytes | bytearray) -> DeviceSample:
    """Decode the two register bursts (0x22..0x35, 0x36..0x43) into a DeviceSample."""
    if len(block1) != BLOCK1_LEN or len(block2) != BLOCK2_LEN:
        raise DeviceProtocolError(f'myAHRS+ bursts must be {BLOCK1_LEN} + {BLOCK2_LEN} bytes, '
                                  f'got {len(block1)} + {len(block2)}')
    v1 = _B1.unpack(bytes(block1))
    v2 = _B2.unpack(bytes(block2))
    acc = tuple(c * ACC_G * GRAVITY for c in v1[0:3])
    gyro = (math.radians(v1[3] * GYRO_DPS), math.radians(v1[4] * GYRO_DPS),
            math.radians(v1[5] * GYRO_DPS))
    euler = (math.radians(v2[0] * EULER_DEG), math.radians(v2[1] * EULER_DEG),
             math.radians(v2[2] * EULER_DEG))
    quat = tuple(c * QUAT for c in v2[3:7])
    return DeviceSample(acc, gyro, (v1[6], v1[7], v1[8]), v1[9] * TEMP_C, euler, quat)


def decode_sample(burst: bytes | bytearray) -> DeviceSample:
    """Decode the one-transaction burst 0x22..0x43 into a DeviceSample."""
    if len(burst) != SAMPLE_LEN:
        raise DeviceProtocolError(f'myAHRS+ sample burst must be {SAMPLE_LEN} bytes, '
                                  f'got {len(burst)}')
    return decode_blocks(burst[:BLOCK1_LEN], burst[BLOCK1_LEN:])


def _i16(value: float) -> int:
    return max(-32768, min(32767, round(value)))


def encode_blocks(sample: DeviceSample) -> tuple[bytes, bytes]:
    """Return the register bytes a myAHRS+ would hold for ``sample`` (sim and tests)."""
    acc = [_i16(a / GRAVITY / ACC_G) for a in sample.accel]
    gyro = [_i16(math.degrees(g) / GYRO_DPS) for g in sample.gyro]
    mag = [_i16(m) for m in sample.magnet]
    euler = [_i16(math.degrees(e) / EULER_DEG) for e in sample.euler]
    quat = [_i16(q / QUAT) for q in sample.quaternion]
    return (_B1.pack(*acc, *gyro, *mag, _i16(sample.temperature / TEMP_C)),
            _B2.pack(*euler, *quat))


def quaternion_norm(sample: DeviceSample) -> float:
    """Return |q| of the sample's orientation (1 for a sound sample)."""
    return math.sqrt(sum(q * q for q in sample.quaternion))


def implausible(sample: DeviceSample) -> str | None:
    """Return why ``sample`` cannot be a real measurement (None: plausible).

    Reasons: ``quaternion_norm`` (|q| off 1 by more than :data:`QUAT_NORM_TOLERANCE`: garbage
    on the bus or registers cleared by a reset), ``gyro_full_scale`` / ``accel_full_scale``
    (a register at the +-2000 dps / +-16 g rail: clipped).
    """
    if not abs(quaternion_norm(sample) - 1.0) <= QUAT_NORM_TOLERANCE:
        return 'quaternion_norm'
    if any(not abs(g) < GYRO_LIMIT for g in sample.gyro):
        return 'gyro_full_scale'
    if any(not abs(a) < ACC_LIMIT for a in sample.accel):
        return 'accel_full_scale'
    return None


def to_ros(sample: DeviceSample, ready: bool = True) -> ImuSample:
    """Convert a board-frame sample to REP-103 (y and z flipped) with a status code."""
    ax, ay, az = sample.accel
    gx, gy, gz = sample.gyro
    qx, qy, qz, qw = sample.quaternion
    roll, pitch, yaw = sample.euler
    norm = quaternion_norm(sample)
    status = ImuStatus.OK
    if not ready:
        status = ImuStatus.NOT_READY
    elif abs(norm - 1.0) > 0.05:
        status = ImuStatus.BAD_QUATERNION
    if norm > 0.0:   # renormalise the 16-bit quantisation (|q| = 1 +/- 1e-4)
        qx, qy, qz, qw = qx / norm, qy / norm, qz / norm, qw / norm
    return ImuSample((qx, -qy, -qz, qw), (gx, -gy, -gz), (ax, -ay, -az),
                     (roll, -pitch, -yaw), sample.temperature, status)
