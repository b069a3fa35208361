"""A scenario file: a world overlay, a scripted commander, faults, and the outcome expected.

A scenario is one YAML file (``config/scenarios/*.yaml`` ships the suite; write your own)::

    name: corridor                      # default: the file name
    description: 1.2 m x 15 m corridor driven end to end
    world: {walls: [...], obstacles: [...], events: [...]}   # merged over config/ world:
    commands:                           # cmd_vel segments, published at 20 Hz, then zero
      - {v: 0.25, w: 0.0, t: 12.0}      # m/s, rad/s, s: open loop
      - {v: 0.5, t: 27.0, heading: hold}  # steer on odometry to keep the segment's first
                                        # heading, as a navigation stack would (w = -1.0 * err)
    faults:                             # processes the runner kills -9 (bringup restarts them)
      - {kill: driver_host, at: {travelled: 1.0}}   # driver_host | bridge | rt_core; at:
                                        # {travelled: m} or {after: s since the drive began}
    e_stop: true                        # the runner publishes e_stop (std_msgs/Bool) true first
    expect:                             # written before the run
      distance: commanded               # the true path covers the commanded distance (or
                                        # a number of metres, e.g. 0: must not move)
      stop: sonar                       # the robot stops, within the bound of this cause
      max_speed: 0.5                    # m/s: peak true body and wheel-rim speed below this
      motor_fault: true                 # a latched motor fault: zero outputs, at rest while
                                        # still commanded, to the end of the commands
      still_after_estop: true           # after the e-stop contact (world.faults) closes again
                                        # the robot stays at rest (no reset is ever sent)
      max_w_after_kill: 0.02            # rad/s: |w| on ground truth from the kill on
    short: 0.5                          # the test's version: command durations x 0.5

``expect.stop`` names why the robot must come to rest, and so which bound from ``config/``
applies (:mod:`m4k_bench.scenarios.bounds`): ``sonar`` / ``laser`` (an obstacle the sensor
sees), ``sonar_unplugged`` / ``laser_unplugged`` (stale policy), ``bridge_killed``,
``driver_host_killed``. Every scenario is also judged on: no contact, minimum clearance > 0.
Sensor unplugging is a world event (``world.events``, m4k_drivers.scene), executed by the
simulator at the same ground-truth moment as the moving obstacles.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
import os
from typing import Any

import yaml

from m4k_rt import yamlload
from m4k_rt.schema import ConfigError

__all__ = ['Command', 'Fault', 'Scenario', 'ScenarioError', 'STOP_CAUSES', 'load', 'load_dir']

STOP_CAUSES = ('sonar', 'laser', 'sonar_unplugged', 'laser_unplugged', 'bridge_killed',
               'driver_host_killed')
KILLABLE = ('driver_host', 'bridge', 'rt_core')


class ScenarioError(ConfigError):
    """A bad scenario file; the message names the file and the field."""


@dataclass(frozen=True)
class Command:
    """One cmd_vel segment; ``hold``: steer to keep the odometry heading of its start."""

    v: float
    w: float
    t: float
    hold: bool = False


@dataclass(frozen=True)
class Fault:
    """A process killed when the robot has truly covered ``travelled`` m (or ``after`` s)."""

    kill: str
    travelled: float = 0.0
    after: float | None = None      # s since the drive began, instead of travelled


@dataclass(frozen=True)
class Scenario:
    """One scenario, validated."""

    name: str
    description: str
    world: dict[str, Any]
    commands: tuple[Command, ...]
    faults: tuple[Fault, ...] = ()
    distance: bool = False          # expect the commanded distance
    distance_m: float | None = None  # or expect this distance (m), e.g. 0: must not move
    stop: str | None = None         # expect a stop, for this cause
    short: float = 1.0
    max_speed: float | None = None  # m/s: peak true speed (body, wheel rims) below this
    motor_fault: bool = False       # expect a latched motor fault
    still_after_estop: bool = False  # no motion after the e-stop contact closes again
    max_w_after_kill: float | None = None   # rad/s: |w| from the kill on
    e_stop: bool = False            # the runner requests an e-stop before driving
    path: str = ''
    overlay: dict[str, Any] = field(default_factory=dict)

    def scaled(self, short: bool) -> tuple[Command, ...]:
        """Return the commands, durations scaled for the short (test) version."""
        k = self.short if short else 1.0
        return tuple(Command(c.v, c.w, c.t * k, c.hold) for c in self.commands)

    def commanded_distance(self, short: bool = False) -> float:
        """Return the path length the commands ask for, m."""
        return sum(abs(c.v) * c.t for c in self.scaled(short))

    def expected(self) -> str:
        """Return the expectation in words (the table's column)."""
        parts = ['commanded distance' if self.distance else
                 f'{self.distance_m:g} m' if self.distance_m is not None else '']
        if self.stop:
            parts.append(f'stop ({self.stop.replace("_", " ")})')
        if self.max_speed is not None:
            parts.append(f'peak speed < {self.max_speed:g} m/s')
        if self.motor_fault:
            parts.append('motor fault latched')
        if self.still_after_estop:
            parts.append('no motion after the e-stop release')
        if self.max_w_after_kill is not None:
            parts.append(f'|w| < {self.max_w_after_kill:g} rad/s after the kill')
        return ', '.join(p for p in parts if p) + '; no contact'


def _num(v: Any, where: str, lo: float | None = None) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ScenarioError(f'{where}: expected a finite number, got {v!r}')
    if lo is not None and v < lo:
        raise ScenarioError(f'{where}: must be >= {lo}, got {v!r}')
    return float(v)


def parse(doc: Any, where: str) -> Scenario:
    """Validate one scenario document."""
    if not isinstance(doc, dict):
        raise ScenarioError(f'{where}: expected a mapping, got {type(doc).__name__}')
    known = {'name', 'description', 'world', 'commands', 'faults', 'expect', 'short', 'config',
             'e_stop'}
    if set(doc) - known:
        raise ScenarioError(f'{where}: unknown field(s) {sorted(set(doc) - known)}; valid: '
                            f'{sorted(known)}')
    name = str(doc.get('name') or os.path.splitext(os.path.basename(where))[0])
    world = doc.get('world') or {}
    if not isinstance(world, dict):
        raise ScenarioError(f'{where}.world: expected a mapping, got {world!r}')
    cmds_raw = doc.get('commands')
    if not isinstance(cmds_raw, list) or not cmds_raw:
        raise ScenarioError(f'{where}.commands: expected a list of {{v, w, t}}, got {cmds_raw!r}')
    cmds = []
    for i, c in enumerate(cmds_raw):
        if not isinstance(c, dict) or set(c) - {'v', 'w', 't', 'heading'} or 't' not in c \
                or c.get('heading', 'hold') != 'hold' or ('heading' in c and 'w' in c):
            raise ScenarioError(f'{where}.commands[{i}]: expected {{v, w, t}} or {{v, t, '
                                f'heading: hold}}, got {c!r}')
        cmds.append(Command(_num(c.get('v', 0.0), f'{where}.commands[{i}].v'),
                            _num(c.get('w', 0.0), f'{where}.commands[{i}].w'),
                            _num(c['t'], f'{where}.commands[{i}].t', 0.0),
                            c.get('heading') == 'hold'))
    faults = []
    for i, f in enumerate(doc.get('faults') or []):
        if not isinstance(f, dict) or set(f) != {'kill', 'at'} or f['kill'] not in KILLABLE \
                or not isinstance(f['at'], dict) or len(f['at']) != 1 \
                or set(f['at']) - {'travelled', 'after'}:
            raise ScenarioError(f'{where}.faults[{i}]: expected {{kill: {"|".join(KILLABLE)}, '
                                f'at: {{travelled: m}} or {{after: s}}}}, got {f!r}')
        at = f['at']
        if 'after' in at:
            faults.append(Fault(f['kill'], 0.0, _num(at['after'], f'{where}.faults[{i}]', 0.0)))
        else:
            faults.append(Fault(f['kill'], _num(at['travelled'], f'{where}.faults[{i}]', 0.0)))
    exp = doc.get('expect')
    exp_keys = {'distance', 'stop', 'max_speed', 'motor_fault', 'still_after_estop',
                'max_w_after_kill'}
    if not isinstance(exp, dict) or set(exp) - exp_keys or not exp:
        raise ScenarioError(f'{where}.expect: expected a mapping with keys from '
                            f'{sorted(exp_keys)}, got {exp!r}')
    for key in ('motor_fault', 'still_after_estop'):
        if key in exp and not isinstance(exp[key], bool):
            raise ScenarioError(f'{where}.expect.{key}: expected true or false, got '
                                f'{exp[key]!r}')
    if not isinstance(doc.get('e_stop', False), bool):
        raise ScenarioError(f'{where}.e_stop: expected true or false, got {doc["e_stop"]!r}')
    dist = exp.get('distance')
    distance_m = None
    if dist not in (None, 'commanded'):
        distance_m = _num(dist, f'{where}.expect.distance ("commanded" or metres)', 0.0)
    stop = exp.get('stop')
    if stop is not None and stop not in STOP_CAUSES:
        raise ScenarioError(f'{where}.expect.stop: expected one of {STOP_CAUSES}, got {stop!r}')
    short = _num(doc.get('short', 1.0), f'{where}.short', 0.05)
    overlay = doc.get('config') or {}       # any further config/ overlay (e.g. control:)
    if not isinstance(overlay, dict) or 'world' in overlay:
        raise ScenarioError(f'{where}.config: expected a mapping without world: (use the '
                            f"scenario's world:), got {overlay!r}")
    return Scenario(name, str(doc.get('description', '')), world, tuple(cmds), tuple(faults),
                    dist == 'commanded', distance_m, stop, min(short, 1.0),
                    max_speed=None if exp.get('max_speed') is None else
                    _num(exp['max_speed'], f'{where}.expect.max_speed', 0.0),
                    motor_fault=bool(exp.get('motor_fault', False)),
                    still_after_estop=bool(exp.get('still_after_estop', False)),
                    max_w_after_kill=None if exp.get('max_w_after_kill') is None else
                    _num(exp['max_w_after_kill'], f'{where}.expect.max_w_after_kill', 0.0),
                    e_stop=bool(doc.get('e_stop', False)), path=where, overlay=overlay)


def load(path: str) -> Scenario:
    """Load and validate one scenario file (the world section too, as the simulator will)."""
    with open(path, encoding='utf-8') as f:
        try:
            doc = yamlload.load(f)
        except yaml.YAMLError as exc:
            raise ScenarioError(f'{path}: not YAML: {exc}') from None
    sc = parse(doc, path)
    from m4k_drivers.world import WorldConfig, WorldConfigError
    try:
        WorldConfig.from_dict(sc.world, 'world')
    except WorldConfigError as exc:
        raise ScenarioError(f'{path}: {exc}') from None
    return sc


def load_dir(directory: str) -> list[Scenario]:
    """Load every ``*.yaml`` of ``directory``, sorted by file name."""
    return [load(os.path.join(directory, f)) for f in sorted(os.listdir(directory))
            if f.endswith('.yaml')]
