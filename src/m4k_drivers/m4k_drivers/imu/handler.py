"""IMU handler: identify the myAHRS+ (WHO_AM_I), then read samples in the ROS frame.

A sample that cannot be a measurement (:func:`m4k_drivers.imu.protocol.implausible`: a
quaternion far from unit norm, a rate or acceleration at the full-scale rail) is rejected here,
in the NRT handler that decodes the registers, not in the RT task: counted per reason in
``rejected``, recorded as a fault (DEVICE_STATUS level WARN, fault count, last error PROTOCOL)
and never sent as an IMU datagram.

With a data-ready line (``drdy``, :mod:`m4k_drivers.imu.drdy`) a read first takes the newest
DATA READY edge -- one already pending, or the next within ``drdy_timeout_s`` -- and the
sample is stamped at that edge (``sample_ns``, the datagram's header stamp).  No edge in time
(a broken wire, the wrong edge configured): the read falls back to polling STATUS, counted in
``drdy_misses``, and the sample is timed on arrival.
"""

from __future__ import annotations

import collections
from typing import Any, Callable

from m4k_drivers.handler import DeviceHandler, DeviceIdentityError, DeviceProtocolError
from m4k_drivers.imu import protocol as p
from m4k_drivers.imu.drdy import DataReady
from m4k_drivers.imu.real import I2cDevice

__all__ = ['ImuHandler']


class ImuHandler(DeviceHandler):
    """Lifecycle handler for a myAHRS+ on I2C (real smbus2 bus or the register-level fake)."""

    kind = 'imu'

    def __init__(self, opener: Callable[[], I2cDevice], *, name: str = 'imu',
                 drdy: Callable[[], DataReady] | None = None, drdy_timeout_s: float = 0.02,
                 **kw: Any) -> None:
        super().__init__(name, **kw)
        self._opener = opener
        self._drdy_opener = drdy
        self.drdy: DataReady | None = None
        self.drdy_timeout_s = drdy_timeout_s
        self.drdy_misses = 0
        self.sample_ns: int | None = None     # the last sample's data-ready edge (None: unknown)
        self.dev: I2cDevice | None = None
        self.revision = (0, 0)
        self.rejected: collections.Counter[str] = collections.Counter()   # reason -> samples

    def on_configure(self) -> None:
        """Open the bus and check WHO_AM_I == 0xB1."""
        self.dev = self._opener()
        who = self.dev.read_byte(p.REG_WHO_AM_I)
        if who != p.WHO_AM_I_VALUE:
            raise DeviceIdentityError(f'{self.dev.where}: WHO_AM_I is 0x{who:02x}, expected '
                                      f'0x{p.WHO_AM_I_VALUE:02x} (is this a myAHRS+?)')
        self.revision = (self.dev.read_byte(p.REG_REV_MAJOR), self.dev.read_byte(p.REG_REV_MINOR))
        if self._drdy_opener is not None:
            self.drdy = self._drdy_opener()

    def on_read(self) -> p.ImuSample:
        """Read STATUS, then the whole sample in one transaction; return it in the ROS frame.

        Raise DeviceProtocolError (counted in ``rejected``) for an implausible sample.
        """
        assert self.dev is not None
        self.sample_ns = None
        if self.drdy is not None:
            came, self.sample_ns = self.drdy.wait(self.drdy_timeout_s)
            if not came:
                self.drdy_misses += 1             # polled instead: timed on arrival
        ready = bool(self.dev.read_byte(p.REG_STATUS) & p.STATUS_READY)
        sample = p.decode_sample(self.dev.read_burst(p.SAMPLE, p.SAMPLE_LEN))
        reason = p.implausible(sample)
        if reason is not None:
            self.rejected[reason] += 1
            n = sum(self.rejected.values())
            if n == 1 or n % 100 == 0:      # a glitching bus repeats: not every sample logged
                self.log.warning('%s: rejected %d implausible sample(s), last: %s %s',
                                 self.name, n, reason, _describe(sample))
            raise DeviceProtocolError(f'{self.name}: sample rejected: {reason} '
                                      f'{_describe(sample)}')
        return p.to_ros(sample, ready)

    def on_cleanup(self) -> None:
        """Close the bus and the data-ready line."""
        if self.drdy is not None:
            self.drdy.close()
            self.drdy = None
        if self.dev is not None:
            self.dev.close()
            self.dev = None


def _describe(sample: p.DeviceSample) -> str:
    """Return the quantities the plausibility rules judge, for the error message."""
    return (f'(|q|={p.quaternion_norm(sample):.4f}, '
            f'gyro={tuple(round(g, 3) for g in sample.gyro)} rad/s, '
            f'accel={tuple(round(a, 2) for a in sample.accel)} m/s^2)')
