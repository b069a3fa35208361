"""Render ``report.md`` from the bench summary (pure: dict in, Markdown out).

Table 1, the utilization test and the response-time analysis come from
:func:`m4k_rt.recorder.format_table1`; everything else (targets, ratios, Fig. 10 statistics,
cyclictest, XDDP round trip, cmd_vel latency, machine) is formatted here.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

from m4k_bench.benchlib.analysis import RATIO_KEYS
from m4k_rt import recorder

__all__ = ['CONDITION_LABELS', 'render']

CONDITION_LABELS = {
    'm4k_idle': 'm4k (XDDP), idle',
    'm4k_stress': 'm4k (XDDP), stress-ng',
    'baseline_idle': 'plain ROS, idle',
    'baseline_stress': 'plain ROS, stress-ng',
    'm4k_alone': 'm4k actuator alone, idle',
}


def _f(v: Any, digits: int = 1) -> str:
    if v is None:
        return '-'
    if isinstance(v, bool):
        return 'yes' if v else 'no'
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return '{:.{}f}'.format(v, digits)
    return str(v)


def _g(d: Mapping[str, Any] | None, *path: str) -> Any:
    for k in path:
        if not isinstance(d, Mapping) or k not in d:
            return None
        d = d[k]
    return d


def _table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> list[str]:
    out = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    out += ['| ' + ' | '.join(str(c) for c in r) + ' |' for r in rows]
    return out


def _targets(summ: Mapping[str, Any]) -> list[str]:
    rows = []
    for t in summ.get('targets', []):
        met = {True: '**met**', False: '**NOT met**', None: 'not measured'}[t['met']]
        digits = 2 if t['key'] != 'rt_cpu_percent' else 2
        rows.append([t['label'], t['target'], _f(t['measured'], digits), met, t['why'] or ''])
    lines = ['## Targets', '',
             'Ratios measured in this run (absolute numbers on a shared VM are noise; the '
             'ratios compare things measured side by side).', '']
    lines += _table(['What', 'Target', 'Measured', 'Verdict', 'Why (when missed)'], rows)
    return lines


def _ratios(summ: Mapping[str, Any]) -> list[str]:
    r = summ.get('ratios', {})
    lines = ['', '### summary.json "ratios"', '']
    lines += _table(['key', 'value'], [['`{}`'.format(k), _f(r.get(k), 3)] for k in RATIO_KEYS])
    lines += ['', '`rt_cpu_percent` = {} (utime + stime of the rt_core process over the Table 1 '
              'run, % of one core).'.format(_f(summ.get('rt_cpu_percent'), 2))]
    return lines


def _machine(m: Mapping[str, Any]) -> list[str]:
    keys = [('os', 'OS'), ('kernel', 'Kernel release'), ('kernel_version', 'Kernel build'),
            ('preempt_model', 'Preemption model'), ('preempt_rt', 'PREEMPT_RT'),
            ('cpu_model', 'CPU'), ('cpus_online', 'CPUs online'),
            ('cpus_allowed', 'CPUs allowed'), ('memory_gib', 'Memory (GiB)'),
            ('virtualization', 'Virtualization'), ('clocksource', 'Clock source'),
            ('sched_rt_runtime_us', 'sched_rt_runtime_us'), ('python', 'Python'),
            ('numpy', 'numpy'), ('euid', 'Effective uid'),
            ('loadavg', 'Load average at start')]
    return ['## Machine and kernel', ''] + _table(
        ['', ''], [[label, _f(m.get(k))] for k, label in keys if k in m])


def _conditions(summ: Mapping[str, Any]) -> list[str]:
    conds = summ.get('conditions', {})
    rows = []
    for key, label in CONDITION_LABELS.items():
        c = conds.get(key)
        if not c:
            continue
        p = c['period_ms_stats']
        j = c['jitter_us']
        lat = c['latency_us']
        rows.append([label, c['samples'], _f(p['avg'], 3), _f(p['max'], 3), _f(p['min'], 3),
                     _f(j['avg']), _f(j['max']), _f(j['std']), _f(j['p50']), _f(j['p99']),
                     _f(j['p999']), _f(lat['p99']), c['overruns'], c['deadline_misses']])
    lines = ['## Fig. 10: periodicity of the actuator task', '',
             'Same control code (`m4k_rt.control.BaseController`) and the same simulated motor '
             'handler in both: **m4k** runs it in the RT actuator task (SCHED_FIFO thread, '
             'timerfd, XDDP ports to the driver host); the **plain-ROS baseline** runs it in an '
             'rclpy node timer (SCHED_OTHER) that calls the motor handler directly. '
             'Jitter = |period - 10 ms|.', '',
             '![Fig. 10 periodicity](fig10_periodicity.png)', '']
    lines += _table(['Condition', 'Samples', 'Period avg (ms)', 'Period max (ms)',
                     'Period min (ms)', 'Jitter avg (us)', 'Jitter max (us)', 'Jitter std (us)',
                     'Jitter p50 (us)', 'Jitter p99 (us)', 'Jitter p99.9 (us)',
                     'Release p99 (us)', 'Overruns', 'Deadline misses'], rows)
    warm = summ.get('warmup') or {}
    parts = ['{} {} us'.format(CONDITION_LABELS.get(k, k), _f(v.get('max_latency_us')))
             for k, v in warm.items() if isinstance(v, Mapping) and v.get('max_latency_us')]
    if parts:
        lines += ['', 'Start-up transient, excluded above: the first {} s of every run. Worst '
                  'release latency in it: {}.'.format(_f(warm.get('seconds'), 0),
                                                      '; '.join(parts))]
    return lines + _interference(summ)


def _interference(summ: Mapping[str, Any]) -> list[str]:
    inter = summ.get('interference') or {}
    rows = []
    for cond, d in inter.items():
        if not d:
            continue
        shares = ', '.join('{} {:.1f} %'.format(k, v * 100)
                           for k, v in d['share_by_task'].items() if v > 0) or 'none'
        rows.append([CONDITION_LABELS.get(cond, cond), d['cycles'],
                     _f(d['interfered_share'] * 100, 2), shares,
                     _f(d['latency_p99_interfered_us']), _f(d['latency_p99_clean_us']),
                     _f(d['latency_p99_all_us'])])
    if not rows:
        return []
    return ['', '### Interference inside the RT process', '',
            'Actuator cycles whose release found another task of the same process running '
            '(that task held the interpreter lock while the actuator waited), and the release '
            'latency p99 of those cycles vs the others:', ''] + _table(
        ['Condition', 'Cycles', 'Interfered (%)', 'By task', 'p99 interfered (us)',
         'p99 clean (us)', 'p99 all (us)'], rows)


def _cyclictest(summ: Mapping[str, Any]) -> list[str]:
    ct = summ.get('cyclictest') or {}
    conds = summ.get('conditions', {})
    rows = []
    for cond in ('idle', 'stress'):
        c = _g(ct, cond, 'latency_us')
        m = _g(conds, 'm4k_' + cond, 'latency_us')
        if c:
            rows.append(['cyclictest, ' + cond, _f(c.get('p50')), _f(c.get('p99')),
                         _f(c.get('p999')), _f(c.get('max')), c.get('n', '-')])
        if m:
            rows.append(['m4k actuator, ' + cond, _f(m['p50']), _f(m['p99']), _f(m['p999']),
                         _f(m['max']), m['n']])
    lines = ['## Release latency: m4k actuator vs cyclictest', '',
             "cyclictest at the actuator's period (10 ms) and priority, run right before the "
             'm4k run of the same condition: `{}`.'.format(ct.get('command', 'cyclictest'))]
    if not rows:
        return lines + ['', 'Not measured: {}.'.format(ct.get('error', 'cyclictest missing'))]
    return lines + [''] + _table(['Run', 'p50 (us)', 'p99 (us)', 'p99.9 (us)', 'max (us)',
                                  'samples'], rows)


def _rtt(summ: Mapping[str, Any]) -> list[str]:
    r = summ.get('xddp_rtt')
    lines = ['## XDDP round trip vs raw Unix-socket ping-pong', '']
    if not r or 'xddp' not in r:
        return lines + ['Not measured: {}.'.format((r or {}).get('error', 'skipped'))]
    rows = [[name, _f(r[k]['min_us']), _f(r[k]['p50_us']), _f(r[k]['p99_us']),
             _f(r[k]['max_us']), r[k]['n']]
            for k, name in (('xddp', 'XDDP emulation (RtXddpSocket <-> NrtXddpEndpoint)'),
                            ('raw', 'raw SOCK_SEQPACKET, blocking'))]
    return lines + ['{}-byte datagram echoed by a peer process; measuring thread SCHED_FIFO: '
                    '{} (`m4k_bench.xddp_bench.run_rtt`).'.format(
                        r.get('payload_bytes', '?'), _f(r.get('sched_fifo'))), ''] + _table(
        ['Transport', 'min (us)', 'p50 (us)', 'p99 (us)', 'max (us)', 'round trips'], rows)


def _cmdlat(summ: Mapping[str, Any]) -> list[str]:
    c = summ.get('cmd_latency')
    lines = ['## cmd_vel -> motor command latency', '']
    if not c or not c.get('trials'):
        return lines + ['Not measured: {}.'.format((c or {}).get('error', 'skipped'))]
    rows = []
    for key, label in (('to_cycle_us', 'publish -> start of the actuator cycle that used it'),
                       ('to_probe_us', 'publish -> WHEEL_CMD received by the motor peer')):
        s = c.get(key)
        if s:
            rows.append([label, _f(s['p50']), _f(s['p99']), _f(s['max']), _f(s['min']), s['n']])
    lines += [c.get('method', ''), '']
    lines += _table(['Interval', 'p50 (us)', 'p99 (us)', 'max (us)', 'min (us)', 'trials'], rows)
    if c.get('lost'):
        lines += ['', '{} trial(s) saw no reacting WHEEL_CMD within the timeout.'.format(
            c['lost'])]
    return lines


def render(summ: Mapping[str, Any]) -> str:
    """Return the whole report as Markdown."""
    run = summ.get('run', {})
    lines = ['# m4k bench report', '',
             'Run {} (UTC), {} mode: Table 1 run {} s, each Fig. 10 / cyclictest condition '
             '{} s. Reproduce: `{}`.'.format(
                 run.get('started_utc', '?'), run.get('mode', '?'),
                 _f(run.get('table1_s'), 0), _f(run.get('condition_s'), 0),
                 run.get('reproduce', 'make bench')), '']
    lines += _targets(summ)
    lines += _ratios(summ)
    lines += ['']
    table1 = summ.get('table1')
    if table1 and table1.get('tasks'):
        lines += ['# Table 1 and the utilization test', '',
                  'Full stack on simulated devices (rt_core with the five robot tasks + monitor, '
                  'driver_host with the sim backends), idle machine, velocity commands at 20 Hz '
                  'as the navigation stack would send them. Response = t_end - t_start; '
                  'release latency = t_start - t_rel. Worst case = max measured response.', '']
        lines += recorder.format_table1(table1).splitlines()
        lines += ['', 'RT process CPU over the run: {} % of one core.'.format(
            _f(summ.get('rt_cpu_percent'), 2))]
    else:
        lines += ['# Table 1', '', 'Not measured: {}.'.format(
            summ.get('skipped', {}).get('table1', 'no samples received'))]
    lines += [''] + _conditions(summ)
    lines += [''] + _cyclictest(summ)
    lines += [''] + _rtt(summ)
    lines += [''] + _cmdlat(summ)
    lines += [''] + _machine(summ.get('machine', {}))
    notes = summ.get('notes') or []
    if notes:
        lines += ['', '## Notes', ''] + ['* ' + n for n in notes]
    method = summ.get('method') or []
    if method:
        lines += ['', '## How this was measured', ''] + ['* ' + m for m in method]
    files = summ.get('files') or []
    if files:
        lines += ['', '## Files', ''] + ['* `{}`'.format(f) for f in files]
    return '\n'.join(lines) + '\n'
