#!/usr/bin/env python3
"""Write the figures README.md and docs/results/README.md quote, from the result artifacts.

Every number the two pages quote from a run sits between markers::

    <!-- generated: NAME (tools/readme_results.py; do not edit by hand) -->
    ...
    <!-- end: NAME -->

and is rendered here from the files the runs wrote under ``docs/results/`` (the bench's
``bench-combined.md`` and ``readme_snippet.md``, ``demo/summary.json``, the scenario table,
``fuzz/results.json``, ``soak/summary.json``). After a new run is published::

    python tools/readme_results.py          # rewrite the blocks
    python tools/readme_results.py --check  # exit 1, naming the block, when a page is stale

``test/test_readme.py`` runs the check, so a page never quotes a run the artifacts do not hold.
Standard library only: it runs before the workspace is built.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
from typing import Any, Callable

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RESULTS = os.path.join(ROOT, 'docs', 'results')
README = os.path.join(ROOT, 'README.md')
NOTEBOOK = os.path.join(RESULTS, 'README.md')

_BLOCK = re.compile(r'(<!-- generated: (?P<name>[\w-]+) \(tools/readme_results\.py; do not '
                    r'edit by hand\) -->\n)(?P<body>.*?)(<!-- end: (?P=name) -->)', re.S)


class ArtifactError(RuntimeError):
    """A result artifact is missing or does not hold what a block quotes."""


def _read(rel: str) -> str:
    path = os.path.join(RESULTS, rel)
    try:
        with open(path, encoding='utf-8') as f:
            return f.read()
    except OSError as e:
        raise ArtifactError(f'docs/results/{rel}: {e.strerror}') from None


def _json(rel: str) -> Any:
    try:
        return json.loads(_read(rel))
    except json.JSONDecodeError as e:
        raise ArtifactError(f'docs/results/{rel}: not JSON ({e})') from None


def _table_rows(text: str) -> list[list[str]]:
    """Return the body rows of the first Markdown table in ``text`` as lists of cells."""
    rows, seen_rule = [], False
    for line in text.splitlines():
        if not line.startswith('|'):
            if seen_rule and rows:
                break
            continue
        cells = [c.strip() for c in line.strip().strip('|').split('|')]
        if all(set(c) <= set('-: ') for c in cells):
            seen_rule = True
        elif seen_rule:
            rows.append(cells)
    return rows


def _cm(m: float) -> str:
    return f'{m * 100:.1f} cm'


def _thousands(n: int) -> str:
    return f'{n:,}'.replace(',', '\u202f')


# --- the facts, one function per artifact ------------------------------------------------------

def bench_facts() -> dict[str, Any]:
    """Return the bench targets of ``bench-combined.md``: met in every run, missed, reported."""
    rows = _table_rows(_read('bench-combined.md'))
    if not rows:
        raise ArtifactError('docs/results/bench-combined.md: no target table')
    verdicts = [r[-1] for r in rows]
    text = _read('bench-combined.md')
    runs = len(set(re.findall(r'(?m)^\* run (\d+): \[', text)))
    rounds = set(re.findall(r'(?m)^\* run \d+: .*? — (\d+) rounds?,', text))
    # the command that reproduces it: a run of other than the default rounds says so
    command = 'make bench RUNS={}'.format(runs) + (
        ' ROUNDS={}'.format(rounds.pop()) if len(rounds) == 1 and rounds != {'5'} else '')
    return {'targets': sum(v != 'reported' for v in verdicts),
            'met': sum(v == 'met' for v in verdicts),
            'reported': sum(v == 'reported' for v in verdicts), 'runs': runs,
            'command': command}


def fleet_facts() -> dict[str, Any]:
    """Return the three-robot fleet's wheel-command drops from ``fleet-drops/summary.json``."""
    d = _json('fleet-drops/summary.json')
    s = d['summary']
    return {'command': d['command'], 'runs': s['runs'], 'met': bool(s['met']),
            'host': s['host_per_10k'], 'load': s['load_1min'],
            'commit': d['provenance']['commit'][:7]}


def demo_facts() -> dict[str, Any]:
    """Return Fig. 9's verdict from ``demo/summary.json`` (the simulator's ground truth)."""
    d = _json('demo/summary.json')
    return {k: d[k] for k in ('passed', 'goal_reached', 'final_error_m', 'goal_tolerance_m',
                              'min_clearance_m', 'contacts', 'duration_s', 'odom_vs_truth_m')}


def scenario_facts() -> dict[str, Any]:
    """Return the scenario table's header facts and its verdicts."""
    text = _read('scenarios/README.md')
    rows = _table_rows(text)
    if not rows:
        raise ArtifactError('docs/results/scenarios/README.md: no scenario table')
    head = re.search(r'`make scenarios` at (?:commit )?(?P<commit>\w+)[^\n]*?[,;] '
                     r'(?P<when>\d{4}-\d\d-\d\d \d\d:\d\d UTC), (?P<s>\d+) s', text)
    return {'n': len(rows), 'passed': sum(r[-1] == 'PASS' for r in rows),
            'commit': head['commit'] if head else '?', 'when': head['when'] if head else '?',
            'seconds': int(head['s']) if head else None,
            'contacts': sum(int(r[5]) for r in rows if r[5].isdigit())}


def fuzz_facts() -> dict[str, Any]:
    """Return the campaign's totals from ``fuzz/results.json``."""
    d = _json('fuzz/results.json')
    ports = d['ports']
    return {'ports': len(ports), 'ok': bool(d['ok']) and all(p['ok'] for p in ports),
            'sent': sum(p['expected']['sent'] for p in ports),
            'malformed': sum(p['malformed'] for p in ports),
            'oversize': sum(p['oversize'] for p in ports),
            'unexpected': sum(p['unexpected'] for p in ports), 'seed': d['seed'],
            'minutes': round(d['wall_s'] / 60)}


def soak_facts() -> dict[str, Any]:
    """Return the soak's verdicts from ``soak/summary.json``."""
    d = _json('soak/summary.json')
    v = d['verdicts']
    return {'minutes': round(d['duration_s'] / 60), 'stress': bool(d['stress']),
            'no_crash': v['no_crash'], 'no_leak': v['no_leak'],
            'timing': v['misses_within_cyclictest'], 'no_body_errors': v['no_body_errors'],
            'restarts': d['restarts'], 'started': d['started_utc']}


# --- the blocks ----------------------------------------------------------------------------------

def _yes(ok: bool, good: str, bad: str) -> str:
    return good if ok else bad


def results_summary() -> str:
    """Return README.md's results table (one row per kind of evidence, with its link)."""
    b, d, s, f, k = bench_facts(), demo_facts(), scenario_facts(), fuzz_facts(), soak_facts()
    fl = fleet_facts()
    missed = b['targets'] - b['met']
    rows = [
        (f"Timing (`{b['command']}`)",
         f"{b['met']} of {b['targets']} targets met in all {b['runs']} runs, {missed} missed "
         f"(each analysed); {b['reported']} ratios against plain ROS reported",
         '[bench](docs/results/README.md#timing-make-bench)'),
        (f"Wheel commands the driver host drops, three-robot fleet (`{fl['command']}`)",
         f"{fl['host']['median']:.2f} per 10 000 of its own, median over {fl['runs']} runs "
         f"({fl['host']['min']:.2f}-{fl['host']['max']:.2f}), with 3 stacks on 2 CPUs at load "
         f"{fl['load']['min']:.0f}-{fl['load']['max']:.0f}: target <= 10 "
         + _yes(fl['met'], 'met', 'NOT met') + f" (at {fl['commit']})",
         '[fleet-drops](docs/results/fleet-drops/report.md)'),
        ('Fig. 9 (`make demo`)',
         _yes(d['passed'], 'goal reached', 'FAILED') + f" {_cm(d['final_error_m'])} from the "
         f"target (tolerance {_cm(d['goal_tolerance_m'])}), minimum clearance "
         f"{_cm(d['min_clearance_m'])}, {d['contacts']} contacts, {d['duration_s']:.1f} s",
         '[demo](docs/results/demo/report.md)'),
        ('Scenarios (`make scenarios`)',
         f"{s['passed']} of {s['n']} pass on the simulator's ground truth, {s['contacts']} "
         f"contacts (at {s['commit']}"
         + (f", {s['seconds']} s" if s['seconds'] is not None else '') + ')',
         '[scenarios](docs/results/scenarios/README.md)'),
        ('Fuzzing (`make fuzz`)',
         f"{_thousands(f['sent'])} datagrams on {f['ports']} ports ({_thousands(f['malformed'])}"
         f" malformed, {_thousands(f['oversize'])} oversize, {_thousands(f['unexpected'])} of "
         'a wrong kind), '
         + _yes(f['ok'], 'every one counted where predicted', 'NOT all counted as predicted')
         + f"; seed {f['seed']}", '[fuzz](docs/results/fuzz/report.md)'),
        (f"Soak (`make soak`, {k['minutes']} min"
         + (' under stress-ng' if k['stress'] else '') + ')',
         ', '.join([_yes(k['no_crash'], 'no crash', 'CRASHED'),
                    _yes(k['no_leak'], 'RSS flat', 'RSS GREW'),
                    _yes(k['no_body_errors'], 'no body error', 'body errors'),
                    _yes(k['timing'], "overruns within cyclictest's",
                         'the timing rule FAILS (analysed)')]),
         '[soak](docs/results/README.md#soak)'),
    ]
    out = ['| evidence | result | details |', '|---|---|---|']
    out += [f'| {a} | {r} | {link} |' for a, r, link in rows]
    return '\n'.join(out) + '\n'


def _relink(text: str) -> str:
    """Rewrite root-relative links for a page inside docs/results/."""
    return text.replace('](docs/results/', '](')


def bench_block() -> str:
    """Return the bench block: the combined table of every run and run 1's Table 1."""
    combined = _read('bench-combined.md').rstrip('\n')
    snippet = _read('bench-1/readme_snippet.md')
    at = snippet.find('**Table 1**')
    if at < 0:
        raise ArtifactError('docs/results/bench-1/readme_snippet.md: no Table 1')
    table1 = snippet[at:].replace('per task), ', 'per task), run 1, ', 1)
    return _relink(combined + '\n\n' + table1.rstrip('\n') + '\n')


def scenarios_block() -> str:
    """Return the scenario table with its header line, as the suite wrote it."""
    text = _read('scenarios/README.md')
    lines = text.splitlines()
    head = next((ln for ln in lines if ln.startswith('`make scenarios`')), '')
    table = [ln for ln in lines if ln.startswith('|')]
    if not table:
        raise ArtifactError('docs/results/scenarios/README.md: no scenario table')
    return _relink('\n'.join(([head, ''] if head else []) + table) + '\n').replace(
        'one plot per scenario beside this file',
        'one plot per scenario in [scenarios/](scenarios/README.md)')


BLOCKS: dict[str, dict[str, Callable[[], str]]] = {
    README: {'results-summary': results_summary},
    NOTEBOOK: {'bench': bench_block, 'scenarios': scenarios_block},
}


def render(path: str, text: str) -> str:
    """Return ``text`` (the page at ``path``) with every generated block rendered afresh."""
    wanted = BLOCKS[path]
    found = {m['name'] for m in _BLOCK.finditer(text)}
    if found != set(wanted):
        raise ArtifactError(f'{os.path.relpath(path, ROOT)}: generated blocks {sorted(found)}, '
                            f'expected {sorted(wanted)}')
    return _BLOCK.sub(lambda m: m[1] + wanted[m['name']]() + m[4], text)


def stale_blocks(path: str, text: str) -> list[str]:
    """Return the names of the blocks of ``text`` that differ from their rendering."""
    fresh = render(path, text)
    old = {m['name']: m['body'] for m in _BLOCK.finditer(text)}
    new = {m['name']: m['body'] for m in _BLOCK.finditer(fresh)}
    return sorted(n for n in old if old[n] != new[n])


def main(argv: list[str] | None = None) -> int:
    """Rewrite the blocks, or with ``--check`` report the stale ones (exit 1)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--check', action='store_true',
                    help='change nothing; exit 1 naming every block that is stale')
    args = ap.parse_args(argv)
    rc = 0
    for path in BLOCKS:
        with open(path, encoding='utf-8') as f:
            text = f.read()
        try:
            stale = stale_blocks(path, text)
        except ArtifactError as e:
            print(f'readme_results: {e}', file=sys.stderr)
            return 2
        rel = os.path.relpath(path, ROOT)
        if args.check:
            for name in stale:
                print(f'readme_results: {rel}: block {name!r} differs from the artifacts '
                      '(run python tools/readme_results.py)', file=sys.stderr)
                rc = 1
        elif stale:
            with open(path, 'w', encoding='utf-8') as f:
                f.write(render(path, text))
            print(f'readme_results: {rel}: rewrote {", ".join(stale)}', file=sys.stderr)
    return rc


if __name__ == '__main__':
    raise SystemExit(main())
