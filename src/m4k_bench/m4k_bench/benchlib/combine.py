"""Combine full ``make bench`` runs into one table: each run's median with its spread (pure).

One run's figure is a median over its rounds; a second run on the same code, started later,
shows how far that median moves between runs (the VM's neighbours change). The combined table
gives, for every target, each run's median with its min–max over the rounds, the median of all
rounds of all runs pooled with its min–max, and the verdict: a target counts as met only when
it is met in every run (the pooled median alone could hide a run that missed it).

Usage: ``bench_combine docs/results/bench-1 docs/results/bench-2 [--out FILE]`` (each argument
a published bench directory holding ``summary.json``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Any, Mapping, Sequence

from m4k_bench.benchlib import fleetagg
from m4k_bench.benchlib.report import fmt_spread, md_table
from m4k_bench.benchlib.rounds import spread
from m4k_rt import rosargs

__all__ = ['combine', 'load', 'main', 'render']

_EXTRA = ('baseline_over_m4k_jitter_p99_stress', 'baseline_over_m4k_jitter_max_stress')


def load(directory: str) -> dict[str, Any]:
    """Read one published bench directory's ``summary.json``."""
    with open(os.path.join(directory, 'summary.json'), encoding='utf-8') as f:
        summ: dict[str, Any] = json.load(f)
    summ['_dir'] = directory
    return summ


def _values(entry: Mapping[str, Any] | None) -> list[float | None]:
    sp = (entry or {}).get('spread') or {}
    return list(sp.get('values') or [])


def combine(runs: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Return per-target rows across ``runs`` (each a bench ``summary.json`` mapping)."""
    rows: list[dict[str, Any]] = []
    keys: list[str] = []
    labels: dict[str, tuple[str, str]] = {}
    for r in runs:
        for t in r.get('targets', []):
            if t['key'] not in labels:
                keys.append(t['key'])
                labels[t['key']] = (t['label'], t['target'])
    for key in keys:
        per_run = []
        pooled: list[float | None] = []
        mets = []
        for r in runs:
            t = next((x for x in r.get('targets', []) if x['key'] == key), None)
            vals = _values(t)
            pooled += vals
            per_run.append(spread(vals))
            mets.append(None if t is None else t.get('met'))
        met = (None if any(m is None for m in mets) else all(mets))
        rows.append({'key': key, 'label': labels[key][0], 'target': labels[key][1],
                     'runs': per_run, 'pooled': spread(pooled), 'met_per_run': mets,
                     'met': met})
    for key in _EXTRA:
        entries = [(r.get('ratios') or {}).get(key) for r in runs]
        if not any(entries):
            continue
        label = next(e.get('label', key) for e in entries if e)
        pooled = [v for e in entries for v in _values(e)]
        rows.append({'key': key, 'label': label, 'target': '–',
                     'runs': [spread(_values(e)) for e in entries], 'pooled': spread(pooled),
                     'met_per_run': [None] * len(runs), 'met': 'reported'})
    loop = []
    for r in runs:
        lc = r.get('loop_cost') or {}
        loop.append({k: spread(list((lc.get(k) or {}).get('values') or []))
                     for k in ('paired_m4k_cpu_per_cycle_us', 'paired_floor_cpu_per_cycle_us',
                               'floor_cpu_per_cycle_us')})
    fleet = []
    for r in runs:     # the three-robot fleet's drops, per round (bench's fleet_idle)
        got = [rd['fleet_idle'] for rd in r.get('rounds') or []
               if isinstance(rd, Mapping) and isinstance(rd.get('fleet_idle'), Mapping)]
        fleet.append(fleetagg.summarize(got) if got else None)
    return {'rows': rows, 'loop_cost': loop, 'fleet': fleet,
            'runs': [{'dir': r.get('_dir'), 'started_utc': (r.get('run') or {}).get(
                'started_utc'), 'rounds': ((r.get('run') or {}).get('plan') or {}).get(
                    'rounds'), 'machine': r.get('machine') or {}} for r in runs]}


def render(comb: Mapping[str, Any]) -> str:
    """Return the combined table as Markdown (for the README and docs/results)."""
    runs = comb['runs']
    lines = ['{} full runs of `make bench` on the same code, one after the other:'.format(
        len(runs)), '']
    for i, r in enumerate(runs, 1):
        m = r['machine']
        lines.append('* run {}: [`{}`]({}) — {} rounds, started {} UTC, {}, {} CPUs, kernel '
                     '{}'.format(i, r['dir'], os.path.join(r['dir'] or '', 'report.md'),
                                 r['rounds'], r['started_utc'], m.get('cpu_model', '?'),
                                 m.get('cpus_online', '?'), m.get('kernel', '?')))
    lines += ['', 'Each run: median over its rounds (min–max, rounds). Pooled: all rounds of '
              'all runs. A target is met only when every run meets it.', '']
    head = ['ratio', 'target'] + ['run {}'.format(i) for i in range(1, len(runs) + 1)] + [
        'pooled', '']
    out_rows = []
    for row in comb['rows']:
        if row['met'] == 'reported':
            verdict = 'reported'
        elif row['met'] is None:
            verdict = 'not measured'
        elif row['met']:
            verdict = 'met'
        else:
            verdict = 'NOT met ({} of {} runs met)'.format(
                sum(1 for m in row['met_per_run'] if m), len(runs))
        out_rows.append([row['label'], row['target']] + [fmt_spread(s) for s in row['runs']]
                        + [fmt_spread(row['pooled']), verdict])
    lines += md_table(head, out_rows)
    lines += ['', 'CPU per task cycle (µs), the floor beside the stack and cyclictest in the '
              'same run:', '']
    for i, lc in enumerate(comb['loop_cost'], 1):
        lines.append('* run {}: m4k {}, floor {} (floor run alone: {})'.format(
            i, fmt_spread(lc['paired_m4k_cpu_per_cycle_us'], 1),
            fmt_spread(lc['paired_floor_cpu_per_cycle_us'], 1),
            fmt_spread(lc['floor_cpu_per_cycle_us'], 1)))
    lines += fleetagg.combined_lines(comb.get('fleet') or [])
    return '\n'.join(lines) + '\n'


def main(argv: Sequence[str] | None = None) -> int:
    """Print (or write with ``--out``) the combined table of the given bench directories."""
    ap = argparse.ArgumentParser(prog='bench_combine', description=__doc__.split('\n')[0])
    ap.add_argument('dirs', nargs='+', help='published bench directories (summary.json)')
    ap.add_argument('--out', default=None, help='write the Markdown here')
    args = rosargs.parse_args(ap, argv)
    try:
        runs = [load(d) for d in args.dirs]
    except (OSError, ValueError) as exc:
        sys.stderr.write('bench_combine: {}\n'.format(exc))
        return 2
    text = render(combine(runs))
    if args.out:
        with open(args.out, 'w', encoding='utf-8') as f:
            f.write(text)
    else:
        sys.stdout.write(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
