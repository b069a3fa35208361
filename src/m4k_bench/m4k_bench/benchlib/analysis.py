"""Pure analysis for the bench: samples -> condition statistics, ratios and targets.

Per-task statistics come from :func:`m4k_bench.recorder.summarize` (the same code that makes
Table 1), so the RT actuator task and the plain-ROS baseline are measured identically:
period, jitter = |period - nominal|, release latency = t_start - t_rel, response time.

The ratios compare measurements taken side by side in one round (design.md: absolute numbers
on a shared VM are noise, ratios are the evidence); each is computed per round and reported
as the median with min-max over the rounds. A ratio is None in a round when either side is
missing or zero, or when the m4k run of that round was not hardened (RT_STATUS).
"""

from __future__ import annotations

import csv
import math
from typing import Any, Iterable, Mapping, NamedTuple, Sequence

import numpy as np

from m4k_bench import recorder
from m4k_rt import timing

__all__ = [
    'CHANNEL_FLOORS', 'RATIOS', 'RATIO_KEYS', 'Ratio', 'STRICTER', 'Stricter', 'TARGETS',
    'Target',
    'condition_summary', 'stricter_values',
    'evaluate_targets', 'hardened_rounds', 'interference', 'load_samples_csv', 'loop_cost',
    'median_round_table', 'ratio', 'round_ratios', 'scaling_summary', 'series_from_rows',
    'stats_dict',
    'trim_warmup',
]


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


class Ratio(NamedTuple):
    """One ratio computed per round: numerator and denominator key paths into a round."""

    key: str
    label: str
    num: tuple[str, ...]
    den: tuple[str, ...]


# The channel floors run beside the bare floor in every round (floor.py --channel), stored
# as the round's ``floor_<channel>``.
CHANNEL_FLOORS = ('socket', 'shm')

RATIOS: tuple[Ratio, ...] = (
    Ratio('release_p99_over_cyclictest_idle', 'actuator release p99 ÷ concurrent cyclictest '
          'p99, idle', ('m4k_idle', 'latency_us', 'p99'), ('m4k_idle', 'cyclictest', 'p99')),
    Ratio('release_p999_over_cyclictest_idle', 'actuator release p99.9 ÷ concurrent '
          'cyclictest p99.9, idle', ('m4k_idle', 'latency_us', 'p999'),
          ('m4k_idle', 'cyclictest', 'p999')),
    Ratio('release_p99_over_cyclictest_stress', 'actuator release p99 ÷ concurrent cyclictest '
          'p99, stress-ng', ('m4k_stress', 'latency_us', 'p99'),
          ('m4k_stress', 'cyclictest', 'p99')),
    Ratio('release_p999_over_cyclictest_stress', 'actuator release p99.9 ÷ concurrent '
          'cyclictest p99.9, stress-ng', ('m4k_stress', 'latency_us', 'p999'),
          ('m4k_stress', 'cyclictest', 'p999')),
    Ratio('live_view_over_idle_p99', 'actuator release p99 with the live view and a viewer '
          '÷ without, idle', ('m4k_live', 'latency_us', 'p99'),
          ('m4k_idle', 'latency_us', 'p99')),
    Ratio('five_tasks_over_alone_p99', 'actuator release p99, five tasks ÷ alone',
          ('m4k_idle', 'latency_us', 'p99'), ('m4k_alone', 'latency_us', 'p99')),
    Ratio('xddp_rtt_p50_over_raw', "XDDP round trip p50 (tasks' receive path) ÷ raw socket",
          ('rtt', 'xddp', 'p50_us'), ('rtt', 'raw', 'p50_us')),
    # Paired: rt_core and the floor in the same window, each beside the stack's other
    # processes, the concurrent cyclictest and the other -- the same co-load for both.
    Ratio('cpu_per_cycle_over_floor', 'RT process CPU per task cycle ÷ Python floor, both in '
          'one run beside the stack and cyclictest', ('m4k_floor_paired', 'cpu_per_cycle_us'),
          ('m4k_floor_paired', 'floor', 'cpu_per_cycle_us')),
    Ratio('baseline_over_m4k_jitter_p99_stress', 'plain-ROS ÷ m4k jitter p99, stress-ng',
          ('baseline_stress', 'jitter_us', 'p99'), ('m4k_stress', 'jitter_us', 'p99')),
    Ratio('baseline_over_m4k_jitter_max_stress', 'plain-ROS ÷ m4k jitter max, stress-ng '
          '(paper: 57× on max)', ('baseline_stress', 'jitter_us', 'max'),
          ('m4k_stress', 'jitter_us', 'max')),
    Ratio('baseline_over_m4k_jitter_p99_idle', 'plain-ROS ÷ m4k jitter p99, idle',
          ('baseline_idle', 'jitter_us', 'p99'), ('m4k_idle', 'jitter_us', 'p99')),
    Ratio('cyclictest_concurrent_over_alone_p99_idle', 'cyclictest p99 next to m4k ÷ '
          'cyclictest alone, idle', ('m4k_idle', 'cyclictest', 'p99'),
          ('ct_idle', 'latency_us', 'p99')),
    # The same release latencies over cyclictest alone in the same round (m4k slows the
    # cyclictest that runs beside it, which flatters the concurrent denominator).
    Ratio('release_p99_over_cyclictest_alone_idle', 'actuator release p99 ÷ cyclictest alone '
          'p99, idle', ('m4k_idle', 'latency_us', 'p99'), ('ct_idle', 'latency_us', 'p99')),
    Ratio('release_p999_over_cyclictest_alone_idle', 'actuator release p99.9 ÷ cyclictest '
          'alone p99.9, idle', ('m4k_idle', 'latency_us', 'p999'),
          ('ct_idle', 'latency_us', 'p999')),
    Ratio('release_p99_over_cyclictest_alone_stress', 'actuator release p99 ÷ cyclictest '
          'alone p99, stress-ng', ('m4k_stress', 'latency_us', 'p99'),
          ('ct_stress', 'latency_us', 'p99')),
    Ratio('release_p999_over_cyclictest_alone_stress', 'actuator release p99.9 ÷ cyclictest '
          'alone p99.9, stress-ng', ('m4k_stress', 'latency_us', 'p999'),
          ('ct_stress', 'latency_us', 'p999')),
    # The channel's share: a floor that also makes a task cycle's socket calls (or moves the
    # same datagrams through shared memory), over the bare floor of the same round.
    Ratio('socket_channel_floor_over_floor', "Python floor + a task cycle's socket calls ÷ "
          'Python floor, alone', ('floor_socket', 'cpu_per_cycle_us'),
          ('floor', 'cpu_per_cycle_us')),
    Ratio('shm_channel_floor_over_floor', 'Python floor + the same datagrams through shared '
          'memory ÷ Python floor, alone', ('floor_shm', 'cpu_per_cycle_us'),
          ('floor', 'cpu_per_cycle_us')),
    Ratio('cpu_per_cycle_over_floor_alone', 'RT process CPU per task cycle (full stack, idle) '
          '÷ Python floor run alone', ('m4k_idle', 'cpu_per_cycle_us'),
          ('floor', 'cpu_per_cycle_us')),
)

# The frame executive beside one thread per task (issue 42): the same ratios for its runs, and
# its own denominators (the floor in the frame's structure, with and without the channel).
def _frame_release(q: str, ql: str, cond: str, label: str) -> tuple[Ratio, Ratio]:
    return (Ratio('release_{}_over_cyclictest_frame_{}'.format(q, cond), 'frame executive: '
                  'actuator release {} ÷ concurrent cyclictest {}, {}'.format(ql, ql, label),
                  ('m4k_frame_' + cond, 'latency_us', q), ('m4k_frame_' + cond, 'cyclictest', q)),
            Ratio('release_{}_over_cyclictest_alone_frame_{}'.format(q, cond), 'frame '
                  'executive: actuator release {} ÷ cyclictest alone {}, {}'.format(ql, ql, label),
                  ('m4k_frame_' + cond, 'latency_us', q), ('ct_' + cond, 'latency_us', q)))


FRAME_RATIOS: tuple[Ratio, ...] = (
    *(r for c, lab in (('idle', 'idle'), ('stress', 'stress-ng'))
      for q, ql in (('p99', 'p99'), ('p999', 'p99.9')) for r in _frame_release(q, ql, c, lab)),
    Ratio('frame_floor_over_floor', 'Python floor in the frame structure ÷ one thread per '
          'task, alone', ('floor_frame', 'cpu_per_cycle_us'), ('floor', 'cpu_per_cycle_us')),
    Ratio('frame_socket_floor_over_frame_floor', 'frame floor + socket calls ÷ frame floor, '
          'alone', ('floor_frame_socket', 'cpu_per_cycle_us'),
          ('floor_frame', 'cpu_per_cycle_us')),
    Ratio('cpu_per_cycle_frame_over_floor_alone', 'frame executive: RT process CPU per task '
          'cycle (full stack, idle) ÷ Python floor (thread per task) run alone',
          ('m4k_frame_idle', 'cpu_per_cycle_us'), ('floor', 'cpu_per_cycle_us')),
    Ratio('cpu_per_cycle_frame_over_own_channel_floor', 'frame executive: RT process CPU per '
          'task cycle ÷ its own channel floor (frame structure + socket calls)',
          ('m4k_frame_idle', 'cpu_per_cycle_us'), ('floor_frame_socket', 'cpu_per_cycle_us')),
    Ratio('cpu_per_cycle_over_own_channel_floor', 'thread per task: RT process CPU per task '
          'cycle ÷ its own channel floor (thread per task + socket calls)',
          ('m4k_idle', 'cpu_per_cycle_us'), ('floor_socket', 'cpu_per_cycle_us')),
    Ratio('cpu_per_cycle_frame_over_threads', 'RT process CPU per task cycle, frame ÷ thread '
          'per task (full stack, idle)', ('m4k_frame_idle', 'cpu_per_cycle_us'),
          ('m4k_idle', 'cpu_per_cycle_us')),
    Ratio('slow_body_release_p99_frame_over_threads', 'a sonar body overrunning 15 ms every '
          '0.3 s: actuator release p99, frame ÷ thread per task',
          ('m4k_slow_frame', 'latency_us', 'p99'), ('m4k_slow_threads', 'latency_us', 'p99')),
)
RATIOS = RATIOS + FRAME_RATIOS
RATIO_KEYS = tuple(r.key for r in RATIOS)


class Stricter(NamedTuple):
    """A latency ratio judged on the stricter of two denominators, round by round."""

    key: str
    label: str
    concurrent: str     # the ratio over the cyclictest running beside m4k
    alone: str          # the ratio over cyclictest alone in the same round


STRICTER: tuple[Stricter, ...] = tuple(
    Stricter('release_{}_stricter_{}'.format(q, c), 'actuator release {} ÷ cyclictest {}, '
             'the stricter of concurrent and alone, {}'.format(
                 ql, ql, 'idle' if c == 'idle' else 'stress-ng'),
             'release_{}_over_cyclictest_{}'.format(q, c),
             'release_{}_over_cyclictest_alone_{}'.format(q, c))
    for c in ('idle', 'stress') for q, ql in (('p99', 'p99'), ('p999', 'p99.9'))) + tuple(
    Stricter('release_{}_stricter_frame_{}'.format(q, c), 'frame executive: actuator release '
             '{} ÷ cyclictest {}, the stricter of concurrent and alone, {}'.format(
                 ql, ql, 'idle' if c == 'idle' else 'stress-ng'),
             'release_{}_over_cyclictest_frame_{}'.format(q, c),
             'release_{}_over_cyclictest_alone_frame_{}'.format(q, c))
    for c in ('idle', 'stress') for q, ql in (('p99', 'p99'), ('p999', 'p99.9')))


def stricter_values(a: Sequence[float | None], b: Sequence[float | None]) -> list[float | None]:
    """Return the larger ratio of each round (the smaller denominator); None if one is."""
    return [max(x, y) if x is not None and y is not None else None
            for x, y in zip(a, b, strict=True)]
M4K_CONDITIONS = ('m4k_idle', 'm4k_live', 'm4k_alone', 'm4k_stress', 'm4k_floor_paired',
                  'm4k_frame_idle', 'm4k_frame_stress', 'm4k_slow_threads', 'm4k_slow_frame')


def hardened_rounds(rounds_: Sequence[Mapping[str, Any]]) -> tuple[list[dict[str, Any]],
                                                                    list[str]]:
    """Return the rounds without m4k runs whose RT_STATUS was not the real thing, and why."""
    out, excluded = [], []
    for r in rounds_:
        r2 = dict(r)
        for cond in M4K_CONDITIONS:
            c = r2.get(cond)
            if isinstance(c, Mapping) and not _get(c, 'hardening', 'ok'):
                excluded.append('round {} {}: {}'.format(
                    r.get('round'), cond, _get(c, 'hardening', 'why') or 'no RT_STATUS'))
                r2[cond] = None
        out.append(r2)
    return out, excluded


def round_ratios(rounds_: Sequence[Mapping[str, Any]],
                 period_us: float = 10_000.0) -> dict[str, Any]:
    """Return every ratio as its per-round values and their spread (median, min, max).

    A round whose conditions' cyclictest reference is broken (:mod:`.validity`) gives the
    ratio no value; the reasons are the entry's ``invalid``.
    """
    from m4k_bench.benchlib.rounds import per_round_ratios, spread
    from m4k_bench.benchlib.validity import round_invalid
    ok, excluded = hardened_rounds(rounds_)
    out: dict[str, Any] = {}
    for r in RATIOS:
        values = per_round_ratios(ok, r.num, r.den)
        invalid = []
        for i, rnd in enumerate(ok):
            why = round_invalid(rnd, (r.num[0], r.den[0]), period_us)
            if why:
                invalid.append('round {}: {}'.format(rnd.get('round', i + 1), why))
                values[i] = None
        out[r.key] = {'label': r.label, 'spread': spread(values), 'values': values,
                      'invalid': invalid}
    for st in STRICTER:
        values = stricter_values(out[st.concurrent]['values'], out[st.alone]['values'])
        out[st.key] = {'label': st.label, 'spread': spread(values), 'values': values,
                       'of': [st.concurrent, st.alone],
                       'invalid': out[st.concurrent]['invalid'] + out[st.alone]['invalid']}
    out['_excluded'] = excluded
    return out


def _get(d: Mapping[str, Any] | None, *path: str) -> Any:
    for key in path:
        if not isinstance(d, Mapping) or key not in d:
            return None
        d = d[key]
    return d


class Target(NamedTuple):
    """One target of issue 14 on the median over the rounds of a ratio."""

    key: str
    op: str            # '<=' or '>='
    limit: float


TARGETS: tuple[Target, ...] = (
    Target('release_p99_stricter_idle', '<=', 1.5),
    Target('release_p999_stricter_idle', '<=', 2.0),
    Target('release_p99_stricter_stress', '<=', 1.5),
    Target('release_p99_stricter_frame_idle', '<=', 1.5),
    Target('release_p99_stricter_frame_stress', '<=', 1.5),
    Target('cpu_per_cycle_over_own_channel_floor', '<=', 1.3),
    Target('cpu_per_cycle_frame_over_own_channel_floor', '<=', 1.3),
    Target('cpu_per_cycle_frame_over_floor_alone', '<=', 2.0),
    Target('release_p999_stricter_stress', '<=', 2.0),
    Target('xddp_rtt_p50_over_raw', '<=', 1.3),
    Target('cpu_per_cycle_over_floor', '<=', 2.0),
    Target('five_tasks_over_alone_p99', '<=', 1.25),
    Target('scaling_1khz_release_p99_over_cyclictest', '<=', 2.0),
)


def evaluate_targets(ratios: Mapping[str, Any], scaling: Sequence[Mapping[str, Any]] = (),
                     targets: Iterable[Target] = TARGETS) -> list[dict[str, Any]]:
    """Return one row per target: the median, min-max, rounds, met (None = not measured).

    The verdict is on the median; the spread is shown next to it. No explanation is made up:
    a missed target shows its measured figures and nothing else. A latency target is judged
    on the stricter of its two denominators (the larger ratio of each round); ``of`` gives
    both, concurrent and alone, for the report.
    """
    from m4k_bench.benchlib.rounds import spread
    rows = []
    for t in targets:
        of: dict[str, Any] | None = None
        invalid: list[str] = []
        if t.key == 'scaling_1khz_release_p99_over_cyclictest':
            label = ('actuator alone at 1 kHz: release p99 ÷ cyclictest p99 at 1 kHz, the '
                     'stricter of concurrent and alone')
            sel = [r for r in scaling if r.get('rate_hz') == 1000 and r.get('set') == 'alone'
                   and r.get('hardening_ok') is not False]
            sp = spread([r.get('ratio_p99_stricter') for r in sel])
            of = {'concurrent': spread([r.get('ratio_p99') for r in sel]),
                  'alone': spread([r.get('ratio_p99_alone') for r in sel])}
        else:
            entry = ratios.get(t.key) or {}
            label = entry.get('label', t.key)
            sp = entry.get('spread')
            invalid = list(entry.get('invalid') or [])
            if entry.get('of'):
                conc, alone = entry['of']
                of = {'concurrent': (ratios.get(conc) or {}).get('spread'),
                      'alone': (ratios.get(alone) or {}).get('spread')}
        if sp is None:
            met = None
        else:
            m = sp['median']
            met = m <= t.limit if t.op == '<=' else m >= t.limit
        rows.append({'key': t.key, 'label': label, 'target': '{} {:g}×'.format(t.op, t.limit),
                     'spread': sp, 'met': met, 'of': of,
                     # no valid round left: the verdict is INVALID, with the reasons
                     'invalid': invalid if sp is None else [], 'rounds_invalid': invalid})
    return rows


SCALING_FIELDS = ('release_p99_us', 'release_p999_us', 'cyclictest_p99_us', 'ratio_p99',
                  'cyclictest_alone_p99_us', 'ratio_p99_alone', 'ratio_p99_stricter',
                  'cpu_per_cycle_us')


def scaling_summary(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Return one row per (rate, task set): each field's spread over the rounds.

    ``rows`` are the per-round scaling runs. A run whose RT hardening failed is left out of
    the spreads (it is not an m4k run) and counted in ``degraded``; overruns and deadline
    misses are summed over every run.
    """
    from m4k_bench.benchlib.rounds import spread
    groups: dict[tuple[Any, Any], list[Mapping[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r.get('rate_hz'), r.get('set')), []).append(r)
    out = []
    for (hz, label), sel in sorted(groups.items(), key=lambda g: (g[0][0] or 0, str(g[0][1]))):
        ok = [r for r in sel if r.get('hardening_ok') is not False]
        row: dict[str, Any] = {'rate_hz': hz, 'set': label, 'runs': len(sel),
                               'degraded': len(sel) - len(ok)}
        for f in SCALING_FIELDS:
            row[f] = spread([r.get(f) for r in ok])
        for f in ('overruns', 'deadline_misses'):
            vals = [r.get(f) for r in sel if isinstance(r.get(f), int)]
            row[f] = sum(vals) if vals else None
        out.append(row)
    return out


def loop_cost(rounds_: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Return CPU per cycle of m4k (full stack, idle) and of the floor, per round and spread.

    Two floors: run alone (``floor``) and paired, in one run with rt_core beside the stack
    and the concurrent cyclictest (``paired_*``: the loop-cost target's two sides).

    Also the median over rounds of each task's response p50: what its body costs per cycle.
    """
    from m4k_bench.benchlib.rounds import spread
    ok, _ = hardened_rounds(rounds_)
    m4k = [_get(r, 'm4k_idle', 'cpu_per_cycle_us') for r in ok]
    floor = [_get(r, 'floor', 'cpu_per_cycle_us') for r in ok]
    channels = {ch: spread([_get(r, 'floor_' + ch, 'cpu_per_cycle_us') for r in ok])
                for ch in CHANNEL_FLOORS}
    bodies: dict[str, list[Any]] = {}
    for r in ok:
        for name, v in (_get(r, 'm4k_idle', 'task_response_p50_us') or {}).items():
            bodies.setdefault(name, []).append(v)
    paired = [_get(r, 'm4k_floor_paired', 'cpu_per_cycle_us') for r in ok]
    paired_floor = [_get(r, 'm4k_floor_paired', 'floor', 'cpu_per_cycle_us') for r in ok]
    return {'m4k_cpu_per_cycle_us': spread(m4k), 'floor_cpu_per_cycle_us': spread(floor),
            'paired_m4k_cpu_per_cycle_us': spread(paired),
            'paired_floor_cpu_per_cycle_us': spread(paired_floor),
            'channel_floor_cpu_per_cycle_us': channels,
            'body_response_p50_us': {k: spread(v) for k, v in bodies.items()},
            'breakdown': cycle_breakdown(rounds_)}


def cycle_breakdown(rounds_: Sequence[Mapping[str, Any]]) -> dict[str, Any] | None:
    """Return the per-task cycle breakdown of the profiled runs, median over the rounds.

    Per task: the rate, every part of ``m4k_rt.cycleprof.PARTS`` and the thread CPU per cycle
    (µs, as spreads). ``all`` weighs the tasks by their rates: what one average task cycle of
    the process is made of; ``process_cpu_per_cycle_us`` is the profiled run's process CPU
    per cycle (the unprofiled one is ``m4k_cpu_per_cycle_us``).
    """
    from m4k_bench.benchlib.rounds import spread
    from m4k_rt.cycleprof import PARTS
    per: dict[str, dict[str, list[Any]]] = {}
    weighted: dict[str, list[Any]] = {}
    proc: list[Any] = []
    probe: dict[str, list[Any]] = {}
    for r in rounds_:
        run = r.get('m4k_profiled') or {}
        for k, v in (_get(run, 'floor', 'probe_us') or {}).items():
            probe.setdefault(k, []).append(v)
        prof = _get(run, 'cycle_profile', 'tasks')
        if not prof:
            continue
        proc.append(run.get('cpu_per_cycle_us'))
        tot: dict[str, float] = {}
        rate_sum = 0.0
        for name, t in prof.items():
            rate = 1e9 / t['period_ns'] if t.get('period_ns') else 0.0
            row = per.setdefault(name, {})
            row.setdefault('rate_hz', []).append(rate)
            parts = t.get('parts_us') or {}
            for k in (*PARTS, 'thread_cpu_per_cycle_us'):
                v = parts.get(k) if k in PARTS else t.get(k)
                row.setdefault(k, []).append(v)
                if isinstance(v, (int, float)):
                    tot[k] = tot.get(k, 0.0) + v * rate
            rate_sum += rate
        for k, v in tot.items():
            weighted.setdefault(k, []).append(v / rate_sum if rate_sum else None)
    if not per:
        return None
    return {'tasks': {n: {k: spread(v) for k, v in row.items()} for n, row in per.items()},
            'all': {k: spread(v) for k, v in weighted.items()},
            'process_cpu_per_cycle_us': spread(proc),
            'cache_ab_us': {k: spread(v) for k, v in probe.items() if k != 'n'} or None}


def median_round_table(rounds_: Sequence[Mapping[str, Any]],
                       tables: Mapping[str, Any]) -> tuple[int | None, Any]:
    """Pick the round whose m4k_idle actuator release p99 is the (lower) median; its Table 1."""
    scored = sorted((p99, r['round']) for r in rounds_
                    if (p99 := _get(r, 'm4k_idle', 'latency_us', 'p99')) is not None)
    if not scored:
        return None, None
    k = scored[(len(scored) - 1) // 2][1]
    return k, tables.get('r{}_m4k_idle'.format(k))
