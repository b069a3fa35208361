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

Every key is declared once, by its schema Field (:mod:`m4k_rt.schema`): on the dataclass that
holds it (:class:`Start`, :class:`Event`) or in the entry's table (:data:`OBSTACLE`,
:data:`PATH`); the parsers below validate with them and the docs are generated from them.
Only what involves several values is checked by hand (waypoint times increasing).
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass
import math
from typing import Any, Callable

from m4k_rt.schema import (
    build,
    ConfigError,
    Field,
    REQUIRED,
    section,
    setting,
    table,
    validate_tree,
)

__all__ = ['EVENT', 'EVENT_TARGETS', 'Event', 'OBSTACLE', 'PATH', 'Path', 'START', 'Start',
           'SURFACES', 'SceneError', 'Surface', 'TALL', 'parse_events', 'parse_obstacle']

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

    travelled: float = setting(Field(
        'float', 0.0, 'Begins once the robot has truly covered this path length (ground '
        'truth, not odometry).', unit='m', lo=0))
    after: float = setting(Field(
        'float', 0.0, 'Begins this long after the robot first moved -- 5 mm along its path, '
        "or at its wheels' rim turning in place (both conditions must hold; {} = at the first "
        'motion).', unit='s', lo=0))

    def reached(self, travelled: float, moving_s: float | None) -> bool:
        """Return True once the robot has moved and both conditions hold."""
        return moving_s is not None and travelled >= self.travelled and moving_s >= self.after

    @classmethod
    def from_flat(cls, flat: dict[str, Any]) -> 'Start':
        """Return the Start of a validated tree's ``start.*`` keys (a path's, a fault's)."""
        return build(cls, {k.split('.', 1)[1]: x for k, x in flat.items()
                           if k.startswith('start.')})


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

    at: Start = section(Start)
    unplug: str = setting(Field(
        'str', REQUIRED, 'The device whose cable is pulled: its simulated hardware stops '
        'answering as unplugged hardware does (the driver reports it, the guard treats a '
        'guard sensor as stale).', choices=EVENT_TARGETS))


def _min_items(n: int, what: str) -> Callable[[Any], str | None]:
    def check(v: Any) -> str | None:
        return None if len(v) >= n else f'expected {what}, got {v!r}'
    return check


START: dict[str, Field] = table(Start)
EVENT: dict[str, Field] = table(Event)
_POLYGON_WHAT = 'a polygon of at least 3 [x, y] points'
# One obstacle given as a mapping (a bare list is its polygon: tall, normal, still).
OBSTACLE: dict[str, Field] = {
    'polygon': Field('list', REQUIRED, 'Outline at rest, world frame: [[x, y], ...] (the '
                     "robot's body touches it whatever its height or surface).", unit='m',
                     expect=_POLYGON_WHAT, check=_min_items(3, _POLYGON_WHAT)),
    'height': Field('float', None, 'Top above the floor; null: taller than every sensor. A '
                    'sensor mounted higher does not see it (a low box under the laser plane is '
                    'sonar-only).', unit='m', lo=0, lo_open=True, nullable=True),
    'surface': Field('str', 'normal', 'normal: both sensors see it; soft: no sonar echo; '
                     'glass: the laser passes through; black: the laser reports error code 2.',
                     choices=SURFACES),
    'path': Field('map', None, 'A moving obstacle (a person): offsets of the outline in time '
                  '(see world.obstacles[].path); null: it stands still.', nullable=True),
}
PATH: dict[str, Field] = {
    **{'start.' + k: f for k, f in START.items()},
    'waypoints': Field('list', REQUIRED, '[[t, dx, dy], ...]: offset dx, dy (m) of the outline '
                       't s after the start; times start >= 0 and increase; held before the '
                       'first and after the last, linear between.', expect='a list of [t, dx, dy]',
                       check=_min_items(1, 'a list of [t, dx, dy]')),
}
_POINT = Field('float[]', REQUIRED, length=2, expect='[x, y]')
_WAYPOINT = Field('float[]', REQUIRED, length=3, expect='[t, dx, dy]')


def _path(v: Any, where: str) -> Path:
    flat = validate_tree(PATH, v, where, SceneError)
    rows = [_WAYPOINT.validate(f'{where}.waypoints[{i}]', w, SceneError)
            for i, w in enumerate(flat['waypoints'])]
    ts = [r[0] for r in rows]
    if ts[0] < 0 or any(b <= a for a, b in zip(ts, ts[1:], strict=False)):
        raise SceneError(f'{where}.waypoints', f'times must start >= 0 and increase, got {ts!r}')
    start = Start.from_flat(flat)
    return Path(start, tuple(ts), tuple(r[1] for r in rows), tuple(r[2] for r in rows))


def parse_obstacle(v: Any, where: str
                   ) -> tuple[tuple[tuple[float, float], ...], Surface, Path | None]:
    """Return (polygon, surface, path or None) of one ``world.obstacles`` entry."""
    if isinstance(v, dict):
        flat = validate_tree(OBSTACLE, v, where, SceneError)
        height = TALL if flat['height'] is None else flat['height']
        path = None if flat['path'] is None else _path(flat['path'], f'{where}.path')
        poly_raw, surface = flat['polygon'], Surface(height, flat['surface'])
        where = f'{where}.polygon'
    else:
        poly_raw = OBSTACLE['polygon'].validate(where, v, SceneError)
        surface, path = Surface(), None
    points = [_POINT.validate(f'{where}[{j}]', p, SceneError) for j, p in enumerate(poly_raw)]
    return tuple((x, y) for x, y in points), surface, path


def parse_events(v: Any, where: str = 'world.events') -> tuple[Event, ...]:
    """Return the events of a ``world.events`` list."""
    if v is None:
        return ()
    if not isinstance(v, list):
        raise SceneError(where, f'expected a list of {{at: ..., unplug: ...}}, got {v!r}')
    out = []
    for i, e in enumerate(v):
        at = f'{where}[{i}]'
        if isinstance(e, dict) and 'at' not in e:     # no default moment: say when
            raise SceneError(f'{at}.at', 'missing ({travelled: m} and/or {after: s})')
        out.append(build(Event, validate_tree(EVENT, e, at, SceneError)))
    return tuple(out)
