"""The suite's evidence: one markdown table and one plot per scenario (ground truth only)."""

from __future__ import annotations

import math
import os
from typing import Any, Sequence

from m4k_bench.scenarios.run import Result
from m4k_bench.scenarios.spec import Scenario

__all__ = ['plot', 'table', 'write_csv']

_COLOURS = {'normal': '0.25', 'soft': 'tab:orange', 'glass': 'tab:cyan', 'black': 'black'}


def _f(v: float | None, fmt: str = '.3f') -> str:
    return '-' if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, fmt)


def table(results: Sequence[Result], header: str = '') -> str:
    """Return the markdown table of the results."""
    lines = [header, '',
             '| scenario | expected | commanded (m) | measured distance (m) | min clearance (m) '
             '| contacts | stop time (s) / bound | stop distance (m) / bound | peak decel '
             '(m/s²) / μg | verdict |',
             '|---|---|---|---|---|---|---|---|---|---|']
    for r in results:
        stop = '-' if r.stop_s is None and r.stop_bound_s is None else \
            f'{_f(r.stop_s)} / {_f(r.stop_bound_s)}'
        dist = '-' if r.stop_bound_m is None else f'{_f(r.stop_m)} / {_f(r.stop_bound_m)}'
        verdict = 'PASS' if r.passed else 'FAIL: ' + '; '.join(r.failures)
        lines.append(f'| {r.name} | {r.expected} | {r.commanded:.2f} | {_f(r.travelled)} | '
                     f'{_f(r.min_clearance)} | {r.contacts} | {stop} | {dist} | '
                     f'{_f(r.peak_decel, ".2f")} / {_f(r.max_decel, ".2f")} | {verdict} |')
    return '\n'.join(lines) + '\n'


CSV_KEYS = ('t', 'x', 'y', 'theta', 'v', 'w', 'wheel_speed_left', 'wheel_speed_right',
            'travelled', 'clearance', 'front_clearance', 'min_clearance', 'contacts',
            'motor_volts_left', 'motor_volts_right', 'slip_left', 'slip_right', 'accel')


def _row(s: dict) -> list:
    volts = s.get('motor_volts') or ('', '')
    return [volts[0] if k == 'motor_volts_left' else volts[1] if k == 'motor_volts_right'
            else s.get(k, '') for k in CSV_KEYS]


def write_csv(res: Result, path: str) -> None:
    """Write the ground-truth samples of one run (one row per 20 ms sample)."""
    import csv
    with open(path, 'w', encoding='utf-8', newline='') as f:
        out = csv.writer(f)
        out.writerow(CSV_KEYS)
        for s in res.samples:
            out.writerow(_row(s))


def _walls(world: dict[str, Any]) -> list[tuple[float, ...]]:
    w = world.get('walls')
    if isinstance(w, dict):
        x0, y0, x1, y1 = w['rectangle']
        return [(x0, y0, x1, y0), (x1, y0, x1, y1), (x1, y1, x0, y1), (x0, y1, x0, y0)]
    return [tuple(s) for s in (w or [])]


def plot(sc: Scenario, res: Result, path: str, world: dict[str, Any]) -> None:
    """Write the world map, the obstacles' paths and the robot's true path to ``path``."""
    import matplotlib
    matplotlib.use('Agg')
    from matplotlib.patches import Polygon
    import matplotlib.pyplot as plt

    from m4k_drivers.scene import parse_obstacle
    fig, ax = plt.subplots(figsize=(8, 5))
    for x0, y0, x1, y1 in _walls(world):
        ax.plot([x0, x1], [y0, y1], color='0.2', lw=2)
    offsets = [s.get('obstacle_offsets') or [] for s in res.samples]
    for i, entry in enumerate(world.get('obstacles') or []):
        poly, surf, path_ = parse_obstacle(entry, f'obstacles[{i}]')
        label = surf.kind + ('' if math.isinf(surf.height) else f', {surf.height:g} m high')
        ax.add_patch(Polygon(poly, closed=True, fc=_COLOURS[surf.kind], alpha=0.35,
                             ec=_COLOURS[surf.kind], label=label))
        if path_ is not None:
            cx = sum(p[0] for p in poly) / len(poly)
            cy = sum(p[1] for p in poly) / len(poly)
            track = [(cx + o[i][0], cy + o[i][1]) for o in offsets if len(o) > i]
            if track:
                ax.plot([p[0] for p in track], [p[1] for p in track], ls='--', color='tab:red',
                        lw=1, label='obstacle path')
                ex, ey = track[-1][0] - cx, track[-1][1] - cy
                ax.add_patch(Polygon([(p[0] + ex, p[1] + ey) for p in poly], closed=True,
                                     fc='none', ec='tab:red', ls='--'))
    xs = [s['x'] for s in res.samples]
    ys = [s['y'] for s in res.samples]
    if xs:
        ax.plot(xs, ys, color='tab:blue', lw=2, label='robot (ground truth)')
        ax.plot(xs[0], ys[0], 'o', color='tab:green', label='start')
        ax.plot(xs[-1], ys[-1], 's', color='tab:blue', label='end')
    verdict = 'PASS' if res.passed else 'FAIL'
    ax.set_title(f'{sc.name}: {verdict} -- {res.travelled:.2f} m of {res.commanded:.2f} m, '
                 f'min clearance {_f(res.min_clearance)} m, contacts {res.contacts}',
                 fontsize=9)
    ax.set_aspect('equal')
    ax.set_xlabel('x (m)')
    ax.set_ylabel('y (m)')
    handles, labels = ax.get_legend_handles_labels()
    uniq = dict(zip(labels, handles, strict=True))
    ax.legend(uniq.values(), uniq.keys(), fontsize=7, loc='best')
    fig.tight_layout()
    os.makedirs(os.path.dirname(path) or '.', exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
