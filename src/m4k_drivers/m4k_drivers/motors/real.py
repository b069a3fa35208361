"""Motor transport on real spidev nodes (python-periphery), one node per chip select.

The paper's RPi3 extends the SPI chip selects with GPIO so that two MCP4911 DACs and two
AS5045 encoders each get their own ``/dev/spidevB.C`` node; the config names the four paths.
The amplifier enable heartbeat is one GPIO output line (python-periphery GPIO on the gpiochip
character device); the handler toggles it on every fresh command (docs/internals.md).
"""

from __future__ import annotations

from typing import Callable, Protocol

from m4k_drivers.handler import DeviceIOError, DriverError, wrap_os_error

__all__ = ['EnableLine', 'InputLike', 'LineLike', 'MotorBus', 'ReadbackLine', 'SpiLike',
           'SpiPort', 'open_ldac', 'open_real_bus', 'open_real_enable', 'open_real_readback']


class SpiLike(Protocol):
    """What the motor code needs from an SPI device: full-duplex transfer and close."""

    def transfer(self, data: bytes) -> bytes | bytearray | list[int]:
        """Clock ``data`` out and return the bytes clocked in (periphery: as given)."""

    def close(self) -> None:
        """Release the device."""


class SpiPort:
    """One spidev node: wraps periphery errors into DriverErrors naming the path."""

    def __init__(self, dev: SpiLike, path: str) -> None:
        self.dev = dev
        self.path = path

    def transfer(self, data: bytes) -> bytes:
        """Do one full-duplex transfer; OSError -> DeviceIOError with path and errno."""
        try:
            return bytes(self.dev.transfer(data))
        except OSError as exc:
            raise wrap_os_error(exc, self.path, 'transfer') from exc

    def close(self) -> None:
        """Close the node, ignoring errors (cleanup must not raise)."""
        try:
            self.dev.close()
        except OSError:
            pass


class LineLike(Protocol):
    """An output GPIO line (python-periphery GPIO): write and close."""

    def write(self, value: bool) -> None:
        """Drive the line."""

    def close(self) -> None:
        """Release the line."""


class EnableLine:
    """The amplifier-enable heartbeat output: each :meth:`toggle` retriggers the monostable."""

    def __init__(self, line: LineLike, where: str) -> None:
        self.line = line
        self.where = where
        self.level = False
        self.toggles = 0

    def toggle(self) -> None:
        """Flip the line (a rising edge retriggers); OSError -> DeviceIOError naming it."""
        try:
            self.line.write(not self.level)
        except OSError as exc:
            raise wrap_os_error(exc, self.where, 'heartbeat') from exc
        self.level = not self.level
        self.toggles += 1

    def close(self) -> None:
        """Release the line, ignoring errors (the monostable then times out)."""
        try:
            self.line.close()
        except OSError:
            pass


class InputLike(Protocol):
    """An input GPIO line (python-periphery GPIO): read and close."""

    def read(self) -> bool:
        """Return the line level."""

    def close(self) -> None:
        """Release the line."""


class ReadbackLine:
    """The e-stop read-back: the monostable's output after a dedicated safety-relay contact.

    :meth:`read` returns True (*asserted*) while the enable passes the contact; False while the
    relay is open -- or while nobody drives the enable (no heartbeat), which the handler tells
    apart.  ``invert`` turns a raw level into that sense where the line itself cannot (the
    sim-bus line; on the kernel the request carries ACTIVE_LOW instead).
    """

    def __init__(self, line: InputLike, where: str, *, invert: bool = False) -> None:
        self.line = line
        self.where = where
        self.invert = invert
        self.reads = 0

    def read(self) -> bool:
        """Return the level; OSError -> DeviceIOError naming the line."""
        try:
            level = bool(self.line.read())
        except OSError as exc:
            raise wrap_os_error(exc, self.where, 'e-stop read-back') from exc
        self.reads += 1
        return level != self.invert

    def close(self) -> None:
        """Release the line, ignoring errors."""
        try:
            self.line.close()
        except OSError:
            pass


class MotorBus:
    """The four SPI endpoints of the base (left/right DAC, left/right encoder), /LDAC, enable.

    ``ldac`` None: /LDAC is tied low on the board, every DAC output follows its own write.
    Otherwise the line idles high and :meth:`latch` pulses it low after both writes.
    ``enable`` is the amplifier-enable heartbeat (None: enable strapped on); ``readback`` the
    e-stop read-back input (None: not wired, the contact's state is unknown to software).
    """

    def __init__(self, left_dac: SpiPort, right_dac: SpiPort, left_enc: SpiPort,
                 right_enc: SpiPort, ldac: LineLike | None = None,
                 ldac_where: str = 'LDAC', enable: EnableLine | None = None,
                 readback: ReadbackLine | None = None) -> None:
        self.dacs = (left_dac, right_dac)
        self.encoders = (left_enc, right_enc)
        self.ldac = ldac
        self.ldac_where = ldac_where
        self.latches = 0
        self.enable = enable
        self.readback = readback

    def latch(self) -> None:
        """Pulse /LDAC low then high (a Python GPIO write pair lasts >> t_LD = 100 ns)."""
        if self.ldac is None:
            return
        try:
            self.ldac.write(False)
            self.ldac.write(True)
        except OSError as exc:
            raise wrap_os_error(exc, self.ldac_where, 'pulse') from exc
        self.latches += 1

    def close(self) -> None:
        """Close every endpoint."""
        for port in (*self.dacs, *self.encoders):
            port.close()
        if self.ldac is not None:
            try:
                self.ldac.close()
            except OSError:
                pass
        if self.enable is not None:
            self.enable.close()
        if self.readback is not None:
            self.readback.close()


def open_spi(path: str, mode: int, speed_hz: int) -> SpiPort:
    """Open one spidev node, raising DeviceNotFoundError/DevicePermissionError naming it."""
    from periphery import SPI
    try:
        return SpiPort(SPI(path, mode, speed_hz), path)
    except OSError as exc:
        raise wrap_os_error(exc, path) from exc
    except (TypeError, ValueError) as exc:
        raise DeviceIOError(f'{path}: bad SPI settings mode={mode!r} speed={speed_hz!r}: {exc}'
                            ) from exc


def open_ldac(chip: str, line: int) -> LineLike:
    """Request /LDAC as an output idling high (outputs hold until the pulse)."""
    from periphery import GPIO
    try:
        return GPIO(chip, line, 'high')
    except OSError as exc:
        raise wrap_os_error(exc, f'{chip} line {line} (LDAC)') from exc


def open_real_enable(chip: str, line: int) -> EnableLine:
    """Request the heartbeat line as an output, initially low."""
    from periphery import GPIO
    where = f'{chip} line {line}'
    try:
        return EnableLine(GPIO(chip, line, 'low'), where)
    except OSError as exc:
        raise wrap_os_error(exc, where) from exc


def open_real_readback(chip: str, line: int, *, active_low: bool = False) -> ReadbackLine:
    """Request the e-stop read-back input; ``active_low``: GPIO_V2_LINE_FLAG_ACTIVE_LOW."""
    from periphery import GPIO
    where = f'{chip} line {line} (e-stop read-back, active {"low" if active_low else "high"})'
    try:
        return ReadbackLine(GPIO(chip, line, 'in', inverted=active_low), where)
    except OSError as exc:
        raise wrap_os_error(exc, where) from exc


def open_real_bus(left_dac: str, right_dac: str, left_enc: str, right_enc: str, *,
                  dac_mode: int = 0, dac_speed_hz: int = 1_000_000, enc_mode: int = 2,
                  enc_speed_hz: int = 500_000, ldac_chip: str | None = None,
                  ldac_line: int | None = None,
                  enable: Callable[[], EnableLine] | None = None,
                  readback: Callable[[], ReadbackLine] | None = None) -> MotorBus:
    """Open the four spidev nodes, /LDAC if driven, the enable and read-back lines.

    Everything opened is closed again when a later part fails.
    """
    opened: list[SpiPort] = []
    try:
        for path, mode, speed in ((left_dac, dac_mode, dac_speed_hz),
                                  (right_dac, dac_mode, dac_speed_hz),
                                  (left_enc, enc_mode, enc_speed_hz),
                                  (right_enc, enc_mode, enc_speed_hz)):
            opened.append(open_spi(path, mode, speed))
        ldac = None if ldac_chip is None else open_ldac(ldac_chip, int(ldac_line or 0))
        line = back = None
        try:
            line = enable() if enable is not None else None
            back = readback() if readback is not None else None
        except DriverError:
            if ldac is not None:
                ldac.close()
            if line is not None:
                line.close()
            raise
    except DriverError:
        for port in opened:
            port.close()
        raise
    dac_l, dac_r, enc_l, enc_r = opened
    return MotorBus(dac_l, dac_r, enc_l, enc_r, ldac=ldac,
                    ldac_where=f'{ldac_chip} line {ldac_line} (LDAC)', enable=line,
                    readback=back)
