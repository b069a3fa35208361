"""NS-LED-02 colour handling (pure): 24-bit RGB plus an 8-bit brightness.

The strip takes a 24-bit colour and a brightness; on Linux we drive it through the LED class
(multicolor: ``multi_intensity`` holds one intensity per colour in the order the kernel lists
in ``multi_index`` -- e.g. "green red blue" -- and ``brightness`` scales all of them; see
Documentation/ABI/testing/sysfs-class-led-multicolor), through three single-colour LED class
devices, or through three sysfs PWM channels (duty = colour / 255 * brightness / 255 of the
period).
"""

from __future__ import annotations

from typing import NamedTuple

__all__ = ['OFF', 'RGB_INDEX', 'LedColor', 'channel_levels', 'duty_ns', 'multicolor_values',
           'parse_multi_index', 'to_hex']

RGB_INDEX = ('red', 'green', 'blue')


class LedColor(NamedTuple):
    """The LED datagram payload: r, g, b, brightness, each 0..255."""

    r: int
    g: int
    b: int
    brightness: int = 255

    def validated(self) -> LedColor:
        """Return self, or raise ValueError naming the bad component."""
        for name, value in zip(self._fields, self, strict=True):
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 255:
                raise ValueError(f'LED {name} must be an int 0..255, got {value!r}')
        return self


OFF = LedColor(0, 0, 0, 0)


def channel_levels(color: LedColor) -> tuple[float, float, float]:
    """Return the r, g, b output levels in [0, 1] after brightness scaling."""
    k = color.brightness / 255.0
    return (color.r / 255.0 * k, color.g / 255.0 * k, color.b / 255.0 * k)


def duty_ns(level: float, period_ns: int) -> int:
    """Return the PWM duty cycle for a level in [0, 1] (clamped)."""
    return round(max(0.0, min(1.0, level)) * period_ns)


def parse_multi_index(text: str) -> tuple[str, ...]:
    """Return the colour names of a ``multi_index`` file; ValueError without red/green/blue.

    The kernel lists one LED_COLOR_ID name per channel (``red``, ``green``, ``blue``,
    ``white``, ``amber``, ...); channels other than red, green and blue are written 0.
    """
    names = tuple(text.split())
    if not names or not set(RGB_INDEX) & set(names):
        raise ValueError(f'multi_index {text.strip()!r} has no red, green or blue channel')
    return names


def multicolor_values(color: LedColor, max_brightness: int,
                      index: tuple[str, ...] = RGB_INDEX) -> tuple[str, int]:
    """Return (multi_intensity text in ``index`` order, brightness) for a multicolor LED."""
    scale = max_brightness / 255.0
    level = {'red': color.r, 'green': color.g, 'blue': color.b}
    text = ' '.join(str(round(level.get(name, 0) * scale)) for name in index)
    return text, round(color.brightness * scale)


def to_hex(color: LedColor) -> str:
    """Return '#rrggbb@bri' for logs and the console."""
    return f'#{color.r:02x}{color.g:02x}{color.b:02x}@{color.brightness}'
