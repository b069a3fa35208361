"""ROS 2 command-line arguments for the executables that are not rclpy nodes (pure, no rclpy).

``ros2 launch`` (launch_ros's ``Node`` action) and ``ros2 run ... --ros-args`` append ROS
arguments to every executable they start::

    exe [own args] --ros-args -r __node:=NAME --params-file /tmp/launch_params_XXXX
        -r __ns:=/NS -p name:=value -r from:=to --log-level debug [--] [own args]

rclpy nodes hand them to rcl. The RT process and the tools must not import rclpy (the RT side's
rule), so they parse them here, following rcl's ``arguments.c``: any number of ``--ros-args``
sections, each ended by ``--`` or the end of the command line; every flag that takes a value
must have one; an unknown flag inside a section is an error (as rclpy's UnknownROSArgsError).

What applies to a plain process is used: the node name and namespace (``__node``/``__name``,
``__ns``, also in their ``node:`` prefixed form) for its log prefix, ``--log-level`` for
Python logging. Parameters, parameter files, other remaps, the enclave and the log switches
are kept for the caller and otherwise ignored.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
from typing import Sequence

__all__ = ['RosArgs', 'RosArgsError', 'parse_args', 'python_level', 'split']

ROS_ARGS = '--ros-args'
END = '--'
_VALUE_FLAGS = {
    '-r': 'remap', '--remap': 'remap', '-p': 'param', '--param': 'param',
    '--params-file': 'params_file', '--log-level': 'log_level', '-e': 'enclave',
    '--enclave': 'enclave', '--log-config-file': 'log_config_file',
    '--log-file-name': 'log_file_name',
}
_SWITCHES = ('stdout-logs', 'rosout-logs', 'external-lib-logs')
# rcutils severities -> Python logging levels ('unset' keeps the default).
_LEVELS = {'debug': logging.DEBUG, 'info': logging.INFO, 'warn': logging.WARNING,
           'warning': logging.WARNING, 'error': logging.ERROR, 'fatal': logging.CRITICAL,
           'unset': logging.NOTSET}


class RosArgsError(ValueError):
    """A ``--ros-args`` section is malformed; the message names the argument."""


@dataclasses.dataclass
class RosArgs:
    """The ROS arguments of one command line, as rcl would read them."""

    present: bool = False                 # at least one --ros-args section
    node_name: str | None = None          # from -r [node:]__node:=NAME (or __name)
    namespace: str | None = None          # from -r [node:]__ns:=/NS
    remaps: list[tuple[str | None, str, str]] = dataclasses.field(default_factory=list)
    params: dict[str, str] = dataclasses.field(default_factory=dict)    # -p name:=yaml text
    params_files: list[str] = dataclasses.field(default_factory=list)
    log_levels: dict[str, str] = dataclasses.field(default_factory=dict)  # '' = default level
    enclave: str | None = None
    log_config_file: str | None = None
    log_file_name: str | None = None
    switches: dict[str, bool] = dataclasses.field(default_factory=dict)  # 'stdout-logs': True

    def name(self, default: str) -> str:
        """Return the fully qualified node name: namespace + (remapped) name."""
        base = self.node_name or default
        ns = (self.namespace or '').rstrip('/')
        return '{}/{}'.format(ns, base) if ns else base


def _rule(flag: str, text: str) -> tuple[str | None, str, str]:
    lhs, sep, rhs = text.partition(':=')
    if not sep or not lhs:
        raise RosArgsError('{} {!r}: expected [node:]from:=to'.format(flag, text))
    node, colon, match = lhs.rpartition(':')
    if colon and not node:
        raise RosArgsError('{} {!r}: empty node name before ":"'.format(flag, text))
    return (node or None, match, rhs)


def _take(out: RosArgs, flag: str, value: str, node: str | None) -> None:
    kind = _VALUE_FLAGS[flag]
    if kind == 'remap':
        target, match, rhs = _rule(flag, value)
        if not rhs:
            raise RosArgsError('{} {!r}: empty replacement'.format(flag, value))
        if target is not None and node is not None and target != node:
            return  # a rule for another node (rcl ignores it for this one)
        if match in ('__node', '__name'):
            out.node_name = rhs
        elif match == '__ns':
            if not rhs.startswith('/'):
                raise RosArgsError('{} {!r}: a namespace must be absolute'.format(flag, value))
            out.namespace = rhs
        else:
            out.remaps.append((target, match, rhs))
    elif kind == 'param':
        name, sep, text = value.partition(':=')
        if not sep or not name:
            raise RosArgsError('{} {!r}: expected name:=value'.format(flag, value))
        out.params[name] = text
    elif kind == 'params_file':
        out.params_files.append(value)
    elif kind == 'log_level':
        logger, sep, level = value.rpartition(':=')
        if level.lower() not in _LEVELS:
            raise RosArgsError('{} {!r}: unknown severity (one of {})'.format(
                flag, value, ', '.join(sorted(_LEVELS))))
        out.log_levels[logger if sep else ''] = level.lower()
    else:
        setattr(out, kind, value)


def split(argv: Sequence[str], node: str | None = None) -> tuple[list[str], RosArgs]:
    """Return (the non-ROS arguments, the parsed ROS arguments) of ``argv`` (no program name).

    ``node`` is the executable's own node name: ``other:__node:=x`` rules for other nodes are
    skipped, as rcl does. Raise :class:`RosArgsError` for a malformed section.
    """
    rest: list[str] = []
    out = RosArgs()
    args = list(argv)
    i, inside = 0, False
    while i < len(args):
        a = args[i]
        if not inside:
            if a == ROS_ARGS:
                inside = out.present = True
            else:
                rest.append(a)
            i += 1
            continue
        if a == ROS_ARGS:
            i += 1
        elif a == END:
            inside = False
            i += 1
        elif a in _VALUE_FLAGS:
            if i + 1 >= len(args):
                raise RosArgsError('{} needs a value (at the end of the command line)'.format(a))
            _take(out, a, args[i + 1], node)
            i += 2
        elif a.startswith(('--enable-', '--disable-')) and a.split('-', 3)[3] in _SWITCHES:
            out.switches[a.split('-', 3)[3]] = a.startswith('--enable-')
            i += 1
        else:
            raise RosArgsError('unknown ROS argument {!r} after {} (known: {})'.format(
                a, ROS_ARGS, ', '.join(sorted(_VALUE_FLAGS))))
    return rest, out


def python_level(ros: RosArgs, logger: str = '') -> int | None:
    """Return the Python logging level ``--log-level`` asks for ``logger`` (or the default)."""
    level = ros.log_levels.get(logger, ros.log_levels.get(''))
    return None if level in (None, 'unset') else _LEVELS[level]


def configure_logging(ros: RosArgs, verbose: bool = False) -> None:
    """Set up the root logger of an NRT process: ``--ros-args --log-level`` wins over ``-v``."""
    level = python_level(ros)
    if level is None:
        level = logging.DEBUG if verbose else logging.INFO
    logging.basicConfig(level=level, format='%(asctime)s %(name)s %(levelname)s: %(message)s')


def parse_args(ap: argparse.ArgumentParser, argv: Sequence[str] | None = None,
               node: str | None = None) -> argparse.Namespace:
    """Parse a tool's command line with ``ap`` after taking out its ROS arguments.

    The result carries them as ``ros_args`` (:class:`RosArgs`). A ``--log-level`` sets the
    root Python logger's level. A malformed ROS section is a usage error (exit code 2), like
    any other bad argument.
    """
    raw = list(sys.argv[1:] if argv is None else argv)
    try:
        rest, ros = split(raw, node or ap.prog)
    except RosArgsError as exc:
        ap.error(str(exc))
    level = python_level(ros)
    if level is not None:
        logging.getLogger().setLevel(level)
    ns = ap.parse_args(rest)
    ns.ros_args = ros
    return ns
