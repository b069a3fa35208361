"""Tests of the bench report rendering, progress line and plot from fake summaries."""

import io

import numpy as np

from m4k_bench.benchlib import analysis, plots, progress, report

MS = 1_000_000


def _stats(**kw):
    base = {'n': 100, 'avg': 1.0, 'max': 2.0, 'min': 0.5, 'std': 0.1, 'p50': 1.0, 'p99': 1.9,
            'p999': 2.0}
    base.update(kw)
    return base


def _m4k(lat_p99, ct_p99, ok=True, stall=None):
    return {'samples': 100, 'latency_us': _stats(p99=lat_p99), 'jitter_us': _stats(p99=11.0),
            'cyclictest': {'p99': ct_p99, 'p999': 40, 'max': 50},
            'hardening': {'ok': ok, 'why': '' if ok else 'not SCHED_FIFO'},
            'overruns': 0, 'deadline_misses': 3, 'cpu_per_cycle_us': 90.0,
            'utilization': {'utilization': 3.1, 'utilization_p999': 0.05},
            'verdicts': {'utilization': 'overloaded', 'utilization_p999': 'schedulable'},
            'task_response_p50_us': {'actuator': 55.5},
            'stalls': [stall] if stall else []}


def _summary():
    rounds_ = [
        {'round': 0, 'm4k_idle': _m4k(42.0, 30.0, stall={
            'metric': 'response_us', 'stall_us': 20000.0, 'cyclictest_max_us': 15000.0,
            'owner': 'host'}),
         'baseline_stress': dict(_m4k(7777.0, 30.0), hardening=None),
         'ct_idle': {'latency_us': {'p50': 20, 'p99': 28, 'p999': 40, 'max': 50}},
         'floor': {'cpu_per_cycle_us': 45.0},
         'rtt': {'xddp': {'n': 5, 'min_us': 1.0, 'p50_us': 12.0, 'p99_us': 20.0,
                          'max_us': 30.0},
                 'raw': {'n': 5, 'min_us': 1.0, 'p50_us': 10.0, 'p99_us': 15.0,
                         'max_us': 25.0}}},
        {'round': 1, 'm4k_idle': _m4k(99.0, 30.0, ok=False)},
    ]
    s = {
        'run': {'started_utc': '2026-01-01T00:00:00+00:00', 'mode': 'quick',
                'plan': {'rounds': 2, 'condition_s': 8.0}, 'reproduce': 'make bench QUICK=1'},
        'machine': {'kernel': '6.18.0-test', 'cpus_online': 2, 'preempt_rt': False},
        'rounds': rounds_,
        'scaling': [{'rate_hz': 1000, 'set': 'alone', 'release_p99_us': 50.0,
                     'release_p999_us': 80.0, 'cyclictest_p99_us': 20.0, 'ratio_p99': 2.5,
                     'cyclictest_alone_p99_us': 10.0, 'ratio_p99_alone': 5.0,
                     'ratio_p99_stricter': 5.0,
                     'cpu_per_cycle_us': 70.0, 'overruns': 0, 'deadline_misses': 0,
                     'hardening_ok': True}],
        'cmd_latency': {'trials': 4, 'lost': 1, 'method': 'PROBE METHOD',
                        'to_cycle_us': _stats(p50=4321.0), 'to_probe_us': _stats()},
        'table1': {'tasks': [], 'utilization': None}, 'table1_round': 0,
        'notes': ['driver host missing'], 'files': ['report.md'], 'skipped': {},
        'cpu_dma_latency': {'held': True},
    }
    s['ratios'] = analysis.round_ratios(rounds_)
    s['targets'] = analysis.evaluate_targets(s['ratios'], s['scaling'])
    s['loop_cost'] = analysis.loop_cost(rounds_)
    s['loop_cost']['parts_us'] = {'clock': 0.2, 'drain_decode': 6.54, 'drain_empty': 0.7,
                                  'encode_send': 2.9, 'timing_record': 0.33, 'rusage': 0.04}
    s['method'] = report.method_lines(s, 42)
    return s


def test_report_has_every_section_and_values():
    text = report.render(_summary())
    for heading in ('# m4k bench report', '## Targets', '## All ratios, per round',
                    '## Release latency per round', '## Stalls', '## Utilization per round',
                    '## Cost of the RT loop', '## Scaling', '## XDDP round trip',
                    '## cmd_vel -> motor command latency', '## Machine and kernel',
                    '## Method'):
        assert heading in text, heading
    assert '7777.0' in text and '4321.0' in text and 'PROBE METHOD' in text
    assert '| 0 | m4k full stack, idle | response | 20000.0 | 15000.0 | host |' in text
    assert '| 1 | rt_core (degraded, not an m4k run) full stack, idle |' in text
    assert '**degraded: not SCHED_FIFO**' in text
    assert 'Left out of the m4k ratios (RT hardening not obtained): round 1 m4k_idle' in text
    # release p99 / concurrent ct p99, idle: 42/30 = 1.40 in round 0; round 1 left out;
    # over cyclictest alone 42/28 = 1.50: the stricter, judged, with both shown
    assert '| actuator release p99 ÷ cyclictest p99, the stricter of concurrent and alone, ' \
        'idle | <= 1.5× | 1.50 (1.50–1.50, n=1) | 1.40 (1.40–1.40, n=1) | ' \
        '1.50 (1.50–1.50, n=1) | **met** |' in text
    assert '310.00 % (overloaded)' in text and '5.00 % (schedulable)' in text
    assert '6.18.0-test' in text and 'make bench QUICK=1' in text
    assert 'ROS_DOMAIN_ID=42' in text
    assert '| 0.20 | 6.54 | 0.70 | 2.90 | 0.33 | 0.04 |' in text


def test_report_shows_a_missed_target_with_figures_only():
    text = report.render(_summary())
    line = next(x for x in text.splitlines() if x.startswith('| actuator alone at 1 kHz'))
    assert '**NOT met**' in line and '2.50 (2.50–2.50, n=1)' in line
    assert 'because' not in text.lower() and 'why' not in line.lower()


def test_readme_snippet_has_the_spread_and_the_machine():
    text = report.readme_snippet(_summary())
    assert '1.40 (1.40–1.40, n=1)' in text and '6.18.0-test' in text
    assert 'make bench QUICK=1' in text and 'plain-ROS ÷ m4k jitter p99, stress-ng' in text
    assert '**Table 1**' not in text                # no task measured: no table


def test_readme_snippet_has_a_compact_table1_and_both_utilization_tests():
    s = _summary()
    lat = {'n': 10, 'p50': 40.0, 'p99': 100.0, 'max': 13000.0}
    resp = {'n': 10, 'p50': 80.0, 'p99': 150.0, 'max': 400.0}
    s['table1'] = {
        'tasks': [{'name': 'imu', 'priority': 85, 'period_ms': 10.0, 'cycles': 3100,
                   'latency_us': lat, 'response_us': resp, 'overruns': 1,
                   'deadline_misses': 0}],
        'rta': [{'name': 'imu', 'response_us': None, 'deadline_us': 10000.0,
                 'schedulable': False}],
        'rta_p999': [{'name': 'imu', 'response_us': 1108.4, 'deadline_us': 10000.0,
                      'schedulable': True}],
        'utilization': {'per_task': {'imu': 0.04}, 'total': 0.04,
                        'liu_layland_bound': 1.0, 'verdict': 'schedulable'}}
    s['table1_round'] = 3
    text = report.readme_snippet(s)
    assert 'round 3 of the full stack' in text
    assert ('| imu | 85 | 10 | 3100 | 80.0 / 150.0 / 400.0 | 40.0 / 100.0 / 13000.0 | 1 / 0 '
            '| no (> 10000) | yes (1108) |') in text
    assert 'Σ C/T = 4.00 % against the Liu–Layland bound 100.0 % for 1 tasks' in text
    assert 'p99.9 response' not in text             # no p99.9 utilization given


def test_report_renders_an_empty_summary():
    text = report.render({})
    assert '# m4k bench report' in text and 'Not measured' in text


def test_progress_plain_lines_when_not_a_tty():
    out = io.StringIO()
    p = progress.Progress(3, stream=out, tty=False)
    p.phase('first', 10.0)
    p.update('x')          # within plain_every_s: no extra line
    p.log('hello')
    p.done('bye')
    lines = out.getvalue().splitlines()
    assert lines[0].startswith('[1/3] first  [') and '0/10 s' in lines[0]
    assert lines[1:] == ['bench: hello', 'bye']
    assert '\r' not in out.getvalue()


def test_progress_updates_one_line_on_a_tty():
    out = io.StringIO()
    p = progress.Progress(2, stream=out, tty=True)
    p.phase('a', 5.0)
    p.update('note')
    p.phase('b')
    text = out.getvalue()
    assert text.count('\r') == 3 and text.count('\n') == 1


def test_format_line_bar_is_clamped():
    line = progress.format_line(2, 5, 'x', 20.0, 10.0, width=4)
    assert line == '[2/5] x  [####] 20/10 s'


def test_fig10_writes_a_png(tmp_path):
    rng = np.random.default_rng(1)
    periods = {'m4k_idle': 10 * MS + rng.normal(0, 5e3, 500).astype(np.int64),
               'baseline_stress': 10 * MS + rng.normal(0, 2e6, 500).astype(np.int64),
               'not_a_condition': np.array([1, 2, 3])}
    path = plots.fig10(periods, 10 * MS, str(tmp_path / 'f.png'))
    data = (tmp_path / 'f.png').read_bytes()
    assert path.endswith('f.png') and data[:8] == b'\x89PNG\r\n\x1a\n' and len(data) > 10_000


def test_busy_note_only_when_load_exceeds_half_the_cpus():
    from m4k_bench.benchlib import system
    assert system.busy_note({'loadavg': '0.50 0.4 0.3 1/100 5', 'cpus_online': 2}) is None
    note = system.busy_note({'loadavg': '3.25 2.0 1.0 1/100 5', 'cpus_online': 2})
    assert '1-min load average 3.25 on 2 CPUs' in note
    assert system.busy_note({'loadavg': None}) is None


def test_scaling_writes_a_png(tmp_path):
    rows = [{'rate_hz': hz, 'set': s, 'release_p99_us': 50.0, 'cyclictest_p99_us': 20.0,
             'cpu_per_cycle_us': None if hz == 500 else 70.0}
            for hz in (100, 250, 500, 1000) for s in ('alone', 'task set')]
    plots.scaling(rows, str(tmp_path / 's.png'))
    assert (tmp_path / 's.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'


def test_scaling_writes_a_png_when_every_run_was_degraded(tmp_path):
    # A host that grants no SCHED_FIFO (make test's confined streams, an unprivileged user):
    # every run is left out of the spreads, and the figure still comes out (it crashed the
    # bench at its end, on a log axis over no data).
    rows = [{'rate_hz': hz, 'set': s, 'hardening_ok': False, 'release_p99_us': 50.0,
             'cyclictest_p99_us': 20.0, 'cpu_per_cycle_us': 70.0}
            for hz in (100, 250, 500, 1000) for s in ('alone', 'task set')]
    plots.scaling(rows, str(tmp_path / 's.png'))
    assert (tmp_path / 's.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
