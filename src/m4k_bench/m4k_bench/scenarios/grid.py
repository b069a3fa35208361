"""The envelope grid: scenarios generated over speed x motion x obstacle and fault kind.

One declaration (``config/envelope.yaml``, top key ``envelope``) names the speeds, the motions,
the kinds (each of a class: ``obstacle``, ``moving``, ``fault``, ``estop``), the cells that are
not promised (with the reason) and the sample ``make test`` runs. :func:`cells` turns it into
ordinary :class:`~m4k_bench.scenarios.spec.Scenario` objects, named ``<kind>.<speed>.<motion>``
and validated by the same parser as a hand-written file, so the runner and the judge treat
them alike. Where a cell puts its obstacle comes from the configuration, never from a run: far
enough ahead for the speed ramp (``v^2 / 2 a``), the slow-down zone at that speed (d(v) with
the ramp's deceleration) and half a metre more -- the robot meets it at full speed.

* ``obstacle`` / ``moving``: straight (heading held) towards the obstacle, expect the stop of
  the kind's ``stop`` cause; ``turning`` drives an arc of ``obstacle_radius_per_m`` x the
  distance to a wall across it. A ``moving`` kind is a person who steps into the path from the
  left as the robot sets off and stands there.
* ``fault``: the fault from the start, commanded for 5 s; expect a latched motor fault and a
  peak true speed below ``max(0.5, v + 0.2)`` m/s.
* ``estop``: the contact opens once the robot has moved long enough to be at the cell's speed
  (the ramp's ``v / a`` + 1 s, a moment of the drive: ``world.faults[].start``) and closes 2 s
  later under a live command; expect no motion after the release. Straight, the world is long
  enough for the ramp, a second at speed, a coast from it and 6 m more (no wall in the guard's
  slow-down zone when the contact opens).

Turning in place uses the rim speed ``v``: ``w = v / (track / 2)``, capped at
``angular.max_velocity`` (the cell's description says when the cap binds).
"""

from __future__ import annotations

import math
import os
from typing import Any, Iterable, Mapping

from m4k_bench.scenarios import spec
from m4k_rt import yamlload

__all__ = ['Cell', 'cells', 'is_grid', 'load', 'not_promised', 'sample', 'scenarios']

CLASSES = ('obstacle', 'moving', 'fault', 'estop')
FAULT_S = 5.0            # s commanded with a fault from the start
COAST_DECEL = 0.3        # m/s^2: less than the simulated base's rolling resistance (0.37)
ESTOP_OPEN_S = 2.0       # s the e-stop contact stays open
ESTOP_AFTER_S = 5.0      # s of commands after it closes: a stop from speed, then >= 1 s held
EXTRA_M = 0.5            # m beyond the slow-down zone: the robot meets the line at full speed
SETTLE_S = 5.0           # s of commands beyond reaching the obstacle


class Cell:
    """One grid cell: its name, and the scenario (None with the reason when not promised)."""

    def __init__(self, name: str, kind: str, speed: str, motion: str,
                 scenario: spec.Scenario | None, why: str = '') -> None:
        self.name, self.kind, self.speed, self.motion = name, kind, speed, motion
        self.scenario, self.why = scenario, why

    def __repr__(self) -> str:
        return 'Cell({!r}{})'.format(self.name, '' if self.scenario else ', not promised')


def is_grid(path: str) -> bool:
    """Tell whether ``path`` is an envelope declaration (a YAML file with ``envelope:``)."""
    if not (os.path.isfile(path) and path.endswith('.yaml')):
        return False
    with open(path, encoding='utf-8') as f:
        return any(line.startswith('envelope:') for line in f)


def _err(where: str, msg: str) -> spec.ScenarioError:
    return spec.ScenarioError(where, msg)


def load(path: str) -> dict[str, Any]:
    """Read and check the declaration's shape; raise ScenarioError naming the key."""
    with open(path, encoding='utf-8') as f:
        doc = yamlload.load(f)
    env = doc.get('envelope') if isinstance(doc, dict) else None
    if not isinstance(env, dict):
        raise _err(path, 'expected a mapping with envelope:')
    for key in ('speeds', 'motions', 'kinds'):
        if not isinstance(env.get(key), dict) or not env[key]:
            raise _err(f'{path}: envelope.{key}', f'expected a non-empty mapping, got '
                       f'{env.get(key)!r}')
    for name, v in env['speeds'].items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v <= 3.0:
            raise _err(f'{path}: envelope.speeds.{name}', f'expected m/s in (0, 3], got {v!r}')
    for name, k in env['kinds'].items():
        if not isinstance(k, dict) or k.get('class') not in CLASSES:
            raise _err(f'{path}: envelope.kinds.{name}', f'expected {{class: one of '
                       f'{CLASSES}}}, got {k!r}')
        if k['class'] in ('obstacle', 'moving') and k.get('stop') not in spec.STOP_CAUSES:
            raise _err(f'{path}: envelope.kinds.{name}.stop', f'expected one of '
                       f'{spec.STOP_CAUSES}, got {k.get("stop")!r}')
    unknown = set(env['motions']) - {'straight', 'turning', 'in_place'}
    if unknown:
        raise _err(f'{path}: envelope.motions', f'unknown motion(s) {sorted(unknown)}')
    env.setdefault('not_promised', [])
    env.setdefault('sample', [])
    return env


def _listed(value: Any, item: str) -> bool:
    return value is None or item == value or (isinstance(value, list) and item in value)


def _why_not(env: Mapping[str, Any], kind: str, cls: str, motion: str, speed: str) -> str:
    for rule in env['not_promised']:
        if (_listed(rule.get('motion'), motion) and _listed(rule.get('kind'), kind)
                and _listed(rule.get('class'), cls) and _listed(rule.get('speed'), speed)):
            return ' '.join(str(rule.get('why', 'not promised')).split())
    return ''


def _obstacle_x(raw: Mapping[str, Any], v: float) -> float:
    """Return where (x of the obstacle's near side, m) the robot meets it at full speed."""
    from m4k_bench.scenarios.bounds import judge_reaction
    from m4k_rt.control.params import control_params
    p = control_params(raw.get('control'))
    a = p.linear.max_deceleration or p.linear.max_acceleration
    t = judge_reaction(raw, 'laser', timeouts=True)   # the guard's own stop zone
    slow_zone = v * t + v * v / (2.0 * a) + p.guard.stop_distance
    front = float(((raw.get('robot') or {}).get('body') or {}).get('length', 0.45)) / 2.0
    return round(front + v * v / (2.0 * p.linear.max_acceleration) + slow_zone + EXTRA_M, 2)


def _doc(raw: Mapping[str, Any], env: Mapping[str, Any], kind: str, speed: str,
         motion: str) -> dict[str, Any]:
    from m4k_rt.control.footprint import half_width_of
    from m4k_rt.control.params import control_params
    p = control_params(raw.get('control'))
    k = env['kinds'][kind]
    cls = k['class']
    v = float(env['speeds'][speed])
    mo = env['motions'][motion] or {}
    w_max = p.angular.max_velocity
    half_track = p.track_width / 2.0
    desc = f'{kind} at {speed} ({v:g} m/s), {motion.replace("_", " ")}'
    if cls in ('fault', 'estop'):
        if motion == 'straight':
            cmd: dict[str, Any] = {'v': v, 'w': 0.0}
        elif motion == 'turning':
            r = float(mo.get('radius', 1.0))
            w = min(v / r, w_max)
            cmd = {'v': w * r, 'w': w}
            if w < v / r:
                desc += (f' (w capped at angular.max_velocity {w_max:g} rad/s: {w * r:g} m/s '
                         f'on the {r:g} m circle)')
        else:
            w = min(v / half_track, w_max)
            cmd = {'v': 0.0, 'w': w}
            if w < v / half_track:
                desc += f' (w capped at angular.max_velocity {w_max:g} rad/s)'
        world: dict[str, Any] = {'walls': {'rectangle': [-8.0, -8.0, 8.0, 8.0]},
                                 'obstacles': []}
        if cls == 'fault':
            wheel = 'both' if kind == 'wheel_stall' else 'left'
            world['faults'] = [{'at_s': 0.0, 'kind': kind, 'wheel': wheel}]
            return {'description': desc, 'world': world,
                    'commands': [dict(cmd, t=FAULT_S)],
                    'expect': {'motor_fault': True, 'max_speed': round(max(0.5, v + 0.2), 2)},
                    'short': 0.8}
        # at the cell's speed (or turn rate) by then, moving for a second
        at = round(max(abs(cmd['v']) / p.linear.max_acceleration,
                       abs(cmd['w']) / p.angular.max_acceleration) + 1.0, 1)
        if motion == 'straight':
            # the ramp and a second at speed, a coast from it (no brake), and beyond the
            # laser's reach (5.6 m) to spare: no wall in the slow-down zone at the contact
            far = (v * v / (2.0 * p.linear.max_acceleration) + v
                   + v * v / (2.0 * COAST_DECEL) + 6.0)
            world['walls'] = {'rectangle': [-2.0, -4.0, round(far, 1), 4.0]}
        world['faults'] = [{'start': {'after': at}, 'for_s': ESTOP_OPEN_S, 'kind': 'estop'}]
        return {'description': desc, 'world': world,
                'commands': [dict(cmd, t=round(at + ESTOP_OPEN_S + ESTOP_AFTER_S, 1))],
                'expect': {'still_after_estop': True}}
    if motion == 'in_place':
        return _in_place_doc(raw, p, kind, min(v / half_track, w_max), desc)
    x = _obstacle_x(raw, v)
    t = round((x + 0.5) / v + v / p.linear.max_acceleration + SETTLE_S, 1)
    far = x + 3.0
    walls: list[Any] | dict[str, Any] = {'rectangle': [-1.0, -4.0, far, 4.0]}
    obstacles: list[Any] = []
    if kind == 'wall':
        walls = {'rectangle': [-1.0, -4.0, x, 4.0]}
    elif kind == 'leg':
        obstacles = [[[x, 0.115], [x + 0.03, 0.115], [x + 0.03, 0.145], [x, 0.145]]]
    elif kind == 'wheel_leg':
        # past the body's side, in the left wheel's path (m4k_rt.control.footprint)
        out = half_width_of(raw.get('robot'), p.track_width)
        obstacles = [[[x, out - 0.03], [x + 0.03, out - 0.03], [x + 0.03, out], [x, out]]]
    elif kind == 'low':
        obstacles = [{'polygon': [[x, -0.3], [x + 0.4, -0.3], [x + 0.4, 0.3], [x, 0.3]],
                      'height': 0.25}]
    elif kind == 'glass':
        obstacles = [{'polygon': [[x, -0.6], [x + 0.02, -0.6], [x + 0.02, 0.6], [x, 0.6]],
                      'surface': 'glass'}]
    elif kind == 'person':
        obstacles = [{'polygon': [[x, 1.775], [x + 0.25, 1.775], [x + 0.25, 2.225],
                                  [x, 2.225]],
                      'path': {'start': {'after': 0.0}, 'waypoints': [[0, 0, 0], [2.0, 0, -2.0]]}}]
    else:
        raise _err(f'envelope.kinds.{kind}', 'no world for this obstacle kind (wall, leg, '
                   'wheel_leg, low, glass, person)')
    if motion == 'turning':
        r = float(mo.get('obstacle_radius_per_m', 3.0)) * x
        command: dict[str, Any] = {'v': v, 'w': round(v / r, 5), 't': t}
        commands: list[dict[str, Any]] = [command]
        desc += f' (an arc of radius {r:.1f} m)'
        if kind in ('leg', 'wheel_leg'):
            # straight up to speed, then the arc (the ramps of v and w differ, so an arc from
            # rest is no circle); the leg on the arc, as far along and as far off it as the
            # straight world's: it enters the straight corridor from the side, late
            acc = p.linear.max_acceleration
            s0 = v * v / (2.0 * acc)
            t0 = round(v / acc, 2)
            obstacles = [_on_arc(poly, x, r, s0) for poly in obstacles]
            commands = [{'v': v, 't': t0}, dict(command, t=round(t - t0, 1))]
            desc += f', straight for {s0:.2f} m to speed, the leg on the arc'
    else:
        commands = [{'v': v, 't': t, 'heading': 'hold'}]
    return {'description': desc + f'; the obstacle {x:.2f} m ahead',
            'world': {'walls': walls, 'obstacles': obstacles},
            'commands': commands, 'expect': {'stop': k['stop']}}


def _on_arc(poly: list[list[float]], s: float, r: float, s0: float = 0.0) -> list[list[float]]:
    """Carry a polygon placed ``s`` ahead of the start onto the arc of radius ``r`` (left).

    The drive goes straight for ``s0``, then on the arc. The polygon's point (px, py) is taken
    relative to where a straight drive is after ``s`` (px - s, py) and placed the same way
    relative to where this drive is after ``s``.
    """
    a = (s - s0) / r
    ox, oy = s0 + r * math.sin(a), r * (1.0 - math.cos(a))
    c, sn = math.cos(a), math.sin(a)
    return [[round(ox + c * (px - s) - sn * py, 4), round(oy + sn * (px - s) + c * py, 4)]
            for px, py in poly]


IN_PLACE_GAP = 0.03     # m between the obstacle and the outline at the start of a turn in place
#                        (less than the body corner swings out past the front face: 4 cm)
IN_PLACE_S = 4.0        # s of turning toward it


def _in_place_doc(raw: Mapping[str, Any], p: Any, kind: str, w: float,
                  desc: str) -> dict[str, Any]:
    """Return a turn in place with the obstacle where the turn meets it.

    The robot starts ``IN_PLACE_GAP`` from the obstacle (it was pushed up to a robot at rest,
    or the robot reversed or arced there): a wall across the front face, a 3 cm leg beside the
    body's front-left corner (the turn counter-clockwise swings the corner into it), or one
    beside the body just ahead of the left wheel (clockwise: the wheel's front swings into
    it), within a few degrees. The turn guard must keep it from turning that way.
    """
    from m4k_rt.control.footprint import outline_of
    robot = raw.get('robot')
    shape = outline_of(robot, p.track_width, p.wheel_radius)
    front, side = shape[0]      # the body's front-left corner (m4k_rt.control.footprint)
    g = IN_PLACE_GAP
    walls: Any = {'rectangle': [-2.0, -2.0, 2.0, 2.0]}
    obstacles: list[Any] = []
    if kind == 'wall':
        walls = {'rectangle': [-2.0, -2.0, front + g, 2.0]}
    elif kind == 'leg':
        # beside the front-left corner of the body (its side, y = width / 2)
        x0, y0 = front - 0.04, side + g
        obstacles = [[[x0, y0], [x0 + 0.03, y0], [x0 + 0.03, y0 + 0.03], [x0, y0 + 0.03]]]
    elif kind == 'wheel_leg':
        # beside the body just ahead of the left wheel: a clockwise turn swings the wheel's
        # front into it
        x0, y0 = p.wheel_radius + g, side + g
        obstacles = [[[x0, y0], [x0 + 0.03, y0], [x0 + 0.03, y0 + 0.03], [x0, y0 + 0.03]]]
        w = -w
    else:
        raise _err(f'envelope.kinds.{kind}', 'no turn-in-place world for this kind (wall, '
                   'leg, wheel_leg); declare its in_place cells under not_promised')
    return {'description': desc + f' toward the obstacle {g:g} m from the outline',
            'world': {'walls': walls, 'obstacles': obstacles},
            'commands': [{'v': 0.0, 'w': round(w, 5), 't': IN_PLACE_S}],
            'expect': {'distance': 0}}


def cells(path: str, raw: Mapping[str, Any] | None = None) -> list[Cell]:
    """Return every cell of the grid at ``path`` (``raw``: the layered config, default)."""
    from m4k_rt import config
    env = load(path)
    if raw is None:
        raw = config.load_layered(None, os.path.dirname(os.path.abspath(path)))
    out = []
    for kind, k in env['kinds'].items():
        for speed in env['speeds']:
            for motion in env['motions']:
                name = f'{kind}.{speed}.{motion}'
                why = _why_not(env, kind, k['class'], motion, speed)
                if why:
                    out.append(Cell(name, kind, speed, motion, None, why))
                    continue
                doc = dict(_doc(raw, env, kind, speed, motion), name=name)
                out.append(Cell(name, kind, speed, motion,
                                spec.parse(doc, f'{path}#{name}')))
    names = {c.name for c in out}
    missing = [s for s in env['sample'] if s not in names]
    if missing:
        raise _err(f'{path}: envelope.sample', f'no such cell(s) {missing}')
    return out


def sample(path: str, raw: Mapping[str, Any] | None = None) -> list[spec.Scenario]:
    """Return the scenarios of the cells listed under ``sample`` (what ``make test`` runs)."""
    want = load(path)['sample']
    by = {c.name: c for c in cells(path, raw)}
    return [_promised(by[n]) for n in want]


def _promised(c: Cell) -> spec.Scenario:
    if c.scenario is None:
        raise spec.ScenarioError(c.name, f'sampled but not promised: {c.why}')
    return c.scenario


def scenarios(path: str, raw: Mapping[str, Any] | None = None) -> list[spec.Scenario]:
    """Return the scenarios of every promised cell, in declaration order."""
    return [c.scenario for c in cells(path, raw) if c.scenario is not None]


def not_promised(path: str) -> Iterable[Cell]:
    """Return the cells the grid declares outside the promise (with the reason)."""
    return [c for c in cells(path) if c.scenario is None]

