"""Collision guard: cap the forward velocity from sonar and laser ranges (pure).

Evaluated every actuator cycle from the latest readings the sonar and lrf tasks left in the
shared state, so a reading closer than ``stop_distance`` stops forward motion within one
actuator cycle of its arrival. The guard only ever caps *forward* (positive) linear velocity:
rotation and reversing stay allowed so the robot can turn or back away from the obstacle.

* Stop zone: distance < ``stop_distance`` -> cap 0. The caller applies a zero cap after its
  speed limiter, bypassing the deceleration ramp (a safety stop, not a comfort ramp).
* Hysteresis: once stopped, the guard releases only when the distance exceeds
  ``stop_distance + release_margin``, so a reading jittering around the threshold does not
  make the robot lurch.
* Slow-down zone (optional, ``slow_distance`` > ``stop_distance``): the cap falls linearly from
  ``max_velocity`` at ``slow_distance`` to 0 at ``stop_distance``; the caller applies it to the
  target before the limiter, so slowing respects the deceleration limit.
* Staleness: a sensor in use whose last valid reading is older than its timeout (or that never
  reported) is *stale*. With ``stale_policy='stop'`` (default, fail-safe) a stale sensor counts
  as an obstacle at distance 0: forward motion stops until it reports again -- the guard cannot
  vouch for free space it cannot see. With ``'ignore'`` a stale sensor is left out (if every
  sensor is stale the guard does not limit at all); ``stale`` still reports it.

Distances are ahead of the robot's front face: each sensor's range is reduced by how far the
front face is ahead of the sensor (:func:`front_offset`; 0 for the US-100 on the front, 0.225 m
for the URG on top of the body's centre), so ``stop_distance`` means the same gap in front of
the body whichever sensor sees the obstacle.
"""

from __future__ import annotations

import math
from typing import Any

STALE_POLICIES = ('stop', 'ignore')


class GuardError(ValueError):
    """Raised for invalid guard parameters."""


class CollisionGuard:
    """Compute the forward velocity cap from the latest range readings."""

    __slots__ = ('enabled', 'stop_distance', 'release_distance', 'slow_distance', 'use_sonar',
                 'use_laser', 'sonar_timeout_ns', 'laser_timeout_ns', 'stale_policy', 'active',
                 'slowing', 'sonar_stale', 'laser_stale', 'distance', 'activations')

    def __init__(self, *, enabled: bool = True, stop_distance: float = 0.35,
                 release_margin: float = 0.05, slow_distance: float = 0.0,
                 use_sonar: bool = True, use_laser: bool = True, sonar_timeout: float = 0.2,
                 laser_timeout: float = 0.5, stale_policy: str = 'stop') -> None:
        if not (isinstance(stop_distance, (int, float)) and math.isfinite(stop_distance)
                and stop_distance >= 0.0):
            raise GuardError(f'stop_distance must be a finite number >= 0, got {stop_distance!r}')
        if not (isinstance(release_margin, (int, float)) and math.isfinite(release_margin)
                and release_margin >= 0.0):
            raise GuardError(f'release_margin must be a finite number >= 0, got '
                             f'{release_margin!r}')
        if not (isinstance(slow_distance, (int, float)) and math.isfinite(slow_distance)
                and (slow_distance == 0.0 or slow_distance > stop_distance)):
            raise GuardError(f'slow_distance must be 0 (off) or > stop_distance '
                             f'({stop_distance!r}), got {slow_distance!r}')
        for name, value in (('sonar_timeout', sonar_timeout), ('laser_timeout', laser_timeout)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
                raise GuardError(f'{name} must be a finite number > 0, got {value!r}')
        if stale_policy not in STALE_POLICIES:
            raise GuardError(f'stale_policy must be one of {STALE_POLICIES}, got '
                             f'{stale_policy!r}')
        self.enabled = bool(enabled)
        self.stop_distance = float(stop_distance)
        self.release_distance = float(stop_distance + release_margin)
        self.slow_distance = float(slow_distance)
        self.use_sonar = bool(use_sonar)
        self.use_laser = bool(use_laser)
        self.sonar_timeout_ns = int(sonar_timeout * 1e9)
        self.laser_timeout_ns = int(laser_timeout * 1e9)
        self.stale_policy = stale_policy
        self.activations = 0
        self.reset()

    def reset(self) -> None:
        """Forget the stop state (the next evaluation starts released)."""
        self.active = False
        self.slowing = False
        self.sonar_stale = False
        self.laser_stale = False
        self.distance = math.inf

    def evaluate(self, now_ns: int, max_velocity: float, sonar_range: float, sonar_rx_ns: int,
                 laser_min: float, laser_rx_ns: int) -> float:
        """Return the forward velocity cap (``math.inf`` = no cap, 0.0 = stop).

        ``*_rx_ns`` is when the last valid reading arrived (0 = never); a reading with nothing
        in range is ``math.inf``.
        """
        if not self.enabled:
            self.active = self.slowing = False
            return math.inf
        fail_safe = self.stale_policy == 'stop'
        d = math.inf
        self.sonar_stale = False
        self.laser_stale = False
        if self.use_sonar:
            if sonar_rx_ns <= 0 or now_ns - sonar_rx_ns > self.sonar_timeout_ns:
                self.sonar_stale = True
                if fail_safe:
                    d = 0.0
            elif sonar_range < d:
                d = sonar_range
        if self.use_laser:
            if laser_rx_ns <= 0 or now_ns - laser_rx_ns > self.laser_timeout_ns:
                self.laser_stale = True
                if fail_safe:
                    d = 0.0
            elif laser_min < d:
                d = laser_min
        self.distance = d
        if self.active:
            if d > self.release_distance:
                self.active = False
        elif d < self.stop_distance:
            self.active = True
            self.activations += 1
        if self.active:
            self.slowing = False
            return 0.0
        if self.slow_distance > 0.0 and d < self.slow_distance:
            self.slowing = True
            span = self.slow_distance - self.stop_distance
            frac = (d - self.stop_distance) / span
            return max_velocity * (frac if frac > 0.0 else 0.0)
        self.slowing = False
        return math.inf


def front_offset(robot: Any, sensor: str) -> float:
    """Return how far the body's front face is ahead of ``sensor`` (the robot: section), m.

    ``robot.body.length / 2 - robot.sensors.<sensor>.pose[0]``, never below 0 (a sensor ahead of
    the body sees from its own position); 0 when the section does not say (a bare test config).
    """
    try:
        front = float(robot['body']['length']) / 2.0
        x = float(robot['sensors'][sensor]['pose'][0])
    except (KeyError, TypeError, IndexError, ValueError):
        return 0.0
    off = front - x
    return off if math.isfinite(off) and off > 0.0 else 0.0


class FrontSector:
    """Minimum range of a laser scan inside a sector centred straight ahead (angle 0).

    Ranges are the LASER_SCAN's millimetres; values below 20 are URG error codes and values
    outside [range_min, range_max] are not measurements -- both are skipped. A sector without a
    single valid point reports ``math.inf`` (nothing seen): code 0 is "nothing within 5.6 m",
    and the other codes (a black or shiny surface) measured nothing -- the laser's counterpart
    of the sonar's no echo, which is also inf and fresh. The scan itself answered, so the laser
    stays fresh; only no scan at all (unplugged, no answer) makes it stale. A surface one sensor
    cannot measure is the other's to see (docs/sensor-outcomes.md). The index window is computed
    once per scan geometry and cached, so a scan costs one short loop over the sector only.
    """

    __slots__ = ('half_width', 'offset_mm', '_key', '_i0', '_i1', '_cos')

    def __init__(self, width_deg: float, offset: float = 0.0) -> None:
        if not (isinstance(width_deg, (int, float)) and 0.0 < width_deg <= 360.0):
            raise GuardError(f'front_sector_deg must be in (0, 360], got {width_deg!r}')
        if not (isinstance(offset, (int, float)) and math.isfinite(offset) and offset >= 0.0):
            raise GuardError(f'laser front offset must be a finite number >= 0, got {offset!r}')
        self.half_width = math.radians(width_deg) / 2.0
        self.offset_mm = float(offset) * 1000.0   # the front face is this far ahead of the laser
        self._key: tuple[float, float, int] | None = None
        self._i0 = 0
        self._i1 = -1
        self._cos: list[float] = []

    def window(self, angle_min: float, angle_increment: float, count: int) -> tuple[int, int]:
        """Return the inclusive index range (i0, i1) of the sector (i1 < i0 when empty)."""
        key = (angle_min, angle_increment, count)
        if key != self._key:
            self._key = key
            if angle_increment <= 0.0 or count <= 0:
                self._i0, self._i1 = 0, -1
            else:
                i0 = math.ceil((-self.half_width - angle_min) / angle_increment - 1e-9)
                i1 = math.floor((self.half_width - angle_min) / angle_increment + 1e-9)
                self._i0 = max(0, i0)
                self._i1 = min(count - 1, i1)
            self._cos = [math.cos(angle_min + i * angle_increment)
                         for i in range(self._i0, self._i1 + 1)]
        return self._i0, self._i1

    def minimum(self, angle_min: float, angle_increment: float, range_min: float,
                range_max: float, ranges_mm: tuple[int, ...] | list[int]) -> float:
        """Return the smallest distance (m) ahead of the front face in the sector, inf if none.

        Each valid range is projected on the heading (r cos a) less the front offset: the gap
        between the body's front face and the point, 0 at the least.
        """
        i0, i1 = self.window(angle_min, angle_increment, len(ranges_mm))
        lo = range_min * 1000.0
        if lo < 20.0:
            lo = 20.0
        hi = range_max * 1000.0
        best = math.inf
        cos = self._cos
        off = self.offset_mm
        for i in range(i0, i1 + 1):
            r = ranges_mm[i]
            if lo <= r <= hi:
                d = r * cos[i - i0] - off
                if d < best:
                    best = d
        if best == math.inf:
            return math.inf
        return best * 0.001 if best > 0.0 else 0.0
