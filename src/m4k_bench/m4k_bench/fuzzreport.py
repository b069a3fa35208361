"""``report.md`` of ``make fuzz`` from its results dict (pure: dict in, Markdown out)."""

from __future__ import annotations

from typing import Any

from m4k_bench.benchlib import provenance

__all__ = ['format_report']


def _ok(flag: bool) -> str:
    return 'ok' if flag else '**FAIL**'


def _overrun_lines(name: str, window: str, rows: list[dict[str, Any]], whose: str) -> list[str]:
    return ['* {} ({}, {}): at {:.1f} s, {} release(s) missed, started {:.1f} ms late{}'.format(
        name, window, whose, r['t_s'], r['missed'], r['late_ms'],
        '; probe on CPU {} stalled {:.1f} ms of it'.format(r['stall_cpu'], r['stall_ms'])
        if 'stall_cpu' in r else '') for r in rows]


def format_report(out: dict[str, Any]) -> str:
    """Return the Markdown report of one fuzz run."""
    w = out.get('windows_s', {})
    st = out.get('rt_status') or {}
    prov = out.get('provenance')
    lines = [
        '# m4k fuzz', '',
        '`make fuzz` (`fuzz --count {count} --seed {seed} --seconds-per-port {spp:g}{cfg}`): '
        'the real `rt_core` process, started as `make run` starts it (layered configuration, '
        'configured periods and priorities), with no driver host and no bridge; a sender per '
        'port writes a deterministic stream of valid, mutated, random and oversize datagrams '
        "(`status` and `stat` through the fuzzer's own links, which keep reading them). Every "
        'count below comes from what rt_core reported over XDDP (PORT_STATS, TASK_STATS, '
        'TASK_HEALTH, RT_STATUS).'.format(
            count=out['count'], seed=out['seed'], spp=out['seconds_per_port'],
            cfg=' --config {}'.format(out['config']) if out.get('config') else ''), '',
        'Result: **{}**. Measured at {} (Python {}); rt_core: {}, memory {}, {}. '
        'Quiet window {:.0f} s, then the campaign {:.0f} s; {:.0f} s wall in all. Replay: '
        '`make fuzz SEED={}`.'.format(
            'all verdicts hold' if out['ok'] else 'FAILED',
            provenance.text(prov) if prov else 'an unknown commit and machine',
            (prov or {}).get('machine', {}).get('python'),
            'SCHED_FIFO' if st.get('policy') else 'NOT SCHED_FIFO',
            'locked' if st.get('mem_locked') else 'NOT locked',
            'degraded' if st.get('degraded') else 'not degraded', w.get('quiet', 0.0),
            w.get('campaign', 0.0), out.get('wall_s', 0.0), out['seed']), '']
    if out['failures']:
        lines += ['Failures:', ''] + ['* ' + f for f in out['failures']] + ['']
    lines += ['## Ports: RT counters against the prediction', '',
              "Predicted from the stream: longer than the owning body's receive buffer -> "
              'oversize; rejected by `protocol.decode` -> malformed; valid but of a kind the '
              "port does not carry -> the body's unexpected count; the rest accepted. "
              'Observed: deltas of PORT_STATS (received, malformed, dropped_oversize) and of '
              "the owner's TASK_HEALTH.unexpected over the port's turn.", '',
              '| port | owner | sent | malformed | oversize | unexpected | accepted | s | '
              'result |', '|---|---|---|---|---|---|---|---|---|']
    for p in out['ports']:
        e = p['expected']
        lines.append('| {} | {} | {} | {} / {} | {} / {} | {} / {} | {} | {:.1f} | {} |'.format(
            p['label'], p['owner'], e['sent'], p['malformed'], e['malformed'], p['oversize'],
            e['oversize'], p['unexpected'], e['unexpected'], e['accepted'], p['seconds'],
            'ok' if p['ok'] else '; '.join(p['problems'])))
    lines += ['', '(counted / predicted)', '',
              '## Tasks: cycles and overruns, quiet window vs campaign', '',
              'Cycles started in the campaign must be within 1 % (at least one cycle) of '
              "campaign time ÷ period, and no overrun may be the fuzzing's. An overrun is the "
              "host's when a stall probe -- one process per CPU, SCHED_FIFO 99 above every RT "
              'task, waking every 1 ms, so nothing in rt_core can delay it; a wake-up more than '
              "{:g} ms late is a stall -- saw its CPU stalled for at least half of the task's "
              "lateness, between the release before the missed one and the task's start; "
              'otherwise the overrun is counted against the fuzzing. The quiet window, same '
              "run, no fuzzing, shows the machine's own rate.".format(
                  out['probes']['threshold_ms']), '',
              '| task | period (ms) | campaign cycles | expected | quiet overruns (host / '
              'other) | campaign overruns (host / fuzzing) | deadline misses (quiet / campaign) '
              '| body errors | result |', '|---|---|---|---|---|---|---|---|---|']
    detail: list[str] = []
    for name, t in out['tasks'].items():
        q, c, v = t.get('quiet', {}), t['campaign'], t['verdict']
        lines.append('| {} | {:g} | {} | {:.1f} ± {:.1f} | {} / {} | {} / {} | {} / {} | {} | '
                     '{} |'.format(name, t['period_ms'], c['cycles'], v['expected'], v['slack'],
                                   q.get('host_overruns', '-'), q.get('own_overruns', '-'),
                                   c['host_overruns'], c['own_overruns'],
                                   q.get('deadline_misses', '-'), c['deadline_misses'],
                                   t['body_errors'], _ok(v['ok'])))
        for win, row in (('quiet', q), ('campaign', c)):
            detail += _overrun_lines(name, win, row.get('host', []), 'host stall')
            detail += _overrun_lines(name, win, row.get('own', []), 'no probe stall')
    stalls = out['probes']['stalls']
    lines += ['', 'Probe stalls over {:g} ms: quiet {} (max {:.1f} ms), campaign {} '
              '(max {:.1f} ms).'.format(
                  out['probes']['threshold_ms'], len(stalls.get('quiet', [])),
                  max((s['ms'] for s in stalls.get('quiet', [])), default=0.0),
                  len(stalls.get('campaign', [])),
                  max((s['ms'] for s in stalls.get('campaign', [])), default=0.0))]
    if detail:
        lines += ['', 'Every overrun:', ''] + detail
    rc = out['rt_core']
    lines += ['', '## rt_core', '',
              'Running at the end: {}; exit code on SIGTERM: {}. Its last lines:'.format(
                  'yes' if rc['alive_at_end'] else 'NO', rc['exit']), '', '```']
    lines += rc['log_tail'] + ['```', '']
    return '\n'.join(lines)
