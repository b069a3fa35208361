"""IMU handler: identify the myAHRS+ (WHO_AM_I), then read samples in the ROS frame."""

from __future__ import annotations

from typing import Any, Callable

from m4k_drivers.handler import DeviceHandler, DeviceIdentityError
from m4k_drivers.imu import protocol as p
from m4k_drivers.imu.real import I2cDevice

__all__ = ['ImuHandler']


class ImuHandler(DeviceHandler):
    """Lifecycle handler for a myAHRS+ on I2C (real smbus2 bus or the register-level fake)."""

    kind = 'imu'

    def __init__(self, opener: Callable[[], I2cDevice], *, name: str = 'imu',
                 **kw: Any) -> None:
        super().__init__(name, **kw)
        self._opener = opener
        self.dev: I2cDevice | None = None
        self.revision = (0, 0)

    def on_configure(self) -> None:
        """Open the bus and check WHO_AM_I == 0xB1."""
        self.dev = self._opener()
        who = self.dev.read_byte(p.REG_WHO_AM_I)
        if who != p.WHO_AM_I_VALUE:
            raise DeviceIdentityError(f'{self.dev.where}: WHO_AM_I is 0x{who:02x}, expected '
                                      f'0x{p.WHO_AM_I_VALUE:02x} (is this a myAHRS+?)')
        self.revision = (self.dev.read_byte(p.REG_REV_MAJOR), self.dev.read_byte(p.REG_REV_MINOR))

    def on_read(self) -> p.ImuSample:
        """Read STATUS, then the whole sample in one transaction; return it in the ROS frame."""
        assert self.dev is not None
        ready = bool(self.dev.read_byte(p.REG_STATUS) & p.STATUS_READY)
        return p.to_ros(p.decode_sample(self.dev.read_burst(p.SAMPLE, p.SAMPLE_LEN)), ready)

    def on_cleanup(self) -> None:
        """Close the bus."""
        if self.dev is not None:
            self.dev.close()
            self.dev = None
