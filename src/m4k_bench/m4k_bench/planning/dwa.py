"""A costmap-free dynamic-window (DWA) local planner for the M4K base (pure: numpy, no ROS).

Each control period (``dt``, 50 ms as the paper's local planner) :meth:`DwaPlanner.plan`:

1. **Dynamic window.** Target velocities reachable within ``window_time`` from the measured
   velocity under the acceleration limits, intersected with the velocity limits; the measured
   velocity is the median of the last three odometry samples (odometry velocity spikes).
2. **Arcs.** ``v_samples`` x ``w_samples`` targets; each arc ramps from the measured velocity to
   its target at the acceleration limits (as the RT actuator's speed limiter does), then holds
   it, over ``horizon`` seconds, sampled every ``sim_step`` -- the ``base_local_planner``
   trajectory model of the paper's navigation stack. The target is what gets commanded.
3. **Admissibility.** The robot footprint (``length`` x ``width``, centred on ``base_link``) is
   checked against the obstacle points at every sample: an arc is rejected when any point
   comes closer than ``margin`` to the footprint (the footprint inflated by ``margin``, rounded
   corners). Already inside the margin (after noise or a close pass), only arcs that do not go
   closer than now are admitted, so the robot can always back out of a tight spot.
4. **Score** (lower is better): the arc's closest approach to the goal, heading error at the
   arc's end toward the goal (faded out near the goal), free path along the arc's curvature
   (a fixed-length probe, so crawling at an obstacle does not look safe), lack of clearance
   below ``clearance_ref``, speed below ``max_v``, and change of turn rate (against dithering).
5. **Goal.** Arcs faster than braking at ``goal_brake * acc_v`` to the goal allows (after
   ``latency`` seconds at the current speed) are not admitted; within ``goal_tolerance``
   (position only) the planner stops and latches ``GOAL_REACHED`` until a new goal is set --
   at half the tolerance, or anywhere inside it when the best arc is to stop.
6. **Stuck / recovery.** When the robot moved less than ``stuck_distance`` in ``stuck_time``
   seconds, or the best admissible arc has been "stand still" for ``stuck_time``, the planner
   rotates in place (``recovery_w``) away from the side with more nearby obstacle points, each
   step collision-checked, until it has turned at least ``recovery_min_angle`` and a forward
   arc is admissible again (or it has turned a full circle). If neither rotation direction is
   free it reports ``BLOCKED`` and stands still.

Poses are ``(x, y, yaw)`` in the odom frame; obstacle points an (N, 2) odom-frame array
(see :mod:`m4k_bench.planning.scan`).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, replace
import enum
import math
from typing import Any, Mapping, NamedTuple, Sequence

import numpy as np

from m4k_rt.schema import check_keys, ConfigError, Field, setting, table

__all__ = ['DWA', 'DwaConfig', 'DwaConfigError', 'DwaError', 'DwaInputError', 'DwaPlanner', 'Plan',
           'State', 'dynamic_window', 'footprint_clearance', 'rollout', 'sample_window']


class DwaError(ValueError):
    """Base of the planner's errors."""


class DwaConfigError(DwaError, ConfigError):
    """Raise for a bad planner parameter; the message names the field and the bad value."""


class DwaInputError(DwaError):
    """Raise for a bad pose, velocity, goal or point array handed to the planner."""


class State(enum.Enum):
    """What the planner is doing."""

    IDLE = 'idle'                   # no goal
    MOVING = 'moving'
    RECOVERING = 'recovering'       # rotating in place to get unstuck
    BLOCKED = 'blocked'             # no admissible motion at all: standing still
    GOAL_REACHED = 'goal_reached'


def _pos(default: float, unit: str, description: str, hi: float | None = None) -> Any:
    return setting(Field('float', default, description, unit=unit, lo=0, lo_open=True, hi=hi))


def _nonneg(default: float, unit: str, description: str) -> Any:
    return setting(Field('float', default, description, unit=unit, lo=0))


def _samples(default: int, description: str) -> Any:
    return setting(Field('int', default, description, lo=2, expect='an integer >= 2'))


@dataclass(frozen=True)
class DwaConfig:
    """Planner parameters (SI units: m, s, rad); defaults fit the M4K of the paper.

    Each field is declared once, by its schema Field (type, default, unit, range, what a wrong
    value does): the node's ``dwa.*`` parameters, their descriptors, the validation and the
    docs come from it. Construction validates (:data:`DWA`); the checks across fields are in
    :meth:`__post_init__`.
    """

    max_v: float = _pos(0.25, 'm/s', "Highest forward speed commanded (the paper's "
                        'experiments: 0.25; Table 2 top speed: 2).')
    min_v: float = setting(Field(
        'float', 0.0, "Lowest linear speed, within [-max_v, max_v]; 0 = never reverse (the "
        "paper's local planner).", unit='m/s'))
    max_w: float = _pos(1.0, 'rad/s', 'Highest turn rate commanded.')
    acc_v: float = _pos(0.37, 'm/s^2', 'Linear acceleration limit (Table 2: 0.37); too high: '
                        'arcs the robot cannot follow.')
    acc_w: float = _pos(1.85, 'rad/s^2', 'Angular acceleration limit (0.37 m/s^2 per wheel over '
                        'a 0.40 m track).')
    dt: float = _pos(0.05, 's', "Control period the planner assumes (the paper's 50 ms; keep "
                     '1/rate_hz).')
    window_time: float = _pos(0.5, 's', 'The dynamic window holds the velocities reachable '
                              'this soon.')
    horizon: float = _pos(2.0, 's', 'Arc simulation time; too short: sees obstacles late.')
    sim_step: float = _pos(0.1, 's', 'Time between collision-checked samples along an arc '
                           '(<= horizon).')
    v_samples: int = _samples(6, 'Linear velocity samples across the window.')
    w_samples: int = _samples(15, 'Angular velocity samples across the window.')
    length: float = _pos(0.45, 'm', 'Footprint along x (Table 2 body: 0.45).')
    width: float = _pos(0.28, 'm', 'Footprint along y (Table 2 body: 0.28).')
    margin: float = _nonneg(0.06, 'm', 'Footprint inflation: arcs closer to a scan point are '
                            'rejected.')
    clearance_ref: float = _nonneg(0.40, 'm', 'Clearance beyond which an arc is not penalised '
                                   '(> margin).')
    probe_length: float = _pos(1.2, 'm', "Path along each arc's curvature checked for free "
                               'room.')
    probe_step: float = _pos(0.1, 'm', 'Between free-path probe samples (a score, not the '
                             'safety check; <= probe_length).')
    probe_min_v: float = _pos(0.05, 'm/s', "Slower arcs are probed with this speed's "
                              'curvature.')
    goal_weight: float = _nonneg(1.0, '', 'Cost weight: closest approach of an arc to the goal.')
    free_weight: float = _nonneg(1.0, '', "Cost weight: lack of free path along the arc's "
                                 'curvature.')
    heading_weight: float = _nonneg(0.4, '', 'Cost weight: heading error toward the goal at the '
                                    "arc's end.")
    clearance_weight: float = _nonneg(1.2, '', 'Cost weight: clearance below clearance_ref.')
    velocity_weight: float = _nonneg(0.25, '', 'Cost weight: speed below max_v.')
    smooth_weight: float = _nonneg(0.05, '', 'Cost weight: change of turn rate (against '
                                   'dithering).')
    goal_tolerance: float = _pos(0.05, 'm', 'Position tolerance at the goal.')
    goal_brake: float = _pos(0.5, '', 'Fraction of acc_v planned for braking to the goal; '
                             'high: overshoot.', hi=1.0)
    latency: float = _nonneg(0.2, 's', 'From command to motion (period, ramp, motor, '
                             'odometry), used when braking for the goal; low: overshoot.')
    stuck_time: float = _pos(4.0, 's', 'Without progress (or standing still) this long, the '
                             'rotate recovery starts.')
    stuck_distance: float = _nonneg(0.04, 'm', 'Motion within stuck_time that counts as '
                                    'progress.')
    recovery_w: float = _pos(0.6, 'rad/s', 'Rotate-in-place speed of the recovery (<= max_w).')
    recovery_min_angle: float = _nonneg(0.6, 'rad', 'Turned before the recovery may end.')
    crop_extra: float = _nonneg(0.1, 'm', 'Beyond the reach of any arc, where scan points '
                                'still matter.')

    def __post_init__(self) -> None:
        for name, f in DWA.items():
            f.validate(name, getattr(self, name), DwaConfigError)
        if not -self.max_v <= self.min_v <= self.max_v:
            raise DwaConfigError('min_v', f'must be within [-max_v, max_v] '
                                 f'({-self.max_v!r}..{self.max_v!r}), got {self.min_v!r}')
        if self.sim_step > self.horizon:
            raise DwaConfigError('sim_step', f'must be <= horizon ({self.horizon!r}), got '
                                 f'{self.sim_step!r}')
        if self.probe_step > self.probe_length:
            raise DwaConfigError('probe_step', f'must be <= probe_length '
                                 f'({self.probe_length!r}), got {self.probe_step!r}')
        if self.clearance_ref <= self.margin:
            raise DwaConfigError('clearance_ref', f'must be > margin ({self.margin!r}), got '
                                 f'{self.clearance_ref!r}')
        if self.recovery_w > self.max_w:
            raise DwaConfigError('recovery_w', f'must be <= max_w ({self.max_w!r}), got '
                                 f'{self.recovery_w!r}')

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any] | None, path: str = 'dwa') -> DwaConfig:
        """Build from a mapping (e.g. a YAML section), naming an unknown field on error."""
        data = dict(data or {})
        check_keys(data, DWA, path, DwaConfigError)
        return replace(cls(), **data)


# The planner's table, derived from the declaration above (node parameters, docs).
DWA: dict[str, Field] = table(DwaConfig)


class Plan(NamedTuple):
    """One planning step's result."""

    v: float                        # m/s command
    w: float                        # rad/s command
    state: State
    goal_distance: float            # m from the current pose to the goal (nan without goal)
    clearance: float                # m, min footprint clearance along the chosen arc
    admissible: int                 # arcs that passed the collision check
    candidates: int                 # arcs evaluated
    arc: np.ndarray                 # (N + 1, 3) poses of the chosen arc (for display)


def _wrap(angle: Any) -> Any:
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


def dynamic_window(v: float, w: float, cfg: DwaConfig) -> tuple[float, float, float, float]:
    """Return (v_lo, v_hi, w_lo, w_hi): velocities reachable within ``cfg.window_time``."""
    dv, dw = cfg.acc_v * cfg.window_time, cfg.acc_w * cfg.window_time
    v_lo, v_hi = max(cfg.min_v, v - dv), min(cfg.max_v, v + dv)
    w_lo, w_hi = max(-cfg.max_w, w - dw), min(cfg.max_w, w + dw)
    # A current velocity outside the limits (e.g. pushed, or limits just lowered): the window
    # is the reachable edge of the limits.
    if v_lo > v_hi:
        v_lo = v_hi = cfg.max_v if v > cfg.max_v else cfg.min_v
    if w_lo > w_hi:
        w_lo = w_hi = cfg.max_w if w > cfg.max_w else -cfg.max_w
    return v_lo, v_hi, w_lo, w_hi


def sample_window(window: Sequence[float], cfg: DwaConfig) -> np.ndarray:
    """Return (C, 2) velocity samples spanning the window, including (0, 0)-ward edges."""
    v_lo, v_hi, w_lo, w_hi = window
    vs = np.linspace(v_lo, v_hi, cfg.v_samples)
    ws = np.linspace(w_lo, w_hi, cfg.w_samples)
    # Exact straight-ahead and stop are worth having: they are what a tie should pick.
    if w_lo < 0.0 < w_hi:
        ws = np.union1d(ws, [0.0])
    if v_lo < 0.0 < v_hi:
        vs = np.union1d(vs, [0.0])
    vv, ww = np.meshgrid(np.unique(vs), np.unique(ws), indexing='ij')
    return np.column_stack((vv.ravel(), ww.ravel()))


def rollout(pose: Sequence[float], targets: np.ndarray, horizon: float, step: float,
            start: Sequence[float] | None = None,
            acc: Sequence[float] = (math.inf, math.inf)) -> np.ndarray:
    """Return (C, N + 1, 3) poses driving toward each (v, w) target; sample 0 is ``pose``.

    From the ``start`` velocity (default: already at the target) the velocities ramp to the
    target at the ``acc`` (linear, angular) limits, as the actuator's speed limiter does, then
    stay constant. Each step is integrated exactly along the arc of its mean velocities.
    """
    x0, y0, th0 = (float(p) for p in pose)
    n = max(1, round(horizon / step))
    h = horizon / n
    t = np.arange(n + 1) * h
    tv = targets[:, 0:1]
    tw = targets[:, 1:2]
    if start is None:
        v = np.broadcast_to(tv, (len(targets), n + 1))
        w = np.broadcast_to(tw, (len(targets), n + 1))
    else:
        v0, w0 = float(start[0]), float(start[1])
        v = v0 + np.clip(tv - v0, -acc[0] * t, acc[0] * t)
        w = w0 + np.clip(tw - w0, -acc[1] * t, acc[1] * t)
    vm = 0.5 * (v[:, :-1] + v[:, 1:])
    wm = 0.5 * (w[:, :-1] + w[:, 1:])
    th = np.concatenate((np.full((len(targets), 1), th0),
                         th0 + np.cumsum(wm * h, axis=1)), axis=1)
    straight = np.abs(wm) < 1e-9
    w_safe = np.where(straight, 1.0, wm)
    dx = np.where(straight, vm * h * np.cos(th[:, :-1]),
                  vm / w_safe * (np.sin(th[:, 1:]) - np.sin(th[:, :-1])))
    dy = np.where(straight, vm * h * np.sin(th[:, :-1]),
                  -vm / w_safe * (np.cos(th[:, 1:]) - np.cos(th[:, :-1])))
    x = np.concatenate((np.full((len(targets), 1), x0), x0 + np.cumsum(dx, axis=1)), axis=1)
    y = np.concatenate((np.full((len(targets), 1), y0), y0 + np.cumsum(dy, axis=1)), axis=1)
    return np.stack((x, y, th), axis=-1)


def footprint_clearance(poses: np.ndarray, points: np.ndarray, length: float,
                        width: float) -> np.ndarray:
    """Return the signed distance (m, < 0 inside) from each pose's footprint to the points.

    ``poses`` (..., 3), ``points`` (P, 2); the result has the shape of ``poses[..., 0]`` and is
    +inf when there are no points. Computed in float32 with in-place operations: this is the
    planner's inner loop (arcs x samples x points), and centimetres need no more precision.
    """
    if len(points) == 0:
        return np.full(poses.shape[:-1], np.inf)
    f32 = np.float32
    px, py = points[:, 0].astype(f32), points[:, 1].astype(f32)
    x, y = poses[..., 0, None].astype(f32), poses[..., 1, None].astype(f32)
    c, s = np.cos(poses[..., 2, None]).astype(f32), np.sin(poses[..., 2, None]).astype(f32)
    # Point coordinates in each pose's body frame, folded into the first quadrant and measured
    # from the rectangle's corner: q > 0 is outside along that axis.
    qx = c * px
    qx += s * py
    qx -= c * x + s * y
    np.abs(qx, out=qx)
    qx -= f32(0.5 * length)
    qy = c * py
    qy -= s * px
    qy -= c * y - s * x
    np.abs(qy, out=qy)
    qy -= f32(0.5 * width)
    inside = np.maximum(qx, qy).min(axis=-1)      # < 0 only when a point is inside
    np.maximum(qx, 0.0, out=qx)
    np.maximum(qy, 0.0, out=qy)
    qx *= qx
    qy *= qy
    qx += qy
    outside = np.sqrt(qx.min(axis=-1))
    return np.where(inside < 0.0, inside, outside).astype(float)


def _finite_pose(value: Sequence[float], name: str) -> tuple[float, float, float]:
    try:
        x, y, yaw = (float(v) for v in value)
    except (TypeError, ValueError):
        raise DwaInputError(f'{name}: expected (x, y, yaw), got {value!r}') from None
    if not all(math.isfinite(v) for v in (x, y, yaw)):
        raise DwaInputError(f'{name}: expected finite values, got {value!r}')
    return x, y, yaw


class DwaPlanner:
    """Stateful DWA planner: set a goal, then call :meth:`plan` once per control period."""

    def __init__(self, config: DwaConfig | None = None) -> None:
        self.cfg = config or DwaConfig()
        self.goal: tuple[float, float] | None = None
        self.recoveries = 0
        self._age = 0.0
        self._vel_hist: deque[tuple[float, float]] = deque(maxlen=3)
        self._reset_motion()

    def _reset_motion(self) -> None:
        self.state = State.IDLE if self.goal is None else State.MOVING
        self._last_w = 0.0
        self._track: deque[tuple[float, float, float]] = deque()
        self._idle_since: float | None = None
        self._rec_dir = 0.0
        self._rec_turned = 0.0
        self._rec_last_yaw = 0.0
        self._rec_flipped = False

    def set_goal(self, x: float, y: float) -> None:
        """Set a new goal (odom frame) and start moving toward it."""
        if not (math.isfinite(x) and math.isfinite(y)):
            raise DwaInputError(f'goal: expected finite (x, y), got {(x, y)!r}')
        self.goal = (float(x), float(y))
        self._reset_motion()

    def clear_goal(self) -> None:
        """Drop the goal: the planner commands zero until a new one is set."""
        self.goal = None
        self._reset_motion()

    # -- one control period -----------------------------------------------------------------
    def plan(self, t: float, pose: Sequence[float], velocity: Sequence[float],
             points: np.ndarray, age: float = 0.0) -> Plan:
        """Return the command for this period from the odom pose, measured (v, w) and points.

        ``age`` (s) is how old the pose and velocity already are (odometry stamp to now): on a
        loaded machine it grows to hundreds of ms, and the robot has gone on that long at its
        speed. It is added to ``latency`` when braking for the goal.
        """
        cfg = self.cfg
        self._age = min(max(float(age), 0.0), 1.0) if math.isfinite(age) else 0.0
        x, y, yaw = _finite_pose(pose, 'pose')
        try:
            v0, w0 = (float(v) for v in velocity)
        except (TypeError, ValueError):
            raise DwaInputError(f'velocity: expected (v, w), got {velocity!r}') from None
        if not (math.isfinite(v0) and math.isfinite(w0) and math.isfinite(t)):
            raise DwaInputError(f'time/velocity: expected finite values, got {(t, v0, w0)!r}')
        v0, w0 = self._filter_velocity(v0, w0)
        try:
            pts = np.asarray(points, dtype=float).reshape(-1, 2)
        except ValueError:
            raise DwaInputError(f'points: expected an (N, 2) array, got shape '
                                f'{np.shape(points)!r}') from None
        pts = pts[np.isfinite(pts).all(axis=1)]
        here = (x, y, yaw)
        if self.goal is None:
            return self._hold(State.IDLE, math.nan, here)
        gd = math.hypot(self.goal[0] - x, self.goal[1] - y)
        # Arrive at half the tolerance (the braking aims there), so the robot's residual motion
        # and odometry noise stay well inside the tolerance; see also the latch in _dwa.
        if self.state is State.GOAL_REACHED or gd <= 0.5 * cfg.goal_tolerance:
            self.state = State.GOAL_REACHED
            return self._hold(State.GOAL_REACHED, gd, here)
        # Keep only the points an arc or a probe could come near: the cost is C x N x P.
        reach = (max(abs(cfg.max_v) * cfg.horizon, cfg.probe_length)
                 + 0.5 * math.hypot(cfg.length, cfg.width) + cfg.clearance_ref + cfg.crop_extra)
        if len(pts):
            pts = pts[np.hypot(pts[:, 0] - x, pts[:, 1] - y) <= reach]
        self._track.append((t, x, y))
        while len(self._track) > 1 and self._track[1][0] <= t - cfg.stuck_time:
            self._track.popleft()
        if self.state is State.RECOVERING:
            out = self._recover(t, here, (v0, w0), pts, gd)
            if out is not None:
                return out
        return self._dwa(t, here, (v0, w0), pts, gd)

    def _filter_velocity(self, v: float, w: float) -> tuple[float, float]:
        """Return the median of the last three measured velocities, clamped to what is possible.

        Odometry velocity is a difference quotient: one late or early encoder sample makes a
        one-sample spike (seen: 1.3 m/s at a 0.25 m/s cruise). Fed raw into the window it moves
        the window off the real velocity, and every arc it admits may collide.
        """
        cfg = self.cfg
        self._vel_hist.append((v, w))
        vs = sorted(h[0] for h in self._vel_hist)
        ws = sorted(h[1] for h in self._vel_hist)
        v, w = vs[len(vs) // 2], ws[len(ws) // 2]
        dv, dw = cfg.acc_v * cfg.window_time, cfg.acc_w * cfg.window_time
        v = min(max(v, min(cfg.min_v, 0.0) - dv), cfg.max_v + dv)
        w = min(max(w, -cfg.max_w - dw), cfg.max_w + dw)
        return v, w

    def _hold(self, state: State, gd: float, here: tuple[float, float, float]) -> Plan:
        self._last_w = 0.0
        return Plan(0.0, 0.0, state, gd, math.inf, 0, 0, np.array([here]))

    def _evaluate(self, pose: tuple[float, float, float], start: tuple[float, float],
                  targets: np.ndarray, pts: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return (arcs, per-arc min clearance, admissible mask) for velocity targets."""
        cfg = self.cfg
        arcs = rollout(pose, targets, cfg.horizon, cfg.sim_step, start, (cfg.acc_v, cfg.acc_w))
        clear = footprint_clearance(arcs, pts, cfg.length, cfg.width)   # (C, N + 1)
        now = float(clear[0, 0])
        cmin = clear.min(axis=1)
        # Inside the margin already: admit what does not go closer than now (minus float fuzz).
        limit = cfg.margin if now >= cfg.margin else now - 1e-6
        return arcs, cmin, cmin >= limit

    def _free_path(self, pose: tuple[float, float, float], targets: np.ndarray,
                   pts: np.ndarray) -> np.ndarray:
        """Return, per target, the free path length (m) along its curvature, up to the probe.

        Scoring clearance only over the time horizon rewards crawling: a slow arc straight at
        an obstacle stays clear for the whole horizon. The probe follows each arc's *shape*
        for a fixed distance, so an arc that bends around the obstacle scores better than one
        that merely approaches it slowly (the "distance" term of Fox et al.'s DWA).
        """
        cfg = self.cfg
        if len(pts) == 0:
            return np.full(len(targets), cfg.probe_length)
        speed = np.maximum(np.abs(targets[:, 0]), cfg.probe_min_v)
        direction = np.where(targets[:, 0] < 0.0, -1.0, 1.0)
        unit = np.column_stack((direction, targets[:, 1] / speed))
        probe = rollout(pose, unit, cfg.probe_length, cfg.probe_step)
        clear = footprint_clearance(probe, pts, cfg.length, cfg.width)
        limit = min(cfg.margin, float(clear[0, 0]) - 1e-6)
        hit = clear[:, 1:] < limit
        first = np.argmax(hit, axis=1)
        step = cfg.probe_length / (probe.shape[1] - 1)
        return np.where(hit.any(axis=1), first * step, cfg.probe_length)

    def _dwa(self, t: float, pose: tuple[float, float, float], start: tuple[float, float],
             pts: np.ndarray, gd: float) -> Plan:
        cfg = self.cfg
        assert self.goal is not None
        targets = sample_window(dynamic_window(*start, cfg), cfg)
        arcs, cmin, ok = self._evaluate(pose, start, targets, pts)
        # Brake for the goal: no faster than what stops within the remaining distance (aiming
        # at half the tolerance), unless the window cannot slow down that much yet.
        v_goal = math.sqrt(2.0 * cfg.goal_brake * cfg.acc_v
                           * max(gd - 0.5 * cfg.goal_tolerance
                                 - abs(start[0]) * (cfg.latency + self._age), 0.0))
        ok &= targets[:, 0] <= max(v_goal, float(targets[:, 0].min())) + 1e-9
        n_ok = int(ok.sum())
        if n_ok == 0:
            return self._blocked(t, pose, start, pts, gd, len(targets))
        end = arcs[:, -1, :]
        gx, gy = self.goal
        # Closest approach, not the end point: an end-point cost makes the robot creep up on
        # the goal (speed ~ distance / horizon). The braking cap below does the slowing down.
        end_gd = np.hypot(gx - arcs[:, :, 0], gy - arcs[:, :, 1]).min(axis=1)
        heading = np.abs(_wrap(np.arctan2(gy - end[:, 1], gx - end[:, 0]) - end[:, 2])) / np.pi
        # The bearing from an arc's end to a goal it reached is meaningless: fade it out.
        fade = min(1.0, gd / 0.5)
        span = cfg.clearance_ref - cfg.margin
        lack = np.clip((cfg.clearance_ref - cmin) / span, 0.0, None)
        free = self._free_path(pose, targets, pts)
        cost = (cfg.goal_weight * end_gd / (cfg.max_v * cfg.horizon)
                + cfg.heading_weight * fade * heading
                + cfg.free_weight * (1.0 - free / cfg.probe_length)
                + cfg.clearance_weight * lack
                + cfg.velocity_weight * (cfg.max_v - targets[:, 0]) / cfg.max_v
                + cfg.smooth_weight * np.abs(targets[:, 1] - self._last_w) / cfg.max_w)
        cost = np.where(ok, cost, np.inf)
        best = int(np.argmin(cost))
        v, w = float(targets[best, 0]), float(targets[best, 1])
        if gd <= cfg.goal_tolerance and v < 0.5 * cfg.acc_v * cfg.dt:
            # Inside the tolerance and choosing to stop (e.g. the goal is beside the robot):
            # that is arrival, not a reason to creep about.
            self.state = State.GOAL_REACHED
            return self._hold(State.GOAL_REACHED, gd, pose)
        # Stuck: standing (almost) still by choice, or not getting anywhere while commanding.
        if abs(v) < 1e-3 and abs(w) < 0.05:
            self._idle_since = t if self._idle_since is None else self._idle_since
        else:
            self._idle_since = None
        t0, x0, y0 = self._track[0]
        no_progress = (t - t0 >= cfg.stuck_time * 0.999
                       and math.hypot(pose[0] - x0, pose[1] - y0) < cfg.stuck_distance)
        idle = self._idle_since is not None and t - self._idle_since >= cfg.stuck_time * 0.999
        if self.state is State.MOVING and (no_progress or idle):
            out = self._start_recovery(t, pose, start, pts, gd)
            if out is not None:
                return out
        self.state = State.MOVING
        self._last_w = w
        return Plan(v, w, State.MOVING, gd, float(cmin[best]), n_ok, len(targets), arcs[best])

    # -- stuck handling ---------------------------------------------------------------------
    def _blocked(self, t: float, pose: tuple[float, float, float], start: tuple[float, float],
                 pts: np.ndarray, gd: float, n: int) -> Plan:
        out = self._start_recovery(t, pose, start, pts, gd)
        if out is not None:
            return out
        return self._stand(State.BLOCKED, pose, gd, n)

    def _stand(self, state: State, pose: tuple[float, float, float], gd: float,
               n: int) -> Plan:
        self.state = state
        self._last_w = 0.0
        return Plan(0.0, 0.0, state, gd, math.nan, 0, n, np.array([pose]))

    def _rotation(self, pose: tuple[float, float, float], start: tuple[float, float],
                  direction: float, pts: np.ndarray) -> tuple[bool, np.ndarray, float]:
        """Return (free, arc, target w) for rotating in place toward ``direction``."""
        cfg = self.cfg
        _, _, w_lo, w_hi = dynamic_window(*start, cfg)
        w = min(max(direction * cfg.recovery_w, w_lo), w_hi)
        target = np.array([[0.0, w]])
        # Check a quarter turn ahead, or the time to stop from the current speed if longer.
        horizon = max(cfg.dt, (math.pi / 2.0) / cfg.recovery_w, abs(start[0]) / cfg.acc_v)
        arcs = rollout(pose, target, horizon, cfg.sim_step, start, (cfg.acc_v, cfg.acc_w))
        clear = footprint_clearance(arcs, pts, cfg.length, cfg.width)[0]
        limit = cfg.margin if clear[0] >= cfg.margin else clear[0] - 1e-6
        return bool(clear.min() >= limit), arcs[0], w

    def _start_recovery(self, t: float, pose: tuple[float, float, float],
                        start: tuple[float, float], pts: np.ndarray, gd: float) -> Plan | None:
        # Turn away from the side with more obstacle points near the robot.
        x, y, yaw = pose
        near = pts[np.hypot(pts[:, 0] - x, pts[:, 1] - y) < 1.0] if len(pts) else pts
        left = int(np.sum(-math.sin(yaw) * (near[:, 0] - x) + math.cos(yaw) * (near[:, 1] - y)
                          > 0.0))
        self.state = State.RECOVERING
        self.recoveries += 1
        self._rec_dir = -1.0 if left > len(near) - left else 1.0
        self._rec_turned = 0.0
        self._rec_last_yaw = yaw
        self._rec_flipped = False
        self._idle_since = None
        return self._recover(t, pose, start, pts, gd)

    def _recover(self, t: float, pose: tuple[float, float, float], start: tuple[float, float],
                 pts: np.ndarray, gd: float) -> Plan | None:
        """Return the rotate-in-place command, or None when recovery is over (plan normally)."""
        cfg = self.cfg
        yaw = pose[2]
        self._rec_turned += abs(float(_wrap(yaw - self._rec_last_yaw)))
        self._rec_last_yaw = yaw
        if self._rec_turned >= cfg.recovery_min_angle:
            targets = sample_window(dynamic_window(*start, cfg), cfg)
            forward = targets[targets[:, 0] >= min(cfg.max_v, 0.05)]
            if (len(forward) and self._evaluate(pose, start, forward, pts)[2].any()) \
                    or self._rec_turned >= 2.0 * math.pi:
                self._end_recovery(t, pose)
                return None
        free, arc, w = self._rotation(pose, start, self._rec_dir, pts)
        if not free and not self._rec_flipped:
            self._rec_dir = -self._rec_dir
            self._rec_flipped = True
            free, arc, w = self._rotation(pose, start, self._rec_dir, pts)
        if not free:
            self._end_recovery(t, pose)
            return self._stand(State.BLOCKED, pose, gd, 2)
        self._last_w = w
        return Plan(0.0, w, State.RECOVERING, gd, math.nan, 1, 1, arc)

    def _end_recovery(self, t: float, pose: tuple[float, float, float]) -> None:
        self.state = State.MOVING
        self._track.clear()
        self._track.append((t, pose[0], pose[1]))
        self._idle_since = None
