"""Wheel supervision latch times in the closed loop, in virtual time (docs/safety.md's tables).

Run: ``python -m m4k_bench.latch [--seeds 1 2 3]``. Each figure is the simulated time from
the first command (or from the moment named) to the latched motor fault, the worst over the
seeds, from :class:`m4k_bench.virtualbase.VirtualBase` (the RT controller driving the
simulated base: the faults are the simulator's own, judged by the supervisor without ground
truth). Deterministic: the same seeds, the same figures; not a load-dependent measurement.

Bases: ``calibrated`` (the default simulated base: no amplifier offset or dead band),
``trim -2 codes`` (a 0.9 V dead band and both zero trims 2 codes low, as ``calibrate`` leaves
a caster-loaded base), ``uncalibrated`` (0.9 V dead band, offsets +0.3 / -1.2 V).
"""

from __future__ import annotations

import argparse
from typing import Any, Sequence

from m4k_bench.virtualbase import VirtualBase
from m4k_rt.control.supervision import COUNT

__all__ = ['BASES', 'CREEPS', 'driven_at_zero', 'from_the_start', 'HOLD_MOTIONS', 'HOLD_OFF',
           'HOLD_ON', 'hold_load', 'hold_offset', 'hold_ramp', 'main', 'still_after_stop',
           'turn_after_guard_stops']

TRIM_V = 2 * 24.0 / 511          # two DAC codes of the 24 V full scale
BASES: dict[str, dict[str, float]] = {
    'calibrated': {},
    'trim -2 codes': {'amp_offset_left_v': -TRIM_V, 'amp_offset_right_v': -TRIM_V,
                      'deadband_v': 0.9},
    'uncalibrated': {'amp_offset_left_v': 0.3, 'amp_offset_right_v': -1.2, 'deadband_v': 0.9},
}
# creep motions (v m/s, w rad/s): straight, reverse, turning, in place
CREEPS = ((0.02, 0.0), (0.05, 0.0), (-0.02, 0.0), (0.02, 0.05), (0.0, 0.1))


def from_the_start(kind: str, wheel: str | None, v: float, w: float, seed: int,
                   robot: dict[str, Any], limit_s: float = 3.0,
                   imu_lag_s: float = 0.0) -> tuple[float | None, float]:
    """Return (latch time after the first command or None, ground-truth peak speed m/s).

    ``wheel``: left or right; None for a fault of both (crossed channels). ``imu_lag_s``: the
    gyro reaches the controller this long after the encoders (VirtualBase).
    """
    fault: dict[str, Any] = {'at_s': 0.0, 'kind': kind}
    if wheel is not None:
        fault['wheel'] = wheel
    vb = VirtualBase(world={'seed': seed, 'robot': robot, 'faults': [fault]},
                     imu_lag_s=imu_lag_s)
    try:
        return vb.run(limit_s, v, w, until=vb.faulted), vb.world.peak_speed
    finally:
        vb.close()


def still_after_stop(v: float, w: float, guard: bool, seed: int, offset_v: float = 1.0,
                     limit_s: float = 3.0, control: dict[str, Any] | None = None
                     ) -> tuple[float | None, float | None]:
    """Stop from (v, w) with a left amplifier offset that drives the wheel at a zero command.

    Return (latch time after the left setpoint reached zero, after the healthy right wheel
    reached rest on ground truth): a ramped stop (``guard`` False) or a guard stop (the
    forward cap zero: both setpoints zero at once, the drive brakes from speed). ``control``:
    an overlay on the shipped control configuration (:data:`HOLD_OFF`).
    """
    vb = VirtualBase(world={'seed': seed, 'robot': {'amp_offset_left_v': offset_v}},
                     control=control)
    try:
        vb.run(max(abs(v) / 0.37, abs(w) / 1.85) + 0.5, v, w)
        kw: dict[str, Any] = {'forward_cap': 0.0, 'guard_active': True} if guard else {}
        t0 = t_rest = None
        for _ in range(round(limit_s / 0.01)):
            vb.cycle(0.0, 0.0, **kw)
            if t0 is None and vb.ctl.left_setpoint == 0.0:
                t0 = vb.t
            if t_rest is None and vb.world.state().wheel_speed[1] == 0.0:
                t_rest = vb.t
            if vb.faulted():
                return (None if t0 is None else vb.t - t0,
                        None if t_rest is None else vb.t - t_rest)
        return None, None
    finally:
        vb.close()


def turn_after_guard_stops(w: float, seed: int, robot: dict[str, Any],
                           imu_lag_s: float = 0.0) -> float | None:
    """Return when a healthy base latched (s into the last phase), or None (nothing latched).

    An arc at 0.25 m/s with ``w``, then the guard stopping and releasing to a creep three times
    (0.1 s stopped, 0.15 s at a 0.05 m/s cap), then stopped with the turn still asked: a slow
    turn in place, as in front of a wall (the wall.*.turning cells of the envelope).
    """
    vb = VirtualBase(world={'seed': seed, 'robot': robot}, imu_lag_s=imu_lag_s)
    try:
        if vb.run(2.0, 0.25, w, until=vb.faulted) is not None:
            return 0.0
        for _ in range(3):
            if (vb.run(0.1, 0.25, w, until=vb.faulted, forward_cap=0.0, guard_active=True)
                    is not None or vb.run(0.15, 0.25, w, until=vb.faulted, forward_cap=0.05)
                    is not None):
                return 0.0
        return vb.run(3.0, 0.25, w, until=vb.faulted, forward_cap=0.0, guard_active=True)
    finally:
        vb.close()


# control overlays: the standstill hold switched on (as shipped) / off (the speed still test
# judges every wheel at a zero setpoint)
HOLD_ON: dict[str, Any] = {'hold': {'enabled': True}}
HOLD_OFF: dict[str, Any] = {'hold': {'enabled': False}}


def _held_counts(vb: VirtualBase, seconds: float, v: float | None, **kw: Any
                 ) -> tuple[float, float | None]:
    """Run ``seconds``; return (counts held unlatched, the latch time in s or None).

    The counts: the most a wheel turned from where a hold began while no fault was latched.
    The first figure is what the standstill window bounds: a held wheel never turns more than
    ``supervision.standstill_window`` counts unlatched.
    """
    worst, start, latched = 0.0, None, None
    for i in range(round(seconds / 0.01)):
        vb.cycle(v, 0.0, **kw)
        c = vb.ctl
        if c.supervisor.latched:
            latched = (i + 1) * 0.01
            break
        if c.holding:
            start = start or c.wheel_angles
            worst = max(worst, *(abs(a - b) / COUNT for a, b in zip(c.wheel_angles, start,
                                                                       strict=True)))
        else:
            start = None
    return worst, latched


def hold_offset(offset_v: float, seed: int, seconds: float = 2.0,
                imu: bool = True) -> tuple[float, float | None]:
    """With the hold on, a left amplifier offset from rest on the level, never commanded.

    Return (most counts a wheel turned from where the hold began, the latch time or None).
    ``imu`` False: as with the IMU unplugged (no orientation: the level test is skipped).
    """
    vb = VirtualBase(world={'seed': seed, 'robot': {'amp_offset_left_v': offset_v}},
                     control=HOLD_ON, imu=imu)
    try:
        return _held_counts(vb, seconds, 0.0)
    finally:
        vb.close()


# healthy motions on the level, then a hold (v, w, seconds, forward cap; inf: no guard stop)
_INF = float('inf')
HOLD_MOTIONS: dict[str, list[tuple[float, float, float, float]]] = {
    'placed': [(0.0, 0.0, 3.0, _INF)],
    'stop from a creep': [(0.02, 0.0, 2.0, _INF), (0.0, 0.0, 3.0, _INF)],
    'stop from 0.25 m/s': [(0.25, 0.0, 2.0, _INF), (0.0, 0.0, 3.0, _INF)],
    'stop from 2 m/s': [(2.0, 0.0, 4.0, _INF), (0.0, 0.0, 3.0, _INF)],
    'stop reversing': [(-0.1, 0.0, 2.0, _INF), (0.0, 0.0, 3.0, _INF)],
    'stop turning in place': [(0.0, 0.8, 2.0, _INF), (0.0, 0.0, 3.0, _INF)],
    'guard stop from 1 m/s': [(1.0, 0.0, 3.0, _INF), (1.0, 0.0, 3.0, 0.0)],
    'guard stop in a 2 m/s arc': [(2.0, 0.8, 4.0, _INF), (2.0, 0.8, 3.0, 0.0)],
    'guard chattering at 0.3 m/s': ([(0.3, 0.0, 2.0, _INF)]
                                    + [(0.3, 0.0, 0.3, 0.0), (0.3, 0.0, 0.3, 0.05)] * 8),
}


def hold_load(robot: dict[str, Any], motion: str, seed: int) -> tuple[float, float | None]:
    """Run a healthy base on the level through a motion of :data:`HOLD_MOTIONS`, then hold.

    Return (the most the hold's integral held on a wheel, normalized command -- what
    ``supervision.level_hold_effort`` bounds on the level; the latch time or None).
    """
    vb = VirtualBase(world={'seed': seed, 'robot': robot}, control=HOLD_ON)
    try:
        most, k = 0.0, 0
        for v, w, seconds, cap in HOLD_MOTIONS[motion]:
            for _ in range(round(seconds / 0.01)):
                vb.cycle(v, w, forward_cap=cap, guard_active=cap == 0.0)
                k += 1
                if vb.ctl.holding:
                    most = max(most, abs(vb.ctl.hold_effort[0]), abs(vb.ctl.hold_effort[1]))
                if vb.ctl.supervisor.latched:
                    return most, k * 0.01
        return most, None
    finally:
        vb.close()


def driven_at_zero(offset_v: float, seed: int, control: dict[str, Any] | None = None,
                   seconds: float = 2.0) -> tuple[float | None, float]:
    """Drive the left wheel by an amplifier offset from rest on the level, never commanded.

    The still fault latches, then the fault stop acts. Return (the latch time in s or None,
    the most counts a wheel turned from its angle at the start over ``seconds``, the fault
    stop included). ``control``: an overlay (:data:`HOLD_OFF`); None: as shipped.
    """
    vb = VirtualBase(world={'seed': seed, 'robot': {'amp_offset_left_v': offset_v}},
                     control=control)
    try:
        vb.cycle(0.0, 0.0)
        start = vb.ctl.wheel_angles
        latched = vb.run(seconds, 0.0, 0.0, until=vb.faulted)
        if latched is not None:
            vb.run(seconds - latched, 0.0, 0.0)
        turned = max(abs(a - b) / COUNT for a, b in zip(vb.ctl.wheel_angles, start,
                                                         strict=True))
        return latched, turned
    finally:
        vb.close()


def hold_ramp(robot: dict[str, Any], grade_deg: float, downhill_deg: float, how: str,
              seed: int, seconds: float = 3.0) -> tuple[float, float | None]:
    """With the hold on, on a ramp: placed, a stop from 0.5 m/s, or a guard stop from 1 m/s.

    The ramp falls toward ``downhill_deg`` (0: ahead, 180: behind). Return as
    :func:`hold_offset`.
    """
    floor = [{'rectangle': [-30.0, -30.0, 30.0, 30.0], 'mu': 0.6, 'grade_deg': grade_deg,
              'downhill_deg': downhill_deg}]
    vb = VirtualBase(world={'seed': seed, 'floor': floor, 'robot': robot}, control=HOLD_ON)
    try:
        if how == 'stop':
            vb.run(2.5, 0.5)
            return _held_counts(vb, seconds, 0.0)
        if how == 'guard stop':
            vb.run(3.5, 1.0)
            return _held_counts(vb, seconds, 1.0, forward_cap=0.0, guard_active=True)
        return _held_counts(vb, seconds, None)
    finally:
        vb.close()


def _hold_tables(seeds: Sequence[int]) -> None:
    print('The standstill hold as shipped (control.hold): how far a held wheel turns from where '
          'the hold began while no fault is latched [encoder counts, the most over the seeds; '
          'supervision.standstill_window bounds it]; against an offset, in how many seeds the '
          'fault latched and the worst latch time [s]; on a ramp, where nothing should latch, '
          'every latch time\n')
    offsets = (0.5, 1.0, 2.0, 3.0, 4.0, 6.0)
    print('| left amplifier offset, from rest on the level | '
          + ' | '.join(f'{o:g} V' for o in offsets) + ' |')
    print('|---|' + '---|' * len(offsets))
    runs = [[hold_offset(o, sd) for sd in seeds] for o in offsets]
    print('| counts; latched | ' + ' | '.join(
        f'{max(r[0] for r in rs):.0f}; {_latched([r[1] for r in rs])}' for rs in runs) + ' |')
    print('\nHealthy bases on the level: the most the hold held on a wheel [normalized command; '
          'supervision.level_hold_effort bounds it where the IMU reads level] and what latched\n')
    print('| motion, then the hold | ' + ' | '.join(BASES) + ' |')
    print('|---|' + '---|' * len(BASES))
    for motion in HOLD_MOTIONS:
        cells = []
        for robot in BASES.values():
            rs = [hold_load(robot, motion, sd) for sd in seeds]
            cells.append(f'{max(r[0] for r in rs):.3f}; {_latched([r[1] for r in rs])}')
        print(f'| {motion} | ' + ' | '.join(cells) + ' |', flush=True)
    hows = ('placed', 'stop', 'guard stop')
    print('\n| 4.8 deg ramp | base | ' + ' | '.join(hows) + ' |')
    print('|---|---|' + '---|' * len(hows))
    for dh, what in ((0.0, 'downhill ahead'), (180.0, 'uphill ahead')):
        for name, robot in BASES.items():
            cells = []
            for how in hows:
                rs = [hold_ramp(robot, 4.8, dh, how, sd) for sd in seeds]
                falsely = [f'{r[1]:.2f}' for r in rs if r[1] is not None]
                cells.append(f'{max(r[0] for r in rs):.0f}; '
                             + (f'latched ({", ".join(falsely)})' if falsely else 'none'))
            print(f'| {what} | {name} | ' + ' | '.join(cells) + ' |', flush=True)
    print('\nA wheel driven at the zero word, then its fault stop: the counts it turned in the '
          '2 s from rest (the most over the seeds; the stop cuts the power once the zero word '
          'does not slow it) and the worst latch time\n')
    print('| left amplifier offset, from rest on the level | '
          + ' | '.join(f'{o:g} V' for o in offsets) + ' |')
    print('|---|' + '---|' * len(offsets))
    for label, control in (('hold as shipped', None), ('hold off', HOLD_OFF)):
        driven = [[driven_at_zero(o, sd, control) for sd in seeds] for o in offsets]
        print(f'| {label}: counts in 2 s; latch | ' + ' | '.join(
            f'{max(d[1] for d in ds):.0f}; {_worst([d[0] for d in ds])}' for ds in driven)
            + ' |', flush=True)


def _worst(values: Sequence[float | None]) -> str:
    if any(x is None for x in values):
        return 'none'
    return f'{max(x for x in values if x is not None):.2f}'


def _latched(values: Sequence[float | None]) -> str:
    """Return 'none', or 'k of n seeds, worst t s'."""
    times = [x for x in values if x is not None]
    if not times:
        return 'none'
    return f'{len(times)} of {len(values)} seeds, worst {max(times):.2f} s'


def main(argv: Sequence[str] | None = None) -> int:
    """Print the tables (markdown)."""
    ap = argparse.ArgumentParser(prog='latch', description=__doc__.splitlines()[0])
    ap.add_argument('--seeds', type=int, nargs='+', default=[1, 2, 3])
    ap.add_argument('--imu-lag', type=float, default=0.0, metavar='S',
                    help='the gyro reaches the controller S seconds after the encoders')
    ap.add_argument('--hold', action='store_true',
                    help='only the standstill hold switched on: how far held wheels turn, on '
                    'ramps and against an amplifier offset, and what latches')
    args = ap.parse_args(argv)
    seeds = args.seeds
    if args.hold:
        _hold_tables(seeds)
        return 0
    print(f'seeds {seeds}; gyro {args.imu_lag * 1e3:g} ms behind the encoders; worst latch '
          'time [s] after the first command, left / right wheel; peak ground-truth speed '
          '[m/s]\n')
    heads = ' | '.join(f'{v} m/s {w} rad/s' for v, w in CREEPS)
    print(f'| fault from the start | base | {heads} |')
    print('|---|---|' + '---|' * len(CREEPS))
    for kind in ('encoder_frozen', 'wheel_stall', 'encoder_sign_flip'):
        for name, robot in BASES.items():
            cells = []
            for v, w in CREEPS:
                lr = []
                peak = 0.0
                for wheel in ('left', 'right'):
                    runs = [from_the_start(kind, wheel, v, w, s, robot, imu_lag_s=args.imu_lag)
                            for s in seeds]
                    lr.append(_worst([r[0] for r in runs]))
                    peak = max([peak] + [r[1] for r in runs])
                cells.append(f'{lr[0]} / {lr[1]} ({peak:.2f})')
            print(f'| {kind} | {name} | ' + ' | '.join(cells) + ' |', flush=True)
    print('\nA wheel driven at a zero command (left amplifier offset): worst latch time [s] after '
          'its setpoint reached zero / after the healthy right wheel came to rest\n')
    print('| stop | offset 1.0 V | offset -1.0 V | offset 0.6 V |')
    print('|---|---|---|---|')
    for v, w, guard in ((0.02, 0.0, False), (0.25, 0.0, False), (1.0, 0.0, False),
                        (0.0, 0.8, False), (1.0, 0.0, True), (0.25, 0.4, True)):
        cells = []
        for off in (1.0, -1.0, 0.6):
            stops = [still_after_stop(v, w, guard, s, off) for s in seeds]
            cells.append(f'{_worst([r[0] for r in stops])} / {_worst([r[1] for r in stops])}')
        what = 'guard stop' if guard else 'ramped stop'
        print(f'| {what} from {v} m/s {w} rad/s | ' + ' | '.join(cells) + ' |', flush=True)
    print('\nHealthy bases, guard stops then a slow turn in place (turn_after_guard_stops; 30 '
          'of 72 latched a false "frozen" before the fix of docs/safety.md): runs that latched '
          'a fault, of all\n')
    print('| base | gyro in step | gyro 30 ms late |')
    print('|---|---|---|')
    for name, robot in BASES.items():
        cells = []
        for lag in (0.0, 0.03):
            latched = [turn_after_guard_stops(w, s, robot, lag) for s in seeds
                       for w in (0.02, 0.057, 0.1, -0.057)]
            cells.append(f'{sum(r is not None for r in latched)} of {len(latched)}')
        print(f'| {name} | ' + ' | '.join(cells) + ' |', flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
