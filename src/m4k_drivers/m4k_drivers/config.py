"""Load and validate the driver host configuration (``config/devices.yaml``).

Two sections::

    devices:            # one entry per device kind (motor, imu, sonar, led, lrf)
      imu:
        backend: real   # a backend registered for the kind (see m4k_drivers.registry)
        enabled: true   # optional, default true
        xddp_port: 3    # optional, default: the port labelled imu (the kind)
        bus: 1          # backend fields, schema declared with the backend's registration
                        # (registry.Param, validated as an m4k_rt.schema Field)
    world:              # the simulated world (m4k_drivers.world.WorldConfig.from_dict)

Every error is a :class:`ConfigError` whose message starts with the dotted field name.
"""

from __future__ import annotations

from dataclasses import dataclass
import os
from pathlib import Path
from typing import Any

from m4k_drivers import registry
from m4k_drivers.drive import ROBOT_FIELDS
from m4k_drivers.faults import FAULT
from m4k_drivers.handler import DriverError
from m4k_drivers.scene import EVENT, OBSTACLE, PATH
from m4k_drivers.world import RobotParams, WORLD, WorldConfig, WorldConfigError
from m4k_rt import schema
from m4k_rt.config import deep_merge as merge
from m4k_rt.config import find_config_dir
from m4k_rt.schema import Field, REQUIRED, Section

__all__ = ['COMMON', 'KERNEL_STANDIN', 'ConfigError', 'DriverConfig',
           'default_config_path', 'kernel_standin', 'load', 'load_file', 'merge',
           'fill_actuator_period', 'schema_sections', 'validate']



class ConfigError(DriverError, schema.ConfigError):
    """Raise for a bad configuration; the message names the field."""


@dataclass
class DriverConfig:
    """Validated driver-host configuration: device sections (defaults applied) and world."""

    devices: dict[str, dict[str, Any]]
    world: WorldConfig
    world_raw: dict[str, Any]


def default_config_path() -> Path:
    """Return ``$M4K_DEVICES_CONFIG``, else ``devices.yaml`` in the config directory."""
    env = os.environ.get('M4K_DEVICES_CONFIG')
    if env:
        return Path(env)
    return Path(find_config_dir()) / 'devices.yaml'


def load_file(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read one YAML file into a mapping (ConfigError naming the path on failure)."""
    import yaml

    from m4k_rt import yamlload
    try:
        with open(path, encoding='utf-8') as fh:
            data = yamlload.load(fh)
    except OSError as exc:
        raise ConfigError(f'{path}: {exc.strerror} (errno {exc.errno})') from exc
    except yamlload.DuplicateKeyError as exc:
        raise ConfigError(f'{path}: {exc}') from None
    except yaml.YAMLError as exc:
        raise ConfigError(f'{path}: invalid YAML: {exc}') from exc
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f'{path}: top level must be a mapping, got {type(data).__name__}')
    return data


def _error(path: str, message: str) -> ConfigError:
    return ConfigError(f'{path}: {message}')


def _port_or_label(v: Any) -> str | None:
    return 'expected a port number or label, got {!r}'.format(v) if v == '' else None


# The keys every device section has, whatever its backend (registry.COMMON_KEYS).
COMMON: dict[str, Field] = {
    'backend': Field('str', REQUIRED, 'Which registered backend serves the device (real '
                     'hardware, sim on sim_robot, or an alternative interface). An unknown '
                     'one is refused, listing the valid ones.'),
    'enabled': Field('bool', True, 'false: the driver host does not open the device; the RT '
                     'side reports it silent.', expect='bool'),
    'xddp_port': Field('int|str', '<kind>', 'XDDP port (number or label) of the RT peer; '
                       'default: the label of the device kind (the RT side labels every port '
                       'with its key in ports:, config/m4k.yaml, where the numbers are declared). '
                       'A wrong one never links.',
                       lo=0, expect='a port number or label', check=_port_or_label),
}


# The kernel-ABI stand-in (m4k_drivers.abi): real backends on simulated hardware.
KERNEL_STANDIN: dict[str, Field] = {
    'enabled': Field('bool', False, 'true: the driver host serves the device nodes of every '
                     'enabled real motor, imu and sonar (gpio) backend from the kernel-ABI '
                     'stand-in (m4k_drivers.abi), which forwards what the wires carry to '
                     "sim_robot's models; sim_robot then simulates those devices. The real "
                     'backends (python-periphery, smbus2) run unchanged; no real device node is '
                     'opened. For bring-up rehearsals and tests, never on the robot.',
                     expect='bool'),
}
STANDIN_KINDS = ('motor', 'imu', 'sonar')    # the kinds whose real backends it serves


def kernel_standin(raw: Any) -> bool:
    """Return ``kernel_standin.enabled`` of a merged document (ConfigError if malformed)."""
    section = raw.get('kernel_standin') if isinstance(raw, dict) else None
    if section is None:
        return False
    if not isinstance(section, dict):
        raise ConfigError(f'kernel_standin: expected a mapping, got {section!r}')
    unknown = sorted(set(section) - set(KERNEL_STANDIN))
    if unknown:
        raise ConfigError(f'kernel_standin: unknown field(s) {unknown!r}; valid: '
                          f'{", ".join(KERNEL_STANDIN)}')
    return bool(KERNEL_STANDIN['enabled'].validate('kernel_standin.enabled',
                                                   section.get('enabled', False), _error))


def world_sections() -> list[Section]:
    """Return the schema Sections of ``world:`` (the simulated room and robot), for the docs."""
    where = '(config/devices.yaml, a scenario file)'
    return [
        Section('world', f'world: the simulated room {where}', WORLD,
                'Read by sim_robot (the simulator) and by the judges of the demo and the '
                'scenarios, which use the same world model.'),
        Section('world.robot', 'world.robot: the simulated robot as built (config/devices.yaml)',
                ROBOT_FIELDS,
                "The simulator's physics (m4k_drivers.drive); sources and the braking they "
                "give: docs/sim-physics.md. Geometry unset here takes the control section's "
                'value. Checked together: |amp_offset_*_v| < supply_v, mu_kinetic <= mu, '
                'and the supply must overcome the friction.'),
        Section('world.obstacles[]', 'world.obstacles[]: one obstacle given as a mapping',
                OBSTACLE, 'What each sensor makes of a surface: m4k_drivers.scene.'),
        Section('world.obstacles[].path', 'world.obstacles[].path: a moving obstacle', PATH,
                'start.travelled and start.after must both be reached; {} or null: at the '
                "robot's first motion."),
        Section('world.events[]', 'world.events[]: a change of the simulated hardware', EVENT),
        Section('world.faults[]', 'world.faults[]: a fault the simulator injects', FAULT,
                'Checked together: until_s after at_s; wheel given for the per-wheel kinds '
                'only.'),
    ]


def schema_sections() -> list[Section]:
    """Return the kernel_standin Section and one per registered (device kind, backend)."""
    out = [Section('kernel_standin', 'kernel_standin (real backends on the kernel-ABI '
                   'stand-in; docs/real-robot.md)', KERNEL_STANDIN)]
    for kind in registry.kinds():
        for backend in registry.backends(kind):
            spec = registry.get(kind, backend)
            fields = {k: f for k, f in COMMON.items() if k != 'backend'}
            fields.update((n, p.as_field()) for n, p in spec.params.items())
            out.append(Section(f'devices.{kind}', f'devices.{kind}, backend: {backend} '
                               '(config/devices.yaml)', fields))
    return out


def validate_device(kind: str, section: Any, where: str) -> dict[str, Any]:
    """Validate one device section and return it with defaults applied."""
    if not isinstance(section, dict):
        raise ConfigError(f'{where}: expected a mapping, got {section!r}')
    if 'backend' not in section:
        raise ConfigError(f'{where}.backend: missing; valid backends: '
                          f'{", ".join(registry.backends(kind)) or "(none)"}')
    backend = section['backend']
    try:
        spec = registry.get(kind, backend)
    except registry.RegistryError as exc:
        raise ConfigError(f'{where}.backend: {exc}') from None
    out: dict[str, Any] = {
        'backend': backend,
        'enabled': COMMON['enabled'].validate(f'{where}.enabled', section.get('enabled', True),
                                              _error),
        'xddp_port': COMMON['xddp_port'].validate(
            f'{where}.xddp_port', section.get('xddp_port', kind), _error)}
    unknown = sorted(set(section) - set(registry.COMMON_KEYS) - set(spec.params))
    if unknown:
        valid = sorted(set(registry.COMMON_KEYS) | set(spec.params))
        raise ConfigError(f'{where}: unknown field(s) {unknown!r} for backend {backend!r}; '
                          f'valid: {", ".join(valid)}')
    for name, param in spec.params.items():
        if name in section:
            out[name] = param.as_field().validate(f'{where}.{name}', section[name], _error)
        elif param.required:
            doc = f' ({param.doc})' if param.doc else ''
            raise ConfigError(f'{where}.{name}: missing, required by backend {backend!r}{doc}')
        else:
            out[name] = param.default_value()
    return out


def fill_actuator_period(raw: dict[str, Any]) -> dict[str, Any]:
    """Return ``raw`` with the motor service's period taken from the actuator task.

    The period is declared once, as ``tasks.actuator.period_ms`` (config/m4k.yaml); the motor
    service runs at it (its watchdog counts in those periods) unless ``devices.motor.period_s``
    says otherwise.
    """
    period_ms = ((raw.get('tasks') or {}).get('actuator') or {}).get('period_ms')
    motor = (raw.get('devices') or {}).get('motor')
    if (not isinstance(motor, dict) or 'period_s' in motor or isinstance(period_ms, bool)
            or not isinstance(period_ms, (int, float))):
        return raw
    devices = {**raw['devices'], 'motor': {**motor, 'period_s': period_ms * 1e-3}}
    return {**raw, 'devices': devices}


def validate(doc: dict[str, Any], control: dict[str, Any] | None = None,
             body: dict[str, Any] | None = None, wheel_width: Any = None) -> DriverConfig:
    """Validate a whole document with ``devices:`` and ``world:`` sections.

    ``control`` (the stack's ``control:`` section), ``body`` (``robot.body``) and
    ``wheel_width`` (``robot.wheel_width``) give the
    simulated robot's defaults, so the simulator is the configured robot -- one source for each
    physical value -- unless ``world.robot`` says how it was built differently.
    """
    unknown = sorted(set(doc) - {'devices', 'world'})
    if unknown:
        raise ConfigError(f'unknown top-level section(s) {unknown!r}; valid: devices, world')
    devices = doc.get('devices') or {}
    if not isinstance(devices, dict):
        raise ConfigError(f'devices: expected a mapping of device sections, got {devices!r}')
    out = {}
    for kind, section in devices.items():
        if kind not in registry.KIND_MODULES:
            raise ConfigError(f'devices.{kind}: unknown device; valid: '
                              f'{", ".join(registry.kinds())}')
        out[kind] = validate_device(kind, section, f'devices.{kind}')
    world_raw = doc.get('world') or {}
    try:
        robot = (RobotParams.from_control(control, body, wheel_width)
                 if control is not None or body is not None else None)
        world = WorldConfig.from_dict(world_raw, robot=robot)
    except WorldConfigError as exc:
        raise ConfigError(str(exc)) from None
    return DriverConfig(out, world, world_raw)


def load(path: str | os.PathLike[str] | None = None,
         overrides: dict[str, Any] | None = None) -> DriverConfig:
    """Load ``path`` (default :func:`default_config_path`), layer ``overrides``, validate."""
    doc = load_file(path or default_config_path())
    if overrides:
        doc = merge(doc, overrides)      # m4k_rt.config.deep_merge: the stack's one layering
    return validate(doc)
