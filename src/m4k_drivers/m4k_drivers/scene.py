"""What a simulated world holds besides walls: surfaces, heights, moving obstacles, events.

An obstacle in ``world.obstacles`` is either a plain polygon (``[[x, y], ...]``: a tall, ordinary
surface every sensor sees) or a mapping::

    - polygon: [[x, y], ...]     # its outline at rest (world frame, m)
      height: 0.15               # m above the floor (default: taller than every sensor)
      surface: glass             # normal | soft | glass | black (default normal)
      path:                      # a moving obstacle (a person): offsets of the outline in time
        start: {travelled: 0.5}  # when the robot has truly covered 0.5 m; or {after: 2.0}:
                                 # 2 s after the robot first moved; {} = at the first motion
        waypoints: [[0, 0, 0], [3, 0, -3]]   # [t s since start, dx m, dy m]; held after the last

What each sensor makes of a surface, from what the devices do:

* ``normal`` -- seen by both: a diffuse panel echoes sound and scatters the laser back.
* ``soft`` -- no sonar echo: a curtain or foam absorbs the 40 kHz burst, and a wall oblique to
  the beam reflects it away (specular); the laser sees it (diffuse at 785 nm).
* ``glass`` -- the laser passes through (clear glass transmits near infrared: the URG measures
  what is behind it, or reports code 0 when nothing is within 5.6 m); the sonar echoes off it.
* ``black`` -- the URG gets too little light back: error code 2 ("reflected light has low
  intensity", SCIP 2.0 C-42-03320B Table 3); the sonar echoes off it.

A sensor mounted higher than an obstacle's ``height`` does not see it (the beam passes over; the
laser scans one plane): a low box under the laser plane is a sonar-only obstacle. The robot's body
still touches it.

Events (``world.events``) change the simulated hardware during a drive, executed by sim_robot::

    events:
      - {at: {travelled: 1.0}, unplug: sonar}     # sonar | lrf | imu
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass
import math
from typing import Any

from m4k_rt.schema import ConfigError

__all__ = ['EVENT_TARGETS', 'Event', 'Path', 'Start', 'SURFACES', 'Surface', 'TALL',
           'parse_events', 'parse_obstacle']

SURFACES = ('normal', 'soft', 'glass', 'black')
EVENT_TARGETS = ('sonar', 'lrf', 'imu')
TALL = math.inf


class SceneError(ConfigError):
    """A bad obstacle or event entry; the message names the field."""


@dataclass(frozen=True)
class Surface:
    """How an obstacle looks to the sensors."""

    height: float = TALL
    kind: str = 'normal'


@dataclass(frozen=True)
class Start:
    """When a path or an event begins: the robot covered ``travelled`` m, moved ``after`` s."""

    travelled: float = 0.0
    after: float = 0.0

    def reached(self, travelled: float, moving_s: float | None) -> bool:
        """Return True once the robot has moved and both conditions hold."""
        return moving_s is not None and travelled >= self.travelled and moving_s >= self.after


@dataclass(frozen=True)
class Path:
    """Offsets (dx, dy) of a moving obstacle over the time since its start."""

    start: Start
    t: tuple[float, ...]
    dx: tuple[float, ...]
    dy: tuple[float, ...]

    def offset(self, t_s: float) -> tuple[float, float]:
        """Return the offset ``t_s`` seconds after the start (held before and after)."""
        t = self.t
        if t_s <= t[0]:
            return self.dx[0], self.dy[0]
        if t_s >= t[-1]:
            return self.dx[-1], self.dy[-1]
        k = bisect.bisect_right(t, t_s) - 1      # called every 1 ms step: no numpy here
        f = (t_s - t[k]) / (t[k + 1] - t[k])
        return (self.dx[k] + f * (self.dx[k + 1] - self.dx[k]),
                self.dy[k] + f * (self.dy[k + 1] - self.dy[k]))


@dataclass(frozen=True)
class Event:
    """A change of the simulated hardware at a moment of the drive."""

    at: Start
    unplug: str


def _num(v: Any, where: str, positive: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise SceneError(f'{where}: expected a finite number, got {v!r}')
    if positive and v <= 0:
        raise SceneError(f'{where}: must be > 0, got {v!r}')
    return float(v)


def _start(v: Any, where: str) -> Start:
    if v is None:
        return Start()
    if not isinstance(v, dict) or set(v) - {'travelled', 'after'}:
        raise SceneError(f'{where}: expected a mapping with travelled (m) and/or after (s), '
                         f'got {v!r}')
    vals = {k: _num(x, f'{where}.{k}') for k, x in v.items()}
    if any(x < 0 for x in vals.values()):
        raise SceneError(f'{where}: must be >= 0, got {v!r}')
    return Start(**vals)


def _path(v: Any, where: str) -> Path:
    if not isinstance(v, dict) or set(v) - {'start', 'waypoints'} or 'waypoints' not in v:
        raise SceneError(f'{where}: expected {{start: ..., waypoints: [[t, dx, dy], ...]}}, '
                         f'got {v!r}')
    wps = v['waypoints']
    if not isinstance(wps, list) or not wps:
        raise SceneError(f'{where}.waypoints: expected a list of [t, dx, dy], got {wps!r}')
    rows = []
    for i, w in enumerate(wps):
        if not isinstance(w, list) or len(w) != 3:
            raise SceneError(f'{where}.waypoints[{i}]: expected [t, dx, dy], got {w!r}')
        rows.append(tuple(_num(x, f'{where}.waypoints[{i}]') for x in w))
    ts = [r[0] for r in rows]
    if ts[0] < 0 or any(b <= a for a, b in zip(ts, ts[1:], strict=False)):
        raise SceneError(f'{where}.waypoints: times must start >= 0 and increase, got {ts!r}')
    return Path(_start(v.get('start'), f'{where}.start'), tuple(ts),
                tuple(r[1] for r in rows), tuple(r[2] for r in rows))


def parse_obstacle(v: Any, where: str
                   ) -> tuple[tuple[tuple[float, float], ...], Surface, Path | None]:
    """Return (polygon, surface, path or None) of one ``world.obstacles`` entry."""
    if isinstance(v, dict):
        extra = set(v) - {'polygon', 'height', 'surface', 'path'}
        if extra or 'polygon' not in v:
            raise SceneError(f'{where}: expected a polygon or a mapping with polygon and '
                             f'optional height, surface, path; got {v!r}')
        poly_raw = v['polygon']
        height = TALL if v.get('height') is None else _num(v['height'], f'{where}.height', True)
        kind = v.get('surface', 'normal')
        if kind not in SURFACES:
            raise SceneError(f'{where}.surface: expected one of {SURFACES}, got {kind!r}')
        path = _path(v['path'], f'{where}.path') if v.get('path') is not None else None
        where = f'{where}.polygon'
    else:
        poly_raw, height, kind, path = v, TALL, 'normal', None
    if not isinstance(poly_raw, list) or len(poly_raw) < 3:
        raise SceneError(f'{where}: expected a polygon of at least 3 [x, y] points, '
                         f'got {poly_raw!r}')
    poly = []
    for j, p in enumerate(poly_raw):
        if not isinstance(p, list) or len(p) != 2:
            raise SceneError(f'{where}[{j}]: expected [x, y], got {p!r}')
        poly.append((_num(p[0], f'{where}[{j}]'), _num(p[1], f'{where}[{j}]')))
    return tuple(poly), Surface(height, kind), path


def parse_events(v: Any, where: str = 'world.events') -> tuple[Event, ...]:
    """Return the events of a ``world.events`` list."""
    if v is None:
        return ()
    if not isinstance(v, list):
        raise SceneError(f'{where}: expected a list of {{at: ..., unplug: ...}}, got {v!r}')
    out = []
    for i, e in enumerate(v):
        if not isinstance(e, dict) or set(e) != {'at', 'unplug'}:
            raise SceneError(f'{where}[{i}]: expected {{at: {{travelled|after}}, unplug: '
                             f'{"|".join(EVENT_TARGETS)}}}, got {e!r}')
        if e['unplug'] not in EVENT_TARGETS:
            raise SceneError(f'{where}[{i}].unplug: expected one of {EVENT_TARGETS}, '
                             f'got {e["unplug"]!r}')
        out.append(Event(_start(e['at'], f'{where}[{i}].at'), e['unplug']))
    return tuple(out)
