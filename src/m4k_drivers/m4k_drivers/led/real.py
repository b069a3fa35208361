"""LED outputs on Linux: the LED class (multicolor aware, or three single-colour LEDs) or PWM.

LED class (Documentation/ABI/testing/sysfs-class-led, -led-multicolor): ``brightness`` 0..
``max_brightness``; a multicolor LED also has ``multi_index`` (the colour of each channel, in
the kernel's order) and ``multi_intensity`` (one value per channel, in that same order).

sysfs PWM (Documentation/ABI/testing/sysfs-class-pwm, drivers/pwm/sysfs.c): a channel is
exported by writing its number to ``pwmchipN/export``; ``period``, ``duty_cycle`` (ns),
``polarity`` (``normal``/``inversed``) and ``enable``.  The kernel applies every write as a
whole state and refuses one with duty_cycle > period (EINVAL), and most drivers refuse a
polarity change while enabled (EBUSY).  So :class:`SysfsPwmChannel` configures in the one order
that is valid from any previous state: disable, duty 0, period, polarity, enable.
"""

from __future__ import annotations

import os
import time
from typing import Any, Callable, Sequence

from m4k_drivers.handler import (
    DeviceIdentityError,
    DeviceIOError,
    DeviceNotFoundError,
    DriverError,
    wrap_os_error,
)
from m4k_drivers.led import protocol as p

__all__ = ['LedClassOutput', 'LedClassRgbOutput', 'POLARITIES', 'PixelSpiOutput', 'PwmOutput',
           'SysfsPwmChannel', 'write_attr']

LED_ROOT = '/sys/class/leds'
PWM_ROOT = '/sys/class/pwm'
POLARITIES = ('normal', 'inversed')


def write_attr(path: str, text: str) -> None:
    """Write one sysfs attribute in one write() (the kernel parses each write whole)."""
    with open(path, 'w', encoding='ascii') as fh:
        fh.write(text)


class LedClassOutput:
    """``/sys/class/leds/<name>``: multicolor (multi_intensity + brightness) or mono."""

    def __init__(self, name: str, root: str = LED_ROOT) -> None:
        from periphery import LED
        self.path = os.path.join(root, name)
        if not os.path.isdir(self.path):
            raise DeviceNotFoundError(f'{self.path}: No such file or directory (errno 2)')
        self.multi = os.path.join(self.path, 'multi_intensity')
        self.is_multicolor = os.path.exists(self.multi)
        self.index: tuple[str, ...] = p.RGB_INDEX
        if self.is_multicolor:
            index_path = os.path.join(self.path, 'multi_index')
            try:
                with open(index_path, encoding='ascii') as fh:
                    self.index = p.parse_multi_index(fh.read())
            except OSError as exc:
                raise wrap_os_error(exc, index_path) from exc
            except ValueError as exc:
                raise DeviceIdentityError(f'{index_path}: {exc}') from exc
        try:
            self.led: Any = LED(name) if root == LED_ROOT else _SysfsLed(self.path)
        except (OSError, LookupError) as exc:
            if isinstance(exc, OSError):
                raise wrap_os_error(exc, self.path) from exc
            raise DeviceNotFoundError(f'{self.path}: {exc}') from exc

    def show(self, color: p.LedColor) -> None:
        """Show ``color``; a mono LED shows the brightest channel."""
        try:
            if self.is_multicolor:
                text, bri = p.multicolor_values(color, self.led.max_brightness, self.index)
                with open(self.multi, 'w', encoding='ascii') as fh:
                    fh.write(text + '\n')
                self.led.write(bri)
            else:
                level = max(p.channel_levels(color))
                self.led.write(round(level * self.led.max_brightness))
        except OSError as exc:
            raise wrap_os_error(exc, self.path, 'write') from exc

    def close(self) -> None:
        """Close the brightness file."""
        try:
            self.led.close()
        except OSError:
            pass


class LedClassRgbOutput:
    """An RGB strip wired as three single-colour LED class devices (red, green, blue)."""

    def __init__(self, names: Sequence[str], root: str = LED_ROOT) -> None:
        if len(names) != 3:
            raise ValueError(f'RGB LED needs 3 LED names (red, green, blue), got {list(names)!r}')
        self.leds: list[LedClassOutput] = []
        try:
            for name in names:
                led = LedClassOutput(name, root)
                if led.is_multicolor:
                    raise DeviceIdentityError(f'{led.path}: a multicolor LED, expected a '
                                              f'single-colour one (use backend led_class)')
                self.leds.append(led)
        except BaseException:
            self.close()
            raise

    def show(self, color: p.LedColor) -> None:
        """Set each LED's brightness to its channel level."""
        for led, level in zip(self.leds, p.channel_levels(color), strict=True):
            try:
                led.led.write(round(level * led.led.max_brightness))
            except OSError as exc:
                raise wrap_os_error(exc, led.path, 'write') from exc

    def close(self) -> None:
        """Close the three brightness files."""
        for led in self.leds:
            led.close()
        self.leds = []


class _SysfsLed:
    """Minimal LED-class file access for a non-standard root (tests, containers)."""

    def __init__(self, path: str) -> None:
        with open(os.path.join(path, 'max_brightness'), encoding='ascii') as fh:
            self.max_brightness = int(fh.read())
        self.brightness_path = os.path.join(path, 'brightness')

    def write(self, value: int) -> None:
        with open(self.brightness_path, 'w', encoding='ascii') as fh:
            fh.write(f'{value}\n')

    def close(self) -> None:
        pass


class SysfsPwmChannel:
    """One sysfs PWM channel under ``root`` (default /sys/class/pwm), exported on open."""

    def __init__(self, chip: int, channel: int, root: str = PWM_ROOT, *,
                 write: Callable[[str, str], None] = write_attr,
                 export_timeout_s: float = 1.0) -> None:
        self.chip_dir = os.path.join(root, f'pwmchip{chip}')
        self.dir = os.path.join(self.chip_dir, f'pwm{channel}')
        self._write = write
        if not os.path.isdir(self.chip_dir):
            raise DeviceNotFoundError(f'{self.chip_dir}: No such file or directory (errno 2)')
        if not os.path.isdir(self.dir):
            self._set(os.path.join(self.chip_dir, 'export'), channel)
            # udev applies the group/permissions of a new channel asynchronously.
            deadline = time.monotonic() + export_timeout_s
            while not os.access(os.path.join(self.dir, 'enable'), os.W_OK):
                if time.monotonic() > deadline:
                    raise DeviceIOError(f'{self.dir}: not writable {export_timeout_s} s after '
                                        f'export (udev rule for the pwm group?)')
                time.sleep(0.01)

    def _set(self, path: str, value: object) -> None:
        try:
            self._write(path, f'{value}\n')
        except OSError as exc:
            raise wrap_os_error(exc, path, f'write {value!r}') from exc

    def set(self, attr: str, value: object) -> None:
        """Write one attribute of the channel."""
        self._set(os.path.join(self.dir, attr), value)

    def configure(self, period_ns: int, polarity: str = 'normal') -> None:
        """Period, disable, duty 0, period, polarity, enable: valid whatever the previous state.

        Every write is applied by ``pwm_apply_state()``, which on strict kernels (Raspberry Pi
        5.10..6.6) refuses any state with period 0 with EINVAL -- even ``enable 0``.  A fresh
        export has period 0, so the period goes first when it reads 0 (duty is 0 then, so
        any period > 0 is valid); otherwise duty 0 first, because the present duty may be
        longer than the new period.
        """
        if polarity not in POLARITIES:
            raise ValueError(f'PWM polarity must be one of {POLARITIES}, got {polarity!r}')
        if self.read('period') == '0':
            self.set('period', period_ns)
        self.set('enable', 0)
        self.set('duty_cycle', 0)          # first: the kernel rejects duty > a shorter period
        self.set('period', period_ns)
        self.set('polarity', polarity)     # only while disabled on most controllers
        self.set('enable', 1)

    def read(self, attr: str) -> str:
        """Return one attribute of the channel, stripped ('' when unreadable)."""
        try:
            with open(os.path.join(self.dir, attr), encoding='ascii') as fh:
                return fh.read().strip()
        except (OSError, UnicodeDecodeError):
            return ''

    def off(self) -> None:
        """Duty 0, then disable (never raises: cleanup)."""
        for attr in ('duty_cycle', 'enable'):
            try:
                self.set(attr, 0)
            except DriverError:
                pass                       # a vanished tree must not break cleanup


class PwmOutput:
    """Three sysfs PWM channels (r, g, b) of ``<root>/pwmchipN``."""

    def __init__(self, chip: int, channels: Sequence[int], period_ns: int = 1_000_000,
                 polarity: str = 'normal', root: str = PWM_ROOT,
                 write: Callable[[str, str], None] = write_attr) -> None:
        if len(channels) != 3:
            raise ValueError(f'PWM LED needs 3 channels (r, g, b), got {list(channels)!r}')
        if not isinstance(period_ns, int) or isinstance(period_ns, bool) or period_ns <= 0:
            raise ValueError(f'PWM period_ns must be a positive int, got {period_ns!r}')
        self.where = os.path.join(root, f'pwmchip{chip}')
        self.period_ns = period_ns
        self._write = write
        self.pwms: list[SysfsPwmChannel] = []
        try:
            for ch in channels:
                pwm = SysfsPwmChannel(chip, ch, root, write=write)
                self.pwms.append(pwm)
                pwm.configure(period_ns, polarity)
        except BaseException:
            self.close()
            raise

    def show(self, color: p.LedColor) -> None:
        """Set the three duty cycles."""
        for pwm, level in zip(self.pwms, p.channel_levels(color), strict=True):
            pwm.set('duty_cycle', p.duty_ns(level, self.period_ns))

    def close(self) -> None:
        """Duty 0 and disable every channel (left exported: a re-export waits for udev)."""
        for pwm in self.pwms:
            pwm.off()
        self.pwms = []
        close = getattr(self._write, 'close', None)
        if close is not None:
            close()                        # a sim-bus writer's connection


class PixelSpiOutput:
    """A WS2811/WS2812 pixel strip (NS-LED-02) on spidev MOSI (:mod:`m4k_drivers.led.pixel`).

    Every pixel shows the one colour of the LED datagram.  The frame is planned for the clock
    the aux controller really runs (``core_clock_hz`` divided for ``spi_hz``) and sent whole
    in one SPI message; SPI mode 0, 8-bit words.  A colour equal to the one shown is not sent
    again: WS2812-family pixels latch what they got and hold it (the datasheet's data refresh
    cycle needs no repeat), and every frame is bus time the encoders on the same controller
    wait behind.
    """

    def __init__(self, path: str, pixels: int, *, spi_hz: int, core_clock_hz: int,
                 order: str = 'GRB', reset_us: float = 300.0) -> None:
        from m4k_drivers.led import pixel as px
        if not isinstance(pixels, int) or isinstance(pixels, bool) or pixels < 1:
            raise ValueError(f'pixel strip needs pixels >= 1, got {pixels!r}')
        self.sclk_hz = px.aux_clock_hz(core_clock_hz, spi_hz)
        self.plan = px.plan(1e9 / self.sclk_hz)
        size = px.frame_bytes(pixels, reset_us, self.plan)
        if size > px.SPIDEV_BUFSIZ:
            raise ValueError(f'{pixels} pixels need {size} SPI bytes per frame, more than '
                             f"spidev's bufsiz {px.SPIDEV_BUFSIZ} (spidev.bufsiz=N on the "
                             'kernel command line, or fewer pixels)')
        self.path, self.pixels = path, pixels
        self.order, self.reset_us = order, reset_us
        self.hz = spi_hz
        from periphery import SPI
        try:
            self.spi = SPI(path, 0, self.hz, bit_order='msb', bits_per_word=8)
        except OSError as exc:
            raise wrap_os_error(exc, path) from exc
        self.frames = 0
        self.shown: tuple[int, int, int] | None = None

    def _send(self, rgb: tuple[int, int, int]) -> None:
        from m4k_drivers.led import pixel as px
        frame = px.encode_frame([rgb] * self.pixels, self.plan, order=self.order,
                                reset_us=self.reset_us)
        self.shown = None                  # unknown until the transfer returned
        try:
            self.spi.transfer(frame)
        except OSError as exc:
            raise wrap_os_error(exc, self.path, 'transfer') from exc
        self.frames += 1
        self.shown = rgb

    def show(self, color: p.LedColor) -> None:
        """Show ``color`` (brightness applied) on every pixel."""
        r, g, b = (round(level * 255) for level in p.channel_levels(color))
        if (r, g, b) != self.shown:
            self._send((r, g, b))

    def close(self) -> None:
        """Switch every pixel off, then close the node (never raises: cleanup)."""
        try:
            self._send((0, 0, 0))
        except DriverError:
            pass
        try:
            self.spi.close()
        except OSError:
            pass
