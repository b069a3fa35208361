"""The judge's geometry: exact distances from the robot's footprint to every surface, no rays.

The footprint is the simulator's own (:meth:`m4k_drivers.world.World.footprint` of the world
model the stack builds from ``config/``: ``robot.body`` and ``world.robot``), never restated
here. The surfaces are the world's walls (segments) and obstacles (polygons, moved by the
offsets the simulator reports for each sample). Two measures, per ground-truth sample:

* :meth:`Scene.clearance`: the minimum Euclidean distance between the footprint polygon and
  any surface (0 when they touch or overlap) -- exact segment-to-segment distances;
* :meth:`Scene.front_clearance`: how far ahead of the footprint's front face the nearest surface
  lies inside the band the front face sweeps when driving straight (the whole face, edge to
  edge: a 4 cm table leg anywhere across it counts) -- exact: each segment is clipped to the
  band and the nearest clipped point taken (a segment's distance ahead is linear along it, so
  its minimum is at an end of the clipped piece). A surface inside the body's half-length
  counts 0 (contact). The guard judge widens the band by the guard's ``lateral_margin`` on each
  side: the corridor the guard watches and promises to stop for, so a leg a robot drifting a
  few cm sideways brings into that margin is owed the same stop.
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from m4k_drivers.world import inside, point_seg, segments_touch

__all__ = ['Scene', 'seg_seg_distance']


def seg_seg_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Return the minimum distance between any segment of ``a`` (N x 4) and of ``b`` (M x 4).

    0 when two of them cross or touch; otherwise the smallest end-point-to-segment distance
    (the minimum distance of two non-crossing segments is always at an end of one of them).
    """
    if len(a) == 0 or len(b) == 0:
        return math.inf
    if np.any(segments_touch(a, b)):
        return 0.0
    best = min(float(point_seg(a[:, 0], a[:, 1], b).min()),
               float(point_seg(a[:, 2], a[:, 3], b).min()),
               float(point_seg(b[:, 0], b[:, 1], a).min()),
               float(point_seg(b[:, 2], b[:, 3], a).min()))
    return best


def _edges(poly: np.ndarray) -> np.ndarray:
    return np.hstack([poly, np.roll(poly, -1, axis=0)])


class Scene:
    """The world model of one scenario: the simulator's footprint, the walls, the obstacles."""

    def __init__(self, raw: Mapping[str, Any], lateral: float = 0.0) -> None:
        """Build from the layered configuration (``world:``, ``control:``, ``robot.body``).

        ``lateral`` (m) widens the front band on each side: the guard judge passes the guard's
        ``lateral_margin``, the corridor the guard promises to stop for.

        The world model is the simulator's own: the same ``m4k_drivers`` validation and
        defaults sim_robot applies to the same configuration.
        """
        from m4k_drivers.world import RobotParams, World, WorldConfig
        robot = RobotParams.from_control(dict(raw.get('control') or {}),
                                         (raw.get('robot') or {}).get('body'),
                                         (raw.get('robot') or {}).get('wheel_width'))
        cfg = WorldConfig.from_dict(dict(raw.get('world') or {}), robot=robot)
        self.config = cfg
        self.robot = cfg.robot
        self._world = World(cfg, clock=lambda: 0, t0_ns=0)
        self.walls = np.array([tuple(s) for s in cfg.walls], dtype=float).reshape(-1, 4)
        self.polys = [np.array(p, dtype=float).reshape(-1, 2) for p in cfg.obstacles]
        local = np.asarray(self._world.footprint(_pose(0.0, 0.0, 0.0)), dtype=float)
        self.local_footprint = local             # the footprint in base_link (x forward)
        self.front_x = float(local[:, 0].max())  # the front face, m ahead of base_link
        self.band = (float(local[:, 1].min()) - lateral, float(local[:, 1].max()) + lateral)

    def footprint(self, x: float, y: float, yaw: float) -> np.ndarray:
        """Return the footprint polygon at a pose (the simulator's own function)."""
        return np.asarray(self._world.footprint(_pose(x, y, yaw)), dtype=float)

    def obstacles(self, offsets: Sequence[Sequence[float]] | None = None) -> list[np.ndarray]:
        """Return the obstacle polygons moved by the simulator's reported offsets."""
        offs = list(offsets or [])
        return [p + (offs[i][0], offs[i][1]) if i < len(offs) else p
                for i, p in enumerate(self.polys)]

    def segments(self, offsets: Sequence[Sequence[float]] | None = None) -> np.ndarray:
        """Return every surface as segments (walls, then each obstacle's outline)."""
        parts = [self.walls] + [_edges(p) for p in self.obstacles(offsets)]
        return np.vstack(parts) if parts else np.zeros((0, 4))

    def clearance(self, x: float, y: float, yaw: float,
                  offsets: Sequence[Sequence[float]] | None = None) -> float:
        """Return the exact minimum distance footprint-to-surface (0: touching or overlapping)."""
        fp = self.footprint(x, y, yaw)
        d = seg_seg_distance(_edges(fp), self.segments(offsets))
        if d == 0.0:
            return 0.0
        for poly in self.obstacles(offsets):
            # one polygon wholly inside the other crosses no edge
            if inside(fp, float(poly[0, 0]), float(poly[0, 1])) or \
                    inside(poly, float(fp[0, 0]), float(fp[0, 1])):
                return 0.0
        return d

    def front_clearance(self, x: float, y: float, yaw: float,
                        offsets: Sequence[Sequence[float]] | None = None) -> float:
        """Return the distance from the front face to the nearest surface across its width.

        Exact: in the robot's frame each segment is clipped to the band ``band[0] <= y' <=
        band[1]`` and to ``x' >= 0`` (ahead of the axle); the smallest ``x' - front_x`` of the
        clipped ends, 0 if it lies inside the body. ``inf``: nothing ahead.
        """
        seg = self.segments(offsets)
        if len(seg) == 0:
            return math.inf
        c, s = math.cos(yaw), math.sin(yaw)
        ax, ay = seg[:, 0] - x, seg[:, 1] - y
        bx, by = seg[:, 2] - x, seg[:, 3] - y
        x1, y1 = c * ax + s * ay, -s * ax + c * ay
        x2, y2 = c * bx + s * by, -s * bx + c * by
        t0, t1 = np.zeros(len(seg)), np.ones(len(seg))
        dx, dy = x2 - x1, y2 - y1
        lo, hi = self.band
        ok = np.ones(len(seg), dtype=bool)
        # Liang-Barsky clipping against y' >= lo, y' <= hi, x' >= 0
        for p, q in ((-dy, y1 - lo), (dy, hi - y1), (-dx, x1)):
            par = p == 0
            ok &= ~(par & (q < 0))
            with np.errstate(divide='ignore', invalid='ignore'):
                r = np.where(par, 0.0, q / np.where(par, 1.0, p))
            t0 = np.where(~par & (p < 0), np.maximum(t0, r), t0)
            t1 = np.where(~par & (p > 0), np.minimum(t1, r), t1)
        ok &= t0 <= t1
        if not np.any(ok):
            return math.inf
        xa = x1[ok] + t0[ok] * dx[ok]
        xb = x1[ok] + t1[ok] * dx[ok]
        ahead = float(min(xa.min(), xb.min())) - self.front_x
        return max(ahead, 0.0)

    def judge_sample(self, sample: Mapping[str, Any]) -> tuple[float, float]:
        """Return (clearance, front clearance) of one ground-truth sample."""
        x, y, th = float(sample['x']), float(sample['y']), float(sample['theta'])
        offs = sample.get('obstacle_offsets') or []
        return self.clearance(x, y, th, offs), self.front_clearance(x, y, th, offs)


def _pose(x: float, y: float, yaw: float) -> Any:
    from m4k_drivers.world import Pose
    return Pose(x, y, yaw)
