"""The M4K's robot description: URDF and sensor mounts from the configuration (pure, no rclpy).

One source: the ``robot:`` section of the layered configuration (``config/robot.yaml``) with
``control.wheel_radius`` and ``control.track_width``. From it come

* :func:`urdf` -- the URDF published on ``robot_description`` (paper Table 2 body, two
  continuous wheel joints, two casters, laser / IMU / sonar links at their mounts);
* :func:`fixed_joints` / :func:`wheel_joints` -- read back from a URDF text, so the bridge's
  ``tf_static`` and ``joint_states`` follow whatever description it publishes;
* :func:`mount_2d` / :func:`fill_sim_mounts` -- the (x, y, yaw) mounts the simulated laser and
  sonar see the world from (``devices.<lrf|sonar>.mount`` when the device section has none).

Frames follow REP-103/105: ``base_link`` on the wheel axle midway between the wheels, and
(as TurtleBot3 and Kobuki do) ``base_footprint`` its projection on the ground, the root of the
description and the child frame of odometry: joint ``base_joint`` (fixed) lifts ``base_link``
by the wheel radius above it. A model with ``footprint_frame=''`` keeps ``base_link`` as root.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from typing import Any, Mapping, NamedTuple
import xml.etree.ElementTree as ET

from m4k_rt import schema
from m4k_rt.control.params import CONTROL

__all__ = ['DescriptionError', 'Joint', 'Mount', 'RobotModel', 'SENSORS', 'WHEEL_JOINTS',
           'fill_sim_mounts', 'fixed_joints', 'joints', 'model', 'mount_2d', 'urdf',
           'wheel_joints']

SENSORS = ('laser', 'imu', 'sonar')
WHEEL_JOINTS = ('left_wheel_joint', 'right_wheel_joint')
# Simulated device kind -> sensor of the robot section whose mount it uses.
_SIM_MOUNTS = {'lrf': 'laser', 'sonar': 'sonar'}


class DescriptionError(schema.ConfigError):
    """The robot section (or a URDF text) is wrong; ``path`` names the field."""


@dataclasses.dataclass(frozen=True)
class Mount:
    """A sensor link: frame id and pose in base_link (metres, radians)."""

    frame: str
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]


@dataclasses.dataclass(frozen=True)
class RobotModel:
    """The validated robot section, everything in SI units."""

    name: str
    length: float
    width: float
    height: float
    bottom: float
    mass: float
    wheel_radius: float
    track_width: float
    wheel_width: float
    wheel_mass: float
    caster_radius: float
    caster_x: float
    sensors: Mapping[str, Mount]
    base_frame: str = 'base_link'
    footprint_frame: str = 'base_footprint'   # '' : no footprint link, base_frame is the root


class Joint(NamedTuple):
    """A URDF joint: name, type, parent and child links, origin xyz and rpy, axis."""

    name: str
    type: str
    parent: str
    child: str
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    axis: tuple[float, float, float] = (1.0, 0.0, 0.0)   # URDF's default


def _error(path: str, message: str) -> DescriptionError:
    return DescriptionError(path, message)


def _mapping(v: Any, path: str) -> Mapping[str, Any]:
    if not isinstance(v, Mapping):
        raise DescriptionError(path, 'expected a mapping, got {!r}'.format(v))
    return v


def _mount(m: Any, path: str) -> Mount:
    m = _mapping(m, path)
    sensor = path.rsplit('.', 1)[-1]
    frame = schema.ROBOT['sensors.{}.frame'.format(sensor)].validate(
        path + '.frame', m.get('frame'), _error)
    p = schema.ROBOT['sensors.{}.pose'.format(sensor)].validate(
        path + '.pose', m.get('pose'), _error)
    return Mount(frame, (p[0], p[1], p[2]), (p[3], p[4], p[5]))


def model(doc: Mapping[str, Any], base_frame: str = 'base_link',
          footprint_frame: str = 'base_footprint') -> RobotModel:
    """Return the robot model of a layered configuration document (``robot:`` + ``control:``).

    The ``robot`` section is checked against :data:`m4k_rt.schema.ROBOT` (unknown keys too).
    ``footprint_frame`` ('' for none) is the ground projection of ``base_frame``.
    """
    robot = _mapping(doc.get('robot'), 'robot')
    control = _mapping(doc.get('control') or {}, 'control')
    sensors = _mapping(robot.get('sensors'), 'robot.sensors')
    missing = [s for s in SENSORS if s not in sensors]
    if missing:
        raise DescriptionError('robot.sensors', 'missing {}'.format(', '.join(missing)))
    mounts = {s: _mount(sensors[s], 'robot.sensors.' + s) for s in SENSORS}
    frames = [m.frame for m in mounts.values()] + [base_frame] + [footprint_frame] * bool(
        footprint_frame)
    if len(set(frames)) != len(frames):
        raise DescriptionError('robot.sensors', 'frame ids must differ from each other and from '
                               '{!r}, got {!r}'.format(
                                   [base_frame, footprint_frame], frames[:3]))
    v = schema.validate_tree(schema.ROBOT, robot, 'robot', _error)
    wheel = {k: CONTROL[k].validate('control.' + k, control.get(k, CONTROL[k].default), _error)
             for k in ('wheel_radius', 'track_width')}
    m = RobotModel(
        name=v['name'], length=v['body.length'], width=v['body.width'],
        height=v['body.height'], bottom=v['body.bottom'], mass=v['body.mass'],
        wheel_radius=wheel['wheel_radius'], track_width=wheel['track_width'],
        wheel_width=v['wheel_width'], wheel_mass=v['wheel_mass'],
        caster_radius=v['caster_radius'], caster_x=v['caster_x'], sensors=mounts,
        base_frame=base_frame, footprint_frame=footprint_frame)
    if m.caster_radius >= m.wheel_radius:
        raise DescriptionError('robot.caster_radius', 'must be smaller than control.wheel_radius '
                               '({}), got {}'.format(m.wheel_radius, m.caster_radius))
    if m.mass <= 2 * m.wheel_mass:
        raise DescriptionError('robot.body.mass', 'must exceed the two wheels ({} kg), got {}'
                               .format(2 * m.wheel_mass, m.mass))
    return m


def mount_2d(doc: Mapping[str, Any], sensor: str) -> list[float]:
    """Return the planar mount [x, y, yaw] of ``sensor`` (laser, imu, sonar)."""
    m = _mount(_mapping(_mapping(doc.get('robot'), 'robot').get('sensors'),
                        'robot.sensors').get(sensor), 'robot.sensors.' + sensor)
    return [m.xyz[0], m.xyz[1], m.rpy[2]]


def fill_sim_mounts(doc: Mapping[str, Any]) -> dict[str, Any]:
    """Return ``doc`` with ``devices.<lrf|sonar>.mount`` taken from the robot section if unset.

    Only a section whose backend is ``sim`` gets one: the mount is where sim_robot's simulated
    sensor sees the world from, a field of the ``sim`` backend alone; a real sensor is where it
    is bolted, and the real backends' schemas rightly refuse the key.  A mount written in the
    device section wins (a deliberate test of a mis-mounted sensor); a document without a
    robot section is returned unchanged.
    """
    out = copy.deepcopy(dict(doc))
    devices = out.get('devices')
    if not isinstance(out.get('robot'), Mapping) or not isinstance(devices, dict):
        return out
    for kind, sensor in _SIM_MOUNTS.items():
        section = devices.get(kind)
        if (isinstance(section, dict) and section.get('backend') == 'sim'
                and 'mount' not in section):
            section['mount'] = mount_2d(out, sensor)
    return out


# --- URDF -----------------------------------------------------------------------------------

def _f(v: float) -> str:
    return repr(round(float(v), 6))


def _vec(v: tuple[float, ...] | list[float]) -> str:
    return ' '.join(_f(x) for x in v)


def _box_inertia(mass: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    k = mass / 12.0
    return k * (y * y + z * z), k * (x * x + z * z), k * (x * x + y * y)


def _inertial(link: ET.Element, mass: float, ixx: float, iyy: float, izz: float,
              xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
    el = ET.SubElement(link, 'inertial')
    ET.SubElement(el, 'origin', xyz=_vec(xyz), rpy='0 0 0')
    ET.SubElement(el, 'mass', value=_f(mass))
    ET.SubElement(el, 'inertia', ixx=_f(ixx), ixy='0', ixz='0', iyy=_f(iyy), iyz='0',
                  izz=_f(izz))


def _shape(link: ET.Element, tag: str, geometry: tuple[str, dict[str, str]],
           xyz: tuple[float, float, float] = (0.0, 0.0, 0.0),
           rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
    el = ET.SubElement(link, tag)
    ET.SubElement(el, 'origin', xyz=_vec(xyz), rpy=_vec(rpy))
    g = ET.SubElement(el, 'geometry')
    ET.SubElement(g, geometry[0], geometry[1])  # the attributes as attrib


def _joint(robot: ET.Element, name: str, kind: str, parent: str, child: str,
           xyz: tuple[float, float, float], rpy: tuple[float, float, float] = (0.0, 0.0, 0.0),
           axis: str | None = None) -> None:
    j = ET.SubElement(robot, 'joint', name=name, type=kind)
    ET.SubElement(j, 'parent', link=parent)
    ET.SubElement(j, 'child', link=child)
    ET.SubElement(j, 'origin', xyz=_vec(xyz), rpy=_vec(rpy))
    if axis is not None:
        ET.SubElement(j, 'axis', xyz=axis)


def urdf(m: RobotModel) -> str:
    """Return the URDF (XML text) of the robot model."""
    robot = ET.Element('robot', name=m.name)
    if m.footprint_frame:
        # First, so it is the root: the ground point under the axle centre (no geometry).
        ET.SubElement(robot, 'link', name=m.footprint_frame)
    base = ET.SubElement(robot, 'link', name=m.base_frame)
    if m.footprint_frame:
        _joint(robot, 'base_joint', 'fixed', m.footprint_frame, m.base_frame,
               (0.0, 0.0, m.wheel_radius))
    body_z = m.bottom + 0.5 * m.height
    box = ('box', {'size': _vec((m.length, m.width, m.height))})
    _shape(base, 'visual', box, (0.0, 0.0, body_z))
    _shape(base, 'collision', box, (0.0, 0.0, body_z))
    casters = 0.1 * m.mass / 30.0  # small; the rest of the mass is the body's
    body_mass = m.mass - 2 * m.wheel_mass - 2 * casters
    _inertial(base, body_mass, *_box_inertia(body_mass, m.length, m.width, m.height),
              xyz=(0.0, 0.0, body_z))
    r, w = m.wheel_radius, m.wheel_width
    cyl = ('cylinder', {'radius': _f(r), 'length': _f(w)})
    for side, sign, joint in (('left', 1.0, WHEEL_JOINTS[0]), ('right', -1.0, WHEEL_JOINTS[1])):
        link = ET.SubElement(robot, 'link', name='{}_wheel_link'.format(side))
        # The cylinder's axis is z: roll it onto the wheel axle (y).
        _shape(link, 'visual', cyl, rpy=(math.pi / 2, 0.0, 0.0))
        _shape(link, 'collision', cyl, rpy=(math.pi / 2, 0.0, 0.0))
        k = m.wheel_mass / 12.0
        ixx = k * (3 * r * r + w * w)
        _inertial(link, m.wheel_mass, ixx, 0.5 * m.wheel_mass * r * r, ixx)
        _joint(robot, joint, 'continuous', m.base_frame, link.get('name', ''),
               (0.0, sign * 0.5 * m.track_width, 0.0), axis='0 1 0')
    cr = m.caster_radius
    for side, sign in (('front', 1.0), ('rear', -1.0)):
        link = ET.SubElement(robot, 'link', name='{}_caster_link'.format(side))
        sphere = ('sphere', {'radius': _f(cr)})
        _shape(link, 'visual', sphere)
        _shape(link, 'collision', sphere)
        i = 0.4 * casters * cr * cr
        _inertial(link, casters, i, i, i)
        # Caster touches the ground where the wheels do: centre at -(wheel_radius - radius).
        _joint(robot, '{}_caster_joint'.format(side), 'fixed', m.base_frame,
               link.get('name', ''), (sign * m.caster_x, 0.0, cr - r))
    for sensor, mount in m.sensors.items():
        link = ET.SubElement(robot, 'link', name=mount.frame)
        size = {'laser': (0.05, 0.05, 0.07), 'imu': (0.04, 0.04, 0.01),
                'sonar': (0.02, 0.045, 0.02)}[sensor]
        _shape(link, 'visual', ('box', {'size': _vec(size)}))
        _joint(robot, '{}_joint'.format(sensor), 'fixed', m.base_frame, mount.frame,
               mount.xyz, mount.rpy)
    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding='unicode') + '\n'


# --- reading a URDF back --------------------------------------------------------------------

def _floats(text: str | None, what: str) -> tuple[float, float, float]:
    try:
        v = tuple(float(x) for x in (text or '0 0 0').split())
    except ValueError:
        raise DescriptionError(what, 'expected three numbers, got {!r}'.format(text)) from None
    if len(v) != 3 or not all(math.isfinite(x) for x in v):
        raise DescriptionError(what, 'expected three finite numbers, got {!r}'.format(text))
    return v[0], v[1], v[2]


def joints(text: str) -> list[Joint]:
    """Return every joint of a URDF text; DescriptionError when it is not a usable URDF."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise DescriptionError('robot_description', 'not valid XML: {}'.format(exc)) from None
    if root.tag != 'robot':
        raise DescriptionError('robot_description', 'root element must be <robot>, got <{}>'
                               .format(root.tag))
    links = {e.get('name') for e in root.findall('link')}
    out = []
    for j in root.findall('joint'):
        name, kind = j.get('name', ''), j.get('type', '')
        parent, child = j.find('parent'), j.find('child')
        if parent is None or child is None:
            raise DescriptionError('joint {!r}'.format(name), 'needs <parent> and <child>')
        p, c = parent.get('link', ''), child.get('link', '')
        if p not in links or c not in links:
            raise DescriptionError('joint {!r}'.format(name), 'links {!r} -> {!r} are not both '
                                   'defined'.format(p, c))
        origin = j.find('origin')
        xyz = _floats(origin.get('xyz') if origin is not None else None, name + ' origin xyz')
        rpy = _floats(origin.get('rpy') if origin is not None else None, name + ' origin rpy')
        axis_el = j.find('axis')
        axis = (_floats(axis_el.get('xyz'), name + ' axis') if axis_el is not None
                else (1.0, 0.0, 0.0))
        out.append(Joint(name, kind, p, c, xyz, rpy, axis))
    return out


def fixed_joints(text: str) -> list[Joint]:
    """Return the fixed joints of a URDF: the transforms that go on ``tf_static``."""
    return [j for j in joints(text) if j.type == 'fixed']


def wheel_joints(text: str) -> list[Joint]:
    """Return the joints named in :data:`WHEEL_JOINTS`, in that order (left, right)."""
    by_name = {j.name: j for j in joints(text)}
    missing = [n for n in WHEEL_JOINTS if n not in by_name]
    if missing:
        raise DescriptionError('robot_description', 'no joint {}'.format(', '.join(missing)))
    return [by_name[n] for n in WHEEL_JOINTS]
