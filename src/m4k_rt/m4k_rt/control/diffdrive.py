"""Differential-drive kinematics (pure).

Conventions (REP-103): x forward, z up, positive yaw counter-clockwise. Wheel speeds are in
rad/s at the wheel (after the gearbox); a positive wheel speed drives the robot forward.
"""

from __future__ import annotations

import math


class KinematicsError(ValueError):
    """Raised for invalid kinematic parameters."""


class DiffDrive:
    """Inverse and forward kinematics of a differential-drive base.

    ``inverse`` maps a body twist (v, w) to wheel speeds; ``forward`` maps wheel speeds back to
    the body twist. ``saturate`` scales a wheel-speed pair down so that neither wheel exceeds a
    bound while the ratio between them -- and so the path curvature -- is kept.
    """

    __slots__ = ('wheel_radius', 'track_width', 'gear_ratio', '_half_track')

    def __init__(self, wheel_radius: float, track_width: float, gear_ratio: float = 1.0) -> None:
        for name, value in (('wheel_radius', wheel_radius), ('track_width', track_width),
                            ('gear_ratio', gear_ratio)):
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0.0:
                raise KinematicsError(f'{name} must be a finite number > 0, got {value!r}')
        self.wheel_radius = float(wheel_radius)
        self.track_width = float(track_width)
        self.gear_ratio = float(gear_ratio)
        self._half_track = 0.5 * self.track_width

    def inverse(self, linear: float, angular: float) -> tuple[float, float]:
        """Return (left, right) wheel speeds in rad/s for a body twist (m/s, rad/s)."""
        r = self.wheel_radius
        return ((linear - angular * self._half_track) / r,
                (linear + angular * self._half_track) / r)

    def forward(self, left: float, right: float) -> tuple[float, float]:
        """Return the body twist (m/s, rad/s) for (left, right) wheel speeds in rad/s."""
        r = self.wheel_radius
        return (0.5 * r * (left + right), r * (right - left) / self.track_width)

    def wheel_to_motor(self, wheel: float) -> float:
        """Return the motor-shaft speed for a wheel speed (the gearbox multiplies it)."""
        return wheel * self.gear_ratio

    def motor_to_wheel(self, motor: float) -> float:
        """Return the wheel speed for a motor-shaft speed."""
        return motor / self.gear_ratio

    @staticmethod
    def saturate(left: float, right: float, limit: float) -> tuple[float, float, bool]:
        """Scale (left, right) so that max(|left|, |right|) <= limit, keeping their ratio.

        Returns the scaled pair and whether scaling happened. Scaling both wheels by one factor
        keeps the commanded curvature: the robot follows the same arc, only slower.
        """
        peak = abs(left) if abs(left) > abs(right) else abs(right)
        if peak <= limit:
            return left, right, False
        k = limit / peak
        return left * k, right * k, True
