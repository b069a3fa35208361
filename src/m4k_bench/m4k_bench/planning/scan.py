"""Laser scan to obstacle points in the odom frame, and a short point memory (pure, numpy).

The local planner has no costmap: it scores arcs against the obstacle points of the last few
scans. A scan is converted with the laser's mounting pose in ``base_link`` and the robot's odom
pose at the scan's time; points from the last ``memory_s`` seconds are kept because the
URG-04LX sees only 240 degrees -- an obstacle the robot is passing drifts into the blind sector
behind it exactly when the robot turns back toward the goal.
"""

from __future__ import annotations

from collections import deque
import math
from typing import Sequence

import numpy as np

__all__ = ['PointMemory', 'ScanError', 'scan_to_points', 'voxel_downsample']


class ScanError(ValueError):
    """Raise for a scan or pose that cannot be converted (the message shows the bad value)."""


def _pose3(value: Sequence[float], name: str) -> tuple[float, float, float]:
    try:
        x, y, yaw = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ScanError(f'{name}: expected (x, y, yaw), got {value!r}') from None
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(yaw)):
        raise ScanError(f'{name}: expected finite (x, y, yaw), got {value!r}')
    return x, y, yaw


def scan_to_points(ranges: Sequence[float] | np.ndarray, angle_min: float,
                   angle_increment: float, range_min: float, range_max: float,
                   mount: Sequence[float] = (0.0, 0.0, 0.0),
                   pose: Sequence[float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """Return the valid returns of a scan as an (N, 2) array of odom-frame points.

    ``mount`` is the laser pose in ``base_link`` (x, y, yaw), ``pose`` the robot's odom pose.
    Returns outside [range_min, range_max], NaN and inf (no echo, URG error codes mapped by the
    bridge) carry no obstacle and are dropped.
    """
    for name, value in (('angle_min', angle_min), ('angle_increment', angle_increment),
                        ('range_min', range_min), ('range_max', range_max)):
        if not math.isfinite(value):
            raise ScanError(f'{name}: expected a finite number, got {value!r}')
    if not 0.0 <= range_min < range_max:
        raise ScanError(f'range limits: expected 0 <= range_min < range_max, got '
                        f'{(range_min, range_max)!r}')
    mx, my, myaw = _pose3(mount, 'mount')
    x, y, yaw = _pose3(pose, 'pose')
    r = np.asarray(ranges, dtype=float).ravel()
    ang = angle_min + angle_increment * np.arange(r.size)
    with np.errstate(invalid='ignore'):
        ok = np.isfinite(r) & (r >= range_min) & (r <= range_max)
    r, ang = r[ok], ang[ok]
    # Laser frame -> base_link -> odom, as two planar rigid transforms.
    bx = mx + r * np.cos(ang + myaw)
    by = my + r * np.sin(ang + myaw)
    c, s = math.cos(yaw), math.sin(yaw)
    return np.column_stack((x + c * bx - s * by, y + s * bx + c * by))


def voxel_downsample(points: np.ndarray, resolution: float) -> np.ndarray:
    """Return one point (the first seen) per ``resolution``-sized grid cell."""
    if resolution <= 0.0 or not math.isfinite(resolution):
        raise ScanError(f'resolution: expected a finite number > 0, got {resolution!r}')
    if len(points) == 0:
        return np.empty((0, 2))
    keys = np.floor(points / resolution).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return points[np.sort(first)]


class PointMemory:
    """Obstacle points of the scans of the last ``memory_s`` seconds, voxel-downsampled."""

    def __init__(self, memory_s: float = 2.0, resolution: float = 0.03,
                 max_scans: int = 32) -> None:
        if not (math.isfinite(memory_s) and memory_s >= 0.0):
            raise ScanError(f'memory_s: expected a finite number >= 0, got {memory_s!r}')
        if max_scans < 1:
            raise ScanError(f'max_scans: expected >= 1, got {max_scans!r}')
        self.memory_s = float(memory_s)
        self.resolution = float(resolution)
        voxel_downsample(np.empty((0, 2)), self.resolution)   # validates resolution
        self._scans: deque[tuple[float, np.ndarray]] = deque(maxlen=max_scans)
        self._cache: np.ndarray | None = None

    def add(self, t: float, points: np.ndarray) -> None:
        """Add the points of one scan taken at time ``t`` (s, any monotonic clock)."""
        pts = np.asarray(points, dtype=float).reshape(-1, 2)
        pts = pts[np.isfinite(pts).all(axis=1)]
        self._scans.append((float(t), voxel_downsample(pts, self.resolution)))
        self._cache = None

    def points(self, now: float) -> np.ndarray:
        """Return the remembered points (scans older than ``memory_s`` before ``now`` dropped)."""
        # The newest scan always stays, however old: it is the best knowledge there is.
        while len(self._scans) > 1 and self._scans[0][0] < now - self.memory_s:
            self._scans.popleft()
            self._cache = None
        if self._cache is None:
            if not self._scans:
                self._cache = np.empty((0, 2))
            else:
                self._cache = voxel_downsample(np.vstack([p for _, p in self._scans]),
                                               self.resolution)
        return self._cache

    def clear(self) -> None:
        """Forget every scan."""
        self._scans.clear()
        self._cache = None

    def __len__(self) -> int:
        return len(self._scans)
