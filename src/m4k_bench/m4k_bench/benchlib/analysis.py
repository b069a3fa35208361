"""Pure analysis for the bench: samples -> condition statistics, ratios and targets.

Per-task statistics come from :func:`m4k_rt.recorder.summarize` (the same code that makes
Table 1), so the RT actuator task and the plain-ROS baseline are measured identically:
period, jitter = |period - nominal|, release latency = t_start - t_rel, response time.

The ratios compare measurements taken in one run on one machine (design.md: absolute numbers
on a shared VM are noise, ratios are the evidence). Each ratio is None when either side is
missing or zero, and the report says why.
"""

from __future__ import annotations

import csv
import math
from typing import Any, Iterable, Mapping, NamedTuple, Sequence

import numpy as np

from m4k_rt import recorder, timing

__all__ = [
    'RATIO_KEYS', 'Target', 'condition_summary', 'evaluate_targets', 'compute_ratios',
    'interference', 'load_samples_csv', 'ratio', 'series_from_rows', 'stats_dict', 'TARGETS',
    'trim_warmup',
]

# The keys summary.json carries under "ratios" (issue 6), in report order.
RATIO_KEYS = (
    'release_p99_over_cyclictest_idle', 'release_p99_over_cyclictest_stress',
    'baseline_over_m4k_jitter_p99_stress', 'baseline_over_m4k_jitter_p99_idle',
    'five_tasks_over_alone_p99', 'xddp_rtt_p50_over_raw',
)


def stats_dict(s: timing.Stats, scale: float = 1.0) -> dict[str, float | int | None]:
    """Return a Stats as a JSON-able dict scaled by ``scale`` (NaN -> None)."""
    out: dict[str, float | int | None] = {'n': s.n}
    for k in ('avg', 'max', 'min', 'std', 'p50', 'p99', 'p999'):
        v = getattr(s, k) * scale
        out[k] = None if math.isnan(v) else v
    return out


def load_samples_csv(path: str) -> dict[str, list[tuple[int, int, int, int]]]:
    """Read a samples CSV (task, t_rel_ns, t_start_ns, t_end_ns, expirations) per task."""
    out: dict[str, list[tuple[int, int, int, int]]] = {}
    with open(path, newline='', encoding='utf-8') as f:
        reader = csv.reader(f)
        header = next(reader, None)
        if header is None or header[:5] != ['task', 't_rel_ns', 't_start_ns', 't_end_ns',
                                             'expirations']:
            raise ValueError(f'{path}: not a timing samples CSV (header {header!r})')
        for lineno, row in enumerate(reader, start=2):
            try:
                out.setdefault(row[0], []).append(
                    (int(row[1]), int(row[2]), int(row[3]), int(row[4])))
            except (IndexError, ValueError) as exc:
                raise ValueError(f'{path}:{lineno}: bad sample row {row!r}') from exc
    return out


def series_from_rows(name: str, period_ns: int, rows: Sequence[tuple[int, int, int, int]],
                     priority: int = 0) -> recorder.TaskSeries:
    """Build a recorder TaskSeries from (t_rel, t_start, t_end, expirations) rows."""
    s = recorder.TaskSeries(name, priority=priority, period_ns=period_ns, cycles=len(rows))
    for r in rows:
        s.t_rel.append(r[0])
        s.t_start.append(r[1])
        s.t_end.append(r[2])
        s.expirations.append(r[3])
    return s


def condition_summary(series: recorder.TaskSeries) -> dict[str, Any] | None:
    """Return the recorder's per-task dict for one series (None when it has no samples)."""
    tasks = recorder.summarize([series])['tasks']
    return tasks[0] if tasks else None


def trim_warmup(series: Iterable[recorder.TaskSeries], warmup_ns: int) -> dict[str, Any]:
    """Drop, in place, samples released in the first ``warmup_ns`` of the run (start-up).

    The run starts at the earliest first release of all series (the RT tasks release together).
    Return what was dropped: cycles per task and the worst release latency among them (us), so
    the report can say what the start-up transient looked like instead of hiding it.
    """
    series = [s for s in series if s.t_rel]
    if not series:
        return {'cycles': {}, 'max_latency_us': None}
    until = min(s.t_rel[0] for s in series) + warmup_ns
    dropped: dict[str, int] = {}
    worst = None
    for s in series:
        n = 0
        while n < len(s.t_rel) and s.t_rel[n] < until:
            n += 1
        if n:
            lat = max(s.t_start[i] - s.t_rel[i] for i in range(n)) * 1e-3
            worst = lat if worst is None or lat > worst else worst
            del s.t_rel[:n], s.t_start[:n], s.t_end[:n], s.expirations[:n]
        dropped[s.name] = n
    return {'cycles': dropped, 'max_latency_us': worst}


def interference(series: Mapping[str, recorder.TaskSeries], focus: str) -> dict[str, Any] | None:
    """Tell how often another task of the process was running when ``focus`` was released.

    A cycle of ``focus`` is *interfered* when another task's [t_start, t_end] overlaps its
    [t_rel, t_start] window: that task held the interpreter (GIL) while ``focus`` waited.
    Returns the share per task and the release-latency p99 (us) of interfered vs clean cycles.
    """
    f = series.get(focus)
    if f is None or not f.t_rel:
        return None
    rel = np.asarray(f.t_rel, dtype=np.int64)
    start = np.asarray(f.t_start, dtype=np.int64)
    lat_us = (start - rel) * 1e-3
    hit = np.zeros(rel.size, dtype=bool)
    by_task = {}
    for name, s in series.items():
        if name == focus or not s.t_start:
            continue
        s_start = np.asarray(s.t_start, dtype=np.int64)
        s_end = np.asarray(s.t_end, dtype=np.int64)
        order = np.argsort(s_start, kind='stable')
        s_start, s_end = s_start[order], s_end[order]
        idx = np.searchsorted(s_start, start) - 1   # last cycle of s starting before ours
        ok = idx >= 0
        over = np.zeros(rel.size, dtype=bool)
        over[ok] = s_end[idx[ok]] > rel[ok]
        by_task[name] = float(over.mean())
        hit |= over

    def p99(a: np.ndarray) -> float | None:
        return float(np.percentile(a, 99)) if a.size else None

    return {'cycles': int(rel.size), 'interfered_share': float(hit.mean()),
            'share_by_task': by_task, 'latency_p99_interfered_us': p99(lat_us[hit]),
            'latency_p99_clean_us': p99(lat_us[~hit]), 'latency_p99_all_us': p99(lat_us)}


def ratio(num: float | None, den: float | None) -> float | None:
    """Return num / den, or None when either is missing, not finite, or den is zero."""
    if num is None or den is None:
        return None
    if not (math.isfinite(num) and math.isfinite(den)) or den == 0.0:
        return None
    return num / den


def _get(d: Mapping[str, Any] | None, *path: str) -> Any:
    for key in path:
        if not isinstance(d, Mapping) or key not in d:
            return None
        d = d[key]
    return d


def compute_ratios(summ: Mapping[str, Any]) -> dict[str, float | None]:
    """Compute the summary's ratios from its ``conditions``, ``cyclictest`` and ``xddp_rtt``."""
    c = summ.get('conditions', {})
    ct = summ.get('cyclictest', {})
    return {
        'release_p99_over_cyclictest_idle': ratio(
            _get(c, 'm4k_idle', 'latency_us', 'p99'), _get(ct, 'idle', 'latency_us', 'p99')),
        'release_p99_over_cyclictest_stress': ratio(
            _get(c, 'm4k_stress', 'latency_us', 'p99'),
            _get(ct, 'stress', 'latency_us', 'p99')),
        'baseline_over_m4k_jitter_p99_stress': ratio(
            _get(c, 'baseline_stress', 'jitter_us', 'p99'),
            _get(c, 'm4k_stress', 'jitter_us', 'p99')),
        'baseline_over_m4k_jitter_p99_idle': ratio(
            _get(c, 'baseline_idle', 'jitter_us', 'p99'),
            _get(c, 'm4k_idle', 'jitter_us', 'p99')),
        'five_tasks_over_alone_p99': ratio(
            _get(c, 'm4k_idle', 'latency_us', 'p99'), _get(c, 'm4k_alone', 'latency_us', 'p99')),
        'xddp_rtt_p50_over_raw': ratio(
            _get(summ, 'xddp_rtt', 'xddp', 'p50_us'), _get(summ, 'xddp_rtt', 'raw', 'p50_us')),
    }


class Target(NamedTuple):
    """One benchmark target: the key it checks, how, and what a miss usually means."""

    key: str           # a ratio key, or 'rt_cpu_percent'
    label: str
    op: str            # '<=' or '>='
    limit: float
    miss_reason: str   # why m4k typically falls short there (the report prints it on a miss)


TARGETS: tuple[Target, ...] = (
    Target('release_p99_over_cyclictest_idle', 'Actuator release p99 / cyclictest p99 (idle)',
           '<=', 2.0,
           'the Python wake-up path (timerfd read returning into the interpreter, taking the '
           'GIL from whichever NRT thread of the RT process holds it, the bytecode up to '
           "t_start) costs tens of microseconds that cyclictest's C loop does not pay"),
    Target('release_p99_over_cyclictest_stress',
           'Actuator release p99 / cyclictest p99 (stress-ng)', '<=', 2.0,
           "under stress the interpreter's wake-up path runs with cold caches and memory "
           'pressure from stress-ng --vm; cyclictest touches a few cache lines, the Python task '
           'touches many more'),
    Target('baseline_over_m4k_jitter_p99_stress',
           'Plain-ROS baseline jitter p99 / m4k jitter p99 (stress-ng)', '>=', 50.0,
           "the baseline (SCHED_OTHER) was not slowed as much as the paper's: with 2 vCPUs and "
           "CFS fair sharing it still gets the CPU within a few ms, and the hypervisor's own "
           "preemptions, which hit SCHED_FIFO threads alike, set a floor under m4k's jitter"),
    Target('five_tasks_over_alone_p99',
           'Actuator release p99, five tasks / actuator alone', '<=', 1.25,
           'all tasks share one interpreter: the IMU task has the same period and release '
           'instant, so on 2 CPUs both threads wake together and when the IMU thread takes the '
           'GIL first the actuator waits for its cycle -- a priority inversion a C program does '
           'not have (see "Interference inside the RT process"); the rest of the gap (clean '
           'cycles are slower than alone too) is most likely the bigger working set of five '
           'task bodies evicting the actuator code and data from the caches between cycles'),
    Target('xddp_rtt_p50_over_raw', 'XDDP round trip p50 / raw Unix-socket ping-pong p50',
           '<=', 1.3,
           "the emulation's RT side is non-blocking (poll + recv_into + counters in Python), so "
           'each round trip pays a poll() and more bytecode than a blocking raw recv()'),
    Target('rt_cpu_percent', 'RT process CPU (% of one core, full stack)', '<=', 5.0,
           'every cycle of every task runs Python bytecode (decode, control, encode, timing '
           'ring, rusage); about 10 us per cycle times 300 cycles/s is already 0.3 %, and the '
           "monitor's stats batching and the interpreter's wake-ups add the rest"),
)


def _measured(summ: Mapping[str, Any], key: str) -> float | None:
    if key == 'rt_cpu_percent':
        v = summ.get('rt_cpu_percent')
    else:
        v = _get(summ, 'ratios', key)
    return v if isinstance(v, (int, float)) and math.isfinite(v) else None


def evaluate_targets(summ: Mapping[str, Any],
                     targets: Iterable[Target] = TARGETS) -> list[dict[str, Any]]:
    """Return one row per target: label, target text, measured, met (None = not measured)."""
    rows = []
    for t in targets:
        m = _measured(summ, t.key)
        if m is None:
            met = None
            why = 'not measured in this run' + (
                ': ' + summ['skipped'][t.key] if t.key in summ.get('skipped', {}) else '')
        else:
            met = m <= t.limit if t.op == '<=' else m >= t.limit
            why = '' if met else t.miss_reason
        rows.append({'key': t.key, 'label': t.label,
                     'target': '{} {:g}{}'.format(t.op, t.limit,
                                                  ' %' if t.key == 'rt_cpu_percent' else 'x'),
                     'measured': m, 'met': met, 'why': why})
    return rows
