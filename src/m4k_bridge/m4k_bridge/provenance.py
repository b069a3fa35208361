"""The commit of the code that runs: one lookup for every artifact m4k writes (no ROS).

The flight recorder's dumps, ``record``'s bags (the demo's among them) and every results
writer of m4k_bench (:mod:`m4k_bench.benchlib.provenance`: bench, soak, fuzz, scenarios, demo,
live view) name the commit through :func:`commit`, so an artifact can be traced to the code
that wrote it. It lives here, in the lowest package that writes artifacts, because the bridge
may not import m4k_bench.
"""

from __future__ import annotations

import os
import subprocess
from typing import Any

__all__ = ['COMMIT_KEY', 'commit', 'commit_text']

# The key under which a bag records the commit (metadata.yaml custom_data, MCAP metadata).
COMMIT_KEY = 'm4k.commit'


def _git(args: list[str], cwd: str) -> str | None:
    try:
        p = subprocess.run(['git', *args], cwd=cwd, capture_output=True, text=True,
                           timeout=10, check=False)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return p.stdout.strip() if p.returncode == 0 else None


def commit(where: str | None = None) -> dict[str, Any]:
    """Return ``{commit, dirty}`` of the checkout the code runs from (None when unknown).

    Looked up from ``where``, else this module's real location (a symlink install points
    into the source tree), else the working directory. ``dirty``: tracked files differ from
    the commit, so the commit alone does not reproduce the run.
    """
    here = os.path.dirname(os.path.realpath(__file__))
    for cwd in (where, here, os.getcwd()):
        if not cwd or not os.path.isdir(cwd):
            continue
        sha = _git(['rev-parse', 'HEAD'], cwd)
        if sha:
            status = _git(['status', '--porcelain', '--untracked-files=no'], cwd)
            return {'commit': sha, 'dirty': None if status is None else bool(status)}
    return {'commit': None, 'dirty': None}


def commit_text(info: dict[str, Any] | None = None) -> str:
    """Return the commit as one string: ``<sha>``, ``<sha>-dirty`` or ``unknown``."""
    c = commit() if info is None else info
    if not c.get('commit'):
        return 'unknown'
    return c['commit'] + ('-dirty' if c.get('dirty') else '')
