"""Render ``report.md`` and ``readme_snippet.md`` from the bench summary (pure).

Table 1, the utilization test and the response-time analysis of the median round come from
:func:`m4k_bench.recorder.format_table1`; everything else (targets with their spread over the
rounds, per-round figures, hardening, stalls, loop cost, scaling, XDDP round trip, cmd_vel
latency, machine) is formatted here. Nothing is explained that was not measured: a missed
target shows its figures.
"""

from __future__ import annotations

from typing import Any, Mapping

from m4k_bench import recorder
from m4k_bench.benchlib import analysis, execreport, fleetagg
from m4k_bench.benchlib.analysis import RATIOS
from m4k_bench.benchlib.results import md_table

__all__ = ['CONDITION_LABELS', 'fmt_spread', 'md_table', 'method_lines', 'readme_snippet',
           'render']

CONDITION_LABELS = {
    'm4k_idle': 'm4k full stack, idle',
    'm4k_live': 'm4k full stack + live view viewer, idle',
    'm4k_alone': 'm4k actuator alone, idle',
    'm4k_stress': 'm4k full stack, stress-ng',
    'm4k_frame_idle': 'm4k full stack, frame executive, idle',
    'm4k_frame_stress': 'm4k full stack, frame executive, stress-ng',
    'm4k_slow_threads': 'm4k full stack, slow sonar body, thread per task',
    'm4k_slow_frame': 'm4k full stack, slow sonar body, frame executive',
    'baseline_idle': 'plain ROS, idle',
    'baseline_stress': 'plain ROS, stress-ng',
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


def fmt_spread(sp: Mapping[str, Any] | None, digits: int = 2) -> str:
    """Format a spread: 'median (min–max, n)'."""
    if not sp:
        return '-'
    return '{} ({}–{}, n={})'.format(_f(sp['median'], digits), _f(sp['min'], digits),
                                     _f(sp['max'], digits), sp['n'])


def verdict(t: Mapping[str, Any], bold: str = '') -> str:
    """Return a target row's verdict; INVALID with the reason when no round had a reference."""
    if t.get('invalid'):
        return '{b}INVALID{b}: {}'.format('; '.join(t['invalid'][:2]), b=bold)
    text = {True: 'met', False: 'NOT met', None: 'not measured'}[t['met']]
    text = bold + text + bold if t['met'] is not None else text
    if t.get('rounds_invalid'):
        text += ' ({} round(s) left out: no valid reference)'.format(len(t['rounds_invalid']))
    return text


def _targets(summ: Mapping[str, Any]) -> list[str]:
    rows = []
    for t in summ.get('targets', []):
        met = verdict(t, '**')
        of = t.get('of') or {}
        rows.append([t['label'], t['target'], fmt_spread(t['spread']),
                     fmt_spread(of.get('concurrent')), fmt_spread(of.get('alone')), met])
    lines = ['## Targets (issue 14): median over the rounds, min–max', '',
             'Every ratio is computed within one round, from two measurements taken side by '
             'side; the verdict is on the median. A latency target is judged on the stricter '
             'of two denominators, round by round: cyclictest running concurrently beside '
             'm4k (which m4k slows) and cyclictest alone in the same round; both are shown.',
             '']
    lines += md_table(['Ratio', 'Target', 'judged: stricter, median (min–max, rounds)',
                     '÷ concurrent cyclictest', '÷ cyclictest alone', 'Verdict'], rows)
    return lines


def _ratios(summ: Mapping[str, Any]) -> list[str]:
    ratios = summ.get('ratios', {})
    rows = []
    for r in RATIOS:
        e = ratios.get(r.key) or {}
        rows.append([r.label, fmt_spread(e.get('spread')),
                     ' / '.join(_f(v, 2) for v in e.get('values', []))])
    lines = ['## All ratios, per round', '']
    lines += md_table(['Ratio', 'median (min–max, n)', 'per round'], rows)
    excl = ratios.get('_excluded') or []
    if excl:
        lines += ['', 'Left out of the m4k ratios (RT hardening not obtained): ' +
                  '; '.join(excl) + '.']
    return lines


def _label(key: str, cond: Mapping[str, Any]) -> str:
    """Return the condition's label; a run without RT hardening is never called m4k."""
    label = CONDITION_LABELS[key]
    hard = cond.get('hardening')
    if hard is not None and not hard.get('ok'):
        label = label.replace('m4k', 'rt_core (degraded, not an m4k run)')
    return label


def _per_round(summ: Mapping[str, Any]) -> list[str]:
    rows = []
    for r in summ.get('rounds', []):
        ct_alone = _g(r, 'ct_idle', 'latency_us')
        if ct_alone:
            rows.append([r['round'], 'cyclictest alone, idle', _f(ct_alone.get('p50')),
                         _f(ct_alone.get('p99')), _f(ct_alone.get('p999')),
                         _f(ct_alone.get('max')), '', '', ''])
        ct_s = _g(r, 'ct_stress', 'latency_us')
        if ct_s:
            rows.append([r['round'], 'cyclictest alone, stress-ng', _f(ct_s.get('p50')),
                         _f(ct_s.get('p99')), _f(ct_s.get('p999')), _f(ct_s.get('max')),
                         '', '', ''])
        for key in CONDITION_LABELS:
            c = r.get(key)
            if not c:
                continue
            lat = c.get('latency_us') or {}
            ct = c.get('cyclictest') or {}
            hard = c.get('hardening')
            hard_s = '-' if hard is None else ('SCHED_FIFO, locked' if hard.get('ok') else
                                              '**degraded: {}**'.format(hard.get('why')))
            rows.append([r['round'], _label(key, c), _f(lat.get('p50')), _f(lat.get('p99')),
                         _f(lat.get('p999')), _f(lat.get('max')),
                         '{} / {}'.format(_f(ct.get('p99')), _f(ct.get('max'))),
                         '{} / {}'.format(c.get('overruns', '-'), c.get('deadline_misses', '-')),
                         hard_s])
    lines = ['## Release latency per round and condition (µs)', '',
             'Release latency = cycle start - the release it serves; after an overrun, from the '
             "missed release (cyclictest's metric). The plain-ROS rows are its timer callback. "
             '"concurrent cyclictest" ran at the same period and priority during that run.', '']
    lines += md_table(['Round', 'Condition', 'p50', 'p99', 'p99.9', 'max',
                     'concurrent cyclictest p99 / max', 'overruns / misses', 'RT hardening'],
                    rows)
    return lines


def _stalls(summ: Mapping[str, Any]) -> list[str]:
    rows = []
    for r in summ.get('rounds', []):
        for key in CONDITION_LABELS:
            for st in (r.get(key) or {}).get('stalls') or []:
                rows.append([r['round'], _label(key, r[key]), st['metric'].replace('_us', ''),
                             _f(st['stall_us']), _f(st['cyclictest_max_us']), st['owner']])
    lines = ['## Stalls that set a maximum, checked against the concurrent cyclictest', '',
             "A maximum above a tenth of the period is a stall. It is the host's when the "
             'cyclictest running at the same time saw at least half of it (a C loop at the '
             'same priority cannot be stalled by Python), else it is the measured '
             "process's own.", '']
    if not rows:
        return lines + ['No stall in any round.']
    return lines + md_table(['Round', 'Condition', 'Metric', 'max (µs)',
                           'concurrent cyclictest max (µs)', 'Whose'], rows)


def _utilization(summ: Mapping[str, Any]) -> list[str]:
    rows = []
    for r in summ.get('rounds', []):
        for key in ('m4k_idle', 'm4k_stress'):
            c = r.get(key) or {}
            u = c.get('utilization') or {}
            v = c.get('verdicts') or {}
            if u:
                rows.append([r['round'], _label(key, c),
                             '{} % ({})'.format(_f(100 * u['utilization'], 2)
                                                if 'utilization' in u else '-',
                                                v.get('utilization', '-')),
                             '{} % ({})'.format(_f(100 * u['utilization_p999'], 2)
                                                if 'utilization_p999' in u else '-',
                                                v.get('utilization_p999', '-'))])
    lines = ['## Utilization per round: from the max and from p99.9 of the response', '',
             'Liu–Layland test on measured response ÷ period; the response-time analysis '
             '(with release jitter = the release latency at the same percentile) of the '
             'median round is in the Table 1 section. A max set by a stall is listed above '
             'with its owner.', '']
    return lines + md_table(['Round', 'Condition', 'from max', 'from p99.9'], rows)


def _loop_cost(summ: Mapping[str, Any]) -> list[str]:
    lc = summ.get('loop_cost') or {}
    lines = ['## Cost of the RT loop', '',
             'CPU per task cycle = rt_core process CPU (utime + stime) over the measured window '
             '÷ the cycles its tasks ran in it (full stack, idle). The floor: bare Python '
             'SCHED_FIFO timerfd threads at the same periods, priorities, phases and CPU '
             'pinning (wake, read, clock read), thread CPU ÷ cycles. The target compares the '
             'two measured in one run (paired): the floor runs beside the stack (driver host, '
             'bridge, rt_core) and the concurrent cyclictest, so both pay for the same co-load; '
             'the floor run alone, in every round, is shown for comparison.', '']
    rows = [['m4k full stack, idle, paired with the floor',
             fmt_spread(lc.get('paired_m4k_cpu_per_cycle_us'), 1)],
            ['Python floor beside the stack and cyclictest (paired)',
             fmt_spread(lc.get('paired_floor_cpu_per_cycle_us'), 1)],
            ['m4k ÷ floor, paired (the target)',
             fmt_spread(_g(summ, 'ratios', 'cpu_per_cycle_over_floor', 'spread'))],
            ['m4k full stack, idle', fmt_spread(lc.get('m4k_cpu_per_cycle_us'), 1)],
            ['Python floor, alone', fmt_spread(lc.get('floor_cpu_per_cycle_us'), 1)],
            ['m4k ÷ floor alone',
             fmt_spread(_g(summ, 'ratios', 'cpu_per_cycle_over_floor_alone', 'spread'))],
            ["Python floor + a task cycle's socket calls (poll, 2 recv, poll, 2 send), alone",
             fmt_spread(_g(lc, 'channel_floor_cpu_per_cycle_us', 'socket'), 1)],
            ['  ÷ floor alone: what the socket channel alone costs',
             fmt_spread(_g(summ, 'ratios', 'socket_channel_floor_over_floor', 'spread'))],
            ['Python floor + the same datagrams through shared memory, alone',
             fmt_spread(_g(lc, 'channel_floor_cpu_per_cycle_us', 'shm'), 1)],
            ['  ÷ floor alone',
             fmt_spread(_g(summ, 'ratios', 'shm_channel_floor_over_floor', 'spread'))]]
    lines += md_table(['CPU per cycle (µs)', 'median (min–max, rounds)'], rows)
    lines += ['', "Breakdown: what each task's body costs per cycle (response p50, median "
              'over rounds) and the per-cycle bookkeeping of `RtTask.wait_period` without the '
              'kernel wait (clock read, ring record, rusage every 64 cycles):', '']
    brows = [[k, fmt_spread(v, 1)] for k, v in (lc.get('body_response_p50_us') or {}).items()]
    bk = lc.get('bookkeeping_us') or {}
    if 'per_cycle_us_median' in bk:
        brows.append(['bookkeeping (no wait)', '{} µs'.format(_f(bk['per_cycle_us_median'],
                                                                   2))])
    lines += md_table(['Part', 'µs per cycle'], brows)
    lines += _breakdown(lc.get('breakdown'))
    parts = lc.get('parts_us') or {}
    if parts:
        lines += ['', 'The parts of a cycle, each timed alone on the real objects '
                  '(`m4k_bench.benchlib.loopparts`; µs per call, rusage per cycle):', '']
        lines += md_table(['clock read', 'drain + decode one datagram', 'drain, empty port',
                         'encode + send one datagram', 'timing record', 'rusage'],
                        [[_f(parts.get(k), 2) for k in ('clock', 'drain_decode', 'drain_empty',
                                                         'encode_send', 'timing_record',
                                                         'rusage')]])
    return lines


_PART_LABELS = {'wake': 'wake', 'drain': 'drain + decode', 'control': 'control',
                'send': 'encode + send', 'record': 'timing record', 'rusage': 'rusage'}


def _breakdown(bd: Mapping[str, Any] | None) -> list[str]:
    """Return the per-task cycle breakdown table of the profiled runs (µs per cycle)."""
    if not bd:
        return []
    from m4k_rt.cycleprof import PARTS

    def med(sp: Mapping[str, Any] | None) -> str:
        return _f(sp.get('median'), 1) if sp else '-'
    rows = [[name, med(t.get('rate_hz'))] + [med(t.get(p)) for p in PARTS]
            + [med(t.get('thread_cpu_per_cycle_us'))]
            for name, t in (bd.get('tasks') or {}).items()]
    a = bd.get('all') or {}
    rows.append(['**all, weighted by rate**', ''] + [med(a.get(p)) for p in PARTS]
                + [med(a.get('thread_cpu_per_cycle_us'))])
    lines = ['', 'Cycle breakdown, measured inside the loop (`m4k_rt.cycleprof`, one profiled '
             'full-stack run per round, median over the rounds; µs per cycle). The body parts '
             "are timed with the clock around the ports' readers and writers; wake = the "
             "thread's CPU per cycle minus the timed parts (timer wait system call, switch, GIL, "
             'loop lines). Process CPU per cycle of the profiled runs: {} µs.'.format(
                 fmt_spread(bd.get('process_cpu_per_cycle_us'), 1)), '']
    lines += md_table(['Task', 'rate (Hz)'] + [_PART_LABELS[p] for p in PARTS]
                    + ['thread CPU'], rows)
    ab = bd.get('cache_ab_us')
    if ab:
        lines += ['', 'Cold or warm, inside a periodic loop (`floor --probe`, a floor at the '
                  "task set's rates beside the profiled run): one VELOCITY_CMD decode timed "
                  "with the thread's CPU clock as the first code after the timer wait (cold), "
                  'then again in the same cycle (warm); p50 over every cycle, median over the '
                  'rounds: cold {} µs, warm {} µs, cold ÷ warm {}.'.format(
                      med(ab.get('cold_p50')), med(ab.get('warm_p50')),
                      _f((ab.get('cold_over_warm_p50') or {}).get('median'), 2))]
    return lines


def _scaling(summ: Mapping[str, Any]) -> list[str]:
    rows = [[r['rate_hz'], r['set'], fmt_spread(r['release_p99_us'], 1),
             fmt_spread(r['release_p999_us'], 1), fmt_spread(r['cyclictest_p99_us'], 1),
             fmt_spread(r['ratio_p99']),
             fmt_spread(r['cyclictest_alone_p99_us'], 1), fmt_spread(r['ratio_p99_alone']),
             fmt_spread(r['cpu_per_cycle_us'], 1),
             '{} / {}'.format(_f(r.get('overruns')), _f(r.get('deadline_misses'))),
             '{}{}'.format(r['runs'], ' ({} degraded)'.format(r['degraded'])
                           if r['degraded'] else '')]
            for r in analysis.scaling_summary(summ.get('scaling') or [])]
    lines = ['## Scaling: the actuator at 100, 250, 500 and 1000 Hz', '']
    if not rows:
        return lines + ['Not measured.']
    lines += ['One run per rate and task set in every round, the rates in reverse order every '
              'other round. Median (min–max) over the hardened runs; overruns and deadline '
              'misses summed over all runs. Per-run figures: `summary.json` → `scaling`.', '',
              '![scaling](scaling.png)', '']
    return lines + md_table(['Rate (Hz)', 'Tasks', 'release p99 (µs)', 'release p99.9 (µs)',
                           'concurrent cyclictest p99 (µs)', 'p99 ratio',
                           'cyclictest alone p99 (µs)', 'p99 ratio (alone)',
                           'CPU per cycle (µs)', 'overruns / misses', 'runs'], rows)


def _rtt(summ: Mapping[str, Any]) -> list[str]:
    rows = []
    for r in summ.get('rounds', []):
        t = r.get('rtt')
        if t:
            rows.append([r['round'], _f(t['xddp']['p50_us']), _f(t['raw']['p50_us']),
                         _f(t['xddp']['p99_us']), _f(t['raw']['p99_us']),
                         _f(t['xddp']['p50_us'] / t['raw']['p50_us'], 2)
                         if t['raw']['p50_us'] else '-'])
    lines = ["## XDDP round trip on the tasks' receive path vs a raw socket", '',
             'A 32-byte datagram echoed by a peer process, both pinned to one CPU; the measuring '
             'thread waits in one poll, then receives with `RtXddpSocket.recv_into` (what '
             '`PortReader` does every cycle) -- the raw side with the same poll + recv_into '
             '(`m4k_bench.xddp_bench`).', '']
    return lines + md_table(['Round', 'XDDP p50', 'raw p50', 'XDDP p99', 'raw p99',
                           'p50 ratio'], rows)


def _machine(m: Mapping[str, Any]) -> list[str]:
    keys = [('os', 'OS'), ('kernel', 'Kernel release'), ('kernel_version', 'Kernel build'),
            ('preempt_model', 'Preemption model'), ('preempt_rt', 'PREEMPT_RT'),
            ('cpu_model', 'CPU'), ('cpus_online', 'CPUs online'),
            ('cpus_allowed', 'CPUs allowed'), ('memory_gib', 'Memory (GiB)'),
            ('virtualization', 'Virtualization'), ('clocksource', 'Clock source'),
            ('sched_rt_runtime_us', 'sched_rt_runtime_us'), ('python', 'Python'),
            ('numpy', 'numpy'), ('euid', 'Effective uid'),
            ('loadavg', 'Load average at start')]
    return ['## Machine and kernel', ''] + md_table(
        ['', ''], [[label, _f(m.get(k))] for k, label in keys if k in m])


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
    lines += md_table(['Interval', 'p50 (us)', 'p99 (us)', 'max (us)', 'min (us)', 'trials'], rows)
    if c.get('lost'):
        lines += ['', '{} trial(s) saw no reacting WHEEL_CMD within the timeout.'.format(
            c['lost'])]
    return lines


def _reaction(summ: Mapping[str, Any]) -> list[str]:
    r = summ.get('reaction')
    lines = ['## Guard reaction time and stopping distance', '']
    if not r or not r.get('trials'):
        return lines + ['Not measured: {}.'.format((r or {}).get('error', 'skipped'))]
    def ms(v: float | None) -> str:
        return '-' if v is None else '{:.1f}'.format(1e3 * v)
    lines += ["Stop line crossed on ground truth -> first braking DAC word, on the simulator's "
              'clock (`reaction/reaction.md`, `reaction/reaction.png`).', '']
    lines += md_table(['trials', 'p50 (ms)', 'p99 (ms)', 'max (ms)'],
                      [[r['trials'], ms(r.get('reaction_p50_s')), ms(r.get('reaction_p99_s')),
                        ms(r.get('reaction_max_s'))]])
    rows = [['{:g}'.format(s['v_cmd']), '{:.3f}'.format(s['v']), s['n'],
             '{:.3f}'.format(s['stop_m_median']), '{:.3f}'.format(s['stop_m_max']),
             '{:.3f}'.format(s['physical_min_m']), s['contacts']] for s in r.get('speeds', [])]
    if rows:
        lines += [''] + md_table(['commanded (m/s)', 'true (m/s)', 'stops', 'stop median (m)',
                                  'stop max (m)', 'physical minimum (m)', 'contacts'], rows)
    return lines


def method_lines(summ: Mapping[str, Any], domain: Any) -> list[str]:
    """Return the method, as it was run (the numbers come from the plan)."""
    plan = _g(summ, 'run', 'plan') or {}
    dma = summ.get('cpu_dma_latency') or {}
    return [
        '{} rounds; in each, every condition for {:g} s (+ {:g} s warm-up left out of the '
        'statistics); the order of the conditions is reversed every other round.'.format(
            plan.get('rounds'), plan.get('condition_s', 0), summ.get('warmup_s', 0)),
        'm4k conditions run the architecture end to end: Twist on `cmd_vel` at 20 Hz over DDS '
        '-> `bridge` -> XDDP `cmd` -> actuator task of `rt_core` (+ `driver_host` on simulated '
        'devices); the bench records TASK_STATS on the `status` port. The plain-ROS baseline '
        'gets the same `cmd_vel` publisher.',
        'cyclictest (`-m -p 90 -i <period>`) runs concurrently with every m4k and baseline run, '
        "at the actuator's period and priority, and alone idle and under stress-ng.",
        '/dev/cpu_dma_latency is held at 0 µs by the bench for the whole run: {}.'.format(
            'held' if dma.get('held') else 'NOT held ({})'.format(dma.get('error'))),
        'Stress: `{}`, started 1 s before and stopped after each stressed run.'.format(
            summ.get('stress_command', '')),
        'RT hardening of every m4k run is read from RT_STATUS (policy, memory locked, degraded); '
        'a run without SCHED_FIFO and locked memory is left out of the m4k ratios.',
        'Release latency after an overrun counts from the missed release.',
        'ROS isolation: ROS_DOMAIN_ID={}, localhost discovery.'.format(domain),
    ]


def render(summ: Mapping[str, Any]) -> str:
    """Return the whole report as Markdown."""
    run = summ.get('run', {})
    lines = ['# m4k bench report', '',
             '`{}` -- {} run started {} UTC; results in `{}`.'.format(
                 run.get('reproduce', 'bench'), run.get('mode', ''), run.get('started_utc', ''),
                 run.get('results_dir', '')), '']
    for note in summ.get('notes', []):
        lines.append('* ' + note)
    lines += [''] + _targets(summ)
    lines += [''] + execreport.section(summ)
    lines += [''] + fleetagg.bench_rows(summ.get('rounds') or [])
    lines += [''] + _ratios(summ)
    lines += [''] + _per_round(summ)
    lines += [''] + _stalls(summ)
    lines += [''] + _utilization(summ)
    lines += [''] + _loop_cost(summ)
    lines += [''] + _scaling(summ)
    lines += [''] + _rtt(summ)
    lines += [''] + _cmdlat(summ)
    lines += [''] + _reaction(summ)
    if any(summ.get('rounds', [{}])[0:1]) and 'fig10_periodicity.png' in summ.get('files', []):
        lines += ['', '## Fig. 10: periodicity of the actuator task, all rounds pooled', '',
                  '![Fig. 10 periodicity](fig10_periodicity.png)']
    lines += ['', '## Timing of the median round (paper Table 1)', '']
    if summ.get('table1'):
        lines += ['Round {} (the one whose actuator release p99, idle, is the median).'.format(
            summ.get('table1_round')), '']
        lines += [recorder.format_table1(summ['table1'])]
    else:
        lines += ['Not measured.']
    lines += [''] + _machine(summ.get('machine', {}))
    lines += ['', '## Method', ''] + ['* ' + m for m in summ.get('method', [])]
    skipped = summ.get('skipped') or {}
    if skipped:
        lines += ['', '## Not measured', ''] + ['* {}: {}'.format(k, v)
                                                for k, v in skipped.items()]
    return '\n'.join(lines) + '\n'


def readme_snippet(summ: Mapping[str, Any], where: str = 'docs/results/bench') -> str:
    """Return the README's results block: targets with their spread, the machine, the command.

    ``where`` is the directory the run is published to, as the README links it.
    """
    m = summ.get('machine', {})
    run = summ.get('run', {})
    plan = run.get('plan') or {}
    lines = ['Measured with `{}` ({} rounds × {:g} s per condition, started {} UTC) on: {}, '
             '{} CPUs, kernel {} ({}). Median over the rounds, min–max in brackets; full '
             'report: [`{w}/report.md`]({w}/report.md).'.format(
                 run.get('reproduce', 'make bench'), plan.get('rounds'),
                 plan.get('condition_s', 0), run.get('started_utc', ''),
                 m.get('cpu_model', '?'), m.get('cpus_online', '?'), m.get('kernel', '?'),
                 m.get('preempt_model', '?'), w=where), '']
    rows = [[t['label'], fmt_spread(t['spread']),
             fmt_spread((t.get('of') or {}).get('concurrent')),
             fmt_spread((t.get('of') or {}).get('alone')), t['target'],
             verdict(t)]
            for t in summ.get('targets', [])]
    for key in ('baseline_over_m4k_jitter_p99_stress', 'baseline_over_m4k_jitter_max_stress'):
        e = _g(summ, 'ratios', key) or {}
        rows.append([e.get('label', key), fmt_spread(e.get('spread')), '', '', '–', 'reported'])
    lines += md_table(['ratio', 'judged (stricter): median (min–max, rounds)',
                     '÷ concurrent cyclictest', '÷ cyclictest alone', 'target', ''], rows)
    lc = summ.get('loop_cost') or {}
    lines += ['', 'CPU per task cycle, one run with the Python floor beside the stack and '
              'cyclictest: m4k {} µs, floor {} µs (floor run alone: {} µs).'.format(
                  fmt_spread(lc.get('paired_m4k_cpu_per_cycle_us'), 1),
                  fmt_spread(lc.get('paired_floor_cpu_per_cycle_us'), 1),
                  fmt_spread(lc.get('floor_cpu_per_cycle_us'), 1))]
    fleet = [r['fleet_idle'] for r in summ.get('rounds') or []
             if isinstance(r, Mapping) and isinstance(r.get('fleet_idle'), Mapping)]
    lines += fleetagg.combined_lines([fleetagg.summarize(fleet) if fleet else None],
                                     ['this run'])
    lines += _table1_compact(summ)
    if summ.get('scaling'):
        lines += ['', '![scaling]({}/scaling.png)'.format(where)]
    return '\n'.join(lines) + '\n'


def _table1_compact(summ: Mapping[str, Any]) -> list[str]:
    """Return the median round's Table 1, one row per task, and both utilization tests."""
    t1 = summ.get('table1') or {}
    tasks = t1.get('tasks') or []
    if not tasks:
        return []
    rta = {r['name']: r for r in t1.get('rta') or []}
    rta9 = {r['name']: r for r in t1.get('rta_p999') or []}

    def stats(d: Any) -> str:
        if not isinstance(d, Mapping) or not d.get('n'):
            return '-'
        return ' / '.join(_f(d.get(k)) for k in ('p50', 'p99', 'max'))

    def sched(r: Any) -> str:
        if not r:
            return '-'
        if r.get('response_us') is None:     # the iteration passed the deadline
            return 'no (> {})'.format(_f(r.get('deadline_us'), 0))
        return '{} ({})'.format('yes' if r.get('schedulable') else 'no',
                                _f(r.get('response_us'), 0))

    rows = [[t['name'], t['priority'], _f(t['period_ms'], 0), t.get('cycles', '-'),
             stats(t.get('response_us')), stats(t.get('latency_us')),
             '{} / {}'.format(t.get('overruns', '-'), t.get('deadline_misses', '-')),
             sched(rta.get(t['name'])), sched(rta9.get(t['name']))]
            for t in tasks]
    lines = ['', "**Table 1** (the paper's timing analysis per task), round {} of the full "
             'stack, idle — the round whose actuator release p99 is the median. Times in µs, '
             'p50 / p99 / max; RTA = response-time analysis with release jitter, '
             'worst-case response in brackets:'.format(summ.get('table1_round')), '']
    lines += md_table(['Task', 'Prio', 'Period (ms)', 'Cycles', 'Response', 'Release latency',
                     'Overruns / misses', 'RTA on max', 'RTA on p99.9'], rows)
    for key, label in (('utilization', 'max'), ('utilization_p999', 'p99.9')):
        u = t1.get(key)
        if u:
            lines += ['', 'Utilization test on the {} response: Σ C/T = {} % against the '
                      'Liu–Layland bound {} % for {} tasks: {}.'.format(
                          label, _f(100.0 * u['total'], 2), _f(100.0 * u['liu_layland_bound']),
                          len(u.get('per_task') or {}), u.get('verdict'))]
    return lines
