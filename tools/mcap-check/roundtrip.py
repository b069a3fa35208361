"""The recorder's schemas and CDR as Lichtblick decodes them: every field of the stack's types.

    source tools/env.sh && python tools/mcap-check/roundtrip.py   (npm ci here first)

Builds messages of the types the stack records (nav_msgs/Odometry, sensor_msgs/LaserScan,
Imu, Range, JointState, tf2_msgs/TFMessage, diagnostic_msgs/DiagnosticArray, m4k_msgs/RtStatus,
geometry_msgs/TwistStamped), with every field set to a value of its own, serializes them with
rclpy (the bytes the recorder stores as received), writes them with the recorder's writer and
schemas (``m4k_bridge.bag.msgdef``), then decodes the file with decode.mjs (Lichtblick's
ros2msg parser and CDR reader) and compares every field. Exit 0 when all match.
"""

from __future__ import annotations

import array
import importlib
import json
import math
import os
import subprocess
import sys
import tempfile
from typing import Any

from rclpy.serialization import serialize_message

from m4k_bridge.bag.writer import BagWriter

TYPES = ['nav_msgs/msg/Odometry', 'sensor_msgs/msg/LaserScan', 'sensor_msgs/msg/Imu',
         'sensor_msgs/msg/Range', 'sensor_msgs/msg/JointState', 'tf2_msgs/msg/TFMessage',
         'diagnostic_msgs/msg/DiagnosticArray', 'm4k_msgs/msg/RtStatus',
         'geometry_msgs/msg/TwistStamped']
HERE = os.path.dirname(os.path.abspath(__file__))


def _class(type_name: str) -> Any:
    pkg, _, name = type_name.split('/')
    return getattr(importlib.import_module(pkg + '.msg'), name)


class _Values:
    """A different, exactly representable value for every field filled."""

    def __init__(self) -> None:
        self.n = 0

    def next(self) -> int:
        self.n += 1
        return self.n

    def fill(self, msg: Any) -> Any:
        for field, kind in msg.get_fields_and_field_types().items():
            setattr(msg, field, self.value(kind, getattr(msg, field)))
        return msg

    def value(self, kind: str, current: Any) -> Any:
        if kind.startswith('sequence<') or '[' in kind:
            inner = kind[len('sequence<'):-1] if kind.startswith('sequence<') else \
                kind[:kind.index('[')]
            inner = inner.split(',')[0]
            size = len(current) if '[' in kind and not kind.endswith('[]') else 3
            items = [self.value(inner, None) for _ in range(size)]
            if isinstance(current, array.array):
                return array.array(current.typecode, items)
            return items
        n = self.next()
        if kind in ('double', 'float'):
            return n + 0.25
        if kind in ('boolean',):
            return n % 2 == 0
        if kind in ('string', 'wstring') or kind.startswith('string<'):
            return 'v{}'.format(n)
        if kind in ('octet', 'byte'):
            return bytes([n % 256])               # rclpy's byte: one-byte bytes
        if kind in ('uint8', 'char'):
            return n % 256
        if kind in ('int8',):
            return n % 128
        if kind.startswith(('int', 'uint')):
            return n
        return self.fill(_class(kind.replace('/', '/msg/', 1))())


def _plain(msg: Any) -> Any:
    if hasattr(msg, 'get_fields_and_field_types'):
        out = {f: _plain(getattr(msg, f)) for f in msg.get_fields_and_field_types()}
        if type(msg).__module__.startswith('builtin_interfaces'):
            out['nsec'] = out.pop('nanosec')      # Lichtblick's name for a ROS time's nanosec
        return out
    if isinstance(msg, bytes) and len(msg) == 1:
        return msg[0]
    if isinstance(msg, (list, tuple, array.array)) or type(msg).__name__ == 'ndarray':
        return [_plain(x) for x in msg]
    if isinstance(msg, bytes):
        return list(msg)
    return msg


def _diff(a: Any, b: Any, path: str = '') -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        out = [] if set(a) == set(b) else [
            '{}: fields {} vs {}'.format(path, sorted(a), sorted(b))]
        return out + [d for k in a if k in b for d in _diff(a[k], b[k], path + '.' + k)]
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return ['{}: {} items vs {}'.format(path, len(a), len(b))]
        return [d for i, (x, y) in enumerate(zip(a, b, strict=True))
                for d in _diff(x, y, '{}[{}]'.format(path, i))]
    if isinstance(a, float) or isinstance(b, float):
        return [] if math.isclose(float(a), float(b), rel_tol=1e-6) else [
            '{}: {} vs {}'.format(path, a, b)]
    if isinstance(a, bool) or isinstance(b, bool):
        return [] if bool(a) == bool(b) else ['{}: {} vs {}'.format(path, a, b)]
    return [] if a == b else ['{}: {!r} vs {!r}'.format(path, a, b)]


def main() -> int:
    """Write, decode with Lichtblick's code, compare; print per type; 1 if anything differs."""
    from m4k_bridge.bag.msgdef import message_definition, type_hash
    tmp = tempfile.mkdtemp(prefix='m4k-roundtrip-')
    w = BagWriter(os.path.join(tmp, 'types'))
    written = []
    values = _Values()
    for i, type_name in enumerate(TYPES):
        cid = w.add_topic('/t{}'.format(i), type_name, message_definition(type_name),
                          type_hash(type_name), [], '')
        msg = values.fill(_class(type_name)())
        w.write(cid, 1_000 + i, serialize_message(msg), i)
        written.append((type_name, _plain(msg)))
    w.close()
    out = subprocess.run(['node', os.path.join(HERE, 'decode.mjs'), w.path], check=True,
                         capture_output=True, text=True).stdout.splitlines()
    decoded = [json.loads(line) for line in out]
    problems = [] if len(decoded) == len(written) else ['{} messages decoded of {}'.format(
        len(decoded), len(written))]
    fields = 0
    for (type_name, want), got in zip(written, decoded, strict=False):   # counted above
        d = _diff(want, got['message'], type_name)
        problems += d
        fields += len(json.dumps(want).split(':')) - 1
        print('{:40s} {}'.format(type_name, 'same' if not d else '{} differences'.format(len(d))))
    for p in problems[:20]:
        print('  ' + p)
    print('{} types, {} fields compared: {}'.format(
        len(TYPES), fields, 'all equal' if not problems else '{} differ'.format(len(problems))))
    return 1 if problems else 0


if __name__ == '__main__':
    sys.exit(main())
