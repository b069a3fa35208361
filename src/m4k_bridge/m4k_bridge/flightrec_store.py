"""The flight recorder's dump directory kept bounded: a disk cap and an age limit (no ROS).

A repeating incident (a guard stop every minute for a week) writes a dump each
``min_interval``; on an SD card that must not grow without end. After every dump, and when the
recorder starts, :func:`prune` removes dumps older than ``max_age_s``, then the oldest until
the dumps take at most ``max_disk_bytes`` -- newest evidence kept. Only this recorder's own
dumps are touched: directories named ``flight_<UTC time>_<trigger>[-n]`` directly in the dump
directory, and the same names ending in ``.partial`` (a dump a crash cut off before its
rename takes disk like any other: it counts towards the cap and goes by the same rules);
anything else there is left alone (and not counted). A dump's age comes from the
UTC time in its name (a copy with rsync keeps it), its size from the blocks its files take.
"""

from __future__ import annotations

import calendar
import os
import re
import shutil
import time
from typing import Callable, NamedTuple

__all__ = ['DumpDir', 'dumps', 'prune', 'stamp', 'unused_path']

_NAME = re.compile(r'flight_(\d{4})_(\d\d)_(\d\d)-(\d\d)_(\d\d)_(\d\d)_[a-z_]+(-\d+)?'
                   r'(?:\.partial)?')


def stamp(wall_ns: int) -> str:
    """Return ``wall_ns`` (since the epoch) as the UTC time in names here: 2026_11_29-15_42_28."""
    return time.strftime('%Y_%m_%d-%H_%M_%S', time.gmtime(wall_ns // 1_000_000_000))


def unused_path(base: str, ext: str = '', taken: Callable[[str], bool] = os.path.lexists
                ) -> str:
    """Return ``base + ext``, else the first of ``base-2 + ext``, ``base-3 + ext``... not taken.

    Two dumps (or traces) of the same second and kind keep both.
    """
    path, n = base + ext, 1
    while taken(path):
        n += 1
        path = f'{base}-{n}{ext}'
    return path


class DumpDir(NamedTuple):
    """One dump directory: path, trigger time (UTC seconds since the epoch), disk bytes."""

    path: str
    t_s: float
    size: int


def _disk_bytes(path: str) -> int:
    total = 0
    for root, _, files in os.walk(path):
        for name in files:
            try:
                st = os.lstat(os.path.join(root, name))
            except OSError:
                continue
            total += st.st_blocks * 512
    return total


def dumps(directory: str) -> list[DumpDir]:
    """Return this recorder's dumps in ``directory``, oldest first."""
    try:
        names = os.listdir(directory)
    except FileNotFoundError:
        return []
    out = []
    for name in names:
        m = _NAME.fullmatch(name)
        path = os.path.join(directory, name)
        if m is None or os.path.islink(path) or not os.path.isdir(path):
            continue
        t_s = calendar.timegm(tuple(int(g) for g in m.groups()[:6]) + (0, 0, 0))
        out.append(DumpDir(path, float(t_s), _disk_bytes(path)))
    out.sort(key=lambda d: (d.t_s, d.path))
    return out


def prune(directory: str, max_disk_bytes: int, max_age_s: float, now_s: float | None = None,
          keep: str = '') -> tuple[list[str], int]:
    """Remove dumps past the age limit, then the oldest past the cap; return (removed, bytes).

    ``max_age_s`` 0: no age limit. ``keep``: a dump never removed (the one just written: when
    it alone is over the cap it stays, and the caller says so). The bytes returned are what
    the remaining dumps take.
    """
    now = time.time() if now_s is None else now_s
    found = dumps(directory)
    removed = []
    kept = []
    for d in found:
        if max_age_s > 0 and now - d.t_s > max_age_s and d.path != keep:
            removed.append(d)
        else:
            kept.append(d)
    total = sum(d.size for d in kept)
    for d in list(kept):                 # oldest first
        if total <= max_disk_bytes:
            break
        if d.path == keep:
            continue
        kept.remove(d)
        removed.append(d)
        total -= d.size
    for d in removed:
        shutil.rmtree(d.path, ignore_errors=True)
    return [d.path for d in removed], total
