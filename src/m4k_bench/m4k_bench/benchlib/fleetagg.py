"""The three-robot fleet's wheel-command drops: per robot, pooled, over runs (pure).

:mod:`m4k_bench.fleetdrops` runs three robots (``bringup --robot rN``) on one machine, drives
all three and reads each robot's driver host log. This module turns those logs and the RT
side's motor port counters into drops per 10 000 commands -- per robot and pooled over the
fleet, the host's own apart from the simulation's (:mod:`.hostdrops`) -- and renders the
tables of ``docs/results/fleet-drops`` and of the bench report.
"""

from __future__ import annotations

import re
import time
from typing import Any, Mapping, Sequence

from m4k_bench.benchlib import hostdrops
from m4k_bench.benchlib.results import md_table
from m4k_bench.benchlib.rounds import spread

__all__ = ['ROBOTS', 'TARGET_HOST_PER_10K', 'at_stop', 'before', 'bench_rows', 'bridge_counts',
           'combined_lines', 'command',
           'device_totals', 'drop_cell', 'pool', 'pool_rt', 'render', 'run_rows', 'run_summary',
           'summarize', 'verdict']

ROBOTS = ('r1', 'r2', 'r3')
# Issue 42's target: wheel commands dropped by the host's own threads in the fleet, per 10 000.
TARGET_HOST_PER_10K = 10.0
# (linear m/s, angular rad/s) while moving; r1 and r3 reverse every HALF_S, so r1 goes 0.5 m
# ahead at most: short of the collision guard's stop zone before the default world's obstacle
# 1.5 m ahead (a guard stop would hold it still on zero wheel commands).
DRIVE = {'r1': (0.25, 0.0), 'r2': (0.0, 0.6), 'r3': (0.05, 0.0)}
HALF_S = 2.0


def command(robot: str, t_s: float) -> tuple[float, float]:
    """Return (linear, angular) for ``robot`` at ``t_s`` into the drive.

    r1 forward and back at the paper's 0.25 m/s, r2 turning on the spot, r3 a slow creep
    forward and back: all three moving, so every motor service serves non-zero commands.
    """
    v, w = DRIVE[robot]
    sign = 1.0 if v == 0.0 or (t_s % (2 * HALF_S)) < HALF_S else -1.0
    return sign * v, w


# The time stamp of a log line (logging's asctime: local time, milliseconds after a comma).
_STAMP = re.compile(r'(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d),(\d{3})')


def before(text: str, t_epoch: float) -> str:
    """Return the lines of ``text`` logged before ``t_epoch`` (cut at the first stamped later).

    A line without a time stamp stays with the lines around it.
    """
    out = []
    for line in text.splitlines(keepends=True):
        m = _STAMP.search(line)
        if m is not None:
            t = time.mktime(time.strptime(m.group(1), '%Y-%m-%d %H:%M:%S'))
            if t + int(m.group(2)) / 1e3 >= t_epoch:
                break
        out.append(line)
    return ''.join(out)


# The bridge's own drop of a cmd_vel it got to too late (m4k_bridge.node: cmd_vel_late), and
# the flight recorder's dump on a collision-guard stop: each line carries the count so far.
_LATE = re.compile(r'cmd_vel processed [\d.]+ s after it arrived .*?dropped \((\d+) so far\)')
_GUARD = re.compile(r'flight recorder: guard_stop ')


def bridge_counts(text: str) -> dict[str, int]:
    """Return a bringup log's cmd_vel dropped late by the bridge and its guard stops.

    ``cmd_vel_late``: the highest count logged (the bridge may not log every one);
    ``guard_stops``: the flight recorder's guard_stop dumps (the collision guard stopped
    forward motion: the robot then stands on zero wheel commands until it may go on).
    """
    late = [int(m.group(1)) for m in _LATE.finditer(text)]
    return {'cmd_vel_late': max(late, default=0), 'guard_stops': len(_GUARD.findall(text))}


def device_totals(text: str, device: str = 'motor') -> dict[str, int] | None:
    """Return ``device``'s drop counters over the whole log, across host restarts.

    The host logs cumulative counters; a restarted host starts again from zero, so a line
    whose ``served`` is below the previous line's closes the previous process's segment.
    The totals are the sum of every segment's last line (None when the device never logged).
    """
    segments: list[dict[str, int]] = []
    last: dict[str, int] | None = None
    for m in hostdrops.LINE.finditer(text):
        if m.group('dev') != device:
            continue
        counts = hostdrops.counts_of(m)
        if last is not None and counts['served'] < last['served']:
            segments.append(last)
        last = counts
    if last is None:
        return None
    segments.append(last)
    out: dict[str, int] = {}
    for seg in segments:
        for k, v in seg.items():
            out[k] = out.get(k, 0) + v
    out['segments'] = len(segments)
    return out


def _raw(counts: Mapping[str, int]) -> dict[str, int]:
    return {k: v for k, v in counts.items() if k != 'segments'}


def pool(per_robot: Mapping[str, Mapping[str, int] | None]) -> dict[str, Any] | None:
    """Return :func:`hostdrops.per_10k` of the robots' counters summed (None if none logged)."""
    total: dict[str, int] = {}
    seen = False
    for counts in per_robot.values():
        if not counts:
            continue
        seen = True
        for k, v in _raw(counts).items():
            total[k] = total.get(k, 0) + v
    return hostdrops.per_10k(total) if seen else None


def pool_rt(per_robot: Mapping[str, Mapping[str, Any] | None]) -> dict[str, Any] | None:
    """Return the RT side's motor port drops (:func:`hostdrops.rt_side` dicts) summed."""
    given = [d for d in per_robot.values() if d]
    if not given:
        return None
    sent = sum(int(d['sent']) for d in given)
    queue = sum(int(d['queue']) for d in given)
    link = sum(int(d['link']) for d in given)
    total = sent + queue + link
    return {'sent': sent, 'queue': queue, 'link': link,
            'queue_per_10k': 1e4 * queue / total if total else None,
            'link_per_10k': 1e4 * link / total if total else None}


def at_stop(whole: Mapping[str, int] | None,
            running: Mapping[str, int] | None) -> dict[str, int] | None:
    """Return the counters that moved after the stop signal: ``whole`` minus ``running``.

    ``running``: the totals of the lines logged before the stop (None: no line yet, all zero).
    ``served`` is left out: the host logs it only with a drop, so its value at the stop is not
    known.
    """
    if not whole:
        return None
    run = running or {}
    return {k: v - run.get(k, 0) for k, v in _raw(whole).items() if k != 'served'}


def _running_rate(whole: Mapping[str, int],
                  stop: Mapping[str, int] | None) -> dict[str, Any]:
    """Return :func:`hostdrops.per_10k` of the drops before the stop, of every command.

    Same denominator as the whole run (every command that reached the host): the drops at
    the stop are moved to ``served`` so the total stays.
    """
    counts = dict(_raw(whole))
    moved = 0
    for k, v in (stop or {}).items():
        counts[k] = counts.get(k, 0) - v
        moved += 0 if k in hostdrops.REPLY_REASONS else v
    counts['served'] = counts.get('served', 0) + moved
    return hostdrops.per_10k(counts)


def run_summary(host: Mapping[str, Mapping[str, int] | None],
                rt: Mapping[str, Mapping[str, Any] | None],
                running: Mapping[str, Mapping[str, int] | None] | None = None
                ) -> dict[str, Any]:
    """Return one fleet run's drops: per robot (host and RT side) and pooled.

    ``running``: each robot's counters logged before the stop signal (:func:`before`); the
    drops after it (the stacks stopping) are then reported apart, and ``pooled_running`` is the
    rate without them.
    """
    robots = {r: {'host': hostdrops.per_10k(_raw(c)) if c else None,
                  'segments': (c or {}).get('segments'), 'rt': rt.get(r)}
              for r, c in host.items()}
    out: dict[str, Any] = {'robots': robots, 'pooled': pool(host), 'pooled_rt': pool_rt(rt)}
    if running is not None:
        stops = {r: at_stop(c, running.get(r)) for r, c in host.items()}
        for r, st in stops.items():
            robots[r]['at_stop'] = st
        total: dict[str, int] = {}
        for st in stops.values():
            for k, v in (st or {}).items():
                total[k] = total.get(k, 0) + v
        out['pooled_at_stop'] = total
        whole: dict[str, int] = {}
        for c in host.values():
            for k, v in _raw(c or {}).items():
                whole[k] = whole.get(k, 0) + v
        out['pooled_running'] = _running_rate(whole, total) if whole else None
    return out


def summarize(runs: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Return the spread over runs of the pooled figures, and the reasons summed over runs."""
    def over(key: str) -> dict[str, Any] | None:
        return spread([((r.get('drops') or {}).get('pooled') or {}).get(key) for r in runs])
    reasons: dict[str, int] = {}
    for r in runs:
        for k, v in (((r.get('drops') or {}).get('pooled') or {}).get('by_reason')
                      or {}).items():
            reasons[k] = reasons.get(k, 0) + int(v)
    host = over('host_per_10k')
    running = spread([((r.get('drops') or {}).get('pooled_running') or {}).get('host_per_10k')
                      for r in runs])
    return {'runs': len(runs), 'per_10k': over('per_10k'), 'host_per_10k': host,
            'running_host_per_10k': running,
            # met only when every run is within the target (a median could hide one that is not)
            'met': None if host is None or host['n'] < len(runs)
            else host['max'] <= TARGET_HOST_PER_10K,
            'sim_per_10k': over('sim_per_10k'), 'by_reason': reasons,
            'load_1min': spread([(r.get('load') or {}).get('load_1min') for r in runs]),
            'busy_percent': spread([(r.get('load') or {}).get('busy_percent') for r in runs])}


def _f(v: Any, digits: int = 2) -> str:
    return '-' if not isinstance(v, (int, float)) else '{:.{}f}'.format(v, digits)


def drop_cell(d: Mapping[str, Any] | None) -> str:
    """Return '<host> host + <sim> sim / 10k (dropped of commands: reasons)'."""
    if not d:
        return '-'
    reasons = ', '.join('{} {}'.format(k, v) for k, v in (d.get('by_reason') or {}).items()
                        if v)
    return '{} host + {} sim / 10k ({} of {}{})'.format(
        _f(d.get('host_per_10k')), _f(d.get('sim_per_10k')), d.get('dropped'),
        d.get('commands'), ': ' + reasons if reasons else '')


def _stop_note(stop: Mapping[str, int] | None) -> str:
    moved = {k: v for k, v in (stop or {}).items() if v and k not in hostdrops.REPLY_REASONS}
    if not moved:
        return ''
    return '; at the stop: ' + ', '.join('{} {}'.format(k, v) for k, v in sorted(moved.items()))


def _bridge_cell(b: Mapping[str, int] | None) -> str:
    if not b:
        return '-'
    return '{} of {} late; {} guard stops'.format(b.get('cmd_vel_late', '-'),
                                                   b.get('cmd_vel_sent', '-'),
                                                   b.get('guard_stops', '-'))


def _rt_cell(rt: Mapping[str, Any] | None) -> str:
    if not rt:
        return '-'
    return 'queue {} link {} of {}'.format(rt.get('queue'), rt.get('link'), rt.get('sent'))


def _load_cell(load: Mapping[str, Any] | None) -> str:
    if not load:
        return '-'
    return '{} ({} % of {} CPUs busy; stacks {} cores)'.format(
        _f(load.get('load_1min')), _f(load.get('busy_percent'), 0), load.get('cpus', '?'),
        _f(load.get('stacks_cores')))


def run_rows(run: Mapping[str, Any], label: str) -> list[list[Any]]:
    """Return a run's table rows: one per robot and one pooled."""
    d = run.get('drops') or {}
    bridge = run.get('bridge') or {}
    rows = [[label, r, drop_cell((v or {}).get('host')) + _stop_note((v or {}).get('at_stop')),
             _rt_cell((v or {}).get('rt')), _bridge_cell(bridge.get(r)),
             _f(((run.get('load') or {}).get('stack_cores') or {}).get(r))]
            for r, v in sorted((d.get('robots') or {}).items())]
    pooled: dict[str, int] = {}
    for b in bridge.values():
        for k, v in (b or {}).items():
            pooled[k] = pooled.get(k, 0) + int(v)
    rows.append([label, '**fleet**', drop_cell(d.get('pooled')) + _stop_note(
        d.get('pooled_at_stop')), _rt_cell(d.get('pooled_rt')),
        _bridge_cell(pooled or None), _load_cell(run.get('load'))])
    return rows


HEADER = ['Run', 'Robot', "wheel-command drops at the host (host's own + simulation's)",
          "RT side's motor port (lost before the host)",
          'bridge: cmd_vel dropped late (> cmd_vel_timeout) of sent; guard stops',
          'CPU (cores) / load']


def bench_rows(rounds: Sequence[Mapping[str, Any]], key: str = 'fleet_idle') -> list[str]:
    """Return the bench report's fleet section (empty when no round ran the fleet)."""
    rows = []
    for r in rounds:
        c = r.get(key)
        if isinstance(c, Mapping):
            rows += run_rows(c, 'round {}'.format(r.get('round')))
    if not rows:
        return []
    return ['## Wheel-command drops in the three-robot fleet', '',
            'Three robots (`bringup --robot r1|r2|r3`, each its own world, runtime directory '
            'and RT core) on this machine at once, all three driven over cmd_vel '
            '(`m4k_bench.fleetdrops`). Per robot and pooled: wheel commands the driver host '
            "did not serve, per 10 000 that reached it, the host's own apart from the "
            "simulation's (`stale_device`), by reason; the RT side's motor port; the CPU "
            "each stack's processes used (cores) and the 1-min load average at the end.", ''] \
        + md_table(HEADER, rows) + combined_lines(
            [summarize([r[key] for r in rounds if isinstance(r.get(key), Mapping)])],
            ['this run'])


def render(doc: Mapping[str, Any]) -> str:
    """Return the report of a ``fleetdrops`` run as Markdown."""
    runs = doc.get('runs') or []
    s = doc.get('summary') or {}
    prov = doc.get('provenance') or {}
    commit = '{}{}'.format(prov.get('commit') or '?', ' (dirty)' if prov.get('dirty') else '')
    lines = ['# Wheel-command drops in the three-robot fleet', '',
             '`{}` -- {} run(s) of {:g} s of driving, started {} UTC, commit `{}`.'.format(
                 doc.get('command', 'fleetdrops'), len(runs), doc.get('duration_s', 0),
                 doc.get('started_utc', '?'), commit), '']
    lines += ['Pooled over the three robots, per run, median (min–max, n runs):', '',
              "* host's own: **{}** per 10 000 (target ≤ {:g} in every run: {})".format(
                  _spread(s.get('host_per_10k')), TARGET_HOST_PER_10K, verdict(s)),
              "* host's own before the stop signal (the stacks running, start-up and drive): "
              '{} per 10 000'.format(_spread(s.get('running_host_per_10k'))),
              "* the simulation's (`stale_device`): {} per 10 000".format(
                  _spread(s.get('sim_per_10k'))),
              '* all reasons: {} per 10 000'.format(_spread(s.get('per_10k'))),
              '* reasons summed over the runs: {}'.format(', '.join(
                  '{} {}'.format(k, v) for k, v in sorted((s.get('by_reason') or {}).items())
                  if v) or 'none'),
              '* 1-min load average at the end of the drive: {}; CPUs busy: {} %'.format(
                  _spread(s.get('load_1min')), _spread(s.get('busy_percent'), 0)), '']
    rows = []
    for i, run in enumerate(runs, 1):
        rows += run_rows(run, str(i))
    lines += md_table(HEADER, rows)
    lines += [''] + ['* ' + m for m in doc.get('method') or []]
    for note in doc.get('notes') or []:
        lines.append('* note: ' + note)
    return '\n'.join(lines) + '\n'


def verdict(s: Mapping[str, Any]) -> str:
    """Return 'met', 'NOT met' or 'not measured' for a :func:`summarize` result."""
    return {True: 'met', False: 'NOT met', None: 'not measured'}[s.get('met')]


def combined_lines(per_run: Sequence[Mapping[str, Any] | None],
                   names: Sequence[str] | None = None) -> list[str]:
    """Return the fleet lines: each bench run's :func:`summarize` of its rounds.

    ``names``: how each run is called (default 'run 1', 'run 2', ...).
    """
    if not any(per_run):
        return []
    names = names or ['run {}'.format(i) for i in range(1, len(per_run) + 1)]
    lines = ['', "Wheel-command drops in the three-robot fleet (`fleet_idle`: three robots on "
             'this machine, all driven; pooled over the robots), per 10 000, median (min–max, '
             "rounds); target: the host's own ≤ {:g} in every round:".format(
                 TARGET_HOST_PER_10K), '']
    for name, s in zip(names, per_run, strict=True):
        if not s:
            lines.append('* {}: not measured'.format(name))
            continue
        lines.append("* {}: host's own {}, the simulation's {}; 1-min load {} -- {}".format(
            name, _spread(s.get('host_per_10k')), _spread(s.get('sim_per_10k')),
            _spread(s.get('load_1min')), verdict(s)))
    return lines


def _spread(sp: Mapping[str, Any] | None, digits: int = 2) -> str:
    if not sp:
        return '-'
    return '{} ({}–{}, n={})'.format(_f(sp['median'], digits), _f(sp['min'], digits),
                                     _f(sp['max'], digits), sp['n'])
