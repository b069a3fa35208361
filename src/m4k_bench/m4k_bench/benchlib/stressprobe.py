"""Which stress loads the CPUs without starving the vCPU: cyclictest under stress variants.

``python -m m4k_bench.benchlib.stressprobe [SECONDS]`` runs cyclictest (the actuator's period
and priority) alone and beside each :data:`VARIANTS` stress-ng command line, and prints per
variant: cyclictest p50 / p99 / max (µs), the validity verdict of :mod:`.validity`, and the
steal time the guest kernel counted meanwhile (``/proc/stat``: time the hypervisor ran
something else while this vCPU had work) -- the measurement behind docs/design-notes.md §12.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from typing import Any, Sequence

from m4k_bench.benchlib.validity import broken_reference

__all__ = ['VARIANTS', 'cpu_times', 'probe']

PERIOD_US = 10_000
PRIORITY = 90
_N = str(os.cpu_count() or 1)

# name -> stress-ng argv (after the binary, or the whole command when it names stress-ng);
# None: cyclictest alone.
VARIANTS: dict[str, list[str] | None] = {
    'alone': None,
    # the bench's old stress: every CPU 100 % busy at SCHED_OTHER nice 0
    'cpu_all': ['--cpu', _N],
    # the same work at the lowest class: the guest runs it only when nothing else wants a CPU
    'cpu_all_idleclass': ['--cpu', _N, '--sched', 'idle'],
    # SCHED_OTHER at the lowest weight (nice 19)
    'cpu_all_nice19': ['nice', '-n', '19', 'stress-ng', '--cpu', _N],
    # every CPU loaded to 70 %: the vCPU halts 30 % of the time, so it is not a pure spinner
    # to the host's scheduler
    'cpu_all_load70': ['--cpu', _N, '--cpu-load', '70'],
    # memory and scheduler pressure instead of pure spinning
    'vm_switch': ['--vm', '1', '--vm-bytes', '64M', '--switch', '1'],
    # the bench's stress until issue 42 (system.STRESS_ARGS then), and its parts alone
    'bench_old': ['--cpu', '2', '--vm', '1', '--vm-bytes', '256M', '--io', '1'],
    'vm256': ['--vm', '1', '--vm-bytes', '256M'],
    'io_sync': ['--io', '1'],
    # the bench's stress since issue 42 (system.STRESS_ARGS)
    'bench_new': ['--cpu', _N, '--vm', '1', '--vm-bytes', '256M', '--vm-keep'],
}


def cpu_times() -> dict[str, int]:
    """Return the summed /proc/stat CPU jiffies: busy, idle, steal."""
    with open('/proc/stat', encoding='ascii') as f:
        parts = [int(x) for x in f.readline().split()[1:]]
    user, nice, system, idle, iowait, irq, softirq, steal = (parts + [0] * 8)[:8]
    return {'busy': user + nice + system + irq + softirq, 'idle': idle + iowait, 'steal': steal}


def probe(seconds: float, variants: Sequence[str] = tuple(VARIANTS)) -> list[dict[str, Any]]:
    """Run cyclictest beside each variant for ``seconds``; return one row each."""
    from m4k_bench import core_bench
    exe = shutil.which('stress-ng')
    rows = []
    for name in variants:
        argv = VARIANTS[name]
        stress = None
        if argv is not None:
            if exe is None:
                rows.append({'variant': name, 'error': 'stress-ng not installed'})
                continue
            cmd = argv if 'stress-ng' in argv else [exe, *argv]
            stress = subprocess.Popen([*cmd, '--timeout', '{:d}s'.format(
                int(seconds) + 5), '--quiet'], stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL)
            time.sleep(0.5)
        t0 = cpu_times()
        ct = core_bench.run_cyclictest(seconds, priority=PRIORITY, interval_us=PERIOD_US)
        t1 = cpu_times()
        if stress is not None:
            stress.send_signal(signal.SIGINT)
            stress.wait(10)
        d = {k: t1[k] - t0[k] for k in t0}
        total = sum(d.values()) or 1
        row: dict[str, Any] = {'variant': name, 'stress': ' '.join(argv or []) or '-',
                               'busy_pct': 100.0 * d['busy'] / total,
                               'steal_pct': 100.0 * d['steal'] / total}
        if not ct or 'error' in ct:
            row['error'] = (ct or {}).get('error', 'cyclictest not installed')
        else:
            row.update(p50=ct['p50'], p99=ct['p99'], max=ct['max'],
                       broken=broken_reference(ct, PERIOD_US))
        rows.append(row)
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    """Print the probe's table (markdown): ``[SECONDS] [VARIANT,VARIANT]``."""
    args = list(sys.argv[1:] if argv is None else argv)
    seconds = float(args[0]) if args else 10.0
    names = args[1].split(',') if len(args) > 1 else list(VARIANTS)
    print('| variant | stress-ng | cyclictest p50 / p99 / max µs | CPU busy % | steal % | '
          'reference |')
    print('|---|---|---|---|---|---|')
    for r in probe(seconds, names):
        if 'error' in r:
            print('| {} | {} | {} | | | |'.format(r['variant'], r.get('stress', ''), r['error']))
            continue
        print('| {variant} | `{stress}` | {p50} / {p99} / {max} | {busy_pct:.0f} | '
              '{steal_pct:.1f} | {v} |'.format(v=r['broken'] or 'valid', **r))
    return 0


if __name__ == '__main__':
    sys.exit(main())
