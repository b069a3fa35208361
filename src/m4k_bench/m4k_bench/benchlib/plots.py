"""Fig. 10 plots: the actuator task's periodicity per condition (matplotlib, Agg backend).

Two panels, like the paper's distribution plot but readable across four orders of magnitude:
(a) histogram of the measured period (ms) per condition with a log count axis, so rare late
cycles stay visible next to thousands of on-time ones; (b) the complementary CDF of the jitter
|period - nominal| on log-log axes -- the fraction of cycles whose jitter exceeds x, where a
tail that reaches further right is a less periodic task.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

__all__ = ['COLORS', 'fig10', 'reaction', 'scaling']

# condition key -> (label, colour, line style); XDDP solid, ROS dashed, stress darker.
COLORS = {
    'm4k_idle': ('XDDP (m4k)', '#1f77b4', '-'),
    'm4k_stress': ('XDDP-STRESS (m4k)', '#08306b', '-'),
    'baseline_idle': ('ROS (baseline)', '#ff7f0e', '--'),
    'baseline_stress': ('ROS-STRESS (baseline)', '#b22222', '--'),
}


def fig10(periods_ns: Mapping[str, Sequence[int] | np.ndarray], nominal_ns: int,
          path: str, title: str = '') -> str:
    """Write the two-panel periodicity figure for the conditions present; return ``path``."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    data = {k: np.asarray(v, dtype=np.float64) for k, v in periods_ns.items()
            if k in COLORS and len(v)}
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(13, 5.2))
    if data:
        allp = np.concatenate(list(data.values())) / 1e6
        nominal_ms = nominal_ns / 1e6
        # +-15 ms at most: the shape around the nominal period stays readable; cycles beyond
        # are clipped into the edge bins (the jitter tail in panel b shows them all).
        span = min(max(float(np.percentile(np.abs(allp - nominal_ms), 99.99)), 0.05), 15.0)
        lo, hi = max(nominal_ms - span * 1.1, 0.0), nominal_ms + span * 1.1
        bins = np.linspace(lo, hi, 161)
        for key, p in data.items():
            label, color, ls = COLORS[key]
            ax1.hist(np.clip(p / 1e6, lo, hi), bins=bins, histtype='step', linewidth=1.4,
                     color=color, linestyle=ls, label='{} (n={})'.format(label, p.size))
            jit = np.sort(np.abs(p - nominal_ns)) / 1e3
            jit = np.maximum(jit, 0.1)   # log axis: sub-0.1 us jitter drawn at 0.1 us
            ccdf = 1.0 - np.arange(jit.size) / jit.size
            ax2.step(jit, ccdf, where='post', color=color, linestyle=ls, linewidth=1.4,
                     label='{}: p99 {:.0f} us'.format(label, float(np.percentile(
                         np.abs(p - nominal_ns), 99)) / 1e3))
        ax1.axvline(nominal_ms, color='grey', linewidth=0.8, linestyle=':')
        ax1.set_yscale('log')
        ax2.set_xscale('log')
        ax2.set_yscale('log')
        ax2.set_ylim(bottom=max(0.5 / max(d.size for d in data.values()), 1e-6), top=1.2)
    ax1.set_xlabel('period between cycle starts (ms; outliers counted in the edge bins)')
    ax1.set_ylabel('cycles (log)')
    ax1.set_title('(a) period distribution')
    ax1.legend(fontsize=8, loc='upper right')
    ax2.set_xlabel('jitter |period - {:g} ms| (us, log)'.format(nominal_ns / 1e6))
    ax2.set_ylabel('fraction of cycles with larger jitter (log)')
    ax2.set_title('(b) jitter tail (complementary CDF)')
    ax2.grid(True, which='both', alpha=0.3)
    ax2.legend(fontsize=8, loc='lower left')
    fig.suptitle(title or 'Periodicity of the actuator task (paper Fig. 10)')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def scaling(rows: Sequence[Mapping[str, object]], path: str) -> str:
    """Write the scaling figure: release p99 vs cyclictest p99, and CPU per cycle, per rate.

    ``rows`` are the per-round runs; each point is the median over the rounds, the bar its
    min-max.
    """
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from m4k_bench.benchlib.analysis import scaling_summary

    def med(sel: Sequence[Mapping[str, object]],
            key: str) -> tuple[list[float], list[list[float]]]:
        y: list[float] = []
        err: list[list[float]] = [[], []]
        for r in sel:
            sp = r.get(key)
            if isinstance(sp, Mapping):
                m = float(sp['median'])
                y.append(m)
                err[0].append(m - float(sp['min']))
                err[1].append(float(sp['max']) - m)
            else:
                y.append(np.nan)
                err[0].append(0.0)
                err[1].append(0.0)
        return y, err

    summary = scaling_summary(rows)
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.6))
    for label, style, colour in (('alone', 'o-', '#1f77b4'), ('task set', 's--', '#2ca02c')):
        sel = [r for r in summary if r.get('set') == label]
        hz = [r['rate_hz'] for r in sel]
        for ax, key, alpha, text in (
                (ax1, 'release_p99_us', 1.0, 'actuator release p99, {}'),
                (ax1, 'cyclictest_p99_us', 0.45, 'concurrent cyclictest p99 ({})'),
                (ax2, 'cpu_per_cycle_us', 1.0, 'CPU per cycle, {}')):
            y, err = med(sel, key)
            ax.errorbar(hz, y, yerr=err, fmt=style, color=colour, alpha=alpha, capsize=3,
                        label=text.format(label))
    n = max((int(r.get('runs') or 0) for r in summary), default=0)
    rates = [r['rate_hz'] for r in summary if r.get('rate_hz')] or [100, 1000]
    for ax in (ax1, ax2):
        # The x range from the rates, not the data: a panel of degraded runs has none.
        ax.set_xlim(min(rates) / 1.25, max(rates) * 1.25)
        ax.set_xscale('log')
        ax.set_xticks([100, 250, 500, 1000])
        ax.set_xticklabels(['100', '250', '500', '1000'])
        ax.set_xlabel('actuator rate (Hz)')
        ax.grid(True, which='both', alpha=0.3)
        ax.legend(fontsize=8)
    if any(r.get(k) for r in summary for k in ('release_p99_us', 'cyclictest_p99_us')):
        ax1.set_yscale('log')  # one round's host stall would flatten every other point
        ax1.set_ylabel('µs (log)')
    else:
        # Every run degraded (no SCHED_FIFO or locked memory: left out of the spreads), so
        # there is nothing to plot, and a log axis over no data cannot be drawn.
        ax1.text(0.5, 0.5, 'no hardened run: nothing to plot', transform=ax1.transAxes,
                 ha='center', va='center')
    ax1.set_title('(a) release latency p99 vs cyclictest at the same rate\n'
                  '(median, bars min–max over {} rounds)'.format(n), fontsize=10)
    ax2.set_ylabel('µs of CPU per task cycle')
    ax2.set_title('(b) RT process CPU per cycle\n(median, bars min–max)', fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def reaction(rows: Sequence[Mapping[str, Any]], summary: Mapping[str, Any],
             path: str) -> str:
    """Write the guard's reaction figure: (a) reaction times, (b) stopping distance vs speed.

    (a) histogram of the crossing -> first braking DAC word times (simulator clock) with p50
    and p99 marked; (b) every stop's ground-truth distance from the stop line against the
    physical minimum ``v t_sensor + v^2 / (2 mu g)`` and the judge's allowed distance.
    """
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.6))
    times = [1e3 * float(r['reaction_s']) for r in rows
             if r.get('reaction_s') is not None]
    if times:
        ax1.hist(times, bins=min(30, max(5, len(times) // 3)), color='#1f77b4', alpha=0.8)
        for key, ls in (('reaction_p50_s', '-'), ('reaction_p99_s', '--')):
            val = summary.get(key)
            if isinstance(val, float):
                ax1.axvline(1e3 * val, color='k', ls=ls,
                            label='{} {:.1f} ms'.format(key.split('_')[1], 1e3 * val))
        ax1.legend(fontsize=8)
    ax1.set_xlabel('stop line crossed -> first braking DAC word (ms, simulator clock)')
    ax1.set_ylabel('trials')
    ax1.set_title('(a) guard reaction time', fontsize=10)
    stops = [(float(r['v']), float(r['stop_m'])) for r in rows
             if r.get('stop_m') is not None]
    if stops:
        ax2.plot([s[0] for s in stops], [s[1] for s in stops], 'o', color='#1f77b4',
                 alpha=0.6, label='measured (ground truth)')
        vmax = max(s[0] for s in stops) * 1.1
        v = np.linspace(0.0, vmax, 50)
        t_s = float(summary.get('t_sensor_s') or 0.0)
        mu_g = float(summary.get('mu_g') or 1.0)
        ax2.plot(v, v * t_s + v * v / (2.0 * mu_g), 'k--',
                 label='physical minimum v t_sensor + v²/(2 μg)')
        speeds = summary.get('speeds') or []
        allowed = [(float(r['v']), float(r['judge_allowed_m']))
                   for r in speeds if r.get('judge_allowed_m') is not None]
        if allowed:
            ax2.plot([a[0] for a in allowed], [a[1] for a in allowed], 's', color='#b22222',
                     label="judge's allowed distance")
        ax2.legend(fontsize=8)
    ax2.set_xlabel('true speed at the crossing (m/s)')
    ax2.set_ylabel('stop line -> rest (m)')
    ax2.set_title('(b) stopping distance', fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
