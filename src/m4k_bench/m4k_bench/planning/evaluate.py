"""Judge a recorded drive against the simulated room (pure: numpy, no ROS).

The demo records the odometry trajectory over ROS; this module reads the room with the
simulator's own world model (:meth:`m4k_drivers.world.WorldConfig.from_dict`, the same
parser, defaults and robot footprint the driver host's simulator uses: ``robot.body`` of the
layered configuration, overridden by ``world.robot``) and measures the footprint's clearance
to every wall and obstacle along the trajectory. A contact is an entry into clearance <=
``contact_eps``.

Frames: odometry starts at zero at the world's ``start`` pose, so odom poses are mapped into
the world frame through ``start`` before they are compared with the geometry.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any, Mapping, Sequence

import numpy as np

from m4k_bench.planning.dwa import footprint_clearance
from m4k_drivers.world import RobotParams, WorldConfig, WorldConfigError
from m4k_rt.schema import ConfigError

__all__ = ['EvaluateError', 'WorldGeometry', 'contacts', 'densify', 'odom_to_world',
           'trajectory_clearance']


class EvaluateError(ConfigError):
    """Raise for a world section that cannot be read; the message names the field."""


@dataclass(frozen=True)
class WorldGeometry:
    """Walls (segments x1, y1, x2, y2), obstacle polygons, start pose, footprint size."""

    walls: tuple[tuple[float, ...], ...]
    obstacles: tuple[tuple[tuple[float, float], ...], ...]
    start: tuple[float, float, float]
    length: float
    width: float

    @classmethod
    def from_world(cls, world: WorldConfig) -> WorldGeometry:
        """Return the geometry of the simulator's world model (obstacles at rest)."""
        return cls(tuple(tuple(w) for w in world.walls),
                   tuple(tuple(p) for p in world.obstacles),
                   (world.start.x, world.start.y, world.start.yaw),
                   world.robot.length_m, world.robot.width_m)

    @classmethod
    def from_config(cls, world: Mapping[str, Any] | None,
                    doc: Mapping[str, Any] | None = None) -> WorldGeometry:
        """Build from a ``world:`` section (None or {}: the simulator's defaults).

        ``doc``, the layered configuration, gives the robot the world's ``robot:`` keys
        override, as the driver host builds it (``control:`` and ``robot.body``).
        """
        try:
            base = None
            if doc is not None:
                body = (doc.get('robot') or {}).get('body')
                base = RobotParams.from_control(doc.get('control'), body)
            return cls.from_world(WorldConfig.from_dict(dict(world or {}), robot=base))
        except WorldConfigError as exc:
            raise EvaluateError(str(exc)) from None

    def segments(self) -> list[tuple[float, ...]]:
        """Return every wall and obstacle edge as (x1, y1, x2, y2)."""
        segs = list(self.walls)
        for poly in self.obstacles:
            segs += [(*poly[i], *poly[(i + 1) % len(poly)]) for i in range(len(poly))]
        return segs


def densify(segments: Sequence[Sequence[float]], spacing: float = 0.005) -> np.ndarray:
    """Return points every ``spacing`` metres along the segments (ends included)."""
    if not spacing > 0.0:
        raise EvaluateError(f'spacing: expected > 0, got {spacing!r}')
    out = []
    for x1, y1, x2, y2 in segments:
        n = max(2, int(math.ceil(math.hypot(x2 - x1, y2 - y1) / spacing)) + 1)
        k = np.linspace(0.0, 1.0, n)
        out.append(np.column_stack((x1 + k * (x2 - x1), y1 + k * (y2 - y1))))
    return np.vstack(out) if out else np.empty((0, 2))


def odom_to_world(poses: np.ndarray, start: Sequence[float]) -> np.ndarray:
    """Return odom-frame poses (N, 3) in the world frame of a robot that started at ``start``."""
    sx, sy, sth = (float(v) for v in start)
    c, s = math.cos(sth), math.sin(sth)
    p = np.asarray(poses, dtype=float).reshape(-1, 3)
    return np.column_stack((sx + c * p[:, 0] - s * p[:, 1], sy + s * p[:, 0] + c * p[:, 1],
                            p[:, 2] + sth))


def trajectory_clearance(world_poses: np.ndarray, geometry: WorldGeometry,
                         spacing: float = 0.005, chunk: int = 256) -> np.ndarray:
    """Return the footprint's clearance (m, < 0 = overlap) to the room at each world pose.

    The geometry is sampled every ``spacing`` metres, so a clearance is exact to spacing / 2.
    """
    pts = densify(geometry.segments(), spacing)
    poses = np.asarray(world_poses, dtype=float).reshape(-1, 3)
    out = np.empty(len(poses))
    for i in range(0, len(poses), chunk):
        out[i:i + chunk] = footprint_clearance(poses[i:i + chunk], pts, geometry.length,
                                               geometry.width)
    return out


def contacts(clearance: np.ndarray, contact_eps: float = 0.005) -> int:
    """Return how many times the clearance dropped to ``contact_eps`` or below (onsets)."""
    touching = np.asarray(clearance) <= contact_eps
    if len(touching) == 0:
        return 0
    return int(touching[0]) + int(np.count_nonzero(touching[1:] & ~touching[:-1]))
