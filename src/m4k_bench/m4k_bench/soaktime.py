"""soaktime: the soak's timeline -- when the RT tasks were late, and whether the machine was too.

The soak's rule (:func:`m4k_bench.soak.late_verdict`) compares two totals over the whole run:
a task's overruns + deadline misses, and cyclictest's samples later than one period. They
count different things. A timerfd task that wakes ``L`` late with period ``P`` reads
``1 + floor(L / P)`` expirations: every release that expired in the stall is one overrun.
cyclictest (rt-tests, absolute mode) takes one sample per wake-up and then moves its next
target past the wake-up (``while (now > next) next += interval``), so one stall is one late
sample however long it lasts. This module puts both on one clock (CLOCK_MONOTONIC, the clock
of ``time.monotonic()``, of m4k's samples and of cyclictest's ``--spike`` time stamps):

* :func:`parse_verbose` / :func:`sample_times`: cyclictest ``-v`` lines ``thread: cycle:
  latency_us`` and each sample's target time, following cyclictest's skip after a stall;
* :func:`parse_spikes`: cyclictest ``--spike=T`` lines (latency and wake-up time stamp, us);
* :class:`CounterTimeline`: the monitor's per-task counters polled every second, kept as
  per-second deltas;
* :func:`sample_events`: the same events at the exact cycle, from the task samples the
  ``stat`` port also carries;
* :func:`attribute`: per task, its events binned per second and split into "coincide with a
  machine stall" (within +-``window`` s of a second in which cyclictest was late) and "m4k
  alone", with the largest one-second burst.

Pure functions (lists in, dicts out) so the unit tests feed them synthetic input.
"""

from __future__ import annotations

import csv
import math
import re
from typing import Any, Iterable, Mapping, Sequence

from m4k_rt import timing

__all__ = ['CounterTimeline', 'attribute', 'parse_spikes', 'parse_verbose', 'sample_events',
           'sample_times', 'skipped_releases']

_VERBOSE = re.compile(r'^\s*(\d+):\s*(\d+):\s*(-?\d+)\s*$')
_SPIKE = re.compile(r'^T:\s*(\d+)\s+Spike:\s*(-?\d+):\s*TS:\s*(\d+)\s*$')

Event = tuple[float, int]   # (monotonic time s, count)


def parse_verbose(text: str, thread: int = 0) -> list[tuple[int, int]]:
    """Return [(cycle, latency_us)] of one thread from cyclictest ``-v`` output.

    Other lines (the CPU count, ``Thread 0 Interval``, the ``--spike`` list) are skipped.
    """
    out = []
    for line in text.splitlines():
        m = _VERBOSE.match(line)
        if m and int(m.group(1)) == thread:
            out.append((int(m.group(2)), int(m.group(3))))
    return out


def parse_spikes(text: str) -> list[tuple[int, int, float]]:
    """Return [(thread, latency_us, wake-up time s)] from cyclictest ``--spike`` output."""
    out = []
    for line in text.splitlines():
        m = _SPIKE.match(line.strip())
        if m:
            out.append((int(m.group(1)), int(m.group(2)), int(m.group(3)) / 1e6))
    return out


def sample_times(samples: Sequence[tuple[int, int]], interval_us: int,
                 start_s: float = 0.0) -> list[tuple[float, int]]:
    """Return [(target time s, latency_us)]: sample k's target follows cyclictest's skip.

    After each wake-up cyclictest adds one interval to its target and then more while the
    wake-up is past it, so the next target is ``ceil(latency / interval)`` intervals on (at
    least one): a sample ``k`` is at ``start + k * interval`` only until the first stall.
    """
    out = []
    t_us = 0
    for _, lat in samples:
        out.append((start_s + t_us / 1e6, lat))
        t_us += interval_us * max(1, -(-lat // interval_us))
    return out


def anchor(times: Sequence[tuple[float, int]], spikes: Sequence[tuple[int, int, float]],
           threshold_us: int) -> float | None:
    """Return the offset that puts relative ``times`` on the spikes' clock (None: no spike).

    The first sample above ``threshold_us`` is the first spike; its target is the spike's
    wake-up minus its latency.
    """
    first = next((t for t, lat in times if lat > threshold_us), None)
    if first is None or not spikes:
        return None
    _, lat, ts = spikes[0]
    return ts - lat / 1e6 - first


def skipped_releases(latencies_us: Iterable[int], period_us: int) -> int:
    """Return the releases a timerfd task of ``period_us`` skips in these wake-up latencies.

    A wake-up ``L`` late reads ``1 + floor(L / P)`` expirations: ``floor(L / P)`` overruns.
    """
    return sum(lat // period_us for lat in latencies_us if lat >= period_us)


class CounterTimeline:
    """The monitor's per-task counters, polled every second, as per-second deltas."""

    KEYS = ('overruns', 'deadline_misses')

    def __init__(self, first: Mapping[str, Mapping[str, Any]]) -> None:
        """Start from the counters ``first`` (the soak's baseline)."""
        self.last = {n: {k: t.get(k) for k in self.KEYS} for n, t in first.items()}
        self.rows: list[tuple[float, str, int, int]] = []   # (t s, task, d_over, d_miss)

    def poll(self, now_s: float, tasks: Mapping[str, Mapping[str, Any]]) -> None:
        """Record the change of every task's counters since the previous poll."""
        for name, t in tasks.items():
            prev = self.last.get(name, {})
            d = []
            for k in self.KEYS:
                v, p = t.get(k), prev.get(k)
                d.append(v - p if isinstance(v, int) and isinstance(p, int) else 0)
            self.last[name] = {k: t.get(k) for k in self.KEYS}
            if d[0] or d[1]:
                self.rows.append((now_s, name, d[0], d[1]))

    def events(self) -> dict[str, list[Event]]:
        """Return task -> [(poll time s, overruns + misses in the second before it)]."""
        out: dict[str, list[Event]] = {}
        for t, name, o, m in self.rows:
            out.setdefault(name, []).append((t, o + m))
        return out


def sample_events(t_rel: Sequence[int], t_start: Sequence[int], t_end: Sequence[int],
                  expirations: Sequence[int], period_ns: int, lo_ns: int,
                  hi_ns: int) -> tuple[list[Event], list[Event]]:
    """Return (overruns, deadline misses) of one task's samples with ``lo <= t_start < hi``.

    Overruns (:func:`m4k_rt.timing.overruns`) are placed at the cycle's start (the late
    wake-up); a deadline miss (:func:`m4k_rt.timing.deadline_missed`) at the cycle's end.
    """
    over: list[Event] = []
    miss: list[Event] = []
    for rel, start, end, exp in zip(t_rel, t_start, t_end, expirations, strict=True):
        if not lo_ns <= start < hi_ns:
            continue
        n = timing.overruns(exp)
        if n:
            over.append((start / 1e9, n))
        if timing.deadline_missed(rel, end, period_ns):
            miss.append((end / 1e9, 1))
    return over, miss


def attribute(events: Mapping[str, Sequence[Event]], late: Mapping[str, Sequence[float]],
              t0: float, window: int = 1) -> dict[str, Any]:
    """Split every task's late events into "coincide with a machine stall" and "m4k alone".

    ``events``: task -> [(time s, count)]; ``late``: reference -> cyclictest's late-sample
    times (s), all on one clock; ``t0`` the start of the run. Times are binned into whole
    seconds since ``t0``; an event's second coincides with a reference when that reference
    was late in a second within ``+-window``. Returns per task ``total``, ``coincide`` (any
    reference), ``by_ref`` (each reference), ``alone``, ``per_second`` {second: count},
    ``max_burst`` and ``max_burst_s`` (the largest one-second count and its second), and
    ``alone_seconds``.
    """
    late_s = {ref: {math.floor(t - t0) for t in ts} for ref, ts in late.items()}
    near = {ref: {s + d for s in secs for d in range(-window, window + 1)}
            for ref, secs in late_s.items()}
    any_near = set().union(*near.values()) if near else set()
    out: dict[str, Any] = {}
    for name, evs in events.items():
        per: dict[int, int] = {}
        for t, n in evs:
            if n:
                s = math.floor(t - t0)
                per[s] = per.get(s, 0) + n
        total = sum(per.values())
        coincide = sum(n for s, n in per.items() if s in any_near)
        burst_s = max(per, key=lambda s: (per[s], -s)) if per else None
        out[name] = {
            'total': total, 'coincide': coincide, 'alone': total - coincide,
            'by_ref': {ref: sum(n for s, n in per.items() if s in nr)
                       for ref, nr in near.items()},
            'per_second': dict(sorted(per.items())),
            'max_burst': per[burst_s] if burst_s is not None else 0, 'max_burst_s': burst_s,
            'alone_seconds': sorted(s for s in per if s not in any_near)}
    return {'window_s': window, 'late_seconds': {r: sorted(s) for r, s in late_s.items()},
            'tasks': out}


def reference(text: str, period_us: int, start_s: float, t0: float) -> dict[str, Any]:
    """Return one cyclictest reference from its ``-v``/``--spike`` output.

    The late samples' times are the spikes' wake-up stamps when the spike list holds every
    late sample; otherwise the ``-v`` samples' reconstructed times (target + latency), with
    the target clock anchored on the first spike or, without one, on ``start_s``. The
    per-second maxima are binned in whole seconds since ``t0``.
    """
    samples = parse_verbose(text)
    rel = sample_times(samples, period_us)
    spikes = [s for s in parse_spikes(text) if s[0] == 0]
    off = anchor(rel, spikes, period_us - 1)
    anchored = 'first spike' if off is not None else 'process start'
    if off is None:
        off = start_s + period_us / 1e6
    times = [(t + off, lat) for t, lat in rel]
    late = [(t + lat / 1e6, lat) for t, lat in times if lat >= period_us]
    spike_late = [(ts, lat) for _, lat, ts in spikes if lat >= period_us]
    use_spikes = len(spike_late) == len(late) and bool(late)
    err = max((abs(a[0] - b[0]) for a, b in zip(late, spike_late, strict=True)), default=None) \
        if use_spikes else None
    per_s: dict[int, list[int]] = {}
    for t, lat in times:
        per_s.setdefault(math.floor(t - t0), []).append(lat)
    return {'samples': len(samples), 'late': len(late),
            'late_latencies_us': [lat for _, lat in late],
            'skipped_releases': skipped_releases((lat for _, lat in late), period_us),
            'max_us': max((lat for _, lat in samples), default=None),
            'late_times_s': [t for t, _ in (spike_late if use_spikes else late)],
            'times_from': '--spike stamps' if use_spikes else '-v, anchored on ' + anchored,
            'spikes': len(spike_late), 'spike_vs_v_max_ms': None if err is None else err * 1e3,
            'per_second_max_us': {s: max(v) for s, v in sorted(per_s.items())}}


# The counters reach the soak up to 2 s after the event: the monitor ships them once a second
# and the soak polls once a second (the 90 s check run saw every counter delta 1-2 s after the
# cycle sample of the same overrun). Their attribution window is widened by that delay; the
# cycle samples carry the exact time and keep +-1 s.
COUNTER_WINDOW_S = 2


def analyze(refs: Mapping[str, dict[str, Any]], counters: CounterTimeline,
            series: Mapping[str, Any], t_first: float, t_last: float) -> dict[str, Any]:
    """Return the timeline section of the soak's summary.

    ``refs``: name -> :func:`reference` result plus its ``priority``; ``series``: task ->
    :class:`m4k_bench.recorder.TaskSeries` (the samples the ``stat`` port carried).
    """
    late = {r: v['late_times_s'] for r, v in refs.items()}
    by_counters = attribute(counters.events(), late, t_first, COUNTER_WINDOW_S)
    sampled: dict[str, list[Event]] = {}
    totals: dict[str, dict[str, int]] = {}
    for name, s in series.items():
        over, miss = sample_events(s.t_rel, s.t_start, s.t_end, s.expirations, s.period_ns,
                                   int(t_first * 1e9), int(t_last * 1e9))
        sampled[name] = sorted(over + miss)
        totals[name] = {'overruns': sum(n for _, n in over), 'deadline_misses': len(miss),
                        'samples': sum(1 for st in s.t_start
                                       if t_first * 1e9 <= st < t_last * 1e9)}
    by_samples = attribute(sampled, late, t_first)
    for name, tot in totals.items():
        by_samples['tasks'].setdefault(name, {}).update(tot)
    return {'t_first': t_first, 't_last': t_last, 'references': dict(refs),
            'counters': by_counters, 'samples': by_samples,
            'counter_rows': [list(r) for r in counters.rows]}


def _fmt_ms(lats: Sequence[int]) -> str:
    return ', '.join('{:.1f}'.format(v / 1e3) for v in lats) or 'none'


def report_lines(tl: Mapping[str, Any], period_us: int) -> list[str]:
    """Return the report's timeline section (measured statements, from ``tl`` only)."""
    refs = tl['references']
    lines = ['## Timeline: when the late cycles happened', '',
             'The rule above compares totals of different things. A timerfd task woken L late '
             'counts floor(L / period) overruns (every release that expired); cyclictest counts '
             'one late sample per stall, whatever its length (after a late wake-up it moves its '
             'target past the wake-up: `while (now > next) next += interval`). Below, both on '
             "one clock (CLOCK_MONOTONIC): the monitor's counters polled every second, the "
             "tasks' own cycle samples, and cyclictest's late samples.", '',
             '| cyclictest reference | priority | samples | late (> {} us) | late latencies ms '
             '| releases a {:g} ms task skips in them | times from |'.format(
                 period_us, period_us / 1e3), '|---|---|---|---|---|---|---|']
    for name, r in refs.items():
        lines.append('| {} | {} | {} | {} | {} | {} | {} |'.format(
            name, r.get('priority'), r['samples'], r['late'], _fmt_ms(r['late_latencies_us']),
            r['skipped_releases'], r['times_from']))
    sw, cw = tl['samples']['window_s'], tl['counters']['window_s']
    lines += ['', "Each task's overruns + misses, binned per second since the counters' "
              'baseline. From the cycle samples (exact cycle times): "with a stall" = in a '
              'second within +-{} s of a second in which a cyclictest reference was late, "m4k '
              'alone" = no cyclictest lateness nearby. From the counters polled every second: '
              'the same split within +-{} s, because a count reaches the soak up to 2 s after '
              'its cycle (the monitor ships at 1 Hz, the soak polls at 1 Hz).'.format(sw, cw),
              '', '| task | samples: overruns + misses | with a stall | ' + ' | '.join(
                  'near ct@{}'.format(r) for r in refs) + ' | m4k alone | largest 1-s burst '
              '(second) | counters: overruns + misses | with a stall | m4k alone |',
              '|---|---|---|' + '---|' * len(refs) + '---|---|---|---|---|']
    ct_tasks = tl['counters']['tasks']
    for name, s in tl['samples']['tasks'].items():
        a = ct_tasks.get(name, {})
        lines.append('| {} | {} + {} | {} | {} | {} | {} ({}) | {} | {} | {} |'.format(
            name, s.get('overruns'), s.get('deadline_misses'), s['coincide'],
            ' | '.join(str(s['by_ref'].get(r, 0)) for r in refs), s['alone'], s['max_burst'],
            s['max_burst_s'], a.get('total', 0), a.get('coincide', 0), a.get('alone', 0)))
    lines += ['']
    ref0 = refs.get('actuator')
    for name, s in tl['samples']['tasks'].items():
        if not s['total']:
            continue
        txt = '* {}: {} overruns + misses in its cycle samples ({} in the counters)'.format(
            name, s['total'], ct_tasks.get(name, {}).get('total', 0))
        if ref0 is not None:
            txt += "; cyclictest at the actuator's priority was late {} times, stalls worth " \
                   '{} skipped releases of a {:g} ms task'.format(
                       ref0['late'], ref0['skipped_releases'], period_us / 1e3)
        txt += "; {} of the task's within +-{} s of a cyclictest late sample, {} with none " \
               'near (seconds {}); largest burst {} in second {}.'.format(
                   s['coincide'], sw, s['alone'], s['alone_seconds'] or 'none',
                   s['max_burst'], s['max_burst_s'])
        lines.append(txt)
    return lines + ['']


def write_csv(path: str, tl: Mapping[str, Any]) -> None:
    """Write one row per second: each task's overruns + misses and each reference's max/late.

    The tasks' counts are binned at their exact cycle times (the cycle samples, as the report's
    lead table), not at the 1-2 s later second in which the polled counters showed them.
    """
    tasks = sorted(tl['samples']['tasks'])
    refs = list(tl['references'])
    secs: set[int] = set()
    for r in refs:
        secs.update(tl['references'][r]['per_second_max_us'])
    late = {r: {} for r in refs}   # type: dict[str, dict[int, int]]
    for r in refs:
        for t in tl['references'][r]['late_times_s']:
            s = math.floor(t - tl['t_first'])
            late[r][s] = late[r].get(s, 0) + 1
    with open(path, 'w', newline='') as f:
        w = csv.writer(f)
        w.writerow(['second'] + ['{}_late'.format(t) for t in tasks]
                   + [x for r in refs for x in ('ct_{}_max_us'.format(r), 'ct_{}_late'.format(r))])
        for s in sorted(secs):
            w.writerow([s] + [tl['samples']['tasks'][t]['per_second'].get(s, 0) for t in tasks]
                       + [x for r in refs for x in (
                           tl['references'][r]['per_second_max_us'].get(s, ''),
                           late[r].get(s, 0))])
