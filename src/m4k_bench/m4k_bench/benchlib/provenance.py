"""What a result measured: the commit of the code and the machine it ran on (one helper).

Every results writer of m4k_bench (bench, soak, fuzz, scenarios, demo, live view) stores
:func:`provenance` in what it writes, so a figure in the docs can be traced to the code it
measured and compared with another run on the same kind of machine. The machine is described
by what it is (CPU model, cores, memory, kernel, preemption model, virtualization), never by
its hostname: two runs on identical VMs compare, a renamed host does not break the link.
"""

from __future__ import annotations

import datetime
import os
import platform
import subprocess
from typing import Any

from m4k_bench.benchlib import system

__all__ = ['commit', 'machine', 'provenance', 'text']


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


def machine() -> dict[str, Any]:
    """Describe the machine without its name: CPU model, cores, memory, kernel, virtualization."""
    info = system.machine_info()
    keys = ('cpu_model', 'cpus_online', 'memory_gib', 'machine', 'kernel', 'preempt_model',
            'preempt_rt', 'virtualization', 'os', 'python')
    return {k: info.get(k) for k in keys}


def provenance(where: str | None = None) -> dict[str, Any]:
    """Return ``{commit, dirty, machine, measured_utc}`` for a result file."""
    return {**commit(where), 'machine': machine(),
            'measured_utc': datetime.datetime.now(datetime.timezone.utc).strftime(
                '%Y-%m-%dT%H:%M:%SZ')}


def text(p: dict[str, Any]) -> str:
    """Return one line for a Markdown report: commit (dirty?) on CPU x cores, kernel."""
    m = p['machine']
    sha = p['commit'][:12] if p['commit'] else 'unknown'
    sha += ' (with local changes)' if p['dirty'] else ''
    return 'commit {} on {} x{} ({} GiB), kernel {} {}{}'.format(
        sha, m.get('cpu_model') or platform.processor() or '?', m.get('cpus_online'),
        m.get('memory_gib'), m.get('kernel'), m.get('preempt_model') or '',
        ', {}'.format(m['virtualization']) if m.get('virtualization') else '')
