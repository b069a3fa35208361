"""Judge a recorded drive against the simulated room (pure: numpy, no ROS).

The demo records the odometry trajectory over ROS; this module loads the room geometry from the
same ``world:`` configuration section the driver host's simulator uses (m4k_rt must not import
m4k_drivers, so the small schema -- ``walls`` as segments or ``{rectangle: [...]}``,
``obstacles`` as polygons, ``start`` -- is read here again) and measures the footprint's
clearance to every wall and obstacle along the trajectory. A contact is an entry into
clearance <= ``contact_eps``.

Frames: odometry starts at zero at the world's ``start`` pose, so odom poses are mapped into
the world frame through ``start`` before they are compared with the geometry.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any, Mapping, Sequence

import numpy as np

from m4k_bench.planning.dwa import footprint_clearance
from m4k_rt.schema import ConfigError

__all__ = ['EvaluateError', 'WorldGeometry', 'contacts', 'densify', 'odom_to_world',
           'trajectory_clearance']

# The paper's room (Fig. 8) as the simulator defaults it, for a config without ``world:``.
_DEFAULT_RECT = (-0.8, -1.5, 4.2, 1.5)
_DEFAULT_OBSTACLE = ((1.5, -0.25), (1.5, 0.25), (1.9, 0.0))


class EvaluateError(ConfigError):
    """Raise for a world section that cannot be read; the message names the field."""


def _rect(xmin: float, ymin: float, xmax: float, ymax: float) -> list[tuple[float, ...]]:
    return [(xmin, ymin, xmax, ymin), (xmax, ymin, xmax, ymax),
            (xmax, ymax, xmin, ymax), (xmin, ymax, xmin, ymin)]


def _floats(value: Any, n: int, where: str) -> tuple[float, ...]:
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise EvaluateError(f'{where}: expected a list of {n} numbers, got {value!r}')
    try:
        out = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise EvaluateError(f'{where}: expected numbers, got {value!r}') from None
    if not all(math.isfinite(v) for v in out):
        raise EvaluateError(f'{where}: expected finite numbers, got {value!r}')
    return out


@dataclass(frozen=True)
class WorldGeometry:
    """Walls (segments x1, y1, x2, y2), obstacle polygons, start pose, footprint size."""

    walls: tuple[tuple[float, ...], ...]
    obstacles: tuple[tuple[tuple[float, float], ...], ...]
    start: tuple[float, float, float]
    length: float = 0.45
    width: float = 0.28

    @classmethod
    def from_config(cls, world: Mapping[str, Any] | None) -> WorldGeometry:
        """Build from a ``world:`` config section (None or {}: the simulator's defaults)."""
        world = dict(world or {})
        walls_raw = world.get('walls')
        if walls_raw is None:
            walls = _rect(*_DEFAULT_RECT)
        elif isinstance(walls_raw, Mapping) and set(walls_raw) == {'rectangle'}:
            walls = _rect(*_floats(walls_raw['rectangle'], 4, 'world.walls.rectangle'))
        elif isinstance(walls_raw, list):
            walls = [_floats(s, 4, f'world.walls[{i}]') for i, s in enumerate(walls_raw)]
        else:
            raise EvaluateError(f'world.walls: expected segments or {{rectangle: [...]}}, got '
                                f'{walls_raw!r}')
        obstacles: list[tuple[tuple[float, float], ...]] = []
        raw_obs = world.get('obstacles', [list(_DEFAULT_OBSTACLE)]) or []
        if not isinstance(raw_obs, list):
            raise EvaluateError(f'world.obstacles: expected a list of polygons, got {raw_obs!r}')
        for i, poly in enumerate(raw_obs):
            if isinstance(poly, Mapping):    # {polygon, height, surface, path}: its outline
                poly = poly.get('polygon')   # at rest (m4k_drivers.scene)
            if not isinstance(poly, (list, tuple)) or len(poly) < 3:
                raise EvaluateError(f'world.obstacles[{i}]: expected >= 3 points, got {poly!r}')
            obstacles.append(tuple(_floats(p, 2, f'world.obstacles[{i}][{j}]')  # type: ignore
                                   for j, p in enumerate(poly)))
        start = _floats(world.get('start', [0.0, 0.0, 0.0]), 3, 'world.start')
        robot = world.get('robot') or {}
        length = float(robot.get('length_m', 0.45))
        width = float(robot.get('width_m', 0.28))
        return cls(tuple(tuple(w) for w in walls), tuple(obstacles),
                   (start[0], start[1], start[2]), length, width)

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
