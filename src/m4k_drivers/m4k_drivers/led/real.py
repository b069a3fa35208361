"""LED outputs on Linux: the LED class (python-periphery LED, multicolor aware) or sysfs PWM."""

from __future__ import annotations

import os
from typing import Any, Sequence

from m4k_drivers.handler import DeviceIOError, DeviceNotFoundError, wrap_os_error
from m4k_drivers.led import protocol as p

__all__ = ['LedClassOutput', 'PwmOutput']

LED_ROOT = '/sys/class/leds'


class LedClassOutput:
    """``/sys/class/leds/<name>``: multicolor (multi_intensity + brightness) or mono."""

    def __init__(self, name: str, root: str = LED_ROOT) -> None:
        from periphery import LED
        self.path = os.path.join(root, name)
        if not os.path.isdir(self.path):
            raise DeviceNotFoundError(f'{self.path}: No such file or directory (errno 2)')
        self.multi = os.path.join(self.path, 'multi_intensity')
        self.is_multicolor = os.path.exists(self.multi)
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
                text, bri = p.multicolor_values(color, self.led.max_brightness)
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


PWM_ROOT = '/sys/class/pwm'


class PwmOutput:
    """Three sysfs PWM channels (r, g, b) of ``<root>/pwmchipN`` (root: /sys/class/pwm)."""

    def __init__(self, chip: int, channels: Sequence[int], period_ns: int = 1_000_000,
                 root: str = PWM_ROOT) -> None:
        from periphery import PWM
        if len(channels) != 3:
            raise ValueError(f'PWM LED needs 3 channels (r, g, b), got {list(channels)!r}')
        self.where = os.path.join(root, f'pwmchip{chip}')
        self.period_ns = period_ns
        self.pwms: list[Any] = []
        try:
            for ch in channels:
                pwm = PWM(chip, ch) if root == PWM_ROOT else _SysfsPwm(self.where, ch)
                self.pwms.append(pwm)
                pwm.period_ns = period_ns
                pwm.duty_cycle_ns = 0
                pwm.enable()
        except OSError as exc:
            self.close()
            raise wrap_os_error(exc, self.where) from exc
        except LookupError as exc:
            self.close()
            raise DeviceNotFoundError(f'{self.where}: {exc}') from exc
        except TimeoutError as exc:
            self.close()
            raise DeviceIOError(f'{self.where}: {exc}') from exc

    def show(self, color: p.LedColor) -> None:
        """Set the three duty cycles."""
        try:
            for pwm, level in zip(self.pwms, p.channel_levels(color), strict=True):
                pwm.duty_cycle_ns = p.duty_ns(level, self.period_ns)
        except OSError as exc:
            raise wrap_os_error(exc, self.where, 'duty_cycle') from exc

    def close(self) -> None:
        """Disable and unexport the channels."""
        for pwm in self.pwms:
            try:
                pwm.duty_cycle_ns = 0
                pwm.disable()
                pwm.close()
            except OSError:
                pass
        self.pwms = []


class _SysfsPwm:
    """periphery.PWM's subset on a PWM chip under a non-standard root (tests, sim_robot)."""

    def __init__(self, chip_dir: str, channel: int, tries: int = 50, delay_s: float = 0.02
                 ) -> None:
        import time
        self.chip_dir = chip_dir
        self.channel = channel
        self.path = os.path.join(chip_dir, f'pwm{channel}')
        if not os.path.isdir(chip_dir):
            raise LookupError(f'{chip_dir}: no such PWM chip')
        if not os.path.isdir(self.path):
            with open(os.path.join(chip_dir, 'export'), 'w', encoding='ascii') as fh:
                fh.write(f'{channel}\n')
            for _ in range(tries):          # export is asynchronous, as with the kernel + udev
                if os.path.isdir(self.path):
                    break
                time.sleep(delay_s)
            else:
                raise TimeoutError(f'{self.path}: not exported after {tries * delay_s:.1f} s')

    def _write(self, attr: str, value: Any) -> None:
        with open(os.path.join(self.path, attr), 'w', encoding='ascii') as fh:
            fh.write(f'{value}\n')

    @property
    def period_ns(self) -> int:
        with open(os.path.join(self.path, 'period'), encoding='ascii') as fh:
            return int(fh.read())

    @period_ns.setter
    def period_ns(self, value: int) -> None:
        self._write('period', value)

    @property
    def duty_cycle_ns(self) -> int:
        with open(os.path.join(self.path, 'duty_cycle'), encoding='ascii') as fh:
            return int(fh.read())

    @duty_cycle_ns.setter
    def duty_cycle_ns(self, value: int) -> None:
        self._write('duty_cycle', value)

    @property
    def polarity(self) -> str:
        with open(os.path.join(self.path, 'polarity'), encoding='ascii') as fh:
            return fh.read().strip()

    @polarity.setter
    def polarity(self, value: str) -> None:
        self._write('polarity', value)

    def enable(self) -> None:
        self._write('enable', 1)

    def disable(self) -> None:
        self._write('enable', 0)

    def close(self) -> None:
        with open(os.path.join(self.chip_dir, 'unexport'), 'w', encoding='ascii') as fh:
            fh.write(f'{self.channel}\n')
