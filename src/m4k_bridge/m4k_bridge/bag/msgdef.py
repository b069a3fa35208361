"""Message definitions for MCAP ``ros2msg`` schemas and RIHS01 type hashes (pure: files only).

A ``ros2msg`` schema is what rosbag2 writes and Foxglove, ``ros2 bag`` and mcap-ros2-support
read: the type's ``.msg`` text, then every message type it uses (depth first, each once)
after a line of 80 ``=`` and a line ``MSG: <package>/<Name>``. The texts come from the
``share/<package>/msg/<Name>.msg`` files every interface package installs (the PyPI wheels
too), and the type hash from the ``<Name>.json`` type description installed beside it (ROS 2
Iron and later), so the recorder needs no ROS graph query and no full ROS install.
"""

from __future__ import annotations

import json
import os
import re
from typing import Callable

__all__ = ['MsgDefError', 'dependencies', 'message_definition', 'split_type', 'type_hash']

SEPARATOR = '=' * 80
PRIMITIVES = frozenset((
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16', 'int32',
    'uint32', 'int64', 'uint64', 'string', 'wstring'))
_ARRAY = re.compile(r'\[[^\]]*\]$')
_BOUND = re.compile(r'<=\d+$')


class MsgDefError(LookupError):
    """A message type's definition cannot be found or read."""


def _default_share(package: str) -> str:
    from ament_index_python.packages import get_package_share_directory
    return get_package_share_directory(package)


def split_type(type_name: str) -> tuple[str, str]:
    """Return (package, Name) of ``pkg/msg/Name`` or ``pkg/Name``."""
    parts = type_name.split('/')
    if len(parts) == 3 and parts[1] == 'msg':
        return parts[0], parts[2]
    if len(parts) == 2:
        return parts[0], parts[1]
    raise MsgDefError('not a message type name (pkg/msg/Name): {!r}'.format(type_name))


def _read(package: str, name: str, suffix: str,
          share: Callable[[str], str]) -> str:
    try:
        path = os.path.join(share(package), 'msg', name + suffix)
        with open(path, encoding='utf-8') as f:
            return f.read()
    except (OSError, LookupError, ValueError) as exc:
        raise MsgDefError('no {} for {}/msg/{}: {}'.format(suffix, package, name, exc)) from None


def dependencies(text: str, package: str) -> list[str]:
    """Return the message types (``pkg/Name``) the fields of a ``.msg`` text use, in order."""
    out: list[str] = []
    for line in text.splitlines():
        line = line.split('#', 1)[0].strip()
        if not line:
            continue
        base = _BOUND.sub('', _ARRAY.sub('', line.split()[0]))
        if base in PRIMITIVES:
            continue
        pkg, name = split_type(base) if '/' in base else (package, base)
        dep = '{}/{}'.format(pkg, name)
        if dep not in out:
            out.append(dep)
    return out


def message_definition(type_name: str,
                       share: Callable[[str], str] = _default_share) -> str:
    """Return the ``ros2msg`` schema text of ``type_name`` with every nested definition."""
    package, name = split_type(type_name)
    top = _read(package, name, '.msg', share)
    parts = [top.rstrip('\n')]
    seen = {'{}/{}'.format(package, name)}
    stack = list(reversed(dependencies(top, package)))
    while stack:
        dep = stack.pop()
        if dep in seen:
            continue
        seen.add(dep)
        pkg, dname = split_type(dep)
        text = _read(pkg, dname, '.msg', share)
        parts.append('{}\nMSG: {}\n{}'.format(SEPARATOR, dep, text.rstrip('\n')))
        stack.extend(reversed(dependencies(text, pkg)))
    return '\n'.join(parts) + '\n'


def type_hash(type_name: str, share: Callable[[str], str] = _default_share) -> str:
    """Return the RIHS01 hash of ``type_name`` from its installed type description, or ''."""
    package, name = split_type(type_name)
    try:
        doc = json.loads(_read(package, name, '.json', share))
    except (MsgDefError, ValueError):
        return ''
    full = '{}/msg/{}'.format(package, name)
    for entry in doc.get('type_hashes', ()):
        if entry.get('type_name') == full:
            return str(entry.get('hash_string', ''))
    return ''
