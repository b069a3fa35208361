"""bench_combine: each run's median with its spread, pooled rounds, met only when every run met."""

from __future__ import annotations

import json
import os

from m4k_bench.benchlib import combine, rounds


def _summary(values: list[float], met: bool, started: str) -> dict:
    sp = rounds.spread(values)
    assert sp is not None
    return {'run': {'started_utc': started, 'plan': {'rounds': len(values)}},
            'machine': {'cpu_model': 'cpu', 'cpus_online': 2, 'kernel': 'k'},
            'targets': [{'key': 'x', 'label': 'ratio x', 'target': '<= 2×', 'met': met,
                         'spread': dict(sp, values=values)}],
            'ratios': {}, 'loop_cost': {'paired_m4k_cpu_per_cycle_us': {'values': [80.0, 90.0]},
                                        'paired_floor_cpu_per_cycle_us': {'values': [30.0]}}}


def test_a_target_missed_in_one_run_is_not_met(tmp_path) -> None:
    a = _summary([1.0, 1.5, 1.9], True, 't1')
    b = _summary([1.8, 2.4, 2.6], False, 't2')
    comb = combine.combine([a, b])
    row = comb['rows'][0]
    assert row['met'] is False
    assert row['runs'][0]['median'] == 1.5 and row['runs'][1]['median'] == 2.4
    assert {k: row['pooled'][k] for k in ('median', 'min', 'max', 'n')} == {
        'median': 1.85, 'min': 1.0, 'max': 2.6, 'n': 6}
    text = combine.render(comb)
    assert 'NOT met (1 of 2 runs met)' in text
    assert '1.50 (1.00–1.90, n=3)' in text and '1.85 (1.00–2.60, n=6)' in text
    assert 'm4k 85.0 (80.0–90.0, n=2), floor 30.0' in text


def test_met_in_both_runs_and_cli(tmp_path) -> None:
    dirs = []
    for i, vals in enumerate(([1.0, 1.2], [1.1, 1.3])):
        d = tmp_path / 'bench-{}'.format(i + 1)
        d.mkdir()
        (d / 'summary.json').write_text(json.dumps(_summary(vals, True, 't')))
        dirs.append(str(d))
    out = tmp_path / 'combined.md'
    assert combine.main([*dirs, '--out', str(out)]) == 0
    text = out.read_text()
    assert '| ratio x | <= 2× |' in text and text.rstrip().count('| met |') == 1
    assert os.path.join(dirs[0], 'report.md') in text


def test_a_missing_run_is_a_clear_error(tmp_path, capsys) -> None:
    assert combine.main([str(tmp_path / 'nothing')]) == 2
    assert 'summary.json' in capsys.readouterr().err
