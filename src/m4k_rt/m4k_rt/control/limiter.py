"""Speed limiter: velocity, acceleration/deceleration and optional jerk limits (pure).

Same idea as ros2_controllers' ``SpeedLimiter``, written as a small stateful object so the
caller does not have to carry the last two outputs around: ``step(target, dt)`` returns the
limited value and remembers it. A limit of ``math.inf`` disables that stage.
"""

from __future__ import annotations

import math

INF = math.inf


class LimiterError(ValueError):
    """Raised for invalid limiter parameters."""


def _check_positive(name: str, value: float) -> float:
    if not isinstance(value, (int, float)) or math.isnan(value) or value <= 0.0:
        raise LimiterError(f'{name} must be > 0 (inf disables it), got {value!r}')
    return float(value)


class SpeedLimiter:
    """Limit a velocity command in value, rate of change and (optionally) jerk.

    Acceleration applies when the magnitude of the output grows, deceleration when it shrinks
    toward zero, so braking can be given its own (usually harder) limit.
    """

    __slots__ = ('min_velocity', 'max_velocity', 'max_acceleration', 'max_deceleration',
                 'max_jerk', 'clamped', '_v1', '_v0')

    def __init__(self, max_velocity: float = INF, max_acceleration: float = INF,
                 max_deceleration: float | None = None, max_jerk: float = INF,
                 min_velocity: float | None = None) -> None:
        self.max_velocity = _check_positive('max_velocity', max_velocity)
        if min_velocity is None:
            self.min_velocity = -self.max_velocity
        else:
            if (not isinstance(min_velocity, (int, float)) or math.isnan(min_velocity)
                    or min_velocity > 0.0):
                raise LimiterError(f'min_velocity must be <= 0, got {min_velocity!r}')
            self.min_velocity = float(min_velocity)
        self.max_acceleration = _check_positive('max_acceleration', max_acceleration)
        self.max_deceleration = (self.max_acceleration if max_deceleration is None else
                                 _check_positive('max_deceleration', max_deceleration))
        self.max_jerk = _check_positive('max_jerk', max_jerk)
        self.clamped = False
        self._v1 = 0.0  # last output
        self._v0 = 0.0  # output before the last one (for the jerk stage)

    @property
    def value(self) -> float:
        """Return the last output."""
        return self._v1

    def reset(self, value: float = 0.0) -> None:
        """Forget the history and continue from ``value`` at rest (zero acceleration)."""
        self._v1 = self._v0 = float(value)
        self.clamped = False

    def step(self, target: float, dt: float) -> float:
        """Return ``target`` limited against the previous outputs, ``dt`` seconds later."""
        v1 = self._v1
        v = target
        if v > self.max_velocity:
            v = self.max_velocity
        elif v < self.min_velocity:
            v = self.min_velocity
        if dt > 0.0:
            if self.max_jerk != INF:
                a0 = (v1 - self._v0) / dt
                da = (v - v1) / dt - a0
                dmax = self.max_jerk * dt
                if da > dmax:
                    v = v1 + (a0 + dmax) * dt
                elif da < -dmax:
                    v = v1 + (a0 - dmax) * dt
            dv = v - v1
            # Shrinking magnitude (toward zero) is deceleration.
            limit = self.max_deceleration if v1 * dv < 0.0 else self.max_acceleration
            if limit != INF:
                dv_max = limit * dt
                if dv > dv_max:
                    v = v1 + dv_max
                elif dv < -dv_max:
                    v = v1 - dv_max
        if v > self.max_velocity:
            v = self.max_velocity
        elif v < self.min_velocity:
            v = self.min_velocity
        self.clamped = abs(v - target) > 1e-12
        self._v0 = v1
        self._v1 = v
        return v

    def override(self, value: float) -> None:
        """Replace the last output by ``value`` (e.g. a safety stop that bypasses the ramps)."""
        self._v1 = self._v0 = float(value)
