"""The hazard table of docs/safety.md, generated so that it cannot drift from what proves it.

``config/hazards.yaml`` declares each hazard once (ISO 12100 form: the hazardous situation,
the harm and its severity, the risk reduction, what verifies it). This module checks every
reference -- a scenario (``config/scenarios/<name>.yaml``), a cell of the envelope grid
(``config/envelope.yaml``, promised), a test (a pytest node id whose file and function exist,
and whose parameter id exists) -- and writes the table between the markers of
docs/safety.md's "Hazard table" section, with each scenario's last measured result from
``docs/results/scenarios/README.md``. A hazard without a proof is a **GAP** row naming what
will prove it; a reference to nothing is an error, never a silent blank.

``python -m m4k_bench.hazards [--write | --check] [--root DIR]``: print the section, write it
into docs/safety.md, or exit 1 when the committed one is stale (test/test_hazards.py).
"""

from __future__ import annotations

import argparse
import ast
import os
import re
import sys
from typing import Any, Mapping, Sequence

import yaml

__all__ = ['BEGIN', 'END', 'HazardError', 'load', 'main', 'render', 'splice']

BEGIN = ('<!-- BEGIN hazard table: generated from config/hazards.yaml by '
         '`python -m m4k_bench.hazards --write`; do not edit here -->')
END = '<!-- END hazard table -->'
SEVERITIES = ('S1', 'S2')
KEYS = {'id', 'situation', 'harm', 'severity', 'mitigation', 'proof', 'gap'}


class HazardError(ValueError):
    """A bad hazards file or a reference to something that does not exist."""


def load(root: str) -> list[dict[str, Any]]:
    """Return the hazards of ``<root>/config/hazards.yaml``, every reference checked."""
    path = os.path.join(root, 'config', 'hazards.yaml')
    with open(path, encoding='utf-8') as f:
        doc = yaml.safe_load(f)
    rows = doc.get('hazards') if isinstance(doc, dict) else None
    if not isinstance(rows, list) or not rows:
        raise HazardError(f'{path}: expected hazards: [a list of rows]')
    from m4k_bench.scenarios import grid
    envelope = os.path.join(root, 'config', 'envelope.yaml')
    cells = {c.name: c for c in grid.cells(envelope)}
    seen: set[str] = set()
    for i, row in enumerate(rows):
        where = f'{path}: hazards[{i}]'
        if not isinstance(row, dict) or set(row) - KEYS:
            raise HazardError(f'{where}: expected keys from {sorted(KEYS)}, got {row!r}')
        for key in ('id', 'situation', 'harm', 'severity', 'mitigation'):
            if not row.get(key):
                raise HazardError(f'{where}.{key}: missing')
        if row['id'] in seen:
            raise HazardError(f'{where}.id: {row["id"]!r} declared twice')
        seen.add(row['id'])
        if row['severity'] not in SEVERITIES:
            raise HazardError(f'{where}.severity: expected one of {SEVERITIES}, got '
                              f'{row["severity"]!r}')
        proof = row.get('proof') or []
        if bool(proof) == bool(row.get('gap')):
            raise HazardError(f'{where}: give proof (a list) or gap (what will prove it), '
                              'exactly one')
        for j, ref in enumerate(proof):
            _check_ref(root, ref, cells, f'{where}.proof[{j}]')
    return rows


def _check_ref(root: str, ref: Any, cells: Mapping[str, Any], where: str) -> None:
    if not isinstance(ref, dict) or len(ref) != 1:
        raise HazardError(f'{where}: expected {{scenario|grid|test: ...}}, got {ref!r}')
    (kind, value), = ref.items()
    if kind == 'scenario':
        if not os.path.isfile(os.path.join(root, 'config', 'scenarios', f'{value}.yaml')):
            raise HazardError(f'{where}: no scenario config/scenarios/{value}.yaml')
    elif kind == 'grid':
        if value not in cells:
            raise HazardError(f'{where}: no cell {value!r} in config/envelope.yaml')
        if cells[value].scenario is None:
            raise HazardError(f'{where}: cell {value!r} is not promised ({cells[value].why})')
    elif kind == 'test':
        _check_test(root, str(value), cells, where)
    else:
        raise HazardError(f'{where}: unknown reference kind {kind!r} (scenario, grid, test)')


def _check_test(root: str, node: str, cells: Mapping[str, Any], where: str) -> None:
    m = re.fullmatch(r'([\w/.-]+\.py)::(\w+)(?:\[([^\]]+)\])?', node)
    if not m:
        raise HazardError(f'{where}: not a pytest node id: {node!r}')
    path, func, param = m.groups()
    full = os.path.join(root, path)
    if not os.path.isfile(full):
        raise HazardError(f'{where}: no test file {path}')
    with open(full, encoding='utf-8') as f:
        source = f.read()
    names = {n.name for n in ast.walk(ast.parse(source)) if isinstance(n, ast.FunctionDef)}
    if func not in names:
        raise HazardError(f'{where}: no test {func} in {path}')
    if param is None:
        return
    if func == 'test_scenario':          # parametrized over config/scenarios/*.yaml
        ok = os.path.isfile(os.path.join(root, 'config', 'scenarios', f'{param}.yaml'))
    elif func == 'test_envelope_sample':
        ok = param in cells
    else:                                # a literal of its parametrize list
        ok = repr(param) in source or f'"{param}"' in source
    if not ok:
        raise HazardError(f'{where}: no parameter [{param}] of {func} in {path}')


def results(root: str) -> tuple[str, dict[str, str]]:
    """Return (the suite's provenance line, {scenario: verdict and figures}) of the last run."""
    path = os.path.join(root, 'docs', 'results', 'scenarios', 'README.md')
    out: dict[str, str] = {}
    stamp = ''
    if not os.path.isfile(path):
        return stamp, out
    with open(path, encoding='utf-8') as f:
        lines = f.read().splitlines()
    m = next((re.search(r'at (commit \w+)', ln) for ln in lines if 'at commit' in ln), None)
    stamp = m.group(1) if m else ''
    for ln in lines:
        cols = [c.strip() for c in ln.strip().strip('|').split('|')]
        if len(cols) < 10 or cols[0] in ('scenario', '---'):
            continue
        verdict = 'PASS' if cols[9] == 'PASS' else 'FAIL'
        out[cols[0]] = f'{verdict} (clearance {cols[4]} m)'
    return stamp, out


def _cell(text: str) -> str:
    return ' '.join(str(text).split()).replace('|', '/')


def render(root: str) -> str:
    """Return the generated section (between the markers, markers included)."""
    rows = load(root)
    stamp, last = results(root)
    head = ['| id | hazardous situation | harm (severity) | risk reduction | verified by | '
            'last result |', '|---|---|---|---|---|---|']
    gaps = 0
    for row in rows:
        proof = row.get('proof') or []
        refs, res = [], []
        for ref in proof:
            (kind, value), = ref.items()
            if kind == 'test':
                refs.append(f'test `{value.split("::", 1)[1]}` ({value.split("::")[0]})')
            else:
                refs.append(f'{kind} `{value}`')
                res.append(f'`{value}` {last.get(value, "not run yet")}')
        if not proof:
            gaps += 1
            verified, result = f'**GAP**: {_cell(row["gap"])}', '**GAP**'
        else:
            verified = '; '.join(refs)
            result = '; '.join(res) if res else 'asserted in `make test`'
        head.append('| {} | {} | {} ({}) | {} | {} | {} |'.format(
            row['id'], _cell(row['situation']), _cell(row['harm']), row['severity'],
            _cell(row['mitigation']), verified, result))
    intro = (f'{len(rows)} hazards, {gaps} GAP rows. Last results: docs/results/scenarios '
             f'({stamp or "no run recorded"}); "not run yet" is a scenario or grid cell that '
             'run did not include. Severity of the harm before risk reduction: S1 slight, '
             'S2 serious.')
    return '\n'.join([BEGIN, '', intro, '', *head, '', END])


def splice(doc: str, section: str) -> str:
    """Return ``doc`` with the text between the markers replaced by ``section``."""
    a, b = doc.find(BEGIN), doc.find(END)
    if a < 0 or b < a:
        raise HazardError('docs/safety.md has no hazard table markers')
    return doc[:a] + section + doc[b + len(END):]


def main(argv: Sequence[str] | None = None) -> int:
    """Print, write or check the generated section; return the exit code."""
    ap = argparse.ArgumentParser(prog='hazards', description=__doc__.split('\n\n')[0])
    g = ap.add_mutually_exclusive_group()
    g.add_argument('--write', action='store_true', help='write it into docs/safety.md')
    g.add_argument('--check', action='store_true', help='exit 1 when docs/safety.md is stale')
    ap.add_argument('--root', default='.', help='the workspace (default: the current directory)')
    args = ap.parse_args(argv)
    try:
        section = render(args.root)
        doc_path = os.path.join(args.root, 'docs', 'safety.md')
        with open(doc_path, encoding='utf-8') as f:
            doc = f.read()
        new = splice(doc, section)
    except (OSError, HazardError, yaml.YAMLError) as exc:
        print(f'hazards: {exc}', file=sys.stderr)
        return 2
    if args.write:
        with open(doc_path, 'w', encoding='utf-8') as f:
            f.write(new)
    elif args.check:
        if new != doc:
            print('hazards: docs/safety.md is stale: python -m m4k_bench.hazards --write',
                  file=sys.stderr)
            return 1
    else:
        print(section)
    return 0


if __name__ == '__main__':
    sys.exit(main())
