"""The report's executive section: thread per task and the frame, side by side, every round.

Per round and condition: the actuator's release latency and overruns, the absolute CPU per
task cycle and % of one core, the honest denominators of that round (the bare floor, the
channel floor in the same structure), the driver host's wheel-command drops per 10 000 (the
host's own and the simulation's apart, by reason), and whether the condition's cyclictest
reference held (:mod:`.validity`): a broken reference is named, and its ratios are left out.
"""

from __future__ import annotations

from typing import Any, Mapping

from m4k_bench.benchlib.results import md_table
from m4k_bench.benchlib.validity import broken_reference, condition_reference

__all__ = ['EXEC_CONDITIONS', 'section']

PERIOD_US = 10_000.0
# condition -> (executive, load)
EXEC_CONDITIONS = {
    'm4k_idle': ('thread per task', 'idle'),
    'm4k_frame_idle': ('frame', 'idle'),
    'm4k_stress': ('thread per task', 'stress-ng'),
    'm4k_frame_stress': ('frame', 'stress-ng'),
    'm4k_slow_threads': ('thread per task', 'idle, slow sonar body'),
    'm4k_slow_frame': ('frame', 'idle, slow sonar body'),
}
# the denominators of each structure: (bare floor, channel floor)
FLOORS = {'thread per task': ('floor', 'floor_socket'),
          'frame': ('floor_frame', 'floor_frame_socket')}


def _f(v: Any, digits: int = 1) -> str:
    return '-' if not isinstance(v, (int, float)) else '{:.{}f}'.format(v, digits)


def _drops(d: Mapping[str, Any] | None, rt: Mapping[str, Any] | None) -> str:
    out = '-'
    if d:
        reasons = ', '.join('{} {}'.format(k, v) for k, v in (d.get('by_reason') or {}).items()
                            if v)
        out = '{} host + {} sim / 10k ({} of {}{})'.format(
            _f(d.get('host_per_10k'), 2), _f(d.get('sim_per_10k'), 2), d.get('dropped'),
            d.get('commands'), ': ' + reasons if reasons else '')
    if rt:
        out += '; before the host: queue {} link {} of {} sent'.format(
            rt.get('queue'), rt.get('link'), rt.get('sent'))
    return out


def section(summ: Mapping[str, Any]) -> list[str]:
    """Return the markdown lines of the section (empty when no executive condition ran)."""
    rows = []
    for r in summ.get('rounds', []):
        for key, (exe, load) in EXEC_CONDITIONS.items():
            c = r.get(key)
            if not isinstance(c, Mapping):
                continue
            lat = c.get('latency_us') or {}
            ct = c.get('cyclictest') or {}
            bare, chan = (_f((r.get(k) or {}).get('cpu_per_cycle_us')) for k in FLOORS[exe])
            why = broken_reference(condition_reference(r, key), PERIOD_US)
            misses = c.get('task_misses') or {}
            act = misses.get('actuator') or {}
            rows.append([r.get('round'), exe, load,
                         '{} / {} / {}'.format(_f(lat.get('p50')), _f(lat.get('p99')),
                                               _f(lat.get('max'))),
                         '{} / {}'.format(_f(ct.get('p50')), _f(ct.get('p99'))),
                         '{} / {}'.format(act.get('overruns', '-'),
                                          act.get('deadline_misses', '-')),
                         _f(c.get('cpu_per_cycle_us')), _f(c.get('cpu_percent')),
                         '{} / {}'.format(bare, chan),
                         _drops(c.get('host_drops'), c.get('motor_port_drops')),
                         'INVALID: ' + why if why else 'valid'])
    if not rows:
        return []
    lines = ['## Executives side by side: thread per task (the paper) and the frame', '',
             'Every round runs the same stack under both executives (`runtime.executive`). '
             'Actuator release latency p50 / p99 / max (µs) against its own ideal release; '
             'the concurrent cyclictest p50 / p99 (µs) is the reference, and a round whose '
             'reference shows the host stalling is INVALID (no ratio uses it). CPU is the RT '
             "process's, per task cycle (µs) and in % of one core; the floors are that round's "
             "bare Python floor and channel floor (+ a task cycle's socket calls) in the same "
             'structure (µs per cycle). Drops: wheel commands the driver host did not serve, '
             "per 10 000 that reached it: the host's own (a real robot would see them) + the "
             "simulation's (sim_robot answering late over the sim bus), by reason; then the "
             "RT side's motor port: WHEEL_CMDs lost before the host (its queue full, or no host "
             'linked: start-up and restarts). The slow '
             'rows inject a sonar body spinning 15 ms every 10th cycle (m4k_bench.slowbody).', '']
    lines += md_table(['Round', 'Executive', 'Load', 'actuator p50 / p99 / max',
                       'cyclictest p50 / p99', 'actuator overruns / misses', 'CPU µs/cycle',
                       'CPU % core', 'floor / channel floor µs', 'wheel-command drops',
                       'reference'], rows)
    return lines
