"""Layered YAML configuration of the RT core: load, deep-merge, validate runtime/tasks/ports.

Layers, later wins: ``m4k.yaml`` (required), ``devices.yaml`` and ``control.yaml`` (when
present) from the config directory, then an optional user overlay. Mappings merge key by key;
lists and scalars replace. Other top-level sections belong to other components and pass
through untouched in :attr:`RtConfig.raw`.

Validation goes through the schema (:mod:`m4k_rt.schema`: ``RUNTIME``, ``TASK``, ``PORT``);
errors are :class:`ConfigError` naming the field path and showing the bad value, e.g.
``tasks.led.priority: expected an int in 1..99, got 120``.
"""

import dataclasses
import os
import re
from typing import Any, Callable, Mapping

import yaml

from m4k_rt import schema, yamlload
from m4k_rt.schema import ConfigError

__all__ = [
    'ConfigError', 'LAYERS', 'RtConfig', 'RuntimeConfig', 'TaskConfig', 'deep_merge',
    'find_config_dir', 'load', 'load_layered', 'parse', 'shipped_period_s',
]

LAYERS = ('m4k.yaml', 'devices.yaml', 'control.yaml', 'robot.yaml')
_LABEL = re.compile(r'^[A-Za-z_][A-Za-z0-9_]{0,31}$')


def _d(name: str) -> Any:
    return schema.RUNTIME[name].default


@dataclasses.dataclass(frozen=True)
class RuntimeConfig:
    """The ``runtime`` section (defaults: :data:`m4k_rt.schema.RUNTIME`)."""

    runtime_dir: str | None = _d('runtime_dir')
    group: str | None = _d('group')
    require_rt: bool = _d('require_rt')
    mlockall: bool = _d('mlockall')
    cpu_dma_latency: bool = _d('cpu_dma_latency')
    switch_interval_s: float = _d('switch_interval_s')
    stats_batch: int = _d('stats_batch')
    ring_capacity: int = _d('ring_capacity')
    start_delay_ms: float = _d('start_delay_ms')
    poolsz: int = _d('poolsz')
    max_datagram: int = _d('max_datagram')
    max_ports: int = _d('max_ports')
    transport: str = _d('transport')
    executive: str = _d('executive')
    frame_tasks: tuple[str, ...] = tuple(_d('frame_tasks'))


@dataclasses.dataclass(frozen=True)
class TaskConfig:
    """One entry of the ``tasks`` section."""

    name: str
    index: int
    period_ns: int
    priority: int
    cpu: int | None
    body: str
    ports: tuple[str, ...]
    enabled: bool = True
    params: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    offset_ns: int = 0   # release phase within the period (see config/m4k.yaml, offset_ms)


@dataclasses.dataclass(frozen=True)
class RtConfig:
    """Validated RT configuration plus the whole merged document."""

    runtime: RuntimeConfig
    tasks: tuple[TaskConfig, ...]      # enabled tasks, config order
    ports: Mapping[str, int]           # label -> port number
    raw: Mapping[str, Any]

    def task(self, name: str) -> TaskConfig:
        """Return the task called ``name`` (KeyError when not configured or disabled)."""
        for t in self.tasks:
            if t.name == name:
                return t
        raise KeyError(name)


CONFIG_PACKAGE = 'm4k_bringup'   # the package whose share directory holds config/


def find_config_dir() -> str:
    """Return the config directory: $M4K_CONFIG_DIR, the ament share dir, or the repo's.

    The one install of ``config/`` is ``m4k_bringup``'s share directory (found by the ament
    index, a data lookup: nothing of m4k_bringup is imported).
    """
    env = os.environ.get('M4K_CONFIG_DIR')
    if env:
        return env
    try:
        from ament_index_python.packages import get_package_share_directory
        share = os.path.join(get_package_share_directory(CONFIG_PACKAGE), 'config')
        if os.path.isfile(os.path.join(share, LAYERS[0])):
            return share
    except Exception:  # noqa: BLE001 -- not installed through ament: use the source tree
        pass
    return os.path.normpath(os.path.join(os.path.dirname(__file__), '..', '..', '..', 'config'))


def deep_merge(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    """Return ``base`` updated by ``over``: mappings merge recursively, the rest replaces."""
    out = dict(base)
    for k, v in over.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), Mapping):
            out[k] = deep_merge(out[k], v)
        else:
            out[k] = v
    return out


def _read_yaml(path: str) -> dict[str, Any]:
    try:
        with open(path, encoding='utf-8') as f:
            doc = yamlload.load(f)
    except OSError as exc:
        raise ConfigError(path, 'cannot read: {} [errno {}]'.format(exc.strerror, exc.errno),
                          path) from exc
    except yamlload.DuplicateKeyError as exc:
        raise ConfigError(path, str(exc), exc.key) from None
    except yaml.YAMLError as exc:
        raise ConfigError(path, 'not valid YAML: {}'.format(
            str(exc).replace('\n', ' '))) from exc
    if doc is None:
        return {}
    if not isinstance(doc, dict):
        raise ConfigError(path, 'top level must be a mapping, got {!r}'.format(
            type(doc).__name__), doc)
    return doc


def load_layered(overlay: str | None = None, config_dir: str | None = None) -> dict[str, Any]:
    """Read and deep-merge the config layers; return the merged document (not validated)."""
    d = config_dir or find_config_dir()
    first = os.path.join(d, LAYERS[0])
    merged = _read_yaml(first)
    for name in LAYERS[1:]:
        p = os.path.join(d, name)
        if os.path.isfile(p):
            merged = deep_merge(merged, _read_yaml(p))
    if overlay:
        merged = deep_merge(merged, _read_yaml(overlay))
    return merged


def shipped_period_s(task: str, config_dir: str | None = None) -> float:
    """Return the period of ``task`` as the layered configuration declares it, in s.

    The one source of a task period (``tasks.<task>.period_ms``, config/m4k.yaml) for code
    that runs without the RT side's validated configuration: the motor service's default
    period, a guard plan on a bare rig.
    """
    return float(load_layered(config_dir=config_dir)['tasks'][task]['period_ms']) * 1e-3


# --- validation -----------------------------------------------------------------------------

def _is_num(v: Any) -> bool:
    return (isinstance(v, (int, float)) and not isinstance(v, bool)) and v == v


def _mapping(v: Any, path: str) -> Mapping[str, Any]:
    if not isinstance(v, Mapping):
        raise ConfigError(path, 'expected a mapping, got {!r}'.format(v), v)
    return v


def _parse_runtime(m: Any) -> RuntimeConfig:
    m = _mapping(m if m is not None else {}, 'runtime')
    schema.check_keys(m, schema.RUNTIME, 'runtime')
    out = {k: schema.RUNTIME[k].validate('runtime.' + k, v) for k, v in m.items()}
    if 'frame_tasks' in out:
        names = out['frame_tasks']
        if not all(isinstance(n, str) and n for n in names):
            raise ConfigError('runtime.frame_tasks', 'expected a list of task names, got '
                              '{!r}'.format(names), names)
        out['frame_tasks'] = tuple(names)
    return RuntimeConfig(**out)


def _parse_ports(m: Any, max_ports: int) -> dict[str, int]:
    m = _mapping(m, 'ports')
    field = dataclasses.replace(schema.PORT, hi=max_ports - 1,
                                expect='a port number in 0..{}'.format(max_ports - 1))
    seen: dict[int, str] = {}
    for label, port in m.items():
        path = 'ports.{}'.format(label)
        if not isinstance(label, str) or not _LABEL.match(label):
            raise ConfigError(path, 'label must match {}, got {!r}'.format(
                _LABEL.pattern, label), label)
        field.validate(path, port)
        if port in seen:
            raise ConfigError(path, 'duplicate port {!r} (also ports.{})'.format(
                port, seen[port]), port)
        seen[port] = label
    return dict(m)


def _parse_task(name: Any, m: Any, index: int, ports: Mapping[str, int],
                body_exists: Callable[[str], bool] | None) -> TaskConfig:
    path = 'tasks.{}'.format(name)
    if not isinstance(name, str) or not name or len(name.encode()) > 16:
        raise ConfigError(path, 'task name must be 1..16 bytes of text, got {!r}'.format(
            name), name)
    m = _mapping(m, path)
    schema.check_keys(m, schema.TASK, path)
    for key, field in schema.TASK.items():
        if field.required and key not in m:
            raise ConfigError('{}.{}'.format(path, key), 'missing')

    def get(key: str, default: Any = None) -> Any:
        field = schema.TASK[key]
        value = m.get(key, field.default if default is None else default)
        return field.validate('{}.{}'.format(path, key), value)

    period = get('period_ms')
    offset = m.get('offset_ms', 0)
    if not _is_num(offset) or not 0 <= offset < period:
        raise ConfigError(path + '.offset_ms', 'expected ms in 0..period_ms ({!r}), '
                          'got {!r}'.format(m['period_ms'], offset), offset)
    prio = get('priority')
    cpu = get('cpu')
    body = get('body', name)
    if body_exists is not None and not body_exists(body):
        raise ConfigError(path + '.body', 'unknown task body {!r}'.format(body), body)
    labels = get('ports')
    for label in labels:
        if label not in ports:
            raise ConfigError(path + '.ports', 'unknown port label {!r}'.format(label), label)
    enabled = get('enabled')
    params = schema.TASK['params'].validate(path + '.params', m.get('params') or {})
    return TaskConfig(name, index, int(round(period * 1_000_000)), prio, cpu, body,
                      tuple(labels), enabled, dict(params), int(round(offset * 1_000_000)))


def parse(raw: Mapping[str, Any],
          body_exists: Callable[[str], bool] | None = None) -> RtConfig:
    """Validate the runtime/tasks/ports sections of a merged document into an RtConfig.

    ``body_exists`` (when given) tells whether a task body name can be resolved.
    """
    raw = _mapping(raw, '<config>')
    runtime = _parse_runtime(raw.get('runtime'))
    if 'ports' not in raw:
        raise ConfigError('ports', 'missing')
    ports = _parse_ports(raw['ports'], runtime.max_ports)
    if 'tasks' not in raw:
        raise ConfigError('tasks', 'missing')
    tasks_m = _mapping(raw['tasks'], 'tasks')
    tasks: list[TaskConfig] = []
    owner: dict[str, str] = {}
    for name, m in tasks_m.items():
        t = _parse_task(name, m, len(tasks), ports, body_exists)
        if not t.enabled:
            continue
        for label in t.ports:
            if label in owner:
                raise ConfigError('tasks.{}.ports'.format(name), 'port {!r} already used by '
                                  'task {!r} (one RT owner per port)'.format(
                                      label, owner[label]), label)
            owner[label] = name
        tasks.append(t)
    if not tasks:
        raise ConfigError('tasks', 'no enabled task')
    return RtConfig(runtime, tuple(tasks), ports, raw)


def load(overlay: str | None = None, config_dir: str | None = None,
         body_exists: Callable[[str], bool] | None = None) -> RtConfig:
    """Load the layered configuration and validate it."""
    return parse(load_layered(overlay, config_dir), body_exists)
