"""Wheel odometry from unwrapped encoder wheel angles (pure).

The pose is integrated with the exact arc of each step, not with Euler: between two encoder
samples the wheels are assumed to turn at constant speed, so the robot moves on a circular arc
(a straight line when both wheels moved the same). The chord of an arc of length ``ds`` that
turns by ``dth`` has length ``ds * sinc(dth/2)`` and points along ``yaw + dth/2`` -- written
that way the formula is exact and has no 0/0 for straight motion.

Speeds are angle differences over stamp differences (the driver's CLOCK_MONOTONIC stamps, so a
late or early delivery does not distort them), taken over a *baseline* of several samples from a
small preallocated ring (:class:`AngleHistory`), not as a mean of one-sample derivatives: one
count of a 12-bit wheel encoder is 1.53 mrad, i.e. 0.15 rad/s (0.016 m/s of wheel rim) over a
10 ms difference but only 0.03 rad/s over 50 ms. The same difference over a longer baseline is
exactly the mean speed over that span, so nothing is lost but the high-frequency noise (and
half the window in delay). A baseline is also never shorter than ``min_baseline`` unless the
ring holds nothing older: after a driver stall its queued replies come back to back, stamped
microseconds apart, and one count over 60 us would read as 25 rad/s.
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


class AngleHistory:
    """Fixed-capacity ring of the latest (stamp, left angle, right angle) samples (no allocation).

    :meth:`rates` leaves its result in ``left_rate``, ``right_rate`` (rad/s) and
    ``baseline_ns``, so an RT loop reads floats instead of receiving a new tuple.
    """

    __slots__ = ('capacity', 'count', 'left_rate', 'right_rate', 'baseline_ns', '_head', '_t',
                 '_l', '_r')

    def __init__(self, capacity: int) -> None:
        if isinstance(capacity, bool) or not isinstance(capacity, int) or capacity < 2:
            raise ValueError(f'capacity must be an integer >= 2, got {capacity!r}')
        self.capacity = capacity
        self._t = [0] * capacity
        self._l = [0.0] * capacity
        self._r = [0.0] * capacity
        self.clear()

    def clear(self) -> None:
        """Forget every sample (the next one is a new start; rates go to zero)."""
        self.count = 0
        self._head = -1
        self.left_rate = self.right_rate = 0.0
        self.baseline_ns = 0

    def push(self, stamp_ns: int, left: float, right: float) -> None:
        """Append one sample, overwriting the oldest when full."""
        h = self._head + 1
        if h == self.capacity:
            h = 0
        self._head = h
        self._t[h] = stamp_ns
        self._l[h] = left
        self._r[h] = right
        if self.count < self.capacity:
            self.count += 1

    def rates(self, window: int, min_baseline_ns: int = 1) -> bool:
        """Set the wheel rates over the last ``window`` intervals; False if there is no interval.

        The older end is the sample ``window`` samples back (or the oldest held), moved further
        back while the baseline is shorter than ``min_baseline_ns`` and older samples exist.
        """
        n = self.count
        if n < 2:
            return False
        cap = self.capacity
        h = self._head
        t_new = self._t[h]
        back = window if window < n else n - 1
        j = h - back
        if j < 0:
            j += cap
        while t_new - self._t[j] < min_baseline_ns and back < n - 1:
            back += 1
            j = j - 1 if j else cap - 1
        dt_ns = t_new - self._t[j]
        if dt_ns <= 0:
            return False
        inv = 1e9 / dt_ns
        self.left_rate = (self._l[h] - self._l[j]) * inv
        self.right_rate = (self._r[h] - self._r[j]) * inv
        self.baseline_ns = dt_ns
        return True


class Odometry:
    """Integrate the planar pose and estimate wheel and body speeds from wheel angles.

    ``max_wheel_speed`` (rad/s) bounds a plausible step: a step larger than it allows over the
    sample interval (plus a margin) is a jump -- a driver restart or a glitch -- and only
    re-baselines the angles; it is counted in ``jumps`` instead of being integrated.

    ``left_position``/``right_position`` (rad) accumulate the integrated angle steps: the
    wheels' joint positions, continuous across jumps and re-baselines and kept by
    :meth:`reset` (which moves the pose, not the wheels).

    ``left_speed``, ``right_speed`` (rad/s) and the body twist ``v`` (m/s), ``w`` (rad/s) are
    taken over ``velocity_window`` sample intervals (1 = the single latest difference, the old
    behaviour), with a baseline of at least half the window's nominal span when
    ``sample_period`` (s) is given. The pose is integrated from every sample regardless.
    ``history`` (default ``velocity_window + 16``) is the ring's capacity: other users (the
    wheel-speed feedback) may ask it for their own window, and the 16 spare samples let the
    minimum baseline reach past a burst of back-to-back replies.
    """

    __slots__ = ('wheel_radius', 'track_width', 'max_wheel_speed', 'velocity_window',
                 'min_baseline_ns', 'history', 'x', 'y', 'yaw', 'v', 'w', 'left_speed',
                 'right_speed', 'left_position', 'right_position', 'samples', 'jumps',
                 'bad_intervals', '_left', '_right',
                 '_stamp_ns', '_have')

    def __init__(self, wheel_radius: float, track_width: float,
                 max_wheel_speed: float = math.inf, *, velocity_window: int = 1,
                 sample_period: float | None = None, history: int | None = None) -> None:
        if not (wheel_radius > 0.0 and math.isfinite(wheel_radius)):
            raise ValueError(f'wheel_radius must be a finite number > 0, got {wheel_radius!r}')
        if not (track_width > 0.0 and math.isfinite(track_width)):
            raise ValueError(f'track_width must be a finite number > 0, got {track_width!r}')
        if not max_wheel_speed > 0.0:
            raise ValueError(f'max_wheel_speed must be > 0, got {max_wheel_speed!r}')
        if (isinstance(velocity_window, bool) or not isinstance(velocity_window, int)
                or velocity_window < 1):
            raise ValueError(f'velocity_window must be an integer >= 1 sample, '
                             f'got {velocity_window!r}')
        if sample_period is not None and not (sample_period > 0.0
                                              and math.isfinite(sample_period)):
            raise ValueError(f'sample_period must be a finite number > 0 s or None, '
                             f'got {sample_period!r}')
        if history is None:
            history = velocity_window + 16
        if isinstance(history, bool) or not isinstance(history, int) or history <= velocity_window:
            raise ValueError(f'history must be an integer > velocity_window '
                             f'({velocity_window}), got {history!r}')
        self.velocity_window = velocity_window
        self.min_baseline_ns = (max(1, int(0.5 * velocity_window * sample_period * 1e9))
                                if sample_period is not None else 1)
        self.history = AngleHistory(history)
        self.wheel_radius = float(wheel_radius)
        self.track_width = float(track_width)
        self.max_wheel_speed = float(max_wheel_speed)
        self.samples = 0
        self.jumps = 0
        self.bad_intervals = 0
        self.left_position = self.right_position = 0.0
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
        self.history.clear()

    def set_pose(self, x: float = 0.0, y: float = 0.0, yaw: float = 0.0) -> None:
        """Move the integrated pose to (x, y, yaw), keeping the baseline and the speeds.

        Unlike :meth:`reset` the next sample is still differenced against the last one, so
        a pose reset while driving loses no motion and leaves the twist continuous.
        """
        self.x = float(x)
        self.y = float(y)
        self.yaw = normalize_angle(float(yaw))

    def zero_speeds(self) -> None:
        """Report zero speeds (no fresh samples: the speed is unknown) but keep the baseline.

        The next sample is still differenced against the last one, so the motion made while
        no samples came is integrated, not lost.
        """
        self.v = self.w = self.left_speed = self.right_speed = 0.0

    def rebase(self) -> None:
        """Take the next sample as a new baseline, keeping the pose (speeds go to zero)."""
        self._have = False
        self.v = self.w = self.left_speed = self.right_speed = 0.0
        self.history.clear()

    def update(self, left_angle: float, right_angle: float, stamp_ns: int) -> bool:
        """Integrate one encoder sample; return True when the pose or speeds changed."""
        self.samples += 1
        if not self._have:
            self._left = left_angle
            self._right = right_angle
            self._stamp_ns = stamp_ns
            self._have = True
            self.history.push(stamp_ns, left_angle, right_angle)
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
            # The angles' origin moved: speeds across the jump would be meaningless too.
            self.jumps += 1
            self._left = left_angle
            self._right = right_angle
            self._stamp_ns = stamp_ns
            self.history.clear()
            self.history.push(stamp_ns, left_angle, right_angle)
            return False
        self._left = left_angle
        self._right = right_angle
        self._stamp_ns = stamp_ns
        self.left_position += dl
        self.right_position += dr
        r = self.wheel_radius
        ds = 0.5 * r * (dl + dr)
        dth = r * (dr - dl) / self.track_width
        half = 0.5 * dth
        chord = ds * _sinc(half)
        heading = self.yaw + half
        self.x += chord * math.cos(heading)
        self.y += chord * math.sin(heading)
        self.yaw = normalize_angle(self.yaw + dth)
        hist = self.history
        hist.push(stamp_ns, left_angle, right_angle)
        if hist.rates(self.velocity_window, self.min_baseline_ns):
            wl = hist.left_rate
            wr = hist.right_rate
            self.left_speed = wl
            self.right_speed = wr
            self.v = 0.5 * r * (wl + wr)
            self.w = r * (wr - wl) / self.track_width
        return True
