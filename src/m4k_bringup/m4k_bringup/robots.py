"""One argument for one robot of several, and several bridge parameter files (pure, no ROS).

``bringup --robot r1`` and ``ros2 launch m4k_bringup m4k.launch.py robot:=r1`` both take
:func:`robot_settings`: the namespace ``/r1``, the bridge's ``tf_namespaced: true`` (its
transforms on ``/r1/tf`` and ``/r1/tf_static``, which Nav2's namespaced launch files read
through their ``/tf:=tf`` remap), frames unprefixed: Nav2's multi-robot layout, where each
robot's tree is its own topic, so stock namespaced RViz, map_server and route_server find the
frames they default to (docs/nav2.md). robot_state_publisher gets the
same tf mode and prefix from :func:`robot_state_publisher_setup` -- whichever way they were set
(``robot:=``, ``config:=``'s bridge section or a ``bridge_params`` file) -- so it never publishes
the fixed joints into another tree than the bridge's. The recipes for that robot come from
``recipes --robot r1`` (names and frames to match).
"""

from __future__ import annotations

import os
import re
from typing import Any, Mapping, Sequence

import yaml

from m4k_bridge import params as bridge_params
from m4k_rt import yamlload

__all__ = ['TF_REMAPS', 'effective_bridge_values', 'for_namespace', 'load_param_file',
           'namespaced_files', 'param_files', 'robot_settings', 'robot_state_publisher_setup']

_NAME = re.compile(r'^[A-Za-z_][A-Za-z0-9_]*$')
# Namespaced tf: /tf and /tf_static become the namespace's tf and tf_static (as Nav2's
# navigation_launch.py remaps its nodes).
TF_REMAPS = (('/tf', 'tf'), ('/tf_static', 'tf_static'))


def robot_settings(robot: str) -> tuple[str, dict[str, Any]]:
    """Return (namespace, bridge parameter values) of the robot named ``robot``.

    Raise ValueError for a name that is no ROS name token (it becomes a namespace and a frame
    prefix).
    """
    if not _NAME.match(robot or ''):
        raise ValueError('robot name must be a ROS name token ([A-Za-z_][A-Za-z0-9_]*), got '
                         '{!r}'.format(robot))
    return '/' + robot, {'tf_namespaced': True}


def param_files(value: str | Sequence[str]) -> list[str]:
    """Return the absolute paths of one or more parameter files (comma-separated or a list).

    Raise ValueError naming a file that does not exist: ROS would otherwise fail later, in
    the node, with a less specific message.
    """
    items = value.split(',') if isinstance(value, str) else list(value)
    out = []
    for item in (i.strip() for i in items):
        if not item:
            continue
        path = os.path.abspath(os.path.expanduser(item))
        if not os.path.isfile(path):
            raise ValueError('bridge parameter file {!r} does not exist'.format(item))
        out.append(path)
    return out


def load_param_file(path: str) -> Any:
    """Return the document of a bridge parameter file through the one loader.

    ValueError naming the file for what :mod:`m4k_rt.yamlload` refuses (a duplicate key --
    which plain PyYAML would have resolved to the last value before the bridge's own check
    ever saw the file --, bytes that are not UTF-8, too deep nesting, bad YAML) and for a
    file that cannot be read.
    """
    try:
        with open(path, encoding='utf-8') as f:
            return yamlload.load(f)
    except OSError as exc:
        raise ValueError('bridge parameter file {!r}: cannot read: {}'.format(
            path, exc.strerror)) from None
    except yaml.YAMLError as exc:
        raise ValueError('bridge parameter file {!r}: {}'.format(
            path, str(exc).replace('\n', ' '))) from None


def effective_bridge_values(values: Mapping[str, Any], files: Sequence[str]) -> dict[str, Any]:
    """Return ``values`` as the bridge ends up with them after ``files`` (later files win)."""
    out = dict(values)
    for path in files:
        out.update(bridge_params.flatten_section(load_param_file(path)))
    return out


def for_namespace(doc: Mapping[str, Any], namespace: str) -> dict[str, Any]:
    """Return a parameter document whose bare ``m4k_bridge`` key names the namespaced node.

    rcl matches a section key against the node's fully qualified name: a bare ``m4k_bridge``
    is ``/m4k_bridge`` and never reaches ``/r1/m4k_bridge``, so under a namespace the section
    would silently not apply. Other keys (wildcards, other nodes) stay as they are.
    """
    ns = namespace.strip('/')
    if not ns:
        return dict(doc)
    return {('/{}/{}'.format(ns, key) if key == bridge_params.NODE_NAME else key): value
            for key, value in doc.items()}


def namespaced_files(files: Sequence[str], namespace: str, tmpdir: str) -> list[str]:
    """Return files, each rewritten into tmpdir for the namespace when it has to be."""
    if not namespace.strip('/'):
        return list(files)
    out = []
    for i, path in enumerate(files):
        doc = load_param_file(path) or {}
        if not isinstance(doc, Mapping):
            raise ValueError('bridge parameter file {!r}: top level must be a mapping'.format(
                path))
        if bridge_params.NODE_NAME not in doc:
            out.append(path)
            continue
        new = os.path.join(tmpdir, 'bridge_params_{}_{}'.format(i, os.path.basename(path)))
        with open(new, 'w', encoding='utf-8') as f:
            yaml.safe_dump(for_namespace(doc, namespace), f)
        out.append(new)
    return out


def robot_state_publisher_setup(values: Mapping[str, Any]) -> tuple[dict[str, Any],
                                                                    list[tuple[str, str]]]:
    """Return robot_state_publisher's parameters and remaps matching the bridge's tf mode."""
    rsp: dict[str, Any] = {'robot_description': values['robot_description']}
    if values.get('frame_prefix'):
        rsp['frame_prefix'] = values['frame_prefix']
    remaps = list(TF_REMAPS) if values.get('tf_namespaced') else []
    return rsp, remaps
