"""The simulated world shared by every sim device of one driver host process.

A room of panel walls (line segments) with a triangular obstacle about 1.5 m ahead of the start
(the paper's Fig. 8), and the M4K base (Table 2): differential drive, wheel diameter 0.2032 m,
gear 12:1, top speed 2 m/s, body 0.45 x 0.28 m.  The track width is not in the paper; we use
**0.40 m** (wheel centre to wheel centre: a 0.28 m wide body carrying 5 cm wheels outside it
plus clearance would be ~0.38-0.40 m).

Dynamics, per fixed step (``step_s``, default 1 ms, so results do not depend on how often
callers look): the drive train of :mod:`m4k_drivers.drive` -- DAC volts -> voltage-mode
amplifier with a current limit -> DC motor -> 12:1 gear -> wheel -> tyre traction (slip beyond
``mu`` x load) -> the 30 kg body's speed and yaw rate; the robot pose is integrated exactly
along the arc for the mean body speeds of the step.  A step whose new footprint would touch a
wall or an obstacle is not taken: the robot stops, the wheels stall, and ``collisions`` counts
the contact onset.

The motor amplifiers have an enable input (the heartbeat monostable, docs/internals.md, in
series with the e-stop contact): while it is off the amplifier drives nothing, whatever the
DACs hold; the dynamic brake contact shorts the armatures through ``dynamic_brake_ohm`` (the
back-EMF brakes them), or, without one (null), the outputs float and the wheels coast, slowed
by friction alone (rolling resistance and the drive train: ``RobotParams.coast_decel_mps2``).
``set_enable_until`` sets the time the heartbeat keeps the enable on; ``None`` (the
default) is an enable strapped on; ``set_estop_open`` opens the e-stop contact.  The
amplifiers' input offsets and dead band are in :meth:`RobotParams.effective_volts`.

``world.robot`` is the robot *as built*, the simulator's truth: a field not set there takes the
configuration's value (:meth:`RobotParams.from_control`: ``control.wheel_radius``,
``track_width``, ``gear_ratio``, ``full_scale_wheel_speed``), so by default the simulated robot
is the configured one, and a scenario that sets e.g. ``wheel_diameter_m`` builds a robot whose
configuration is wrong (what ``calibrate`` identifies).

Time is advanced lazily to the caller's CLOCK_MONOTONIC (``advance_to``/``now``); every
access is under one lock.  Noise streams come from :meth:`World.rng`, seeded from the world
seed and the stream name, so a run is reproducible.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, replace
import math
import threading
import time
from typing import Any, Callable, Mapping, NamedTuple, Sequence
import zlib

import numpy as np

from m4k_drivers.drive import (
    DriveState,
    G,
    LEFT,
    parse_robot,
    RIGHT,
    RobotParams,
    step_drive,
    WorldConfigError,
)
from m4k_drivers.faults import Fault, FaultError, KINDS, parse_faults
from m4k_drivers.floor import FloorError, grade_force, parse_floor, Patch, wheel_mu
from m4k_drivers.floor import tilt as slope_tilt
from m4k_drivers.scene import Event, parse_events, parse_obstacle, Path, SceneError, Surface
from m4k_rt.control.footprint import outline
from m4k_rt.schema import check_keys, derived, Field, REQUIRED, section, setting, table

__all__ = ['inside', 'LEFT', 'RIGHT', 'point_seg', 'Pose', 'RobotParams', 'RobotState',
           'segments_touch', 'WORLD', 'World', 'WorldConfig', 'WorldConfigError']

REST_V = 0.01        # m/s: below this the robot is at rest (truth's rest_since_ns)
WHEEL_HISTORY_S = 0.5   # s of wheel angles kept for reads the simulator handles late


class Pose(NamedTuple):
    """Planar pose in the world frame (x forward at start, y left, yaw CCW, REP-103)."""

    x: float
    y: float
    yaw: float


class RobotState(NamedTuple):
    """A consistent snapshot of the simulated robot."""

    t_ns: int
    pose: Pose
    v: float                 # body linear velocity, m/s
    w: float                 # body yaw rate, rad/s
    accel: float             # longitudinal acceleration over the last step, m/s^2
    wheel_speed: tuple[float, float]   # rad/s, positive = forward
    wheel_angle: tuple[float, float]   # rad, continuous
    collisions: int
    in_contact: bool
    slip: tuple[float, float] = (0.0, 0.0)   # m/s, rim speed - ground speed of each contact
    enabled: bool = True                     # the amplifiers' enable (heartbeat and e-stop)


def _rect(xmin: float, ymin: float, xmax: float, ymax: float) -> list[tuple[float, ...]]:
    return [(xmin, ymin, xmax, ymin), (xmax, ymin, xmax, ymax),
            (xmax, ymax, xmin, ymax), (xmin, ymax, xmin, ymin)]


_WALLS_WHAT = 'a list of [x1, y1, x2, y2] segments or {rectangle: [xmin, ymin, xmax, ymax]}'
_SEGMENT = Field('float[]', REQUIRED, length=4, expect='[x1, y1, x2, y2] (4 finite numbers)')
_RECTANGLE = Field('float[]', REQUIRED, length=4,
                   expect='[xmin, ymin, xmax, ymax] (4 finite numbers)')


def _walls(v: Any, where: str) -> tuple[tuple[float, ...], ...]:
    """Return the segments of a validated ``walls`` value (a list, or a rectangle)."""
    if isinstance(v, dict):
        check_keys(v, ['rectangle'], where, WorldConfigError)
        if 'rectangle' not in v:
            raise WorldConfigError(f'{where}.rectangle', 'missing')
        return tuple(_rect(*_RECTANGLE.validate(f'{where}.rectangle', v['rectangle'],
                                                WorldConfigError)))
    return tuple(tuple(_SEGMENT.validate(f'{where}[{i}]', s, WorldConfigError))
                 for i, s in enumerate(v))


def _obstacles(v: Any, where: str) -> dict[str, Any]:
    polys, surfaces, paths = [], [], []
    for i, entry in enumerate(v or []):
        try:
            poly, surface, path = parse_obstacle(entry, f'{where}[{i}]')
        except SceneError as exc:
            raise WorldConfigError(str(exc)) from None
        polys.append(poly)
        surfaces.append(surface)
        paths.append(path)
    return {'obstacles': tuple(polys), 'surfaces': tuple(surfaces), 'paths': tuple(paths)}


def _events(v: Any, where: str) -> dict[str, Any]:
    try:
        return {'events': parse_events(v, where)}
    except SceneError as exc:
        raise WorldConfigError(str(exc)) from None


def _floor(v: Any, where: str) -> dict[str, Any]:
    try:
        return {'floor': parse_floor(v, where)}
    except FloorError as exc:
        raise WorldConfigError(str(exc)) from None


def _faults(v: Any, where: str) -> dict[str, Any]:
    try:
        return {'faults': parse_faults(v, where)}
    except FaultError as exc:
        raise WorldConfigError(str(exc)) from None


# Paper Fig. 8: a room of white panel boards, the robot at the start, a triangular obstacle
# about 1.5 m ahead (its flat side faces the robot) and a goal 3 m ahead.
_ROOM = [-0.8, -1.5, 4.2, 1.5]
DEFAULT_OBSTACLE = ((1.5, -0.25), (1.5, 0.25), (1.9, 0.0))
DEFAULT_WALLS = tuple(_rect(*_ROOM))


@dataclass(frozen=True)
class WorldConfig:
    """Room walls (segments x1,y1,x2,y2), obstacle polygons, start pose, robot, seed.

    Each key of the ``world:`` section is declared once, on its field (schema Fields: type,
    default, unit, range, what it does); :meth:`from_dict` validates with them. ``walls`` and
    ``obstacles`` hold the parsed shapes (segments, polygons) of what the file writes.
    """

    walls: tuple[tuple[float, ...], ...] = setting(Field(
        'list|map', {'rectangle': _ROOM}, 'The room: wall segments [[x1, y1, x2, y2], ...] or '
        '{rectangle: [xmin, ymin, xmax, ymax]} (default: the 5 x 3 m room of the paper, Fig. '
        '8). The laser, sonar and the contact test see them.', unit='m', nullable=True,
        expect=_WALLS_WHAT), value=DEFAULT_WALLS)
    obstacles: tuple[tuple[tuple[float, float], ...], ...] = setting(Field(
        'list', [[list(p) for p in DEFAULT_OBSTACLE]], 'Obstacles: each a polygon [[x, y], ...] '
        '(tall, normal, still) or a mapping (world.obstacles[]: height, surface, path). '
        "Default: the paper's triangle 1.5 m ahead; null or []: none.", unit='m',
        nullable=True, expect='a list of obstacles'), value=(DEFAULT_OBSTACLE,))
    start: Pose = setting(Field(
        'float[]', [0.0, 0.0, 0.0], 'Start pose [x m, y m, yaw rad] in the world frame; '
        'odometry starts at zero here. A footprint overlapping a wall or an obstacle is '
        'refused.', length=3), value=Pose(0.0, 0.0, 0.0))
    robot: RobotParams = section(RobotParams)
    seed: int = setting(Field(
        'int', 0, 'Seed of every noise stream (each device its own, from the seed and its '
        'name): the same seed, the same run.', expect='an integer'))
    step_s: float = setting(Field(
        'float', 0.001, 'Fixed physics step; results do not depend on how often callers look. '
        'Larger: faster but coarser contacts and motor dynamics.', unit='s', lo=1e-5, hi=0.05))
    # Parallel to ``obstacles`` (empty: every obstacle tall, normal and still; m4k_drivers.scene)
    surfaces: tuple[Surface, ...] = derived(())
    paths: tuple[Path | None, ...] = derived(())
    events: tuple[Event, ...] = setting(Field(
        'list', [], 'Changes of the simulated hardware during the drive (world.events[]).',
        nullable=True, expect='a list of {at: ..., unplug: ...}'), value=())
    faults: tuple[Fault, ...] = setting(Field(
        'list', [], 'Faults scheduled from the world start (world.faults[]).',
        nullable=True, expect='a list of faults'), value=())
    floor: tuple[Patch, ...] = setting(Field(
        'list', [], 'Floor patches with their own tyre friction, e.g. a wet patch under one '
        'wheel (world.floor[]: rectangle, mu, mu_kinetic; m4k_drivers.floor).',
        nullable=True, expect='a list of {rectangle: [...], mu: ...}'), value=())

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None, where: str = 'world',
                  robot: RobotParams | None = None) -> WorldConfig:
        """Build from the YAML ``world:`` section, naming the bad field on error.

        ``robot`` is the base the ``robot:`` keys override (default: the paper's M4K).
        """
        if data is None:
            data = {}
        if not isinstance(data, Mapping):
            raise WorldConfigError(where, f'expected a mapping, got {data!r}')
        check_keys(data, WORLD, where, WorldConfigError)
        cfg = cls() if robot is None else cls(robot=robot)
        kw: dict[str, Any] = {}
        for key, value in data.items():
            path = f'{where}.{key}'
            if key == 'robot':
                kw['robot'] = parse_robot(value, cfg.robot, path, WorldConfigError)
                continue
            value = WORLD[key].validate(path, value, WorldConfigError)
            if value is None and key == 'walls':
                continue                     # null: the default room
            if key in _CONVERT:
                kw.update(_CONVERT[key](value, path))
            else:
                kw[key] = Pose(*value) if key == 'start' else value
        return replace(cfg, **kw)


# The keys of ``world:``, derived from the declaration above (world.robot: ROBOT_FIELDS).
WORLD: dict[str, Field] = {k: f for k, f in table(WorldConfig).items() if '.' not in k}
WORLD['robot'] = Field('map', {}, 'The simulated robot as built (world.robot); unset keys: '
                       "the configuration's values.")
_CONVERT = {'walls': lambda v, where: {'walls': _walls(v, where)},
            'obstacles': _obstacles, 'events': _events, 'faults': _faults, 'floor': _floor}


def _cross(ax: Any, ay: Any, bx: Any, by: Any) -> Any:
    return ax * by - ay * bx


def segments_touch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return which segments of ``a`` (N x 4) touch which of ``b`` (M x 4): an N x M mask.

    Each of the two must straddle the other's line; collinear segments give all four crosses
    zero and touch only where their extents overlap (a leg's side in line with a wheel's,
    metres apart, is no contact). The simulator's contact test and the scenario judge's
    clearance both take this one test.
    """
    p, q = a[:, None, :], b[None, :, :]
    d1 = _cross(p[..., 2] - p[..., 0], p[..., 3] - p[..., 1], q[..., 0] - p[..., 0],
                q[..., 1] - p[..., 1])
    d2 = _cross(p[..., 2] - p[..., 0], p[..., 3] - p[..., 1], q[..., 2] - p[..., 0],
                q[..., 3] - p[..., 1])
    d3 = _cross(q[..., 2] - q[..., 0], q[..., 3] - q[..., 1], p[..., 0] - q[..., 0],
                p[..., 1] - q[..., 1])
    d4 = _cross(q[..., 2] - q[..., 0], q[..., 3] - q[..., 1], p[..., 2] - q[..., 0],
                p[..., 3] - q[..., 1])
    overlap = ((np.maximum(p[..., 0], p[..., 2]) >= np.minimum(q[..., 0], q[..., 2]))
               & (np.maximum(q[..., 0], q[..., 2]) >= np.minimum(p[..., 0], p[..., 2]))
               & (np.maximum(p[..., 1], p[..., 3]) >= np.minimum(q[..., 1], q[..., 3]))
               & (np.maximum(q[..., 1], q[..., 3]) >= np.minimum(p[..., 1], p[..., 3])))
    return np.asarray((d1 * d2 <= 0) & (d3 * d4 <= 0) & overlap)


def inside(poly: np.ndarray, x: float, y: float) -> bool:
    """Return True when (x, y) lies inside the simple polygon ``poly`` (even-odd rule)."""
    result = False
    n = len(poly)
    for i in range(n):
        x1, y1 = poly[i]
        x2, y2 = poly[(i + 1) % n]
        if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
            result = not result
    return result


def point_seg(px: float | np.ndarray, py: float | np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Return the distance of a point, or of P points, (px, py) to each segment.

    ``seg`` is S x 4 (rows x1, y1, x2, y2); the result has shape S for one point, P x S for P.
    The simulator's and the scenario judge's (m4k_bench.scenarios.geometry), written once.
    """
    qx = np.asarray(px, dtype=float)[..., None] - seg[:, 0]
    qy = np.asarray(py, dtype=float)[..., None] - seg[:, 1]
    bx, by = seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]
    ll = bx * bx + by * by
    with np.errstate(divide='ignore', invalid='ignore'):
        u = np.clip(np.where(ll > 0, (qx * bx + qy * by) / ll, 0.0), 0.0, 1.0)
    return np.asarray(np.hypot(qx - u * bx, qy - u * by))


SURFACE_CODES = {'normal': 0, 'soft': 1, 'glass': 2, 'black': 3}


class World:
    """Thread-safe simulated room + robot, advanced lazily to the caller's monotonic time."""

    def __init__(self, config: WorldConfig | None = None, *,
                 clock: Callable[[], int] = time.monotonic_ns, t0_ns: int | None = None) -> None:
        self.config = config or WorldConfig()
        self.robot = self.config.robot
        r = self.robot
        self._outline = np.array(outline(r.length_m, r.width_m, r.track_width_m,
                                         r.wheel_radius_m, r.wheel_width_m))
        self.clock = clock
        self._lock = threading.RLock()
        segs = [tuple(s) for s in self.config.walls]
        height, kind = [math.inf] * len(segs), [0] * len(segs)
        self._moving: list[tuple[int, list[int], Path]] = []
        surfaces = self.config.surfaces or (Surface(),) * len(self.config.obstacles)
        paths = self.config.paths or (None,) * len(self.config.obstacles)
        for i, poly in enumerate(self.config.obstacles):
            rows = list(range(len(segs), len(segs) + len(poly)))
            segs += [(*poly[i], *poly[(i + 1) % len(poly)]) for i in range(len(poly))]
            height += [surfaces[i].height] * len(poly)
            kind += [SURFACE_CODES[surfaces[i].kind]] * len(poly)
            path = paths[i]
            if path is not None:
                self._moving.append((i, rows, path))
        self._seg0 = np.array(segs, dtype=float).reshape(-1, 4)   # the outlines at rest
        self._seg = self._seg0.copy()                             # where they are now
        self._seg_height = np.array(height, dtype=float)
        self._seg_kind = np.array(kind, dtype=np.int64)
        self._poly0 = [np.array(p, dtype=float).reshape(-1, 2) for p in self.config.obstacles]
        self._polys = list(self._poly0)
        self._offsets = [(0.0, 0.0)] * len(self.config.obstacles)
        self._path_t0: dict[int, int] = {}     # obstacle index -> world ns its path started
        self.travelled = 0.0                   # m the robot truly covered (path length)
        # world ns the robot first moved: 5 mm of its path, or as much at its wheels' rim
        # turning in place (a turn travels nowhere)
        self._moving_since: int | None = None
        self._turned = 0.0                     # rad the body truly turned (either way)
        self.events_due: list[Event] = []      # events whose moment came (sim_robot takes them)
        self._events = list(self.config.events)
        self.min_clearance = math.inf          # smallest footprint clearance seen (checked 5 ms)
        self._clear_every = max(1, round(0.005 / self.config.step_s))
        self._steps = 0
        self._step_ns = round(self.config.step_s * 1e9)
        self._t_ns = clock() if t0_ns is None else t0_ns
        self.rest_since_ns: int | None = self._t_ns   # since when |v| < REST_V (None: moving)
        self._pose = self.config.start
        # the sloping floor patches, once: the 1 ms step asks for the grade only on these
        self._slopes = tuple(p for p in self.config.floor if p.grade)
        self._drive = DriveState()
        self._wheel_speed = self._drive.wheel          # the same list: rad/s per wheel
        self._wheel_angle = [0.0, 0.0]
        # The wheels' recent past, one entry per step (t_ns, angle and speed of each wheel),
        # newest last: an encoder latches its angle when its read starts (an AS5045 at CSn's
        # falling edge), which a simulator short of CPU handles later, after the world moved on.
        self._past: deque[tuple[int, float, float, float, float]] = deque(
            maxlen=max(2, round(WHEEL_HISTORY_S / self.config.step_s)))
        self._volts = [0.0, 0.0]
        self._enable_until_ns: int | None = None
        self._estop_open = False          # set by tests or a tool (set_estop_open)
        self._start_ns = self._t_ns
        # Faults: (kind, side) -> the wheel angles at its onset; scheduled ones from the
        # config, forced ones from set_fault (tests).
        self._faults: dict[tuple[str, int], tuple[float, float]] = {}
        self._forced: set[tuple[str, int]] = set()
        # per config.faults entry, the world time a ``start`` fault began (None: not yet)
        self._fault_onsets: list[float | None] = [None] * len(self.config.faults)
        self._estop_scheduled = False
        self._v = 0.0
        self._w = 0.0
        self._accel = 0.0
        # Ground-truth peaks of the longitudinal motion (contact steps excluded: a wall is
        # not braking), m/s^2 and m/s.
        self.peak_decel = 0.0
        self.peak_accel = 0.0
        self.peak_speed = 0.0
        self.peak_slip = 0.0
        self.collisions = 0
        self.in_contact = False
        self._contact_pose: Pose | None = None     # where the last contact happened
        self.min_clearance = self.clearance(self._pose)
        if self.collides(self._pose):
            raise WorldConfigError(f'world.start: the robot footprint at {tuple(self._pose)!r} '
                                   'overlaps a wall or an obstacle')

    # -- randomness -----------------------------------------------------------------------
    def rng(self, stream: str) -> np.random.Generator:
        """Return a generator seeded from the world seed and ``stream`` (reproducible)."""
        return np.random.default_rng([self.config.seed & 0xFFFFFFFF,
                                      zlib.crc32(stream.encode())])

    # -- time -----------------------------------------------------------------------------
    @property
    def t_ns(self) -> int:
        """Return the simulated time (monotonic ns) up to which the world has been advanced."""
        return self._t_ns

    def now(self) -> int:
        """Advance to the clock's current time and return it."""
        t = self.clock()
        self.advance_to(t)
        return t

    def advance_to(self, t_ns: int) -> None:
        """Integrate the dynamics in fixed steps up to ``t_ns`` (earlier times are a no-op)."""
        with self._lock:
            while self._t_ns + self._step_ns <= t_ns:
                self._past.append((self._t_ns, self._wheel_angle[0], self._wheel_angle[1],
                                   self._wheel_speed[0], self._wheel_speed[1]))
                self._step(self._step_ns * 1e-9)
                self._t_ns += self._step_ns

    # -- actuation ------------------------------------------------------------------------
    def set_motor_voltage(self, side: int, volts: float) -> None:
        """Set the armature voltage of one motor (clamped to the supply; NaN -> 0)."""
        if side not in (LEFT, RIGHT):
            raise ValueError(f'side must be LEFT (0) or RIGHT (1), got {side!r}')
        sup = self.robot.supply_v
        v = 0.0 if not math.isfinite(volts) else max(-sup, min(sup, float(volts)))
        with self._lock:
            self._volts[side] = v

    def set_enable_until(self, t_ns: int | None) -> None:
        """Keep the heartbeat's enable on until ``t_ns`` (None: always on, no heartbeat)."""
        with self._lock:
            self._enable_until_ns = t_ns

    def set_estop_open(self, is_open: bool) -> None:
        """Open (True) or close the e-stop contact in series with the amplifier enable."""
        with self._lock:
            self._estop_open = bool(is_open)

    @property
    def estop_open(self) -> bool:
        """Return True while the e-stop contact is open (pressed, or an ``estop`` fault)."""
        return self._estop_open or self._estop_scheduled

    # -- faults (m4k_drivers.faults) ------------------------------------------------------
    def set_fault(self, kind: str, wheel: str | int = 'both', active: bool = True) -> None:
        """Force a fault on or off now (tests); ``wheel``: left, right, both or 0/1."""
        if kind not in KINDS:
            raise ValueError(f'fault kind must be one of {", ".join(KINDS)}, got {kind!r}')
        sides = {'left': (LEFT,), 'right': (RIGHT,), 'both': (LEFT, RIGHT), LEFT: (LEFT,),
                 RIGHT: (RIGHT,)}.get(wheel)
        if sides is None:
            raise ValueError(f'wheel must be left, right, both, 0 or 1, got {wheel!r}')
        self.now()
        with self._lock:
            for side in sides:
                key = (kind, side)
                if active:
                    self._forced.add(key)
                else:
                    self._forced.discard(key)
            self._update_faults()

    def active_faults(self) -> list[dict[str, Any]]:
        """Return the faults on now: [{kind, wheel}] (wheel: left/right)."""
        with self._lock:
            return [{'kind': k, 'wheel': ('left', 'right')[side]}
                    for k, side in sorted(self._faults)]

    def _update_faults(self) -> None:
        t_s = (self._t_ns - self._start_ns) * 1e-9
        want = set(self._forced)
        onsets = self._fault_onsets
        for i, f in enumerate(self.config.faults):
            if f.start is not None and onsets[i] is None and \
                    f.start.reached(self.travelled, self._moving_s()):
                onsets[i] = t_s               # a moment of the drive: noted once
            if f.active(t_s, onsets[i]):
                want.update((f.kind, side) for side in f.sides)
        if want == set(self._faults):
            return
        for key in set(self._faults) - want:
            del self._faults[key]
        angles = (self._wheel_angle[LEFT], self._wheel_angle[RIGHT])
        for key in want - set(self._faults):
            self._faults[key] = angles            # onset: the readings continue from here
        self._estop_scheduled = any(k == 'estop' for k, _ in self._faults)
        for side in (LEFT, RIGHT):
            self._drive.blocked[side] = ('wheel_stall', side) in self._faults

    def encoder_angle(self, side: int, t_ns: int | None = None) -> tuple[float, bool]:
        """Return (the angle one wheel's encoder reports at ``t_ns``, frozen?) under faults.

        Without a fault it is the wheel's angle. Frozen: the reading of the onset, always the
        same (the caller adds no noise). The faults compose in the wiring's order: the swap
        (cables) picks the shaft, the flip and the freeze act on what that encoder reads.
        """
        t = self.clock() if t_ns is None else t_ns
        own = self.wheel_angle_at(side, t)
        with self._lock:
            if not self._faults:
                return own, False
            other = 1 - side
            angle = own
            onset = self._faults.get(('encoder_swap', side))
            if onset is not None:    # the other shaft's motion since the swap, from here on
                angle = onset[side] + self.wheel_angle_at(other, t) - onset[other]
            onset = self._faults.get(('encoder_sign_flip', side))
            if onset is not None:
                angle = 2.0 * onset[side] - angle
            onset = self._faults.get(('encoder_frozen', side))
            if onset is not None:
                return onset[side], True
            return angle, False

    def heartbeat_enabled(self, t_ns: int | None = None) -> bool:
        """Return the heartbeat monostable's output at ``t_ns`` (before the e-stop contact)."""
        with self._lock:
            until = self._enable_until_ns
            return until is None or (self._t_ns if t_ns is None else t_ns) < until

    def drive_enabled(self, t_ns: int | None = None) -> bool:
        """Return True when the amplifiers are enabled at ``t_ns`` (default: world time).

        The enable line after the e-stop contact: the heartbeat's output, cut while the
        contact is open.
        """
        with self._lock:
            return not self.estop_open and self.heartbeat_enabled(t_ns)

    def motor_voltage(self, side: int) -> float:
        """Return the armature voltage last set for one motor."""
        with self._lock:
            return self._volts[side]

    # -- dynamics -------------------------------------------------------------------------
    def _step(self, dt: float) -> None:
        self._steps += 1
        if self._moving or self._events:
            self._scene_step()
        if self.config.faults or self._forced or self._faults:
            self._update_faults()
        rob = self.robot
        drv = self._drive
        enabled = self.drive_enabled()
        idle = not enabled or (rob.effective_volts(LEFT, self._volts[0]) == 0.0
                               and rob.effective_volts(RIGHT, self._volts[1]) == 0.0)
        pose = self._pose
        grade = (grade_force(self._slopes, pose.x, pose.y, pose.yaw, rob.mass_kg * G)
                 if self._slopes else 0.0)
        if (idle and grade == 0.0 and drv.v == 0.0 and drv.w == 0.0 and drv.wheel[0] == 0.0
                and drv.wheel[1] == 0.0):
            self._accel = 0.0
            if self.rest_since_ns is None:
                self.rest_since_ns = self._t_ns
            if self._moving:       # a moving obstacle may walk into the robot at rest
                hit = self.collides(self._pose)
                if hit and not self.in_contact:
                    self.collisions += 1
                if hit:
                    self.min_clearance = 0.0
                self.in_contact = hit
                if self._steps % self._clear_every == 0:
                    self._track_clearance()
            return
        old_wheel = list(drv.wheel)
        v_old, w_old = drv.v, drv.w
        mu = None
        if self.config.floor:
            mu = wheel_mu(self.config.floor, pose.x, pose.y, pose.yaw, rob.track_width_m / 2.0,
                          rob.mu, rob.mu_kinetic)
        step_drive(rob, drv, (self._volts[0], self._volts[1]), enabled, dt, mu, grade)
        v = 0.5 * (v_old + drv.v)
        w = 0.5 * (w_old + drv.w)
        x, y, th = self._pose
        if abs(w) < 1e-12:
            cand = Pose(x + v * dt * math.cos(th), y + v * dt * math.sin(th), th)
        else:
            th2 = th + w * dt
            cand = Pose(x + v / w * (math.sin(th2) - math.sin(th)),
                        y - v / w * (math.cos(th2) - math.cos(th)),
                        math.atan2(math.sin(th2), math.cos(th2)))
        if self.collides(cand):
            if not self.in_contact:
                self.collisions += 1
            self.in_contact = True
            self._contact_pose = self._pose
            self.min_clearance = 0.0      # touching: the step into the surface is not taken
            drv.wheel[0] = drv.wheel[1] = 0.0
            drv.v = drv.w = 0.0
            drv.slipping[0] = drv.slipping[1] = False
            self._v = self._w = 0.0
            self._accel = (self._v - v_old) / dt
        else:
            # A drive pushing against the surface nudges the robot into it again and again:
            # one contact until the robot has moved clear of where it touched (1 mm).
            cp = self._contact_pose
            self.in_contact = cp is not None and math.hypot(cand.x - cp.x, cand.y - cp.y) < 1e-3
            if not self.in_contact:
                self._contact_pose = None
            self.travelled += math.hypot(cand.x - self._pose.x, cand.y - self._pose.y)
            if self._moving_since is None:
                self._turned += abs(math.remainder(cand.yaw - self._pose.yaw, 2.0 * math.pi))
                if self.travelled > 0.005 or \
                        self._turned * self.robot.track_width_m / 2.0 > 0.005:
                    self._moving_since = self._t_ns
            self._pose = cand
            self._wheel_angle[0] += 0.5 * (old_wheel[0] + drv.wheel[0]) * dt
            self._wheel_angle[1] += 0.5 * (old_wheel[1] + drv.wheel[1]) * dt
            self._v, self._w = drv.v, drv.w
            self._accel = (self._v - v_old) / dt
            # Deceleration: the speed's magnitude shrinking (a reversal counts up to zero).
            if v_old > 0.0:
                decel = (v_old - max(self._v, 0.0)) / dt
            elif v_old < 0.0:
                decel = (min(self._v, 0.0) - v_old) / dt
            else:
                decel = 0.0
            self.peak_decel = max(self.peak_decel, decel)
            self.peak_accel = max(self.peak_accel, abs(self._accel) if decel <= 0.0 else 0.0)
            self.peak_speed = max(self.peak_speed, abs(self._v))
            s = rob.track_width_m / 2.0
            for i in (LEFT, RIGHT):
                self.peak_slip = max(self.peak_slip, abs(self._slip(i, s)))
        if abs(self._v) >= REST_V:
            self.rest_since_ns = None
        elif self.rest_since_ns is None:
            self.rest_since_ns = self._t_ns + self._step_ns    # at rest from the step's end
        if self._steps % self._clear_every == 0:
            self._track_clearance()

    def _slip(self, side: int, half_track: float) -> float:
        drv = self._drive
        return drv.wheel[side] * self.robot.wheel_radius_m - drv.contact_speed(side, half_track)

    # -- the scene: moving obstacles, events, clearance ----------------------------------
    def _moving_s(self) -> float | None:
        return None if self._moving_since is None else (self._t_ns - self._moving_since) * 1e-9

    def _scene_step(self) -> None:
        moving_s = self._moving_s()
        for i, rows, path in self._moving:
            t0 = self._path_t0.get(i)
            if t0 is None:
                if not path.start.reached(self.travelled, moving_s):
                    continue
                t0 = self._path_t0[i] = self._t_ns
            dx, dy = path.offset((self._t_ns - t0) * 1e-9)
            if (dx, dy) == self._offsets[i]:
                continue                 # standing (before its first or after its last point)
            self._offsets[i] = (dx, dy)
            self._seg[rows] = self._seg0[rows] + (dx, dy, dx, dy)
            self._polys[i] = self._poly0[i] + (dx, dy)
        if self._events:
            due = [e for e in self._events if e.at.reached(self.travelled, moving_s)]
            for e in due:
                self._events.remove(e)
                self.events_due.append(e)

    def take_events(self) -> list[Event]:
        """Return (and forget) the events whose moment has come."""
        with self._lock:
            out, self.events_due = self.events_due, []
            return out

    def obstacle_offsets(self) -> list[tuple[float, float]]:
        """Return each obstacle's present offset from its outline at rest."""
        with self._lock:
            return list(self._offsets)

    def _track_clearance(self) -> None:
        c = self.clearance(self._pose)
        if c < self.min_clearance:
            self.min_clearance = c

    def front_clearance(self, pose: Pose, max_range: float = 10.0) -> float:
        """Return how far ahead of the footprint's front face the nearest surface is (any surface).

        Rays along the heading from five points across the outline's width (body and wheels)
        at the front face: what a guard would have to see, whatever the sensors make of it.
        """
        hl, hw = self.robot.length_m / 2.0, float(self._outline[:, 1].max())
        c, s = math.cos(pose.yaw), math.sin(pose.yaw)
        best = math.inf
        with self._lock:
            for k in np.linspace(-hw, hw, 5):
                o = (pose.x + c * hl - s * k, pose.y + s * hl + c * k)
                best = min(best, float(self._cast(o, [pose.yaw], max_range, None)[0][0]))
        return best

    def clearance(self, pose: Pose) -> float:
        """Return the distance from the footprint at ``pose`` to the nearest surface (0: touch)."""
        if self.collides(pose):
            return 0.0
        corners = self.footprint(pose)
        seg = self._seg
        # corner -> segment and segment end -> footprint edge: the minimum of two segments'
        # distance when they do not cross.
        best = float(point_seg(corners[:, 0], corners[:, 1], seg).min())
        edges = np.hstack([corners, np.roll(corners, -1, axis=0)])
        ends = np.vstack([seg[:, :2], seg[:, 2:]])
        return min(best, float(point_seg(ends[:, 0], ends[:, 1], edges).min()))

    def footprint(self, pose: Pose) -> np.ndarray:
        """Return the robot's outline (Nx2, counter-clockwise) at ``pose``: body and wheels.

        The drive wheels stand outside the body (:mod:`m4k_rt.control.footprint`): a leg that
        clears the body's side but not a wheel is a contact.
        """
        c, s = math.cos(pose.yaw), math.sin(pose.yaw)
        return self._outline @ np.array([[c, s], [-s, c]]) + np.array([pose.x, pose.y])

    def collides(self, pose: Pose) -> bool:
        """Return True when the footprint at ``pose`` touches a wall or obstacle."""
        corners = self.footprint(pose)
        edges = np.hstack([corners, np.roll(corners, -1, axis=0)])   # N x (x1,y1,x2,y2)
        if np.any(segments_touch(edges, self._seg)):
            return True
        # An obstacle entirely inside the footprint crosses no edge: test one of its vertices.
        return any(inside(corners, poly[0][0], poly[0][1]) for poly in self._polys)

    # -- sensing --------------------------------------------------------------------------
    def state(self) -> RobotState:
        """Return a snapshot of the robot at the world's current simulated time."""
        with self._lock:
            s = self.robot.track_width_m / 2.0
            return RobotState(self._t_ns, self._pose, self._v, self._w, self._accel,
                              (self._wheel_speed[0], self._wheel_speed[1]),
                              (self._wheel_angle[0], self._wheel_angle[1]),
                              self.collisions, self.in_contact,
                              (self._slip(LEFT, s), self._slip(RIGHT, s)),
                              self.drive_enabled())

    def wheel_angle_at(self, side: int, t_ns: int | None = None) -> float:
        """Return one wheel's angle at ``t_ns`` (default: the clock's present), in rad.

        The dynamics move in whole steps, so the stepped state can be up to one step older
        than ``t_ns``; the angle is carried forward over that remainder at the wheel's present
        speed. An encoder read at ``t_ns`` and stamped ``t_ns`` must see the angle *of*
        ``t_ns``: a 1 ms stamp/angle mismatch is 10 % of a 10 ms speed difference. A ``t_ns``
        the world has already stepped past (up to WHEEL_HISTORY_S) is answered from the step
        it fell in.
        """
        if side not in (LEFT, RIGHT):
            raise ValueError(f'side must be LEFT (0) or RIGHT (1), got {side!r}')
        t = self.clock() if t_ns is None else t_ns
        with self._lock:
            self.advance_to(t)
            if t < self._t_ns and self._past:
                # Asked for a moment the world has already stepped past (a read handled
                # late): the angle of that moment, from the step it fell in (the oldest kept,
                # WHEEL_HISTORY_S back, for anything older).
                past = self._past
                i = len(past) - 1
                while i > 0 and past[i][0] > t:
                    i -= 1
                t0, a0, a1, w0, w1 = past[i]
                return (a0, a1)[side] + (w0, w1)[side] * max(t - t0, 0) * 1e-9
            ahead = max(t - self._t_ns, 0) * 1e-9
            return self._wheel_angle[side] + self._wheel_speed[side] * ahead

    def pose(self) -> Pose:
        """Advance to the clock's present and return the robot pose."""
        self.now()
        with self._lock:
            return self._pose

    def tilt(self, pose: Pose) -> tuple[float, float]:
        """Return base_link's (roll, pitch) in rad at ``pose``: the floor's slope under it."""
        return slope_tilt(self._slopes, pose.x, pose.y, pose.yaw) if self._slopes else (0.0, 0.0)

    def sensor_pose(self, mount: Sequence[float]) -> Pose:
        """Return the world pose of a sensor mounted at (x, y, yaw) in base_link."""
        x, y, th = self.pose()
        mx, my, myaw = mount
        c, s = math.cos(th), math.sin(th)
        return Pose(x + c * mx - s * my, y + s * mx + c * my, th + myaw)

    def _cast(self, origin: Sequence[float], angles: Any, max_range: float,
              seen: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """Return (distance, segment index or -1) of the nearest hit along each angle."""
        ang = np.atleast_1d(np.asarray(angles, dtype=float))
        seg = self._seg
        dx, dy = np.cos(ang)[:, None], np.sin(ang)[:, None]
        px, py = seg[None, :, 0] - origin[0], seg[None, :, 1] - origin[1]
        sx = seg[None, :, 2] - seg[None, :, 0]
        sy = seg[None, :, 3] - seg[None, :, 1]
        denom = _cross(dx, dy, sx, sy)
        with np.errstate(divide='ignore', invalid='ignore'):
            t = _cross(px, py, sx, sy) / denom
            u = _cross(px, py, dx, dy) / denom
        hit = (np.abs(denom) > 1e-12) & (t >= 0.0) & (u >= 0.0) & (u <= 1.0) & (t <= max_range)
        if seen is not None:
            hit &= seen[None, :]
        d = np.where(hit, t, np.inf)
        idx = d.argmin(axis=1)
        dist = d[np.arange(len(ang)), idx]
        return dist, np.where(np.isfinite(dist), idx, -1)

    def raycast_many(self, origin: Sequence[float], angles: Any,
                     max_range: float) -> np.ndarray:
        """Return the distance along each world-frame angle to the nearest surface (inf: none)."""
        return self._cast(origin, angles, max_range, None)[0]

    def laser_cast(self, origin: Sequence[float], angles: Any, max_range: float,
                   z: float) -> tuple[np.ndarray, np.ndarray]:
        """Return (distance, black) per ray of a laser plane at height ``z``.

        Glass is transparent to it and obstacles lower than ``z`` are under it; ``black`` marks
        the rays that end on a black surface (too little light back: an error code).
        """
        with self._lock:
            seen = (self._seg_height > z) & (self._seg_kind != SURFACE_CODES['glass'])
            dist, idx = self._cast(origin, angles, max_range, seen)
            black = (idx >= 0) & (self._seg_kind[np.maximum(idx, 0)] == SURFACE_CODES['black'])
        return dist, black

    def sonar_cast(self, origin: Sequence[float], angle: float, half_angle: float,
                   max_range: float, z: float, rays: int = 9) -> float:
        """Return the nearest echo in a sonar cone at height ``z`` (inf: no echo).

        A sonar's beam is a cone, not rays: the first echo is the nearest point of any surface
        inside the cone (``_cone_nearest``), a 3 cm leg wherever it stands in it (a fan of
        nine rays missed one between two of them). A soft surface is hit but sends nothing
        back, and hides what is behind it: where it is nearer along the bearing of that
        point, the fan of ``rays`` rays tells what the beam hears past it.
        """
        with self._lock:
            seen = self._seg_height > z
            soft = self._seg_kind == SURFACE_CODES['soft']
            dist, bearing = self._cone_nearest(origin, angle, half_angle, seen & ~soft)
            if not dist <= max_range:
                return math.inf
            if not (seen & soft).any():
                return dist
            d, idx = self._cast(origin, [bearing], max_range, seen)
            if not (idx[0] >= 0 and soft[idx[0]] and d[0] < dist - 1e-9):
                return dist
            fan = np.linspace(angle - half_angle, angle + half_angle, max(rays, 1))
            d, idx = self._cast(origin, fan, max_range, seen)
            muted = (idx >= 0) & soft[np.maximum(idx, 0)]
        return float(np.where(muted, np.inf, d).min())

    def _cone_nearest(self, origin: Sequence[float], angle: float, half_angle: float,
                      mask: np.ndarray) -> tuple[float, float]:
        """Return (distance, world bearing) of the nearest ``mask`` point inside a cone.

        The cone: half-angle ``half_angle`` (< 90 deg) about ``angle``; (inf, angle) when no
        segment reaches into it. Per segment p0 + t d, t in [0, 1]: the cone is the two
        half-planes cross(u_right, p) >= 0 and cross(p, u_left) >= 0, each linear in t, so
        the segment's part inside is one t interval; the distance is convex in t, so its
        least value there is the closest point to the origin clamped to that interval.
        """
        seg = self._seg[mask]
        if not len(seg):
            return math.inf, angle
        px, py = seg[:, 0] - origin[0], seg[:, 1] - origin[1]
        dx, dy = seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]
        lo = np.zeros(len(seg))
        hi = np.ones(len(seg))
        for ux, uy, sign in ((math.cos(angle - half_angle), math.sin(angle - half_angle), 1.0),
                             (math.cos(angle + half_angle), math.sin(angle + half_angle), -1.0)):
            a0 = sign * _cross(ux, uy, px, py)          # a0 + t a1 >= 0 inside this half-plane
            a1 = sign * _cross(ux, uy, dx, dy)
            with np.errstate(divide='ignore', invalid='ignore'):
                tt = -a0 / a1
            lo = np.where(a1 > 0.0, np.maximum(lo, tt), lo)
            hi = np.where(a1 < 0.0, np.minimum(hi, tt), hi)
            hi = np.where((a1 == 0.0) & (a0 < 0.0), -1.0, hi)   # parallel, outside
        dd = dx * dx + dy * dy
        with np.errstate(divide='ignore', invalid='ignore'):
            t = np.where(dd > 0.0, -(px * dx + py * dy) / dd, 0.0)
        t = np.clip(t, lo, np.maximum(lo, hi))
        qx, qy = px + t * dx, py + t * dy
        dist = np.where(lo <= hi, np.hypot(qx, qy), np.inf)
        k = int(dist.argmin())
        if not math.isfinite(dist[k]):
            return math.inf, angle
        return float(dist[k]), math.atan2(float(qy[k]), float(qx[k]))

    def raycast(self, origin: Sequence[float], angle: float, max_range: float) -> float:
        """Return the distance from ``origin`` along world ``angle`` to a surface (inf: none)."""
        return float(self.raycast_many(origin, [angle], max_range)[0])

    def cone_cast(self, origin: Sequence[float], angle: float, half_angle: float,
                  max_range: float, rays: int = 9) -> float:
        """Return the nearest surface inside a cone (a fan of ``rays`` rays), inf if none."""
        fan = np.linspace(angle - half_angle, angle + half_angle, max(rays, 1))
        return float(self.raycast_many(origin, fan, max_range).min())
