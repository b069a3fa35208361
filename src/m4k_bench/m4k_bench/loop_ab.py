"""loop_ab: CPU per task cycle of two (or more) m4k_rt versions side by side, against the floor.

Each round runs the Python floor (:mod:`m4k_bench.benchlib.floor`, the configured task set's
rates) and then the full stack once per variant, in alternating order (reversed every other
round), exactly as the bench's ``m4k_idle`` condition measures it: rt_core's process CPU over
the window ÷ the cycles of its tasks. A variant is a directory holding an ``m4k_rt`` package,
put first on the stack's ``PYTHONPATH`` (rt_core, the bridge and the driver host all import
it). A version of the tree, e.g. before a change::

    git archive <rev> src/m4k_rt | tar -x -C /tmp/before
    loop_ab --variant before=/tmp/before/src/m4k_rt --variant after=src/m4k_rt --rounds 6

Prints every round and the median (min-max) of each variant's CPU per cycle and of its ratio
to the same round's floor. A benchmark, not a test; only ratios taken in one run mean much on
a shared machine.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from typing import Any, Sequence

from m4k_bench.benchlib import floor, rounds, stack
from m4k_rt import config, rosargs

__all__ = ['main', 'run']


def run(variants: dict[str, str], nrounds: int, seconds: float, floor_s: float = 5.0,
        e2e: bool = True) -> dict[str, Any]:
    """Run the rounds; return per-round CPU per cycle (µs) of every variant and of the floor."""
    ts = [t for t in config.load().tasks if t.enabled]
    rates = [1e9 / t.period_ns for t in ts]
    base = os.environ.get('PYTHONPATH', '')
    res: dict[str, list[Any]] = {k: [] for k in (*variants, 'floor')}
    logs = tempfile.mkdtemp(prefix='m4k-loop-ab-')
    for r in range(nrounds):
        fl = floor.run_floor_child([t.period_ns for t in ts], [t.priority for t in ts],
                                   [t.offset_ns for t in ts], floor_s)
        res['floor'].append(None if isinstance(fl, str) else fl['cpu_per_cycle_us'])
        order = list(variants) if r % 2 == 0 else list(reversed(variants))
        for name in order:
            env = dict(os.environ, PYTHONPATH=os.pathsep.join(
                x for x in (os.path.abspath(variants[name]), base) if x))
            rundir = os.path.join(tempfile.mkdtemp(prefix='ab'), 'm4k')
            m4k = stack.run_m4k(seconds, rundir, logs, 'r{}_{}'.format(r, name), env=env,
                                e2e=e2e)
            res[name].append(rounds.cpu_per_cycle_us(m4k.cpu_s, m4k.cpu_window_s, rates))
            for e in m4k.errors:
                sys.stderr.write('round {} {}: {}\n'.format(r, name, e))
        sys.stdout.write('round {}: {}\n'.format(r, ', '.join(
            '{} {}'.format(k, '-' if v[-1] is None else '{:.1f}'.format(v[-1]))
            for k, v in res.items())))
        sys.stdout.flush()
    return {'cpu_per_cycle_us': res, 'logs': logs,
            'ratios': {k: rounds.per_round_ratios(
                [{'a': a, 'f': f} for a, f in zip(res[k], res['floor'], strict=True)],
                ('a',), ('f',)) for k in variants}}


def main(argv: Sequence[str] | None = None) -> int:
    """Parse the variants, run the rounds, print the medians."""
    ap = argparse.ArgumentParser(prog='loop_ab', description=__doc__.splitlines()[0])
    ap.add_argument('--variant', action='append', required=True, metavar='NAME=DIR',
                    help='a directory holding an m4k_rt package (give two or more)')
    ap.add_argument('--rounds', type=int, default=6)
    ap.add_argument('--seconds', type=float, default=8.0, help='seconds per stack run')
    ap.add_argument('--no-e2e', action='store_true',
                    help='no bridge: VELOCITY_CMD written on the cmd port directly')
    args = rosargs.parse_args(ap, argv)
    variants = {}
    for v in args.variant:
        name, sep, path = v.partition('=')
        if not sep or not name or not os.path.isdir(os.path.join(path, 'm4k_rt')):
            ap.error('--variant {!r}: expected NAME=DIR with DIR/m4k_rt'.format(v))
        variants[name] = path
    if args.rounds < 1 or not args.seconds > 0:
        ap.error('--rounds must be >= 1 and --seconds > 0')
    res = run(variants, args.rounds, args.seconds, e2e=not args.no_e2e)
    for k, v in res['cpu_per_cycle_us'].items():
        sp = rounds.spread(v)
        sys.stdout.write('CPU per cycle {}: {}\n'.format(k, '-' if sp is None else
                         '{median:.1f} µs ({min:.1f}-{max:.1f}, n={n})'.format(**sp)))
    for k, v in res['ratios'].items():
        sp = rounds.spread(v)
        sys.stdout.write('{} ÷ floor: {}\n'.format(k, '-' if sp is None else
                         '{median:.2f} ({min:.2f}-{max:.2f}, n={n})'.format(**sp)))
    return 0


if __name__ == '__main__':
    sys.exit(main())
