"""What a result measured: the commit of the code and the machine it ran on (one helper).

Every results writer of m4k_bench (bench, soak, fuzz, scenarios, demo, live view) stores
:func:`provenance` in what it writes, so a figure in the docs can be traced to the code it
measured and compared with another run on the same kind of machine. The commit comes from
:mod:`m4k_bridge.provenance`, the lookup the bags (flight recorder, ``record``) use too. The
machine is described by what it is (CPU model, cores, memory, kernel, preemption model,
virtualization), never by its hostname: two runs on identical VMs compare, a renamed host does
not break the link.
"""

from __future__ import annotations

import datetime
import platform
from typing import Any

from m4k_bench.benchlib import system
from m4k_bridge import provenance as bridge_provenance

__all__ = ['commit', 'machine', 'provenance', 'text']


def commit(where: str | None = None) -> dict[str, Any]:
    """Return ``{commit, dirty}`` of the checkout (:func:`m4k_bridge.provenance.commit`)."""
    return bridge_provenance.commit(where)


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
