"""A register-level fake myAHRS+ on a fake SMBus, fed from the simulated world's motion.

Same methods as ``smbus2.SMBus`` (read_byte_data, read_i2c_block_data, write_byte_data,
i2c_rdwr for combined transactions), so
the real register decoding runs against it.  The registers refresh at the device's output
rate (100 Hz): reads in between return the same sample, as on the real part.  Noise levels are
the standard deviations the ``robotpilot/myahrs_driver`` authors measured on a myAHRS+
(accel 0.0268 m/s^2, gyro 0.00243 rad/s, orientation 0.00214 rad); the calibrated gyro keeps
a constant per-axis bias (``gyro_bias``, ROS frame) drawn once from the world seed (sd 0.002
rad/s).  On a sloping floor patch the body stands tilted (``World.tilt``: roll and pitch from
the slope and the heading): orientation, gravity in the accelerometer and the magnetic field
follow the tilt; on the level roll = pitch = 0 (plus the orientation noise). The heading
reference is the world x axis.

Fault injection (tests): ``garble`` set to one of :data:`GARBLES` makes every sample burst
read as what a real part on a noisy bus or in a reset returns -- ``zeros`` (data registers
cleared while the firmware restarts), ``ones`` (0xFF: nothing drives SDA), ``quaternion``
(bit 6 of QUATERNION_X_HIGH flipped: x off by
0.5, |q| about 1.12), ``gyro_rail`` (gyro z at +32767: the
2000 dps full scale, clipped).  STATUS and WHO_AM_I are not touched (separate transactions).
"""

from __future__ import annotations

import ctypes
import errno
import math
import os
from typing import Any

from m4k_drivers.imu import protocol as p
from m4k_drivers.world import World
from m4k_rt.rotation import quaternion_rpy

__all__ = ['FakeMyAhrsBus', 'GARBLES']

I2C_M_RD = 0x0001          # linux/i2c.h: read message

# Earth field in base_link at yaw 0 (uT): 25 horizontal towards world +x, 40 down.
_EARTH_H_UT = 25.0
_EARTH_DOWN_UT = 40.0
GARBLES = ('zeros', 'ones', 'quaternion', 'gyro_rail')


def _body_field(yaw: float, pitch: float, roll: float) -> tuple[float, float, float]:
    """Return the earth's field (uT) in base_link: R^T of (H, 0, -down), R = Rz Ry Rx."""
    mx, mz = _EARTH_H_UT, -_EARTH_DOWN_UT
    cy, sy = math.cos(yaw), math.sin(yaw)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cr, sr = math.cos(roll), math.sin(roll)
    # undo the yaw (world -> heading frame), then the pitch, then the roll
    hx, hy = cy * mx, -sy * mx
    px, pz = cp * hx - sp * mz, sp * hx + cp * mz
    return px, cr * hy + sr * pz, -sr * hy + cr * pz


class FakeMyAhrsBus:
    """A fake SMBus with one myAHRS+ at ``address`` whose registers follow the world."""

    def __init__(self, world: World, address: int = p.ADDRESS, rate_hz: float = 100.0,
                 accel_sd: float = 0.026831, gyro_sd: float = 0.002428,
                 orientation_sd: float = 0.002143, gyro_bias_sd: float = 0.002) -> None:
        self.world = world
        self.address = address
        self.period_ns = int(1e9 / rate_hz)
        self.accel_sd, self.gyro_sd, self.orientation_sd = accel_sd, gyro_sd, orientation_sd
        self.rng = world.rng('imu')
        # the tilt's noise from a stream of its own: the gyro, accel and heading noise of a
        # seed stay the draws they were before the tilt was modelled
        self._tilt_rng = world.rng('imu.tilt')
        self.gyro_bias = tuple(float(b) for b in self.rng.normal(0.0, gyro_bias_sd, 3))
        self.regs = bytearray(p.REG_LAST + 1)
        self.regs[p.REG_WHO_AM_I] = p.WHO_AM_I_VALUE
        self.regs[p.REG_REV_MAJOR] = 1
        self.regs[p.REG_REV_MINOR] = 6
        self.regs[p.REG_STATUS] = p.STATUS_READY
        self._tick = -1
        self.closed = False
        self.samples = 0
        self.transactions = 0
        self.garble: str | None = None        # fault injection: one of GARBLES, None = sound

    def _refresh(self) -> None:
        now = self.world.now()
        tick = now // self.period_ns
        if tick == self._tick:
            return
        self._tick = tick
        st = self.world.state()
        n = self.rng.normal
        roll, pitch = self.world.tilt(st.pose)
        roll += float(self._tilt_rng.normal(0.0, self.orientation_sd))
        pitch += float(self._tilt_rng.normal(0.0, self.orientation_sd))
        yaw = st.pose.yaw + float(n(0.0, self.orientation_sd))
        cr, sr = math.cos(roll), math.sin(roll)
        cp, sp = math.cos(pitch), math.sin(pitch)
        # ROS frame (x fwd, y left, z up) first, then to the board frame (y, z flipped).
        g = (float(n(0.0, self.gyro_sd)) + self.gyro_bias[0],
             float(n(0.0, self.gyro_sd)) + self.gyro_bias[1],
             st.w + float(n(0.0, self.gyro_sd)) + self.gyro_bias[2])
        # specific force: the motion along the floor, plus the floor's push against gravity
        # (world up) seen in the tilted body: (-g sin(pitch), g cos(pitch) sin(roll),
        # g cos(pitch) cos(roll))
        a = (st.accel - p.GRAVITY * sp + float(n(0.0, self.accel_sd)),
             st.v * st.w + p.GRAVITY * cp * sr + float(n(0.0, self.accel_sd)),
             p.GRAVITY * cp * cr + float(n(0.0, self.accel_sd)))
        mag = _body_field(st.pose.yaw, pitch, roll)
        q = quaternion_rpy(roll, pitch, yaw)
        dev = p.DeviceSample((a[0], -a[1], -a[2]), (g[0], -g[1], -g[2]),
                             (round(mag[0] / 0.3), round(-mag[1] / 0.3), round(-mag[2] / 0.3)),
                             25.0 + float(n(0.0, 0.05)), (roll, -pitch, -yaw),
                             (q[0], -q[1], -q[2], q[3]))
        b1, b2 = p.encode_blocks(dev)
        self.regs[p.BLOCK1:p.BLOCK1 + p.BLOCK1_LEN] = b1
        self.regs[p.BLOCK2:p.BLOCK2 + p.BLOCK2_LEN] = b2
        self.samples += 1

    def _view(self) -> bytearray:
        """Return the registers as a read sees them: with ``garble``, a corrupted sample."""
        if self.garble is None:
            return self.regs
        regs = bytearray(self.regs)
        lo, hi = p.SAMPLE, p.SAMPLE + p.SAMPLE_LEN
        if self.garble == 'zeros':
            regs[lo:hi] = bytes(hi - lo)
        elif self.garble == 'ones':
            regs[lo:hi] = b'\xff' * (hi - lo)
        elif self.garble == 'quaternion':      # one bit flipped in QUATERNION_X_HIGH
            regs[p.REG_QUATERNION_X + 1] ^= 0x40   # x +- 16384 LSB: |q| about 1.12
        elif self.garble == 'gyro_rail':
            regs[p.REG_C_GYRO_X + 4:p.REG_C_GYRO_X + 6] = (32767).to_bytes(2, 'little')
        else:
            raise ValueError(f'garble must be one of {GARBLES} or None, got {self.garble!r}')
        return regs

    def _check(self, i2c_addr: int, register: int, length: int = 1) -> None:
        if self.closed:
            raise OSError(errno.EBADF, 'Bad file descriptor')
        if i2c_addr != self.address:
            # Nobody acknowledges a wrong address: the kernel reports EREMOTEIO.
            raise OSError(errno.EREMOTEIO, os.strerror(errno.EREMOTEIO))
        if register < 0 or register + length > len(self.regs) or not 1 <= length <= 32:
            raise OSError(errno.EIO, f'register 0x{register:02x}+{length} out of range')

    def read_byte_data(self, i2c_addr: int, register: int) -> int:
        """Read one register."""
        self._check(i2c_addr, register)
        self._refresh()
        return self._view()[register]

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int) -> list[int]:
        """Read consecutive registers (auto-increment), at most 32 like SMBus."""
        self._check(i2c_addr, register, length)
        self._refresh()
        return list(self._view()[register:register + length])

    def read_burst(self, i2c_addr: int, register: int, length: int) -> bytes:
        """Read ``length`` registers from ``register`` in one transaction (auto-increment).

        An I2C read (i2c-dev ``I2C_RDWR``) is not limited to SMBus's 32 bytes; past the last
        register the part returns 0xff (nothing drives SDA).
        """
        if self.closed:
            raise OSError(errno.EBADF, 'Bad file descriptor')
        if i2c_addr != self.address:
            raise OSError(errno.EREMOTEIO, os.strerror(errno.EREMOTEIO))
        if not 0 <= register <= 0xFF or length < 1:
            raise OSError(errno.EINVAL, f'register 0x{register:02x}+{length} invalid')
        self._refresh()
        data = bytes(self._view()[register:register + length])
        return data + b'\xff' * (length - len(data))

    def i2c_rdwr(self, *messages: Any) -> None:
        """Run a combined transaction (I2C_RDWR): a pointer write, then auto-incrementing reads.

        The registers are refreshed once, at the START: one transaction sees one update.
        """
        if self.closed:
            raise OSError(errno.EBADF, 'Bad file descriptor')
        self._refresh()
        regs = self._view()
        pointer = 0
        for msg in messages:
            if msg.addr != self.address:
                raise OSError(errno.EREMOTEIO, os.strerror(errno.EREMOTEIO))
            if not msg.flags & I2C_M_RD:
                data = bytes(msg)
                if data:
                    pointer = data[0]
                continue
            if pointer + msg.len > len(regs):
                raise OSError(errno.EIO, f'register 0x{pointer:02x}+{msg.len} out of range')
            ctypes.memmove(msg.buf, bytes(regs[pointer:pointer + msg.len]), msg.len)
            pointer += msg.len
        self.transactions += 1

    def write_byte_data(self, i2c_addr: int, register: int, value: int) -> None:
        """Accept a write (the data registers are read-only and ignore it)."""
        self._check(i2c_addr, register)

    def close(self) -> None:
        """Mark closed."""
        self.closed = True

