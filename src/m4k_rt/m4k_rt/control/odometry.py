"""Wheel odometry from unwrapped encoder wheel angles (pure).

The pose is integrated with the exact arc of each step, not with Euler: between two encoder
samples the wheels are assumed to turn at constant speed, so the robot moves on a circular arc
(a straight line when both wheels moved the same). The chord of an arc of length ``ds`` that
turns by ``dth`` has length ``ds * sinc(dth/2)`` and points along ``yaw + dth/2`` -- written
that way the formula is exact and has no 0/0 for straight motion.

Wheel speeds are the angle differences over the difference of the encoder timestamps (the
driver's CLOCK_MONOTONIC stamps), so a late or early delivery does not distort them.
"""

from __future__ import annotations

import math

_NS = 1e-9


def _sinc(a: float) -> float:
    """Return sin(a)/a, stable near zero."""
    if abs(a) < 1e-4:
        return 1.0 - a * a / 6.0
    return math.sin(a) / a


def normalize_angle(a: float) -> float:
    """Return ``a`` wrapped into (-pi, pi]."""
    a = math.fmod(a, 2.0 * math.pi)
    if a > math.pi:
        a -= 2.0 * math.pi
    elif a <= -math.pi:
        a += 2.0 * math.pi
    return a


class Odometry:
    """Integrate the planar pose and estimate wheel and body speeds from wheel angles.

    ``max_wheel_speed`` (rad/s) bounds a plausible step: a step larger than it allows over the
    sample interval (plus a margin) is a jump -- a driver restart or a glitch -- and only
    re-baselines the angles; it is counted in ``jumps`` instead of being integrated.
    """

    __slots__ = ('wheel_radius', 'track_width', 'max_wheel_speed', 'x', 'y', 'yaw', 'v', 'w',
                 'left_speed', 'right_speed', 'samples', 'jumps', 'bad_intervals',
                 '_left', '_right', '_stamp_ns', '_have')

    def __init__(self, wheel_radius: float, track_width: float,
                 max_wheel_speed: float = math.inf) -> None:
        if not (wheel_radius > 0.0 and math.isfinite(wheel_radius)):
            raise ValueError(f'wheel_radius must be a finite number > 0, got {wheel_radius!r}')
        if not (track_width > 0.0 and math.isfinite(track_width)):
            raise ValueError(f'track_width must be a finite number > 0, got {track_width!r}')
        if not max_wheel_speed > 0.0:
            raise ValueError(f'max_wheel_speed must be > 0, got {max_wheel_speed!r}')
        self.wheel_radius = float(wheel_radius)
        self.track_width = float(track_width)
        self.max_wheel_speed = float(max_wheel_speed)
        self.samples = 0
        self.jumps = 0
        self.bad_intervals = 0
        self.reset()

    def reset(self, x: float = 0.0, y: float = 0.0, yaw: float = 0.0) -> None:
        """Set the pose, zero the speeds and wait for a first sample to baseline on."""
        self.x = float(x)
        self.y = float(y)
        self.yaw = normalize_angle(float(yaw))
        self.v = self.w = self.left_speed = self.right_speed = 0.0
        self._left = self._right = 0.0
        self._stamp_ns = 0
        self._have = False

    def rebase(self) -> None:
        """Take the next sample as a new baseline, keeping the pose (speeds go to zero)."""
        self._have = False
        self.v = self.w = self.left_speed = self.right_speed = 0.0

    def update(self, left_angle: float, right_angle: float, stamp_ns: int) -> bool:
        """Integrate one encoder sample; return True when the pose or speeds changed."""
        self.samples += 1
        if not self._have:
            self._left = left_angle
            self._right = right_angle
            self._stamp_ns = stamp_ns
            self._have = True
            return False
        dt = (stamp_ns - self._stamp_ns) * _NS
        dl = left_angle - self._left
        dr = right_angle - self._right
        if dt <= 0.0:
            # Same or older stamp: a duplicate or reordered sample; it carries no interval.
            self.bad_intervals += 1
            return False
        bound = self.max_wheel_speed * dt * 1.5 + 0.05
        if abs(dl) > bound or abs(dr) > bound:
            self.jumps += 1
            self._left = left_angle
            self._right = right_angle
            self._stamp_ns = stamp_ns
            return False
        self._left = left_angle
        self._right = right_angle
        self._stamp_ns = stamp_ns
        r = self.wheel_radius
        ds = 0.5 * r * (dl + dr)
        dth = r * (dr - dl) / self.track_width
        half = 0.5 * dth
        chord = ds * _sinc(half)
        heading = self.yaw + half
        self.x += chord * math.cos(heading)
        self.y += chord * math.sin(heading)
        self.yaw = normalize_angle(self.yaw + dth)
        inv = 1.0 / dt
        self.left_speed = dl * inv
        self.right_speed = dr * inv
        self.v = ds * inv
        self.w = dth * inv
        return True
