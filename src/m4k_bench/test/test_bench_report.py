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


def _cond(jitter_p99):
    return {'samples': 100, 'period_ms_stats': _stats(avg=10.0), 'jitter_us': _stats(
        p99=jitter_p99), 'latency_us': _stats(p99=42.0), 'overruns': 0, 'deadline_misses': 3}


def _summary():
    s = {
        'run': {'started_utc': '2026-01-01T00:00:00+00:00', 'mode': 'quick', 'table1_s': 15.0,
                'condition_s': 8.0, 'reproduce': 'make bench QUICK=1'},
        'machine': {'kernel': '6.18.0-test', 'cpus_online': 2, 'preempt_rt': False},
        'conditions': {'m4k_idle': _cond(11.0), 'baseline_stress': _cond(7777.0)},
        'cyclictest': {'command': 'cyclictest -m -p 90', 'idle': {'latency_us': {
            'n': 10, 'p50': 20, 'p99': 30, 'p999': 40, 'max': 50}}},
        'xddp_rtt': {'xddp': {'n': 5, 'min_us': 1.0, 'p50_us': 12.0, 'p99_us': 20.0,
                              'max_us': 30.0},
                     'raw': {'n': 5, 'min_us': 1.0, 'p50_us': 10.0, 'p99_us': 15.0,
                             'max_us': 25.0}, 'payload_bytes': 32, 'sched_fifo': True},
        'cmd_latency': {'trials': 4, 'lost': 1, 'method': 'PROBE METHOD',
                        'to_cycle_us': _stats(p50=4321.0), 'to_probe_us': _stats()},
        'table1': {'tasks': [], 'utilization': None},
        'rt_cpu_percent': 3.25,
        'notes': ['driver host missing'], 'files': ['report.md'], 'skipped': {},
    }
    s['ratios'] = analysis.compute_ratios(s)
    s['targets'] = analysis.evaluate_targets(s)
    return s


def test_report_has_every_section_and_values():
    text = report.render(_summary())
    for heading in ('# m4k bench report', '## Targets', '## Fig. 10', '## Release latency',
                    '## XDDP round trip', '## cmd_vel -> motor command latency',
                    '## Machine and kernel', '## Notes', '## Files'):
        assert heading in text
    assert '![Fig. 10 periodicity](fig10_periodicity.png)' in text
    assert '| plain ROS, stress-ng | 100 |' in text
    assert '7777.0' in text and '4321.0' in text and 'PROBE METHOD' in text
    assert '`xddp_rtt_p50_over_raw` | 1.200 |' in text
    assert '6.18.0-test' in text
    assert '1 trial(s) saw no reacting WHEEL_CMD' in text
    assert 'make bench QUICK=1' in text


def test_report_says_plainly_what_is_missed_and_not_measured():
    text = report.render(_summary())
    line = next(x for x in text.splitlines() if x.startswith('| XDDP round trip p50'))
    assert '**NOT met**' not in line and '**met**' in line    # 1.2 <= 1.3
    line = next(x for x in text.splitlines() if x.startswith('| Plain-ROS baseline jitter'))
    assert 'not measured' in line                               # m4k_stress missing
    # no Table 1 samples: the report says so instead of an empty table
    assert 'Not measured: no samples received.' in text


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
