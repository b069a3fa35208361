"""`bench` end to end in smoke mode: every phase runs and leaves its files and keys.

Asserts on structure only (files, keys, sample counts > 0), never on timing values: the
numbers are the benchmark's business, not a test's.
"""

import copy
import json
import os
import shutil
import signal
import subprocess
import sys

from wsenv import check_provenance

from m4k_bench.benchlib import analysis, system

SCALING_KEY = 'scaling_1khz_release_p99_over_cyclictest'


def check_verdicts_follow_the_measurements(summ):
    """Each target verdict in the run's summary is its median against its limit.

    Recomputed here from the run's own numbers, then each measured median is moved to the
    other side of its limit in a copy of the summary's ratios: the verdict must flip, so a
    verdict that ignores its data (always met, always None) fails.
    """
    by_key = {t.key: t for t in analysis.TARGETS}
    for row in summ['targets']:
        t = by_key[row['key']]
        sp = row['spread']
        if sp is None:
            assert row['met'] is None, row
            continue
        m = sp['median']
        assert row['met'] is (m <= t.limit if t.op == '<=' else m >= t.limit), row
        other = t.limit * 2 + 1 if row['met'] == (t.op == '<=') else t.limit / 2
        ratios, scaling = copy.deepcopy(summ['ratios']), copy.deepcopy(summ['scaling'])
        if t.key == SCALING_KEY:
            for r in scaling:
                if r.get('rate_hz') == 1000 and r.get('set') == 'alone':
                    r['ratio_p99_stricter'] = other
        else:
            ratios[t.key]['spread'] = dict(sp, median=other)
        again = {r['key']: r for r in analysis.evaluate_targets(ratios, scaling)}[t.key]
        assert again['met'] is (not row['met']), (row, again)


def _value_or_reason(summ, key):
    """Return the ratio ``key`` of the one round, asserting it has a value or the reason it
    has none -- exactly one. A quick run's cyclictest may show the host stalling (its p99 > 20x
    its p50 and > 500 us: benchlib.validity), and then every ratio over that condition is left
    out with the reason: the load decides which, the bench must say."""
    r = summ['ratios'][key]
    assert len(r['values']) == 1, r
    assert (r['values'][0] is not None) != bool(r['invalid']), (key, r)
    return r


def test_bench_quick_smoke_writes_report_plots_rounds_and_summary(tmp_path):
    # The references are not optional: without them the targets have no denominator. setup
    # installs them as root (tools/setup.sh); a missing one fails here, naming the package.
    for tool, package in system.TOOL_PACKAGES.items():
        assert shutil.which(tool), f'{tool} missing: apt-get install {package} (tools/setup.sh)'
    results = tmp_path / 'results'
    publish = tmp_path / 'published'
    argv = [sys.executable, '-c', 'import sys; from m4k_bench.bench import main; '
            'sys.exit(main())', '--quick', '--duration', '2', '--rounds', '1', '--rtt-n', '200',
            '--cmd-trials', '3', '--reaction-trials', '2', '--reaction-speed-trials', '1',
            '--rates', '500', '--no-install', '--results', str(results),
            '--publish', str(publish)]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            stdin=subprocess.DEVNULL)
    try:
        stdout, stderr = proc.communicate(timeout=360)
    except subprocess.TimeoutExpired:
        # SIGINT first: the bench stops its own children (stacks in their own sessions, which
        # a SIGKILL of the bench alone would leave running), then the kill.
        proc.send_signal(signal.SIGINT)
        try:
            proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
        raise
    assert proc.returncode == 0, stderr[-3000:]
    # plain progress (not a TTY); 27 with the reaction, the two channel floors, the two
    # frame-structure floors, the four executive conditions and the three-robot fleet
    assert '[1/27] set-up' in stderr
    latest = results / 'latest'
    assert latest.is_symlink() and latest.is_dir()
    out = latest
    for name in ('report.md', 'summary.json', 'rounds.json', 'readme_snippet.md',
                 'fig10_periodicity.png', 'scaling.png',
                 'raw/r0_m4k_idle/samples.csv', 'raw/r0_m4k_idle/table1.md',
                 'raw/r0_m4k_alone/samples.csv', 'raw/r0_baseline_idle.csv'):
        assert (out / name).is_file(), name
    for name in ('report.md', 'summary.json', 'rounds.json', 'readme_snippet.md'):
        assert (publish / name).is_file(), name
    summ = json.loads((out / 'summary.json').read_text())
    check_provenance(summ)
    rnd = summ['rounds'][0]
    # Table 1 of the median round: every robot task, with the utilization test and RTA
    names = {t['name'] for t in summ['table1']['tasks']}
    assert {'actuator', 'imu', 'led', 'sonar', 'lrf'} <= names
    assert len(summ['table1']['rta']) == len(names) == len(summ['table1']['rta_p999'])
    for cond in ('m4k_idle', 'm4k_alone', 'baseline_idle'):
        c = rnd[cond]
        assert c['samples'] > 0 and c['jitter_us']['n'] > 0, cond
    # the live view's condition: the stack measured with a viewer reading every channel
    assert rnd['m4k_live']['samples'] > 0 and rnd['m4k_live']['live_view']['messages'] > 0
    for cond in ('m4k_idle', 'm4k_live', 'm4k_alone'):
        assert set(rnd[cond]['hardening']) >= {'ok', 'policy', 'mem_locked', 'degraded'}
        assert rnd[cond]['cpu_per_cycle_us'] is not None
    assert rnd['floor']['cpu_per_cycle_us'] > 0
    # the channel floors: the bare floor plus a task cycle's socket calls / shared memory
    for ch in ('socket', 'shm'):
        fl = rnd['floor_' + ch]
        assert fl['channel'] == ch and fl['cpu_per_cycle_us'] > 0, fl
    # the paired run: rt_core and the floor in one window, beside the stack and cyclictest
    paired = rnd['m4k_floor_paired']
    assert paired['floor']['cpu_per_cycle_us'] > 0 and paired['cpu_per_cycle_us'] > 0
    assert paired['cyclictest']['n'] > 0
    _value_or_reason(summ, 'cpu_per_cycle_over_floor')
    # the stricter target names both its denominators; the one over cyclictest alone has a
    # value, or (a host stall in cyclictest's own tail, as a loaded machine gives) the reason
    # it has none
    alone = _value_or_reason(summ, 'release_p99_over_cyclictest_alone_idle')
    row = {t['key']: t for t in summ['targets']}['release_p99_stricter_idle']
    assert set(row['of']) == {'concurrent', 'alone'}
    assert (row['of']['alone'] is not None) == (alone['values'][0] is not None), (row, alone)
    # the profiled run: rt_core's cycle breakdown of every task, aggregated and reported
    prof = rnd['m4k_profiled']['cycle_profile']['tasks']
    assert {'actuator', 'imu', 'led', 'sonar', 'lrf', 'monitor'} <= set(prof)
    assert set(prof['actuator']['parts_us']) == {'wake', 'drain', 'control', 'send', 'record',
                                                 'rusage'}
    assert prof['actuator']['cycles'] > 0 and prof['actuator']['send_calls'] > 0
    bd = summ['loop_cost']['breakdown']
    assert bd['tasks']['actuator']['drain']['n'] == 1 and bd['all']['send']['n'] == 1
    assert rnd['m4k_stress']['samples'] > 0 and rnd['baseline_stress']['samples'] > 0
    # both executives side by side, each with its own floors and the host's drop counts
    for cond in ('m4k_frame_idle', 'm4k_frame_stress', 'm4k_slow_threads', 'm4k_slow_frame'):
        c = rnd[cond]
        assert c['samples'] > 0 and c['cpu_per_cycle_us'] is not None, cond
        drops = c['host_drops']
        assert drops['commands'] > 0 and set(drops['by_reason']) >= {'stale_host',
                                                                    'stale_device'}, cond
    # the three-robot fleet: every robot's motor counters, pooled, and its table in the report
    fleet = rnd['fleet_idle']
    assert fleet['errors'] == [], fleet['errors']
    assert all(d['host']['commands'] > 0 for d in fleet['drops']['robots'].values())
    assert fleet['drops']['pooled']['commands'] == sum(
        d['host']['commands'] for d in fleet['drops']['robots'].values())
    assert '## Wheel-command drops in the three-robot fleet' in (out / 'report.md').read_text()
    assert rnd['floor_frame']['frame'] and rnd['floor_frame']['cpu_per_cycle_us'] > 0
    assert rnd['floor_frame_socket']['channel'] == 'socket'
    _value_or_reason(summ, 'cpu_per_cycle_frame_over_threads')
    assert rnd['ct_idle']['latency_us']['n'] > 0
    assert rnd['m4k_idle']['cyclictest']['n'] > 0        # ran concurrently
    assert rnd['baseline_idle']['cyclictest']['n'] > 0
    assert rnd['rtt']['xddp']['n'] == 200 and rnd['rtt']['raw']['n'] == 200
    assert [r['rate_hz'] for r in summ['scaling']] == [500, 500]
    assert summ['cmd_latency']['trials'] + summ['cmd_latency']['lost'] == 3, \
        summ['cmd_latency']
    # a command reached the motor in at least one trial: all three lost is the set-up holding
    # every command (the turn guard with no laser did, unseen, from 4640a1e to this check)
    assert summ['cmd_latency']['trials'] >= 1 and 'error' not in summ['cmd_latency'], \
        summ['cmd_latency']
    # the guard's reaction ran its trials (2 at the first speed, 1 at each other) and wrote
    # its evidence; a phase that raised would be a summary with an 'error' and no trials
    reaction = summ['reaction']
    assert 'error' not in reaction, reaction
    assert reaction['trials'] + len(reaction['failed']) >= 1, reaction
    for name in ('reaction.md', 'reaction.json', 'reaction.csv'):
        assert (out / 'reaction' / name).is_file(), name
    check_verdicts_follow_the_measurements(summ)
    assert all(t['spread'] is None or t['spread']['n'] == 1 for t in summ['targets'])
    report = (out / 'report.md').read_text()
    assert '![Fig. 10 periodicity](fig10_periodicity.png)' in report
    assert '## Timing analysis per task (paper Table 1)' in report
    assert 'Cycle breakdown, measured inside the loop' in report
    assert '## Executives side by side' in report
    assert '| **all, weighted by rate** |' in report
    assert summ['machine']['kernel'] in report
    assert os.path.basename(os.readlink(latest)) == os.path.basename(summ['run']['results_dir'])
