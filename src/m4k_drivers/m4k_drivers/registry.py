"""Backend registry: (device kind, backend name) -> factory building a device handler.

Device packages register their backends at import time::

    @register('imu', 'sim', params={'rate_hz': Param(float, 100.0)})
    def _build(name: str, params: dict, ctx: BuildContext) -> DeviceHandler: ...

``params`` is the schema of the device's config section (besides the common keys
``backend``, ``enabled`` and ``xddp_port``); :mod:`m4k_drivers.config` validates against it,
so a backend's accepted fields are declared once, next to its factory.  Kinds are imported
lazily from :data:`KIND_MODULES`, so a missing optional package (e.g. the laser) only matters
when a config actually asks for it.

Next to its backends, each kind registers the service that answers the RT side
(:func:`register_service`, a :class:`ServiceSpec`): which datagram kinds it takes, how it
serves one, its periodic and link-loss hooks, its ``--print`` line.  The driver host
(:mod:`m4k_drivers.host`) is generic plumbing around these specs, so adding a device touches
only its own package and the configuration: a kind registered by a module the host imports
(``driver_host --device-module MOD``) is known like the built-in ones.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
import importlib
import time
from typing import Any, Callable, Generic, Mapping, NamedTuple, Protocol, TYPE_CHECKING, TypeVar

from m4k_drivers.handler import DriverError
from m4k_rt.schema import Field, REQUIRED

if TYPE_CHECKING:  # pragma: no cover
    from m4k_drivers.handler import DeviceHandler
    from m4k_drivers.world import World

__all__ = [
    'COMMON_KEYS', 'KIND_MODULES', 'BackendSpec', 'BuildContext', 'Derived', 'Jog', 'Param',
    'RegistryError', 'Replier', 'ServiceSpec', 'backends', 'create', 'get', 'kinds', 'register',
    'register_service', 'service',
]

# A backend factory ``(name, params, ctx) -> handler``; the decorator keeps its precise type.
_Factory = TypeVar('_Factory', bound='Callable[..., DeviceHandler]')
# The handler class a service spec serves (MotorHandler, ImuHandler, ...).
H = TypeVar('H', bound='DeviceHandler')

# Where each built-in device kind registers its backends and service; imported on first use.
# A kind registered from elsewhere (a plug-in module) is added by register().
KIND_MODULES: dict[str, str] = {
    'motor': 'm4k_drivers.motors',
    'imu': 'm4k_drivers.imu',
    'sonar': 'm4k_drivers.sonar',
    'led': 'm4k_drivers.led',
    'lrf': 'm4k_drivers.lrf.backends',  # the package itself stays free of pyserial
}

# Keys every device section may carry, whatever its backend.
COMMON_KEYS = ('backend', 'enabled', 'xddp_port')


class RegistryError(DriverError, KeyError):
    """Raise for an unknown device kind or backend; the message lists the valid ones."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ''


_REQUIRED = object()


@dataclass(frozen=True)
class Derived:
    """A default that another setting of the layered configuration declares.

    The value is read when a section is validated, so the number lives in one place (a task
    period in ``tasks:``, config/m4k.yaml) and a backend's schema only names it.
    """

    source: str                # the setting it comes from, as the docs name it
    read: Callable[[], Any]    # its value in the shipped configuration

    def __str__(self) -> str:
        return f'<{self.source}>'


@dataclass(frozen=True)
class Param:
    """One config field of a backend: accepted type(s), default (omit = required), help.

    ``check`` (optional) validates the value after the type check: it returns None when the
    value is fine, else a short reason ("must be 1 or -1"); :mod:`m4k_drivers.config` turns
    that into a ConfigError naming the field and the value.  A :class:`Derived` default is
    read from the setting it names when a section leaves the field out.
    """

    type: type | tuple[type, ...]
    default: Any = _REQUIRED
    doc: str = ''
    check: Callable[[Any], str | None] | None = None

    @property
    def required(self) -> bool:
        """Return True when the field has no default."""
        return self.default is _REQUIRED

    def default_value(self) -> Any:
        """Return the default a section without this field gets (a fresh copy)."""
        if isinstance(self.default, Derived):
            return self.default.read()
        return copy.deepcopy(self.default)

    def as_field(self) -> Field:
        """Return this as a schema Field (m4k_rt.schema), which validates it and documents it."""
        types = self.type if isinstance(self.type, tuple) else (self.type,)
        names = [t.__name__ for t in types if t is not type(None)]
        check = self.check

        def full(value: Any) -> str | None:
            reason = check(value) if check is not None else None
            return None if reason is None else f'{reason}, got {value!r}'

        derived = self.default if isinstance(self.default, Derived) else None
        default = REQUIRED if self.required else str(derived) if derived else self.default
        return Field('|'.join(names), default, self.doc,
                     nullable=type(None) in types, derived_from=derived.source if derived else '',
                     expect=' or '.join(t.__name__ for t in types),
                     check=full if check is not None else None)


@dataclass(frozen=True)
class BackendSpec:
    """A registered backend: its kind, name, factory and config schema."""

    kind: str
    name: str
    factory: Callable[[str, dict[str, Any], BuildContext], DeviceHandler]
    params: dict[str, Param] = field(default_factory=dict)


@dataclass
class BuildContext:
    """What factories may need besides their params: the runtime dir, clock and sleep.

    ``sim`` backends reach the ``sim_robot`` process through the sim-bus socket in
    ``runtime_dir`` (:meth:`sim_runtime_dir`); ``world`` is an in-process world for the device
    models themselves (sim_robot and unit tests), never for the driver host.
    """

    world_config: dict[str, Any] | None = None
    clock: Callable[[], int] = time.monotonic_ns
    sleep: Callable[[float], None] = time.sleep      # waits on ``clock`` (sim sonar echoes)
    runtime_dir: str | None = None
    _world: World | None = None

    def sim_runtime_dir(self) -> str:
        """Return the runtime directory holding the simulator's sim-bus socket and pty link."""
        if self.runtime_dir:
            return self.runtime_dir
        from m4k_rt.channel import default_runtime_dir
        return default_runtime_dir()

    @property
    def world(self) -> World:
        """Return the one simulated world shared by all sim devices (created on first use)."""
        if self._world is None:
            from m4k_drivers.world import World, WorldConfig
            cfg = WorldConfig.from_dict(self.world_config or {})
            self._world = World(cfg, clock=self.clock)
        return self._world

    @property
    def has_world(self) -> bool:
        """Return True once a sim device asked for the world."""
        return self._world is not None


class Replier(Protocol):
    """Where a service sends its replies: the driver host's link to the RT side."""

    def send(self, kind: int, *fields: Any, stamp_ns: int | None = None) -> bool:
        """Encode and send one datagram (stamp: the sample time when known, else now)."""


class Jog(NamedTuple):
    """A device's console jog (``driver_host --jog TARGET SPEED --duration S [--yes]``).

    ``check(target, speed, duration_s)`` raises ValueError naming a value outside the caps
    (before any device is opened); ``run(handler, target, speed, duration_s, stop, out=,
    stdin=, assume_yes=)`` brings the device up, jogs, leaves the outputs safe and returns the
    exit code (it may raise ValueError too, e.g. a refused confirmation).
    """

    check: Callable[[str, float, float], None]
    run: Callable[..., int]


def _default_timeout(section: Mapping[str, Any]) -> float:
    return 0.1


def _no_stream(section: Mapping[str, Any]) -> float | None:
    return None


@dataclass(frozen=True)
class ServiceSpec(Generic[H]):
    """How the driver host serves one device kind to the RT side (docs/internals.md).

    * ``accepts``: the datagram kinds (:class:`m4k_rt.protocol.Kind`) it takes from the RT
      side; others are counted ``unexpected`` and dropped.
    * ``serve(handler, msg, tx)``: answer one decoded payload (``msg`` None: a stream tick)
      by sending the reply datagram(s) through ``tx``; called in every lifecycle state, so it
      checks the handler's state itself.  A ``ProtocolError`` while encoding is counted.
    * ``read_timeout(section)``: longest wait for a datagram (the loop's tick rate, s);
      ``stream_period(section)``: s between stream ticks, None = answer requests only.
    * ``tick(handler)``: every loop pass while ACTIVE (the motor watchdog).
    * ``on_link_lost(handler)``: the RT side went away while ACTIVE (motors safe at once);
      a DriverError it raises is counted as a fault.
    * ``max_age(section)``: oldest datagram (its header stamp, the sender's CLOCK_MONOTONIC) still
      served, s; older ones are counted ``stale`` and dropped (None: any age).  The motors
      set two periods, so commands queued during a driver-host stall are not replayed.
    * ``format(value)``: one ``--print`` line for a reading.
    * ``path_key``: the config field ``--port`` sets (and ``--bus`` when ``bus_arg``; a
      number is passed as an int); ``jog``: the ``--jog`` bring-up tool, if any.
    """

    accepts: frozenset[int]
    serve: Callable[[H, Any, Replier], None]
    format: Callable[[Any], str] | None = None
    read_timeout: Callable[[Mapping[str, Any]], float] = _default_timeout
    stream_period: Callable[[Mapping[str, Any]], float | None] = _no_stream
    max_age: Callable[[Mapping[str, Any]], float | None] = _no_stream
    tick: Callable[[H], object] | None = None
    on_link_lost: Callable[[H], object] | None = None
    path_key: str = 'port'
    bus_arg: bool = False
    jog: Jog | None = None


_BACKENDS: dict[tuple[str, str], BackendSpec] = {}
_SERVICES: dict[str, ServiceSpec[Any]] = {}
_LOAD_ERRORS: dict[str, str] = {}
_LOADED: set[str] = set()


def register(kind: str, name: str, params: dict[str, Param] | None = None,
             ) -> Callable[[_Factory], _Factory]:
    """Register ``factory(name, params, ctx) -> DeviceHandler`` for (kind, backend name)."""

    def deco(factory: _Factory) -> _Factory:
        _BACKENDS[(kind, name)] = BackendSpec(kind, name, factory, dict(params or {}))
        KIND_MODULES.setdefault(kind, factory.__module__)   # a plug-in kind is known now
        return factory

    return deco


def register_service(kind: str, spec: ServiceSpec[Any]) -> None:
    """Register how the driver host serves ``kind`` (next to the kind's backends)."""
    _SERVICES[kind] = spec


def service(kind: str) -> ServiceSpec[Any]:
    """Return the service spec of ``kind`` (importing its package) or raise RegistryError."""
    backends(kind)
    spec = _SERVICES.get(kind)
    if spec is None:
        why = f' ({_LOAD_ERRORS[kind]})' if kind in _LOAD_ERRORS else ''
        raise RegistryError(f'device {kind!r} registers no driver-host service{why}')
    return spec


def _load(kind: str) -> None:
    module = KIND_MODULES.get(kind)
    if module is None or kind in _LOADED:
        return
    _LOADED.add(kind)
    try:
        importlib.import_module(module)
    except ImportError as exc:
        # An optional device package (the laser) may not be installed; remember why.
        _LOAD_ERRORS[kind] = f'{module}: {exc}'


def kinds() -> list[str]:
    """Return the known device kinds."""
    return sorted(KIND_MODULES)


def backends(kind: str) -> list[str]:
    """Return the backend names registered for ``kind`` (importing its package)."""
    if kind not in KIND_MODULES:
        raise RegistryError(f'unknown device kind {kind!r}; valid kinds: {", ".join(kinds())}')
    _load(kind)
    return sorted(n for k, n in _BACKENDS if k == kind)


def get(kind: str, backend: str) -> BackendSpec:
    """Return the spec of (kind, backend) or raise RegistryError listing the valid backends."""
    valid = backends(kind)
    spec = _BACKENDS.get((kind, backend))
    if spec is None:
        if not valid and kind in _LOAD_ERRORS:
            raise RegistryError(f'device {kind!r} has no backends ({_LOAD_ERRORS[kind]})')
        raise RegistryError(f'unknown backend {backend!r} for device {kind!r}; '
                            f'valid backends: {", ".join(valid) or "(none)"}')
    return spec


def create(kind: str, section: dict[str, Any], ctx: BuildContext,
           name: str | None = None) -> DeviceHandler:
    """Build the handler for one validated device section (defaults already applied)."""
    spec = get(kind, section['backend'])
    params = {k: v for k, v in section.items() if k not in COMMON_KEYS}
    return spec.factory(name or kind, params, ctx)
