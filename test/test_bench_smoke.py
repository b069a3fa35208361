"""`bench` end to end in smoke mode: every phase runs and leaves its files and keys.

Asserts on structure only (files, keys, sample counts > 0), never on timing values: the
numbers are the benchmark's business, not a test's.
"""

import copy
import json
import os
import shutil
import subprocess
import sys

from m4k_rt.tools.benchlib import analysis

RATIO_KEYS = ('release_p99_over_cyclictest_idle', 'release_p99_over_cyclictest_stress',
              'baseline_over_m4k_jitter_p99_stress', 'baseline_over_m4k_jitter_p99_idle',
              'five_tasks_over_alone_p99', 'xddp_rtt_p50_over_raw')


def _measurement(summ, key):
    return summ.get('rt_cpu_percent') if key == 'rt_cpu_percent' else summ['ratios'].get(key)


def check_verdicts_follow_the_measurements(summ):
    """Each target verdict in the run's summary is its measurement against its limit.

    Recomputed here from the run's own numbers, then each measured value is moved to the
    other side of its limit in a copy of the summary: the verdict must flip, so a verdict
    that ignores its data (always met, always None) fails.
    """
    by_key = {t.key: t for t in analysis.TARGETS}
    for row in summ['targets']:
        t = by_key[row['key']]
        m = _measurement(summ, t.key)
        assert row['measured'] == m, row
        if m is None:
            assert row['met'] is None, row
            continue
        assert row['met'] is (m <= t.limit if t.op == '<=' else m >= t.limit), row
        flipped = copy.deepcopy(summ)
        other = t.limit * 2 + 1 if row['met'] == (t.op == '<=') else t.limit / 2
        if t.key == 'rt_cpu_percent':
            flipped['rt_cpu_percent'] = other
        else:
            flipped['ratios'][t.key] = other
        again = {r['key']: r for r in analysis.evaluate_targets(flipped)}[t.key]
        assert again['met'] is (not row['met']), (row, again)


def test_bench_quick_smoke_writes_report_plots_csvs_and_summary(tmp_path):
    results = tmp_path / 'results'
    argv = [sys.executable, '-c', 'import sys; from m4k_rt.tools.bench import main; '
            'sys.exit(main())', '--quick', '--duration', '2', '--rtt-n', '200',
            '--cmd-trials', '3', '--no-install', '--results', str(results)]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=170,
                          stdin=subprocess.DEVNULL)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert '[1/11] set-up' in proc.stderr            # plain progress lines (not a TTY)
    latest = results / 'latest'
    assert latest.is_symlink() and latest.is_dir()
    out = latest
    for name in ('report.md', 'summary.json', 'fig10_periodicity.png',
                 'raw/m4k_idle/samples.csv', 'raw/m4k_idle/table1.md',
                 'raw/m4k_alone/samples.csv', 'raw/baseline_idle.csv',
                 'raw/periods_m4k_idle.csv', 'raw/periods_baseline_idle.csv'):
        assert (out / name).is_file(), name
    summ = json.loads((out / 'summary.json').read_text())
    assert set(RATIO_KEYS) <= set(summ['ratios'])
    assert 'rt_cpu_percent' in summ and summ['rt_cpu_percent'] is not None
    # Table 1: every robot task reported, with the utilization test and RTA
    names = {t['name'] for t in summ['table1']['tasks']}
    assert {'actuator', 'imu', 'led', 'sonar', 'lrf'} <= names
    assert summ['table1']['utilization']['verdict'] in ('schedulable', 'inconclusive',
                                                        'overloaded')
    assert len(summ['table1']['rta']) == len(names)
    for cond in ('m4k_idle', 'm4k_alone', 'baseline_idle'):
        c = summ['conditions'][cond]
        assert c['samples'] > 0 and c['jitter_us']['n'] > 0, cond
    if shutil.which('stress-ng'):
        assert summ['conditions']['m4k_stress']['samples'] > 0
        assert summ['conditions']['baseline_stress']['samples'] > 0
    if shutil.which('cyclictest'):
        assert summ['cyclictest']['idle']['latency_us']['n'] > 0
        assert summ['ratios']['release_p99_over_cyclictest_idle'] is not None
    assert summ['xddp_rtt']['xddp']['n'] == 200 and summ['xddp_rtt']['raw']['n'] == 200
    assert summ['cmd_latency']['trials'] + summ['cmd_latency']['lost'] == 3, \
        summ['cmd_latency']
    assert len(summ['targets']) == 6
    check_verdicts_follow_the_measurements(summ)
    report = (out / 'report.md').read_text()
    assert '![Fig. 10 periodicity](fig10_periodicity.png)' in report
    assert '## Timing analysis per task (paper Table 1)' in report
    assert summ['machine']['kernel'] in report
    assert os.path.basename(os.readlink(latest)) == os.path.basename(summ['run']['results_dir'])
