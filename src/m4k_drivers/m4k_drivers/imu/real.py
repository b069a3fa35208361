"""I2C transport for the myAHRS+: an smbus2 bus (or a register-level fake) at one address."""

from __future__ import annotations

from typing import Any, Protocol

from m4k_drivers.handler import wrap_os_error

__all__ = ['I2cDevice', 'SmbusLike', 'open_real_i2c']


class SmbusLike(Protocol):
    """The smbus2.SMBus methods the IMU code uses."""

    def read_byte_data(self, i2c_addr: int, register: int) -> int:
        """Read one register."""

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int) -> list[int]:
        """Read ``length`` consecutive registers (at most 32)."""

    def write_byte_data(self, i2c_addr: int, register: int, value: int) -> None:
        """Write one register."""

    def i2c_rdwr(self, *messages: Any) -> None:
        """Run smbus2 ``i2c_msg`` messages as one combined transaction (I2C_RDWR ioctl)."""

    def close(self) -> None:
        """Release the bus."""


class I2cDevice:
    """One I2C slave: register reads/writes with OSError -> DriverError naming bus and address."""

    def __init__(self, bus: SmbusLike, address: int, path: str) -> None:
        self.bus = bus
        self.address = address
        self.path = path
        self.where = f'{path}@0x{address:02x}'

    def read_byte(self, register: int) -> int:
        """Read one register."""
        try:
            return self.bus.read_byte_data(self.address, register)
        except OSError as exc:
            raise wrap_os_error(exc, self.where, f'read 0x{register:02x}') from exc

    def read_block(self, register: int, length: int) -> bytes:
        """Read ``length`` registers from ``register`` in one transaction."""
        try:
            return bytes(self.bus.read_i2c_block_data(self.address, register, length))
        except OSError as exc:
            raise wrap_os_error(exc, self.where, f'read 0x{register:02x}+{length}') from exc

    def read_burst(self, register: int, length: int) -> bytes:
        """Read ``length`` registers from ``register`` in ONE I2C transaction, any length.

        A register-pointer write, a repeated START and a ``length``-byte read in one I2C_RDWR
        ioctl (smbus2 ``i2c_msg``): unlike SMBus block reads it is not limited to 32 bytes, so
        a whole myAHRS+ sample (34 bytes) comes from one transaction and cannot mix two of
        the device's 100 Hz register updates.
        """
        from smbus2 import i2c_msg
        write = i2c_msg.write(self.address, [register])
        read = i2c_msg.read(self.address, length)
        try:
            self.bus.i2c_rdwr(write, read)
        except OSError as exc:
            raise wrap_os_error(exc, self.where, f'read 0x{register:02x}+{length}') from exc
        return bytes(read)

    def write_byte(self, register: int, value: int) -> None:
        """Write one register."""
        try:
            self.bus.write_byte_data(self.address, register, value)
        except OSError as exc:
            raise wrap_os_error(exc, self.where, f'write 0x{register:02x}') from exc

    def close(self) -> None:
        """Close the bus, ignoring errors."""
        try:
            self.bus.close()
        except OSError:
            pass


def open_real_i2c(bus: int | str, address: int) -> I2cDevice:
    """Open ``/dev/i2c-<bus>`` (or a path) with smbus2; a missing bus names its path."""
    from smbus2 import SMBus
    path = bus if isinstance(bus, str) else f'/dev/i2c-{bus}'
    smbus: Any
    try:
        smbus = SMBus(bus)
    except OSError as exc:
        raise wrap_os_error(exc, path) from exc
    return I2cDevice(smbus, address, path)
