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
                                        # (or breakaway: the rim speed the PI's break-away
                                        # cap drives a wheel to, from config/control.yaml)
      motor_fault: true                 # a latched motor fault: zero outputs, at rest while
                                        # still commanded, to the end of the commands
      still_after_estop: true           # after the e-stop contact (world.faults) closes again
                                        # the robot stays at rest (no reset is ever sent)
      max_w_after_kill: 0.02            # rad/s: |w| on ground truth from the kill on
      min_clearance: 0.25               # m: the footprint never nearer to any surface (an arc,
                                        # where the stop line along a straight band says nothing)
    short: 0.5                          # the test's version: command durations x 0.5

``expect.stop`` names why the robot must come to rest, and so which bound from ``config/``
applies (:mod:`m4k_bench.scenarios.bounds`): ``sonar`` / ``laser`` (an obstacle the sensor
sees), ``sonar_unplugged`` / ``laser_unplugged`` (stale policy), ``bridge_killed``,
``driver_host_killed``. Every scenario is also judged on: no contact, minimum clearance > 0.
Sensor unplugging is a world event (``world.events``, m4k_drivers.scene), executed by the
simulator at the same ground-truth moment as the moving obstacles.

Every key is declared once, as a schema Field in :data:`SCENARIO`, :data:`COMMAND`,
:data:`KILL` and :data:`EXPECT` (type, default, unit, range, meaning): the parser validates
with them, and the docs are generated from them (``m4k_bench.configdoc``). Only what involves
several keys is checked by hand (``w`` or ``heading``, ``travelled`` or ``after``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import os
from typing import Any, Callable

import yaml

from m4k_rt import yamlload
from m4k_rt.schema import ConfigError, Field, REQUIRED, validate_tree

__all__ = ['BREAKAWAY', 'COMMAND', 'Command', 'EXPECT', 'Fault', 'KILL', 'SCENARIO',
           'Scenario', 'ScenarioError', 'STOP_CAUSES', 'load', 'load_dir']

STOP_CAUSES = ('sonar', 'laser', 'sonar_unplugged', 'laser_unplugged', 'bridge_killed',
               'driver_host_killed')
KILLABLE = ('driver_host', 'bridge', 'rt_core')
BREAKAWAY = 'breakaway'   # expect.max_speed: the break-away cap's rim speed (bounds.py)


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
    max_speed: float | str | None = None  # m/s: peak true speed (body, wheel rims) below
                                    # this, or BREAKAWAY (m4k_bench.scenarios.bounds)
    motor_fault: bool = False       # expect a latched motor fault
    still_after_estop: bool = False  # no motion after the e-stop contact closes again
    max_w_after_kill: float | None = None   # rad/s: |w| from the kill on
    min_clearance: float | None = None      # m: the footprint never nearer to any surface
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
        if self.max_speed == BREAKAWAY:
            parts.append('peak speed < the break-away cap')
        elif self.max_speed is not None:
            parts.append(f'peak speed < {self.max_speed:g} m/s')
        if self.motor_fault:
            parts.append('motor fault latched')
        if self.still_after_estop:
            parts.append('no motion after the e-stop release')
        if self.max_w_after_kill is not None:
            parts.append(f'|w| < {self.max_w_after_kill:g} rad/s after the kill')
        if self.min_clearance is not None:
            parts.append(f'clearance >= {self.min_clearance:g} m')
        return ', '.join(p for p in parts if p) + '; no contact'


def _nonempty(what: str) -> Callable[[Any], str | None]:
    def check(v: Any) -> str | None:
        return None if v else f'expected {what}, got {v!r}'
    return check


def _no_world(v: Any) -> str | None:
    if v and 'world' in v:
        return "expected a mapping without world: (use the scenario's world:), got {!r}".format(v)
    return None


def _max_speed(v: Any) -> str | None:
    if isinstance(v, str) and v != BREAKAWAY:
        return f'expected m/s >= 0 or "{BREAKAWAY}", got {v!r}'
    return None


def _distance(v: Any) -> str | None:
    if isinstance(v, str) and v != 'commanded':
        return f'expected "commanded" or metres >= 0, got {v!r}'
    return None


# One declaration per key of a scenario file (validation and docs: m4k_bench.configdoc).
SCENARIO: dict[str, Field] = {
    'name': Field('str', None, 'Name in the report; null: the file name.', nullable=True),
    'description': Field('str', '', 'One line for the report.'),
    'world': Field('map', {}, 'Overlay merged over the world: section of config/ (the '
                   'simulated room: walls, obstacles, events, faults, robot; docs/'
                   'configuration.md).', nullable=True),
    'commands': Field('list', REQUIRED, 'cmd_vel segments published at 20 Hz, then zero '
                      '(commands[]).', expect='a list of {v, w, t}',
                      check=_nonempty('a list of {v, w, t}')),
    'faults': Field('list', [], 'Processes the runner kills -9 during the drive (faults[]); '
                    'bringup restarts them.', nullable=True),
    'expect': Field('map', REQUIRED, 'The outcome, written before the run (expect); every '
                    'scenario is also judged on no contact and a clearance > 0.',
                    check=_nonempty('a mapping with at least one expectation')),
    'short': Field('float', 1.0, "The tests' version: command durations times this.",
                   lo=0.05, hi=1.0),
    'config': Field('map', {}, 'Any further overlay of config/ (e.g. control:), without world: '
                    "(use the scenario's world:).", nullable=True, check=_no_world),
    'e_stop': Field('bool', False, 'true: the runner publishes e_stop (std_msgs/Bool) true '
                    'before driving.'),
}
# One entry of commands.
COMMAND: dict[str, Field] = {
    'v': Field('float', 0.0, 'Linear velocity.', unit='m/s'),
    'w': Field('float', 0.0, 'Angular velocity (not with heading).', unit='rad/s'),
    't': Field('float', REQUIRED, 'Duration of the segment.', unit='s', lo=0),
    'heading': Field('str', None, 'hold: steer on odometry to keep the heading of the '
                     "segment's start, as a navigation stack would (w = -1.0 * error).",
                     choices=('hold',), nullable=True),
}
# One entry of faults: a process killed at a moment of the drive.
KILL: dict[str, Field] = {
    'kill': Field('str', REQUIRED, 'The process killed with SIGKILL.', choices=KILLABLE),
    'at.travelled': Field('float', None, 'When the robot has truly covered this distance '
                          '(give travelled or after).', unit='m', lo=0, nullable=True),
    'at.after': Field('float', None, 'This long after the drive began.', unit='s', lo=0,
                      nullable=True),
}
# The expect mapping.
EXPECT: dict[str, Field] = {
    'distance': Field('float|str', None, 'commanded: the true path covers the commanded '
                      'distance; a number: that many metres (0: must not move).', unit='m',
                      lo=0, nullable=True, expect='"commanded" or metres >= 0',
                      check=_distance),
    'stop': Field('str', None, 'The robot comes to rest, within the bound of this cause '
                  '(m4k_bench.scenarios.bounds).', choices=STOP_CAUSES, nullable=True),
    'max_speed': Field('float|str', None, 'Peak true body and wheel-rim speed below this. '
                       f'"{BREAKAWAY}": below the rim speed the wheel PI\'s break-away cap '
                       'drives a wheel to (pi.breakaway_effort x the full-scale rim speed, '
                       'from the configuration): what a frozen or blocked wheel at a creep may '
                       'reach before the supervision latches.',
                       unit='m/s', lo=0, nullable=True,
                       expect=f'm/s >= 0 or "{BREAKAWAY}"', check=_max_speed),
    'motor_fault': Field('bool', False, 'A latched motor fault: zero outputs, at rest while '
                         'still commanded, to the end of the commands.'),
    'still_after_estop': Field('bool', False, 'After the e-stop contact (world.faults) closes '
                               'again the robot stays at rest (no reset is ever sent).'),
    'max_w_after_kill': Field('float', None, '|w| on ground truth from the kill on stays below '
                              'this.', unit='rad/s', lo=0, nullable=True),
    'min_clearance': Field('float', None, 'The footprint never comes nearer than this to any '
                           "surface (ground truth: the judge's exact geometry and the "
                           "simulator's 5 ms minimum). For a drive on an arc, where the stop "
                           'line the judge draws along a straight band says nothing.',
                           unit='m', lo=0, nullable=True),
}


def parse(doc: Any, where: str) -> Scenario:
    """Validate one scenario document against its tables (errors name the file and field)."""
    if not isinstance(doc, dict):
        raise ScenarioError(where, f'expected a mapping, got {type(doc).__name__}')
    top = validate_tree(SCENARIO, doc, where, ScenarioError)
    cmds = []
    for i, c in enumerate(top['commands']):
        at = f'{where}.commands[{i}]'
        v = validate_tree(COMMAND, c, at, ScenarioError)
        if v['heading'] is not None and 'w' in c:
            raise ScenarioError(at, f'expected {{v, w, t}} or {{v, t, heading: hold}} (not '
                                f'both w and heading), got {c!r}')
        cmds.append(Command(v['v'], v['w'], v['t'], v['heading'] == 'hold'))
    faults = []
    for i, f in enumerate(top['faults'] or []):
        at = f'{where}.faults[{i}]'
        v = validate_tree(KILL, f, at, ScenarioError)
        if isinstance(f, dict) and 'at' not in f:
            raise ScenarioError(f'{at}.at', 'missing ({travelled: m} or {after: s})')
        travelled, after = v['at.travelled'], v['at.after']
        if (travelled is None) == (after is None):
            raise ScenarioError(f'{at}.at', f'expected {{travelled: m}} or {{after: s}} (one '
                                f'of them), got {f["at"]!r}')
        faults.append(Fault(v['kill'], travelled or 0.0, after))
    exp = validate_tree(EXPECT, top['expect'], f'{where}.expect', ScenarioError)
    dist, ms = exp['distance'], exp['max_speed']
    name = top['name'] or os.path.splitext(os.path.basename(where))[0]
    return Scenario(name, top['description'], top['world'] or {}, tuple(cmds), tuple(faults),
                    dist == 'commanded', None if dist in (None, 'commanded') else float(dist),
                    exp['stop'], top['short'],
                    max_speed=ms if ms is None or ms == BREAKAWAY else float(ms),
                    motor_fault=exp['motor_fault'],
                    still_after_estop=exp['still_after_estop'],
                    max_w_after_kill=exp['max_w_after_kill'],
                    min_clearance=exp['min_clearance'], e_stop=top['e_stop'],
                    path=where, overlay=top['config'] or {})


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
