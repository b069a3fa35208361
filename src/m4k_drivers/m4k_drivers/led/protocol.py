"""NS-LED-02 colour handling (pure): 24-bit RGB plus an 8-bit brightness.

The strip takes a 24-bit colour and a brightness; on Linux we drive it through the LED class
(multicolor: ``multi_intensity`` = "r g b", ``brightness`` scales all three) or through three
sysfs PWM channels (duty = colour / 255 * brightness / 255 of the period).
"""

from __future__ import annotations

from typing import NamedTuple

__all__ = ['OFF', 'LedColor', 'channel_levels', 'duty_ns', 'multicolor_values', 'to_hex']


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


def multicolor_values(color: LedColor, max_brightness: int) -> tuple[str, int]:
    """Return (multi_intensity text, brightness) for an LED class multicolor device."""
    scale = max_brightness / 255.0
    text = f'{round(color.r * scale)} {round(color.g * scale)} {round(color.b * scale)}'
    return text, round(color.brightness * scale)


def to_hex(color: LedColor) -> str:
    """Return '#rrggbb@bri' for logs and the console."""
    return f'#{color.r:02x}{color.g:02x}{color.b:02x}@{color.brightness}'
