"""NRT timing recorder: collect TASK_STATS batches, compute the paper's Table 1 and more.

The RT monitor task ships every task's ring samples as TASK_STATS datagrams (plus RT_STATUS,
and on the ``stat`` port TASK_HEALTH and FORBIDDEN_SITE, see :mod:`m4k_rt.protocol`). This
module accumulates them per task and writes, from one run:

* ``table1.md`` -- period and response time avg/max/min/std and p50/p99/p99.9 per task, as the
  paper's Table 1, plus counters (overruns, deadline misses, mode-switch analogue, forbidden
  calls) and the schedulability tests;
* ``samples.csv`` -- every raw sample (task, t_rel, t_start, t_end, expirations);
* ``summary.json`` -- everything above, machine-readable.

The formatting functions are pure (summary dict in, text out) so the bench tool reuses them.
"""

import argparse
import csv
import dataclasses
import math
import os
import sys
import time
from typing import Any, Iterable, Sequence

from m4k_bench.benchlib import results
from m4k_rt import protocol, rosargs, timing

__all__ = ['Recorder', 'TaskSeries', 'format_table1', 'main']

_US = 1e-3  # ns -> us
_MS = 1e-6  # ns -> ms


@dataclasses.dataclass
class TaskSeries:
    """Everything received about one task."""

    name: str
    index: int = 0
    priority: int = 0
    cpu: int = -1
    period_ns: int = 0
    cycles: int = 0
    nvcsw: int = 0
    nivcsw: int = 0
    minflt: int = 0
    forbidden_calls: int = 0
    t_rel: list[int] = dataclasses.field(default_factory=list)
    t_start: list[int] = dataclasses.field(default_factory=list)
    t_end: list[int] = dataclasses.field(default_factory=list)
    expirations: list[int] = dataclasses.field(default_factory=list)
    health: protocol.TaskHealth | None = None
    sites: dict[tuple[str, str, int], protocol.ForbiddenSite] = dataclasses.field(
        default_factory=dict)
    duplicates: int = 0

    def add_stats(self, st: Any) -> None:
        """Take the counters of a TASK_STATS payload and append its new samples."""
        self.index, self.priority, self.cpu = st.task_index, st.priority, st.cpu
        self.period_ns, self.cycles = st.period_ns, st.cycles
        self.nvcsw, self.nivcsw, self.minflt = st.nvcsw, st.nivcsw, st.minflt
        self.forbidden_calls = st.forbidden_calls
        last = self.t_rel[-1] if self.t_rel else None
        for s in st.samples:
            # The same batch may arrive on two ports: releases only move forward.
            if last is not None and s.t_rel <= last:
                self.duplicates += 1
                continue
            self.t_rel.append(s.t_rel)
            self.t_start.append(s.t_start)
            self.t_end.append(s.t_end)
            self.expirations.append(s.expirations)
            last = s.t_rel

    def analyze(self, skip: int = 0) -> timing.TaskTiming:
        """Return the timing analysis of the samples received so far, minus the first ``skip``."""
        return timing.analyze(self.t_rel[skip:], self.t_start[skip:], self.t_end[skip:],
                              self.expirations[skip:], self.period_ns or 1, self.name)


class Recorder:
    """Accumulate datagrams from the status/stat ports (or an in-process list)."""

    def __init__(self, warmup_cycles: int = 0) -> None:
        """Start empty; statistics leave out each task's first ``warmup_cycles`` samples.

        The first cycle of a task runs code paths for the first time (and links its peers),
        so its response time is start-up, not steady state; say so when you skip it.
        """
        self.warmup_cycles = warmup_cycles
        self.tasks: dict[str, TaskSeries] = {}
        self.rt_status: Any = None
        self.port_stats: dict[str, protocol.PortStats] = {}   # label -> latest (``status``)
        self.host_drops: dict[str, protocol.HostDrops] = {}   # device -> latest (forwarded)
        self.datagrams = 0
        self.malformed: dict[str, int] = {}
        self.ignored = 0

    def _task(self, name: str) -> TaskSeries:
        t = self.tasks.get(name)
        if t is None:
            t = self.tasks[name] = TaskSeries(name)
        return t

    def feed(self, data: bytes) -> int:
        """Account one datagram; return its kind (-1 when malformed and counted)."""
        self.datagrams += 1
        try:
            header, payload = protocol.decode(data)
        except protocol.ProtocolError as exc:
            self.malformed[exc.reason] = self.malformed.get(exc.reason, 0) + 1
            return -1
        if header.kind == protocol.Kind.TASK_HEALTH:
            self._task(payload.name).health = payload
            return header.kind
        if header.kind == protocol.Kind.FORBIDDEN_SITE:
            self._task(payload.name).sites[(payload.event, payload.file, payload.line)] = payload
            return header.kind
        if header.kind == protocol.Kind.TASK_STATS:
            self._task(payload.name).add_stats(payload)
        elif header.kind == protocol.Kind.RT_STATUS:
            self.rt_status = payload
        elif header.kind == protocol.Kind.PORT_STATS:
            self.port_stats[payload.label] = payload
        elif header.kind == protocol.Kind.HOST_DROPS:
            self.host_drops[payload.device] = payload
        else:
            self.ignored += 1
        return int(header.kind)

    def feed_all(self, datagrams: Iterable[bytes]) -> None:
        """Feed every datagram of an in-process list."""
        for d in datagrams:
            self.feed(d)

    def summary(self) -> dict[str, Any]:
        """Return the JSON-able summary: per-task stats, counters, LL test and RTA."""
        return summarize(self.tasks.values(), self.rt_status, self.warmup_cycles)

    def write(self, outdir: str) -> dict[str, str]:
        """Write table1.md, samples.csv and summary.json into ``outdir``; return the paths."""
        os.makedirs(outdir, exist_ok=True)
        summ = self.summary()
        paths = {'table1': os.path.join(outdir, 'table1.md'),
                 'csv': os.path.join(outdir, 'samples.csv'),
                 'json': os.path.join(outdir, 'summary.json')}
        with open(paths['table1'], 'w', encoding='utf-8') as f:
            f.write(format_table1(summ))
        with open(paths['csv'], 'w', newline='', encoding='utf-8') as f:
            w = csv.writer(f)
            w.writerow(['task', 't_rel_ns', 't_start_ns', 't_end_ns', 'expirations'])
            for t in self.tasks.values():
                for row in zip(t.t_rel, t.t_start, t.t_end, t.expirations, strict=True):
                    w.writerow([t.name, *row])
        results.write_json(paths['json'], summ)
        return paths


def _stats_dict(s: timing.Stats, scale: float) -> dict[str, float | int | None]:
    out: dict[str, float | int | None] = {'n': s.n}
    for k in ('avg', 'max', 'min', 'std', 'p50', 'p99', 'p999'):
        v = getattr(s, k) * scale
        out[k] = None if math.isnan(v) else v
    return out


def summarize(series: Iterable[TaskSeries], rt_status: Any = None,
              warmup_cycles: int = 0) -> dict[str, Any]:
    """Build the summary dict from task series (pure)."""
    tasks: list[dict[str, Any]] = []  # one JSON row per task
    for t in sorted(series, key=lambda s: (-s.priority, s.name)):
        if len(t.t_rel) <= warmup_cycles:
            continue
        a = t.analyze(warmup_cycles)
        h = t.health
        tasks.append({
            'name': t.name, 'index': t.index, 'priority': t.priority, 'cpu': t.cpu,
            'period_ms': t.period_ns * _MS, 'cycles': t.cycles, 'samples': a.cycles,
            'period_ms_stats': _stats_dict(a.period, _MS),
            'jitter_us': _stats_dict(a.jitter, _US),
            'latency_us': _stats_dict(a.latency, _US),
            'response_us': _stats_dict(a.response, _US),
            'overruns': a.overruns, 'deadline_misses': a.deadline_misses,
            # Without TASK_HEALTH (it travels on `stat` only), the same rule from TASK_STATS's
            # cumulative counters: voluntary switches beyond the one timer wait per cycle.
            'nvcsw': t.nvcsw,
            'nvcsw_extra': h.nvcsw_extra if h else max(0, t.nvcsw - t.cycles),
            'nivcsw': t.nivcsw, 'minflt': t.minflt, 'majflt': h.majflt if h else None,
            'body_errors': h.body_errors if h else None, 'fifo': bool(h.fifo) if h else None,
            'forbidden_calls': t.forbidden_calls,
            'forbidden_sites': [
                {'event': s.event, 'file': s.file, 'line': s.line, 'func': s.func,
                 'count': s.calls} for s in t.sites.values()],
            'wcrt_ns': None if math.isnan(a.wcrt_ns) else a.wcrt_ns,
        })
    out: dict[str, Any] = {'tasks': tasks, 'warmup_cycles_skipped': warmup_cycles}
    measured = [t for t in tasks if t['wcrt_ns'] is not None and t['period_ms'] > 0]
    if measured:
        # Two readings of the same test: the worst cycle (max response, max release latency
        # as release jitter) and the p99.9 cycle, so one stall does not decide the verdict
        # alone and the report shows both.
        for key, pick in (('', 'max'), ('_p999', 'p999')):
            c_ns = [t['response_us'][pick] / _US for t in measured]
            u = timing.utilization_test([(t['name'], c, t['period_ms'] / _MS)
                                         for t, c in zip(measured, c_ns, strict=True)])
            out['utilization' + key] = {'per_task': u.per_task, 'total': u.total,
                                        'liu_layland_bound': u.bound, 'verdict': u.verdict,
                                        'from': 'response ' + pick}
            rta = timing.response_time_analysis([
                timing.RtaTask(t['name'], c, t['period_ms'] / _MS, t['priority'],
                               jitter_ns=max(0.0, (t['latency_us'][pick] or 0.0) / _US))
                for t, c in zip(measured, c_ns, strict=True)])
            out['rta' + key] = [{'name': r.name, 'response_us': None if r.response_ns is None
                                 else r.response_ns * _US, 'deadline_us': r.deadline_ns * _US,
                                 'schedulable': r.schedulable} for r in rta]
    if rt_status is not None:
        out['rt_status'] = dict(rt_status._asdict())
    return out


def _f(v: float | None, digits: int = 3) -> str:
    return '-' if v is None else '{:.{}f}'.format(v, digits)


def format_table1(summ: dict[str, Any]) -> str:
    """Format the summary as Markdown: Table 1, counters, utilization and RTA (pure)."""
    lines = ['## Timing analysis per task (paper Table 1)', '',
             '| Task | Range | Period (ms) | Response (us) | Release latency (us) |',
             '|---|---|---|---|---|']
    rows = (('Ave', 'avg'), ('Max', 'max'), ('Min', 'min'), ('St. d.', 'std'),
            ('p50', 'p50'), ('p99', 'p99'), ('p99.9', 'p999'))
    for t in summ['tasks']:
        for i, (label, key) in enumerate(rows):
            lines.append('| {} | {} | {} | {} | {} |'.format(
                t['name'] if i == 0 else '', label, _f(t['period_ms_stats'][key]),
                _f(t['response_us'][key]), _f(t['latency_us'][key])))
    lines += ['', '## Counters (mode-switch analogue)', '',
              '| Task | Prio | Period (ms) | Cycles | Overruns | Deadline misses | CSW vol extra '
              '| CSW invol | Minor PF | Major PF | Body errors | Forbidden calls | Last site |',
              '|---|---|---|---|---|---|---|---|---|---|---|---|---|']
    for t in summ['tasks']:
        sites = t['forbidden_sites']
        site = '{event} {file}:{line} ({func})'.format(**sites[-1]) if sites else ''
        lines.append('| {} | {} | {:g} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |'.format(
            t['name'], t['priority'], t['period_ms'], t['cycles'], t['overruns'],
            t['deadline_misses'], _d(t['nvcsw_extra']), t['nivcsw'], t['minflt'],
            _d(t['majflt']), _d(t['body_errors']), t['forbidden_calls'], site))
    u = summ.get('utilization')
    if u:
        lines += ['', '## Schedulability (worst case = max measured response)', '',
                  '| Task | Utilization (%) | RTA response (us) | Schedulable |',
                  '|---|---|---|---|']
        rta = {r['name']: r for r in summ.get('rta', [])}
        for name, ui in u['per_task'].items():
            r = rta.get(name, {})
            lines.append('| {} | {:.3f} | {} | {} |'.format(
                name, ui * 100, _f(r.get('response_us')),
                'yes' if r.get('schedulable') else 'no'))
        lines += ['', 'Total utilization {:.3f} % vs Liu-Layland bound {:.1f} % for {} tasks: '
                  '{}.'.format(u['total'] * 100, u['liu_layland_bound'] * 100,
                               len(u['per_task']), u['verdict'])]
    return '\n'.join(lines) + '\n'


def _d(v: int | None) -> str:
    return '-' if v is None else str(v)


def record_link(link: Any, duration_s: float, recorder: Recorder,
                poll_s: float = 0.2) -> Recorder:
    """Read datagrams from an NrtLink-like object (``read(timeout)``) for ``duration_s``."""
    end = time.monotonic() + duration_s
    while True:
        left = end - time.monotonic()
        if left <= 0:
            return recorder
        data = link.read(min(poll_s, left))
        if data:
            recorder.feed(data)


def main(argv: Sequence[str] | None = None) -> int:
    """Record from the status port for a while and write Table 1, CSV and JSON."""
    ap = argparse.ArgumentParser(description='Record RT task timing from the status port.')
    ap.add_argument('--port', default='status', help='port label or number (default status)')
    ap.add_argument('--duration', type=float, default=10.0, help='seconds to record')
    ap.add_argument('--out', default='results/timing', help='output directory')
    args = rosargs.parse_args(ap, argv)
    from m4k_rt import channel
    port: int | str = int(args.port) if args.port.isdigit() else args.port
    link = channel.NrtLink(port)
    rec = Recorder()
    try:
        record_link(link, args.duration, rec)
    finally:
        link.close()
    paths = rec.write(args.out)
    sys.stdout.write(format_table1(rec.summary()))
    sys.stdout.write('wrote {}\n'.format(', '.join(paths.values())))
    return 0


if __name__ == '__main__':
    sys.exit(main())
