"""Stopping distance of each kind of stop, measured on the simulator's ground truth.

    python -m m4k_bench.stopping [--speeds 0.05 0.25 1.0 2.0] [--kinds ...] [--seed 1]

The RT base controller drives the simulated base straight at each speed in virtual time
(:mod:`m4k_bench.virtualbase`: the motor and IMU handlers over the simulated buses, the drive
physics of ``m4k_drivers.drive``), then one stop is triggered and the ground truth is followed
to rest. Each row: the distance the body travels from the trigger to rest, the time, and the
peak deceleration. Kinds:

* ``cat1_fault``: a category-1 stop of an RT-detected fault -- the left encoder freezes (valid
  frames, a magnet slipping); the wheel supervision latches, the zero word brakes with the
  enable on, then the enable drops. The distance includes the detection (up to 0.3 s, while
  the PI winds up on the frozen reading).
* ``guard``: the guard's stop from the moment it trips (zero forward cap, the ramp bypassed,
  the zero word): the v^2 / (2 a_brake) part of d(v) plus the amplifier lag; the sensor part
  of t_react is not in it.
* ``cat0_brake``: category 0 -- the hardware e-stop contact cuts the amplifier enable at once,
  with the dynamic brake wired (``world.robot.dynamic_brake_ohm``, the default).
* ``cat0_coast``: the same without the brake contact: the outputs float, the robot coasts.
* ``host_brake`` / ``host_coast``: the driver host dies (no heartbeat: the enable drops after
  the monostable's 50 ms hold, the DACs keep their last word), with and without the brake.

Deterministic (virtual time, a fixed seed): the same code gives the same table.
"""

from __future__ import annotations

import argparse
import math
from typing import Any, NamedTuple, Sequence

from m4k_bench.virtualbase import PERIOD_NS, VirtualBase

__all__ = ['KINDS', 'Stop', 'main', 'measure']

KINDS = ('cat1_fault', 'guard', 'cat0_brake', 'cat0_coast', 'host_brake', 'host_coast')
_COAST = {'dynamic_brake_ohm': None}


class Stop(NamedTuple):
    """One measured stop: the speed at the trigger, distance and time to rest, peak decel."""

    kind: str
    speed: float            # m/s commanded
    v0: float               # m/s true body speed at the trigger
    distance: float         # m travelled on ground truth from the trigger to rest
    time: float             # s from the trigger to rest
    peak_decel: float       # m/s^2, ground truth


def measure(kind: str, speed: float, seed: int = 1, limit_s: float = 15.0) -> Stop:
    """Drive straight at ``speed``, trigger ``kind``, follow the ground truth to rest."""
    if kind not in KINDS:
        raise ValueError(f'kind must be one of {", ".join(KINDS)}, got {kind!r}')
    robot: dict[str, Any] = dict(_COAST) if kind.endswith('coast') else {}
    vb = VirtualBase(world={'seed': seed, 'robot': robot})
    world = vb.world
    try:
        accel = vb.params.linear.max_acceleration
        vb.run(speed / accel + 1.5, speed)                 # ramp up and settle
        st = world.state()
        v0, x0, t0 = st.v, world.travelled, vb.clock.t
        world.peak_decel = 0.0
        if kind == 'cat1_fault':
            world.set_fault('encoder_frozen', 'left')
        elif kind.startswith('cat0'):
            world.set_estop_open(True)
        steps = round(limit_s * 1e9 / PERIOD_NS)
        for _ in range(steps):
            if kind.startswith('host'):
                vb.clock.t += PERIOD_NS                     # nobody writes: no heartbeat
                world.now()
            elif kind == 'guard':
                vb.cycle(speed, 0.0, forward_cap=0.0, guard_active=True)
            else:
                vb.cycle(speed)
            s = world.state()
            if abs(s.v) < 0.001 and world.rest_since_ns is not None:
                break
        return Stop(kind, speed, v0, world.travelled - x0, (vb.clock.t - t0) * 1e-9,
                    world.peak_decel)
    finally:
        vb.close()


def table(stops: Sequence[Stop], speeds: Sequence[float]) -> str:
    """Return the stops as a markdown table: one row per kind, one column per speed."""
    head = '| stop | ' + ' | '.join(f'{v:g} m/s' for v in speeds) + ' |'
    lines = [head, '|---|' + '---|' * len(speeds)]
    for kind in dict.fromkeys(s.kind for s in stops):
        cells = []
        for v in speeds:
            s = next((x for x in stops if x.kind == kind and x.speed == v), None)
            cells.append('' if s is None else
                         f'{s.distance:.3f} m, {s.time:.2f} s, {s.peak_decel:.2f} m/s^2')
        lines.append(f'| {kind} | ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Measure and print the table (distance, time to rest, peak deceleration)."""
    ap = argparse.ArgumentParser(prog='python -m m4k_bench.stopping', description=__doc__
                                 .split('\n')[0])
    ap.add_argument('--speeds', type=float, nargs='+', default=[0.05, 0.25, 1.0, 2.0])
    ap.add_argument('--kinds', nargs='+', choices=KINDS, default=list(KINDS))
    ap.add_argument('--seed', type=int, default=1)
    args = ap.parse_args(argv)
    if any(not (math.isfinite(v) and 0.0 < v <= 2.0) for v in args.speeds):
        ap.error('--speeds: each must be in (0, 2] m/s (the top speed)')
    stops = []
    for kind in args.kinds:
        for v in args.speeds:
            s = measure(kind, v, args.seed)
            print(f'{kind:11} {v:5.2f} m/s (true {s.v0:.3f}): {s.distance:.3f} m, '
                  f'{s.time:.2f} s, peak {s.peak_decel:.2f} m/s^2', flush=True)
            stops.append(s)
    print()
    print(table(stops, args.speeds))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
