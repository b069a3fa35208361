"""The declarative configuration schema: one :class:`Field` per setting (pure, no ROS).

Modelled on generate_parameter_library's YAML (ros2_controllers' diff_drive_controller): every
field states its type, default, unit, range or choices, and a description that says what a
wrong value does. The same table

* validates the configuration files with the messages the loaders always gave
  (``tasks.led.priority: expected an int in 1..99, got 120``): :meth:`Field.validate`;
* builds the bridge's ROS ``ParameterDescriptor`` objects (``m4k_bridge.node``);
* generates ``docs/configuration.md`` (:func:`markdown`, driven by ``m4k_bringup.configdoc``,
  which gathers every package's sections; a test fails when the committed page differs) and
  ``docs/bench-configuration.md`` (``m4k_bench.configdoc``: the planner, the scenario files).

Tables: :data:`RUNTIME`, :data:`TASK` (one entry of ``tasks``), :data:`PORT` (``ports.<label>``)
here and used by :mod:`m4k_rt.config`; :data:`ROBOT` here, used by :mod:`m4k_rt.description`;
``CONTROL`` derived from the control dataclasses, whose fields carry their Fields
(:func:`setting`, :func:`section`, :func:`table`; :mod:`m4k_rt.control.params`); the bridge's
parameters in
:data:`m4k_bridge.params.SPECS`; each device backend's fields next to its factory
(``m4k_drivers.registry.Param``, turned into Fields); the simulated world on its dataclasses
(``m4k_drivers.drive.RobotParams``, ``m4k_drivers.world.WorldConfig``, ``m4k_drivers.scene``,
``m4k_drivers.faults``); the planner on ``m4k_bench.planning.dwa.DwaConfig`` and in
``m4k_bench.planning.params``; the scenario files in ``m4k_bench.scenarios.spec``. Checks
across fields (a task's offset inside its period, a slow-down zone beyond the stop distance)
stay in the loaders.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from typing import Any, Callable, Iterable, Mapping, NoReturn, Sequence

# The channel declares its own limits and transports; the schema states them, never again.
from m4k_rt.channel.contract import DEFAULT_MAX_DATAGRAM, DEFAULT_MAX_PORTS, DEFAULT_POOLSZ
from m4k_rt.channel.shm import SHM_LIVENESS_NS
from m4k_rt.channel.transports import DEFAULT_TRANSPORT, TRANSPORTS

__all__ = [
    'ConfigError', 'Field', 'PORT', 'REQUIRED', 'ROBOT', 'RUNTIME', 'Section', 'TASK',
    'build', 'check_keys', 'derived', 'markdown', 'section', 'setting', 'table',
    'validate_tree',
]


class ConfigError(ValueError):
    """A configuration value is wrong; ``path`` names the field, ``value`` is what was found.

    The one configuration error type of the project (:mod:`m4k_rt.config` re-exports it).
    Each source has a subclass: the control section's ``ControlConfigError``, the robot
    description's ``DescriptionError``, the driver host's ``m4k_drivers.config.ConfigError``,
    the world's ``WorldConfigError``, the scene's ``SceneError``, the simulated faults'
    ``FaultError``, the bridge's and the planner's ``ParamError``, the planner's
    ``DwaConfigError``, the scenario files' ``ScenarioError`` and the demo judge's
    ``EvaluateError``; ``except ConfigError`` catches
    every configuration mistake. Built as ``ConfigError(path, message)`` or, by the sources
    that format their own text, ``ConfigError('path: message')``.
    """

    def __init__(self, path: str, message: str | None = None, value: Any = None) -> None:
        """Build 'path: message' (or take a whole 'path: message' text)."""
        if message is None:
            text = path
            path = text.partition(': ')[0] if ': ' in text else ''
        else:
            text = '{}: {}'.format(path, message)
        super().__init__(text)
        self.path = path
        self.value = value


class _Required:
    def __repr__(self) -> str:
        return 'REQUIRED'


REQUIRED: Any = _Required()   # the default of a field that must be given

# type name -> (accepts, phrase used in messages and docs)
_SCALARS: dict[str, tuple[Callable[[Any], bool], str]] = {
    'bool': (lambda v: isinstance(v, bool), 'true or false'),
    'int': (lambda v: isinstance(v, int) and not isinstance(v, bool), 'an int'),
    'float': (lambda v: isinstance(v, (int, float)) and not isinstance(v, bool)
              and math.isfinite(v), 'a number'),
    'str': (lambda v: isinstance(v, str), 'a string'),
    'list': (lambda v: isinstance(v, list), 'a list'),
    'map': (lambda v: isinstance(v, Mapping), 'a mapping'),
    'any': (lambda v: True, 'a value'),
}


_PLURAL = {'int': 'ints', 'float': 'numbers', 'str': 'strings', 'bool': 'booleans'}


def _num(x: float) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else repr(float(x))


@dataclasses.dataclass(frozen=True)
class Field:
    """One setting: type, default, unit, range or choices, and what a wrong value does.

    ``type`` is ``bool``, ``int``, ``float``, ``str``, ``list``, ``map``, ``any`` or a typed
    list (``float[]``); alternatives are joined with ``|`` (``int|str``). ``lo``/``hi`` bound
    numbers (every element of a list), exclusive when ``lo_open``/``hi_open``. ``expect``
    replaces the generated wording of ``expected <what>, got <value>``; ``check`` adds a test
    of the value that returns the whole message after ``<path>: `` (None when fine).
    ``derived_from`` names the field of the layered configuration a value is derived from.
    """

    type: str
    default: Any = REQUIRED
    description: str = ''
    unit: str = ''
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    choices: tuple[Any, ...] = ()
    nullable: bool = False
    length: int | None = None
    read_only: bool = False
    expect: str = ''
    check: Callable[[Any], str | None] | None = None
    derived_from: str = ''
    name: str = ''

    @property
    def required(self) -> bool:
        """Return True when the field has no default."""
        return self.default is REQUIRED

    @property
    def is_list(self) -> bool:
        """Return True for list types (``float[]``)."""
        return self.type.endswith('[]')

    @property
    def item_types(self) -> tuple[str, ...]:
        """Return the scalar type names a value (or each list element) may have."""
        return tuple(self.type.removesuffix('[]').split('|'))

    def range_text(self) -> str:
        """Return the range as text: ``1..99``, ``> 0``, ``(0, 1]``, or '' when unbounded."""
        lo, hi = self.lo, self.hi
        if lo is not None and hi is not None:
            if self.lo_open or self.hi_open:
                return '{}{}, {}{}'.format('(' if self.lo_open else '[', _num(lo), _num(hi),
                                           ')' if self.hi_open else ']')
            return '{}..{}'.format(_num(lo), _num(hi))
        if lo is not None:
            return '{} {}'.format('>' if self.lo_open else '>=', _num(lo))
        if hi is not None:
            return '{} {}'.format('<' if self.hi_open else '<=', _num(hi))
        return ''

    def expected(self) -> str:
        """Return what a value must be, as the type messages say it (``an int``)."""
        if self.expect:
            return self.expect
        if self.choices:
            what = 'one of ' + ', '.join(str(c) for c in self.choices)
        else:
            what = ' or '.join(_SCALARS[t][1] for t in self.item_types)
            if self.is_list:
                what = 'a list of {}{}'.format(
                    '{} '.format(self.length) if self.length else '',
                    ' or '.join(_PLURAL.get(t, t) for t in self.item_types))
        return what + (' or null' if self.nullable else '')

    def _in_range(self, v: Any) -> bool:
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            if self.lo is not None and (v <= self.lo if self.lo_open else v < self.lo):
                return False
            if self.hi is not None and (v >= self.hi if self.hi_open else v > self.hi):
                return False
        return True

    def problem(self, value: Any) -> str | None:
        """Return why ``value`` is wrong (the message after ``<path>: ``), or None.

        A wrong type says ``expected <what>, got <value>``, a value out of range ``must be
        <range>, got <value>``; a field with ``expect`` says ``expected <expect>`` for both.
        """
        if value is None and self.nullable:
            return None
        items = list(value) if self.is_list and isinstance(value, (list, tuple)) else [value]
        if self.choices:
            typed = value in self.choices and not isinstance(value, bool)
        elif self.is_list:
            typed = (isinstance(value, (list, tuple))
                     and (self.length is None or len(value) == self.length)
                     and all(any(_SCALARS[t][0](v) for t in self.item_types) for v in items))
        else:
            typed = any(_SCALARS[t][0](value) for t in self.item_types)
        if not typed:
            return 'expected {}, got {!r}'.format(self.expected(), value)
        if not all(self._in_range(v) for v in items):
            if self.expect:
                return 'expected {}, got {!r}'.format(self.expect, value)
            rng = self.range_text()
            return 'must be {}{}, got {!r}'.format(
                'in ' if '..' in rng or rng[0] in '[(' else '', rng, value)
        return self.check(value) if self.check is not None else None

    def coerce(self, value: Any) -> Any:
        """Return a valid ``value`` in its canonical form (YAML's ``1`` for a float is 1.0)."""
        if 'float' in self.item_types and 'int' not in self.item_types:
            if self.is_list and isinstance(value, (list, tuple)):
                return [float(v) if isinstance(v, int) and not isinstance(v, bool) else v
                        for v in value]
            if isinstance(value, int) and not isinstance(value, bool):
                return float(value)
        return value

    def validate(self, path: str, value: Any,
                 error: Callable[[str, str], Exception] | None = None) -> Any:
        """Return ``value`` coerced, or raise ``error(path, message)`` (ConfigError)."""
        reason = self.problem(value)
        if reason is not None:
            _raise(error, path, reason, value)
        return self.coerce(value)

    def doc_default(self) -> str:
        """Return the default as the docs show it."""
        if self.required:
            return '(required)'
        if self.default is None:
            return 'null'
        if isinstance(self.default, bool):
            return 'true' if self.default else 'false'
        if isinstance(self.default, str):
            return "''" if self.default == '' else self.default
        if isinstance(self.default, float):
            return repr(self.default)
        return str(self.default)


def _raise(error: Callable[[str, str], Exception] | None, path: str, message: str,
           value: Any) -> NoReturn:
    if error is None:
        raise ConfigError(path, message, value)
    raise error(path, message)


@dataclasses.dataclass(frozen=True)
class Section:
    """A table of fields under a path (``control``, ``tasks.<name>``) for the docs."""

    path: str
    title: str
    fields: Mapping[str, Field]
    note: str = ''


def check_keys(m: Mapping[str, Any], fields: Iterable[str], path: str,
               error: Callable[[str, str], Exception] | None = None) -> None:
    """Raise for the first key of ``m`` that is not a field: a misspelt key keeps a default."""
    allowed = set(fields)
    for k in m:
        if k not in allowed:
            _raise(error, '{}.{}'.format(path, k), 'unknown key (allowed: {})'.format(
                ', '.join(sorted(allowed))), k)


def validate_tree(table: Mapping[str, Field], m: Any, path: str,
                  error: Callable[[str, str], Exception] | None = None) -> dict[str, Any]:
    """Validate a nested section against a table with dotted names; return dotted -> value.

    Missing fields take their defaults (a required one is an error); unknown keys are errors;
    a sub-section given as null counts as empty.
    """
    if m is None:
        m = {}
    if not isinstance(m, Mapping):
        _raise(error, path, 'expected a mapping, got {!r}'.format(m), m)
    groups = {k.split('.', 1)[0] for k in table if '.' in k}
    check_keys(m, [k for k in table if '.' not in k] + sorted(groups), path, error)
    out: dict[str, Any] = {}
    for group in sorted(groups):
        sub = {k.split('.', 1)[1]: f for k, f in table.items() if k.startswith(group + '.')}
        for k, v in validate_tree(sub, m.get(group), '{}.{}'.format(path, group),
                                  error).items():
            out['{}.{}'.format(group, k)] = v
    for key, field in table.items():
        if '.' in key:
            continue
        where = '{}.{}'.format(path, key)
        if key in m:
            out[key] = field.validate(where, m[key], error)
        elif field.required:
            _raise(error, where, 'missing', None)
        else:
            out[key] = copy.deepcopy(field.default)
    return out


# --- settings declared on dataclasses ---------------------------------------------------------
#
# A frozen dataclass whose fields carry their Field (``kp: float = setting(Field(...))``) is the
# one declaration of a section: :func:`table` derives the dotted schema table from it (docs,
# validation), :func:`build` turns a validated flat mapping back into the dataclass. The code
# that runs reads plain dataclass attributes; no table is consulted per cycle.

_SETTING = 'm4k.setting'
_SECTION = 'm4k.section'
_DERIVED = 'm4k.derived'


_AS_DECLARED: Any = object()


def setting(f: Field, value: Any = _AS_DECLARED) -> Any:
    """Return a dataclass field declared by ``f`` (its default is ``f.default``).

    ``value``: the dataclass default when the field holds the file's value in another shape
    (the world's walls: ``{rectangle: [...]}`` in the file and the docs, segments in the
    dataclass); the caller converts a validated value the same way.
    """
    d = f.default if value is _AS_DECLARED else value
    if isinstance(d, (list, dict)):
        return dataclasses.field(default_factory=lambda: copy.deepcopy(d),
                                 metadata={_SETTING: f})
    return dataclasses.field(default=d, metadata={_SETTING: f})


def derived(default: Any) -> Any:
    """Return a dataclass field that is no setting: computed from the settings by the loader.

    :func:`table` and :func:`build` pass it by (the world's per-obstacle surfaces and paths,
    parsed from its ``obstacles`` entries).
    """
    return dataclasses.field(default=default, metadata={_DERIVED: True})


def section(cls: type, fields: Mapping[str, Field] | None = None) -> Any:
    """Return a dataclass field holding the nested section ``cls``.

    Its table is ``cls``'s own settings, or ``fields`` when one class serves several sections
    with different defaults and units (the linear and angular axis limits).
    """
    tab = dict(fields) if fields is not None else table(cls)
    names = {f.name for f in dataclasses.fields(cls) if _DERIVED not in f.metadata}
    if {k.split('.', 1)[0] for k in tab} != names:
        raise TypeError('{}: table keys {} do not match the fields {}'.format(
            cls.__name__, sorted(tab), sorted(names)))
    return dataclasses.field(
        default_factory=lambda: build(cls, {k: f.default for k, f in tab.items()}),
        metadata={_SECTION: (cls, tab)})


def table(cls: type) -> dict[str, Field]:
    """Return the dotted table (``pi.kp`` -> Field) a settings dataclass declares, in order."""
    out: dict[str, Field] = {}
    for f in dataclasses.fields(cls):
        if _SETTING in f.metadata:
            out[f.name] = f.metadata[_SETTING]
        elif _SECTION in f.metadata:
            for k, sub in f.metadata[_SECTION][1].items():
                out['{}.{}'.format(f.name, k)] = sub
        elif _DERIVED not in f.metadata:
            raise TypeError('{}.{} is neither a setting nor a section'.format(
                cls.__name__, f.name))
    return out


def build(cls: type, flat: Mapping[str, Any]) -> Any:
    """Return ``cls`` built from a validated dotted mapping (what :func:`validate_tree` gives)."""
    kw: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if _SECTION in f.metadata:
            p = f.name + '.'
            kw[f.name] = build(f.metadata[_SECTION][0], {k[len(p):]: v for k, v in flat.items()
                                                         if k.startswith(p)})
        elif f.name in flat:
            kw[f.name] = flat[f.name]
    return cls(**kw)


# --- RT core: runtime, tasks, ports (config/m4k.yaml) -----------------------------------------

def _nonempty_or_null(what: str) -> Callable[[Any], str | None]:
    def check(v: Any) -> str | None:
        return 'expected {}, got {!r}'.format(what, v) if v == '' else None
    return check


RUNTIME: dict[str, Field] = {
    'runtime_dir': Field(
        'str', None, 'Directory of the XDDP sockets. null: $M4K_RUNTIME_DIR, '
        '$XDG_RUNTIME_DIR/m4k, /run/m4k as root, else /tmp/m4k-<uid>. The bridge and driver '
        'host must use the same one, or no port ever links.', nullable=True,
        expect='a non-empty path or null', check=_nonempty_or_null('a non-empty path or null')),
    'group': Field(
        'str', None, 'Socket group: directory 0770 and sockets 0660 for its members. null: '
        'owner only (0700); a wrong group lets other users command the robot, or locks the '
        'peers out.', nullable=True, expect='a group name or null',
        check=_nonempty_or_null('a group name or null')),
    'require_rt': Field(
        'bool', False, 'Refuse to run when SCHED_FIFO, mlockall or the CPU DMA latency are not '
        'granted. false: run degraded and say so (fine in a container, not on the robot).'),
    'mlockall': Field(
        'bool', True, 'Lock all memory at start-up (mlockall MCL_CURRENT|MCL_FUTURE). false: a '
        'page fault can stall an RT task for milliseconds.'),
    'cpu_dma_latency': Field(
        'bool', True, 'Hold /dev/cpu_dma_latency at 0 us while running. false: deep C-states '
        'add wake-up latency to every release.'),
    'switch_interval_s': Field(
        'float', 1e-4, 'GIL switch interval (sys.setswitchinterval). The 5 ms default lets a '
        'low-priority task hold the GIL while the actuator waits (priority inversion).',
        unit='s', lo=1e-6, hi=1.0, expect='seconds in 1e-6..1'),
    'stats_batch': Field(
        'int', 128, 'Timing samples per TASK_STATS datagram (also bounded by max_datagram). '
        'Too small: more datagrams per second to the monitor.', lo=1, hi=4096,
        expect='an int in 1..4096'),
    'ring_capacity': Field(
        'int', 4096, 'Timing samples kept per task between two monitor batches. Too small: '
        'samples are overwritten and rt_status misses cycles.', lo=16, hi=1 << 20,
        expect='an int in 16..1048576'),
    'start_delay_ms': Field(
        'float', 100.0, "The task set's first common release this long after start-up.",
        unit='ms', lo=0, hi=10000, expect='ms in 0..10000'),
    'poolsz': Field(
        'int', DEFAULT_POOLSZ, 'Socket buffer per port (XDDP_POOLSZ analogue); with transport '
        'shm the ring each way. Too small: datagrams are dropped (counted) when a peer is slow.',
        unit='bytes', lo=4096, hi=1 << 26, expect='bytes in 4096..67108864'),
    'max_datagram': Field(
        'int', DEFAULT_MAX_DATAGRAM, 'Larger datagrams are dropped and counted, never sent. '
        'Too small: laser scans (about 1.4 kB) never arrive.', unit='bytes', lo=64, hi=65536,
        expect='bytes in 64..65536'),
    'max_ports': Field(
        'int', DEFAULT_MAX_PORTS, 'Port numbers are 0 .. max_ports - 1.', lo=1, hi=1024,
        expect='an int in 1..1024'),
    'transport': Field(
        'str', DEFAULT_TRANSPORT, 'How linked ports carry datagrams. socket: a send/recv on the '
        'Unix socket per datagram. shm: two rings (poolsz bytes each way) in shared memory passed '
        'at link time; the RT side makes no system call per received datagram and one '
        'eventfd write per sent one, and notices a lost peer within {:g} ms (message mode '
        'only). Peers follow what the RT side offers.'.format(SHM_LIVENESS_NS * 1e-6),
        choices=TRANSPORTS),
    'executive': Field(
        'str', 'threads', 'How the tasks are released. threads: one SCHED_FIFO thread and '
        'timerfd per task (the paper). frame: one SCHED_FIFO thread on one timerfd runs the '
        'frame_tasks back to back in every frame (the shortest of their periods), actuator '
        'first, in rate-monotonic order; the other tasks keep their own threads. A frame '
        "task that overruns delays every task after it, the next frame's actuator included.",
        choices=('threads', 'frame')),
    'frame_tasks': Field(
        'list', ['actuator', 'imu', 'led', 'sonar'], 'Tasks the frame executive runs in its '
        'frame (executive frame only): periods whole multiples of the shortest, bodies short. '
        'A configured name not running (disabled, or not in --tasks) is left out.'),
}

TASK: dict[str, Field] = {
    'period_ms': Field(
        'float', REQUIRED, 'Release period. Rate-monotonic order: a shorter period needs a '
        'higher priority, or the utilization test no longer holds.', unit='ms', lo=0,
        lo_open=True, expect='a number of ms > 0'),
    'offset_ms': Field(
        'float', 0, 'Release phase inside the period (0 <= offset < period_ms). Offsets that '
        "make a release coincide with the actuator's let that task take the GIL first.",
        unit='ms', lo=0),
    'priority': Field(
        'int', REQUIRED, 'SCHED_FIFO priority, higher first. Must follow rate-monotonic order; '
        'above 99 is not a valid FIFO priority.', lo=1, hi=99, expect='an int in 1..99'),
    'cpu': Field(
        'int', None, 'CPU to pin the task thread to; null: no pinning. A CPU that does not '
        'exist makes start-up fail.', nullable=True, lo=0,
        expect='a CPU index >= 0 or null'),
    'body': Field(
        'str', '<task name>', 'Task body (m4k_rt.tasks registry, or a --body-module plug-in); '
        'defaults to the task name. An unknown body is refused at start-up.',
        expect='a body name', check=lambda v: 'expected a body name, got {!r}'.format(v)
        if v == '' else None),
    'ports': Field(
        'str[]', [], 'Port labels this task owns (the ports section); one RT owner per port. '
        'The body looks its ports up by label: a missing one fails at start-up.',
        expect='a list of port labels'),
    'enabled': Field(
        'bool', True, 'false: the task is not run, and its ports are not bound (the bridge '
        'reports their devices silent).'),
    'params': Field(
        'map', {}, "Extra parameters for the task's body (body-specific).",
        expect='a mapping'),
}

PORT = Field(
    'int', REQUIRED, 'label -> XDDP port number; labels match [A-Za-z_][A-Za-z0-9_]{0,31} and '
    'numbers are unique. The driver host and bridge open ports by these labels and numbers: '
    'changing a number moves the peer with it.', lo=0, expect='a port number in 0..max_ports-1')


# --- robot (config/robot.yaml) ----------------------------------------------------------------

def _dims(description: str, positive: bool = True) -> Field:
    return Field('float', REQUIRED, description, unit='m', lo=0 if positive else None,
                 lo_open=positive)


def _frame_id(v: Any) -> str | None:
    if not v or any(c.isspace() for c in v):
        return 'expected a frame id, got {!r}'.format(v)
    return None


ROBOT: dict[str, Field] = {
    'name': Field('str', 'm4k', 'Robot name in the URDF.', expect='a name'),
    'body.length': _dims('Body along x (Table 2: 0.45). The URDF box.'),
    'body.width': _dims('Body along y (Table 2: 0.28).'),
    'body.height': _dims('Body along z (Table 2: 0.20).'),
    'body.bottom': _dims('Underside of the body relative to the wheel axle (negative: '
                         'below it).', positive=False),
    'body.mass': Field('float', REQUIRED, 'Whole robot (Table 2: 30); must exceed the two '
                       'wheels.', unit='kg', lo=0, lo_open=True),
    'wheel_width': _dims('Wheel width (radius and track: control.wheel_radius, '
                         'control.track_width).'),
    'wheel_mass': Field('float', REQUIRED, 'Each wheel, part of body.mass.', unit='kg', lo=0,
                        lo_open=True),
    'caster_radius': _dims('Two casters on the centre line; must be smaller than '
                           'control.wheel_radius.'),
    'caster_x': _dims('+-x of the casters from the axle.'),
    **{'sensors.{}.frame'.format(s): Field(
        'str', REQUIRED, "Frame id of the {} link (REP-103/105); the bridge's {}_frame is "
        'derived from it. Must differ from the other frames and base_link.'.format(s, s),
        expect='a frame id', check=_frame_id) for s in ('laser', 'imu', 'sonar')},
    **{'sensors.{}.pose'.format(s): Field(
        'float[]', REQUIRED, 'Pose of the {} in base_link: x y z [m] roll pitch yaw [rad]. '
        'Wrong: its readings land in the wrong place in tf (and in the simulator).'.format(s),
        length=6, expect='[x, y, z, roll, pitch, yaw] (6 finite numbers)')
       for s in ('laser', 'imu', 'sonar')},
}


# --- docs/configuration.md --------------------------------------------------------------------

def _cell(text: str) -> str:
    return text.replace('|', '\\|').replace('\n', ' ')


def _code(text: str) -> str:
    return '`{}`'.format(text) if text else ''


_STACK_SOURCE = ('`config_doc --markdown` (m4k_bringup) from the schema (m4k_rt/schema.py, '
                 "m4k_bridge/params.py, each device backend's registration)")


def markdown(sections: Sequence[Section], preamble: str = '',
             title: str = 'Configuration reference', source: str = _STACK_SOURCE) -> str:
    """Return the configuration reference page for ``sections`` (``source``: its generator)."""
    out = ['# ' + title, '',
           '<!-- Generated by {}. Do not edit: a test compares this page with the generated '
           'one. -->'.format(source), '']
    if preamble:
        out += [preamble, '']
    for sec in sections:
        out += ['## ' + sec.title, '']
        if sec.note:
            out += [sec.note, '']
        out += ['| field | type | default | unit | range / choices | description |',
                '|---|---|---|---|---|---|']
        for name, f in sec.fields.items():
            rng = ', '.join(str(c) for c in f.choices) if f.choices else f.range_text()
            if f.length:
                rng = (rng + '; ' if rng else '') + '{} values'.format(f.length)
            desc = f.description
            if f.read_only:
                desc += ' (read-only)'
            if f.derived_from and 'Derived' not in desc:
                desc += ' Derived from `{}`.'.format(f.derived_from)
            typ = f.type + (' or null' if f.nullable else '')
            out.append('| {} | {} | {} | {} | {} | {} |'.format(
                _code(name), typ, _code(_cell(f.doc_default())), _cell(f.unit),
                _cell(rng), _cell(desc)))
        out.append('')
    return '\n'.join(out)
