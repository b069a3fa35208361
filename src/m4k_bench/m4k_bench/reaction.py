"""reaction: the guard's reaction time and stopping distance, on the simulator's clock.

``reaction [--trials 50] [--speeds 0.5 1.0 2.0] [--speed-trials 5] [--out DIR]`` (also a
phase of ``make bench``). The stack runs for real -- rt_core (guard, PI, actuator) and the
driver host (sonar, laser, IMU, motors) as their own processes over XDDP and the sim-bus --
with the simulator (:class:`m4k_drivers.sim_robot.SimRobot`) in this process, so both ends of
each interval are stamped on the simulator's own clock (its world time, 1 ms steps):

* the **crossing**: while the robot drives straight at a steady speed, a panel (0.6 m wide) is
  put into the world ahead of it, its near face just inside the guard's stop line for the true
  speed (:func:`m4k_bench.scenarios.bounds.stop_line`) -- the instant an obstacle crosses the
  stop line on ground truth; each trial waits a random 0..0.25 s first, so the crossing falls
  at a uniformly random phase of the sensor and actuator cycles;
* the **first braking DAC word**: the first MCP4911 write the simulator receives after the
  crossing whose armature voltage lies below every word of the steady drive just before it
  (less 2 % of the supply: the PI's chatter is far smaller);
* the **stopping distance**: ground-truth path from the crossing to rest, against the physical
  minimum ``v * t_sensor + v^2 / (2 mu g)`` (``t_sensor``: one sonar period, the fastest the
  front sensors can report it; ``mu g``: what the tyres give, the judge's
  :func:`~m4k_bench.scenarios.bounds.traction_limit`) and the scenario judge's allowed
  distance.

Then the panel is taken away, the robot drives on, and the next trial starts. Writes
``reaction.md`` (tables), ``reaction.json``, ``reaction.csv`` (every trial) and
``reaction.png`` into ``--out`` (the processes' output in ``logs/``). A benchmark, not a
test: nothing here asserts a time.
"""

from __future__ import annotations

import argparse
import math
import os
import random
import shutil
import sys
import tempfile
import threading
import time
from typing import Any, Callable, Sequence

import numpy as np
import yaml

from m4k_bench.benchlib import provenance, results
from m4k_bringup.child import Child, Output, Stopping

__all__ = ['main', 'run_reaction']

PANEL_WIDTH_M = 0.6
PANEL_DEPTH_M = 0.05
INSIDE_M = 0.005          # the panel's near face this far inside the stop line
STEADY_WINDOW_S = 0.3
STEADY_BAND = 0.1         # of the speed: the PI's ripple on a busy machine stays inside it
BRAKE_DROP = 0.02         # of the supply: below the steady words by this much = braking
FAR = 1.0e4               # where the panel waits between trials (m)
SIM_PRIORITY = 45         # SCHED_FIFO of the simulator's threads (sim_robot's default)


def _overlay(seed: int) -> dict[str, Any]:
    return {'runtime': {'mlockall': False, 'cpu_dma_latency': False, 'start_delay_ms': 10},
            'world': {'walls': [], 'seed': seed,
                      'obstacles': [[[FAR, FAR], [FAR + PANEL_DEPTH_M, FAR],
                                     [FAR + PANEL_DEPTH_M, FAR + PANEL_WIDTH_M],
                                     [FAR, FAR + PANEL_WIDTH_M]]]}}


class _Sim:
    """The simulator in this process, its DAC writes stamped on the world's clock."""

    def __init__(self, overlay_path: str, runtime_dir: str) -> None:
        from m4k_drivers import config as dconfig
        from m4k_drivers.host import load_raw_config
        from m4k_drivers.sim_robot import _sensor_heights, SimRobot
        self.raw = load_raw_config(None, overlay_path)
        cfg = dconfig.validate({'devices': self.raw.get('devices') or {},
                                'world': self.raw.get('world') or {}},
                               control=self.raw.get('control') or {},
                               body=(self.raw.get('robot') or {}).get('body'))
        # As sim_robot does (its --priority, 45): the simulator's threads run SCHED_FIFO below the
        # RT tasks, so hardware does not slow down when the machine is busy. They inherit it
        # from this thread, which then goes back to SCHED_OTHER for the bench's own loops.
        from m4k_rt.sched import SchedError, set_thread_fifo
        try:
            set_thread_fifo(SIM_PRIORITY)
            self.fifo = True
        except (SchedError, ValueError, OSError):
            self.fifo = False
        try:
            self.robot = SimRobot(cfg, runtime_dir, os.path.join(runtime_dir, 'world.json'),
                                  heights=_sensor_heights(self.raw)).start()
            self.stop = threading.Event()
            self.thread = threading.Thread(target=self.robot.run, args=(self.stop,),
                                           daemon=True, name='reaction-sim')
            self.thread.start()
        finally:
            if self.fifo:
                os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        self.world = self.robot.world
        self.words: list[tuple[int, int, float]] = []     # (world ns, side, armature V)
        self._lock = threading.Lock()
        for side, name in enumerate(('left_dac', 'right_dac')):
            dac = self.robot.spi[name]
            self._wrap(dac, side)

    def _wrap(self, dac: Any, side: int) -> None:
        inner = dac.transfer
        world = self.world

        def transfer(data: bytes) -> bytes:
            out = inner(data)
            with self._lock:
                self.words.append((world.t_ns, side, world.motor_voltage(side)))
            return bytes(out)
        dac.transfer = transfer

    def words_since(self, t_ns: int) -> list[tuple[int, int, float]]:
        with self._lock:
            return [w for w in self.words if w[0] >= t_ns]

    def place_panel(self, ahead_m: float | None) -> tuple[int, float, float]:
        """Put the panel ``ahead_m`` in front of the front face (None: far away).

        Returns (world ns, travelled m, v m/s) at that instant. The panel is the world's one
        obstacle; its outline is moved in place under the world's lock (as a moving
        obstacle's is), so every sensor and contact check sees it from this world step on.
        """
        w = self.world
        with w._lock:                      # noqa: SLF001 - the bench moves its own obstacle
            w.now()
            st = w.state()
            if ahead_m is None:
                poly = np.array([[FAR, FAR], [FAR + PANEL_DEPTH_M, FAR],
                                 [FAR + PANEL_DEPTH_M, FAR + PANEL_WIDTH_M],
                                 [FAR, FAR + PANEL_WIDTH_M]])
            else:
                x, y, th = st.pose
                c, s = math.cos(th), math.sin(th)
                near = w.robot.length_m / 2.0 + ahead_m
                hw = PANEL_WIDTH_M / 2.0
                local = [(near, -hw), (near + PANEL_DEPTH_M, -hw),
                         (near + PANEL_DEPTH_M, hw), (near, hw)]
                poly = np.array([(x + c * px - s * py, y + s * px + c * py) for px, py in local])
            n = len(poly)
            rows = list(range(len(w._seg) - n, len(w._seg)))   # noqa: SLF001
            w._seg[rows] = np.hstack([poly, np.roll(poly, -1, axis=0)])   # noqa: SLF001
            w._polys[-1] = poly                                  # noqa: SLF001
            return w.t_ns, w.travelled, st.v

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5.0)
        self.robot.close()


class _Commander:
    """VELOCITY_CMD at 20 Hz on the ``cmd`` port (the bridge's role), ODOMETRY drained.

    The ``status`` port too (the bridge's other role): the monitor's SAFETY_STATUS (1 Hz)
    names the cause of a latched motor fault, so a latch is reset only once its cause has
    been read (or after ``CAUSE_WAIT_S``).
    """

    CAUSE_WAIT_S = 2.5

    def __init__(self, runtime_dir: str, out_dir: str, log: Callable[[str], None]) -> None:
        from m4k_bridge.faulttrace import TraceWriter
        from m4k_rt import channel
        # each latch's supervision trace (FAULT_TRACE), as the bridge writes it
        self.traces = TraceWriter(os.path.join(out_dir, 'fault_traces'), log)
        self.link = channel.NrtLink('cmd', runtime_dir, retry_interval=0.05)
        self.status = channel.NrtLink('status', runtime_dir, retry_interval=0.05)
        self.v = 0.0
        self.flags = 0            # the last ODOMETRY flags (m4k_rt.protocol.OdomFlag)
        self.fault_resets = 0     # MOTOR_FAULT latches seen (and reset) on healthy wheels
        self.causes: list[str] = []   # the supervision's cause of each, as words
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True, name='reaction-cmd')
        self.thread.start()

    def _run(self) -> None:
        from m4k_rt import protocol as p
        from m4k_rt.control.supervision import cause_text
        seq = 0
        last_reset = 0.0
        cause = 0                 # the latched fault's cause, from SAFETY_STATUS
        seen_at = 0.0             # when the latch was first seen (0: none pending)
        while not self.stop.wait(0.05):
            seq = (seq + 1) & 0xFFFF
            self.link.write(p.encode(p.Kind.VELOCITY_CMD, seq, 0, self.v, 0.0))
            while (data := self.link.read(0.0)) is not None:
                try:
                    hdr, body = p.decode(data)
                except ValueError:
                    continue
                if hdr.kind == p.Kind.ODOMETRY:
                    self.flags = int(body.flags)
            while (data := self.status.read(0.0)) is not None:
                try:
                    hdr, body = p.decode(data)
                except ValueError:
                    continue
                if hdr.kind == p.Kind.SAFETY_STATUS and body.fault_cause:
                    cause = int(body.fault_cause)
                elif hdr.kind == p.Kind.FAULT_TRACE:
                    self.traces.on_row(body)
            now = time.monotonic()
            if self.flags & p.OdomFlag.MOTOR_FAULT and now - last_reset > 0.5:
                seen_at = seen_at or now
                if not cause and now - seen_at < self.CAUSE_WAIT_S:
                    continue
                last_reset = now
                # No fault is injected here: a latch is the supervision tripping on healthy
                # wheels. Count it and its cause (the report says them) and reset it, as an
                # operator would, so the measurement goes on.
                self.fault_resets += 1
                self.causes.append(cause_text(cause) if cause else 'cause not reported')
                cause, seen_at = 0, 0.0
                self.flags &= ~int(p.OdomFlag.MOTOR_FAULT)
                self.link.write(p.encode(p.Kind.FAULT_RESET, seq, 0, self.fault_resets, 0))

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5.0)
        self.traces.join()
        self.link.close()
        self.status.close()


def _wait(pred: Callable[[], bool], timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.005)
    return False


def _steady(sim: _Sim, timeout_s: float, v_cmd: float) -> bool:
    """Wait until the true speed is within 10 % of ``v_cmd`` for STEADY_WINDOW_S."""
    hist: list[tuple[float, float]] = []
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        sim.world.now()
        v = sim.world.state().v
        now = time.monotonic()
        hist = [h for h in hist if now - h[0] <= STEADY_WINDOW_S] + [(now, v)]
        if now - hist[0][0] >= STEADY_WINDOW_S * 0.9 and \
                all(abs(h[1] - v_cmd) < STEADY_BAND * v_cmd for h in hist):
            return True
        time.sleep(0.01)
    return False


def _trial(sim: _Sim, raw: dict[str, Any], rng: random.Random, v_cmd: float
           ) -> dict[str, Any]:
    from m4k_bench.scenarios.bounds import REST_V, stop_line
    w = sim.world
    for _ in range(20):
        if not _steady(sim, 90.0, v_cmd):   # the first: the stack's start-up on a busy machine
            w.now()
            st = w.state()
            return {'error': f'no steady {v_cmd:g} m/s within 90 s (now {st.v:.3f} m/s, '
                    f'{w.motor_voltage(0):.2f}/{w.motor_voltage(1):.2f} V, enabled '
                    f'{w.drive_enabled()})'}
        time.sleep(rng.uniform(0.0, 0.25))                 # a random phase of every cycle
        w.now()
        v_now = w.state().v
        if abs(v_now - v_cmd) < STEADY_BAND * v_cmd:       # still driving (no stale stop)
            break
    else:
        return {'error': f'no steady {v_cmd:g} m/s at the crossing in 20 tries'}
    line = stop_line(raw, abs(v_now))
    contacts0 = w.state().collisions
    t_steady = w.t_ns - int(STEADY_WINDOW_S * 1e9)
    t0, tr0, v0 = sim.place_panel(line - INSIDE_M)
    steady = [x for x in sim.words_since(t_steady) if x[0] < t0]
    floor = {s: min((x[2] for x in steady if x[1] == s), default=math.nan) for s in (0, 1)}
    thr = {s: floor[s] - BRAKE_DROP * w.robot.supply_v for s in (0, 1)}
    brake_ns: list[int] = []

    def braked() -> bool:
        hit = next((x for x in sim.words_since(t0) if x[2] < thr[x[1]]), None)
        if hit is not None:
            brake_ns.append(hit[0])
        return hit is not None
    _wait(braked, 5.0)
    rest = _wait(lambda: (w.now() is not None) and abs(w.state().v) < REST_V, 10.0)
    w.now()
    out = {'v': v0, 'stop_line_m': line, 'crossing_ns': t0,
           'reaction_s': (brake_ns[0] - t0) / 1e9 if brake_ns else None,
           'stop_m': (w.travelled - tr0) if rest else None,
           'contacts': w.state().collisions - contacts0,
           'clearance_m': w.clearance(w.state().pose), 'steady_words': len(steady),
           'steady_floor_v': [floor[0], floor[1]],
           'min_after_v': min((x[2] for x in sim.words_since(t0)), default=None)}
    sim.place_panel(None)
    return out


def run_reaction(out_dir: str, *, trials: int = 50, speeds: Sequence[float] = (0.5, 1.0, 2.0),
                 speed_trials: int = 5, seed: int | None = None,
                 progress: Callable[[str], None] = lambda s: None,
                 env: dict[str, str] | None = None) -> dict[str, Any]:
    """Run the trials; write the evidence into ``out_dir``; return the summary."""
    from m4k_bench.scenarios.bounds import bounds, traction_limit
    # the checkout as the run starts: the evidence written into an out_dir inside it (the
    # committed figure, docs/results/reaction) must not read as local changes
    prov = provenance.provenance()
    rng = random.Random(seed)
    os.makedirs(out_dir, exist_ok=True)
    work = tempfile.mkdtemp(prefix='m4k-reaction-')
    runtime_dir = os.path.join(work, 'run')
    os.makedirs(runtime_dir, mode=0o700)
    overlay = os.path.join(work, 'overlay.yaml')
    with open(overlay, 'w', encoding='utf-8') as f:
        yaml.safe_dump(_overlay(rng.randrange(1 << 30)), f)
    env = dict(env or os.environ, M4K_RUNTIME_DIR=runtime_dir)
    procs: list[Child] = []
    sim = cmd = None
    rows: list[dict[str, Any]] = []
    try:
        sim = _Sim(overlay, runtime_dir)
        raw = sim.raw
        os.makedirs(os.path.join(out_dir, 'logs'), exist_ok=True)
        for name, argv in (('driver_host', ['m4k_drivers.host', '--overlay', overlay]),
                           ('rt_core', ['m4k_rt.rt_core', '--config', overlay])):
            procs.append(Child(name, [sys.executable, '-m', *argv], env,
                               output=Output(log_path=os.path.join(out_dir, 'logs',
                                                                   name + '.log'),
                                             log_append=False, log_header=False),
                               stopping=Stopping(timeout=10.0, must_end=True)).start())
        cmd = _Commander(runtime_dir, out_dir, progress)
        plan = [(speeds[0], trials)] + [(v, speed_trials) for v in speeds[1:]]
        for v_cmd, n in plan:
            cmd.v = v_cmd
            for k in range(n):
                row = _trial(sim, raw, rng, v_cmd)
                row['v_cmd'] = v_cmd
                if 'error' in row:
                    from m4k_rt.protocol import OdomFlag
                    row['error'] += f'; RT flags {OdomFlag(cmd.flags)!r}'
                rows.append(row)
                progress(f'v {v_cmd:g} m/s trial {k + 1}/{n}: reaction '
                         f'{_ms(row.get("reaction_s"))} ms, stop {_m(row.get("stop_m"))} m')
                if 'error' in row:
                    break
        cmd.v = 0.0
        summary = _summarise(rows, raw, trials, bounds, traction_limit)
        summary['false_motor_faults'] = cmd.fault_resets
        summary['false_motor_fault_causes'] = list(cmd.causes)
    finally:
        if cmd is not None:
            cmd.close()         # (waits for the fault traces being written)
        for pr in procs:
            pr.stop()             # SIGTERM, 10 s, SIGKILL
        if sim is not None:
            sim.close()
        shutil.rmtree(work, ignore_errors=True)
    summary['false_motor_fault_traces'] = [os.path.relpath(t, out_dir)
                                           for t in cmd.traces.written]
    _write(out_dir, rows, summary, prov)
    return summary


def _ms(v: float | None) -> str:
    return '-' if v is None else f'{v * 1e3:.1f}'


def _m(v: float | None) -> str:
    return '-' if v is None else f'{v:.3f}'


def _summarise(rows: list[dict[str, Any]], raw: dict[str, Any], trials: int, bounds: Any,
               traction_limit: Any) -> dict[str, Any]:
    mu_g = traction_limit(raw)
    t_sensor = float(raw['tasks']['sonar']['period_ms']) / 1000.0
    react = [r['reaction_s'] for r in rows if r.get('reaction_s') is not None]
    first = rows[:trials]
    react0 = [r['reaction_s'] for r in first if r.get('reaction_s') is not None]
    by_speed = []
    for v_cmd in sorted({r['v_cmd'] for r in rows}):
        rs = [r for r in rows if r['v_cmd'] == v_cmd and r.get('stop_m') is not None]
        if not rs:
            continue
        v = float(np.median([r['v'] for r in rs]))
        b = bounds(raw, v, 'sonar')
        by_speed.append({
            'v_cmd': v_cmd, 'v': v, 'n': len(rs),
            'stop_m_median': float(np.median([r['stop_m'] for r in rs])),
            'stop_m_max': float(max(r['stop_m'] for r in rs)),
            'physical_min_m': v * t_sensor + v * v / (2.0 * mu_g),
            'judge_allowed_m': b.stop_distance(v),
            'stop_line_m': float(np.median([r['stop_line_m'] for r in rs])),
            'contacts': int(sum(r['contacts'] for r in rs)),
            'min_clearance_m': float(min(r['clearance_m'] for r in rs))})
    return {'trials': len(react0), 'reaction_p50_s': _pct(react0, 50),
            'reaction_p99_s': _pct(react0, 99), 'reaction_max_s': max(react0, default=None),
            'reaction_all_p50_s': _pct(react, 50), 't_sensor_s': t_sensor, 'mu_g': mu_g,
            'speeds': by_speed, 'failed': [r for r in rows if r.get('reaction_s') is None]}


def _pct(xs: list[float], q: float) -> float | None:
    return float(np.percentile(xs, q)) if xs else None


def _write(out_dir: str, rows: list[dict[str, Any]], s: dict[str, Any],
           prov: dict[str, Any]) -> None:
    doc = results.write_json(os.path.join(out_dir, 'reaction.json'),
                             {'summary': s, 'trials': rows, 'provenance': prov}, indent=1)
    keys = ('v_cmd', 'v', 'stop_line_m', 'reaction_s', 'stop_m', 'contacts', 'clearance_m')
    with open(os.path.join(out_dir, 'reaction.csv'), 'w', encoding='utf-8') as f:
        f.write(','.join(keys) + '\n')
        for r in rows:
            f.write(','.join('' if r.get(k) is None else str(r.get(k)) for k in keys) + '\n')
    lines = ['# Guard reaction time and stopping distance (simulator clock)', '',
             f'Measured at {provenance.text(doc["provenance"])}.', '',
             f'Reaction: an obstacle crossing the stop line on ground truth -> the first braking '
             f'DAC word the simulator receives, {s["trials"]} trials at random cycle phases '
             f'(the first speed).', '',
             '| trials | p50 (ms) | p99 (ms) | max (ms) |', '|---|---|---|---|',
             f'| {s["trials"]} | {_ms(s["reaction_p50_s"])} | {_ms(s["reaction_p99_s"])} | '
             f'{_ms(s["reaction_max_s"])} |', '',
             f'Stopping distance from the stop line to rest (ground truth), against the '
             f'physical minimum v·t_sensor + v²/(2·μg) (t_sensor {s["t_sensor_s"] * 1e3:.0f} ms, '
             f'one sonar period; μg {s["mu_g"]:.2f} m/s²) and the scenario judge\'s allowed '
             f'v·t_react + v²/(2·a_brake) + margin:', '',
             '| commanded (m/s) | true at crossing (m/s) | trials | stop line (m) | stop median '
             '(m) | stop max (m) | physical minimum (m) | judge allows (m) | contacts | min '
             'clearance (m) |', '|---|---|---|---|---|---|---|---|---|---|']
    for r in s['speeds']:
        lines.append(f'| {r["v_cmd"]:g} | {r["v"]:.3f} | {r["n"]} | {r["stop_line_m"]:.3f} | '
                     f'{r["stop_m_median"]:.3f} | {r["stop_m_max"]:.3f} | '
                     f'{r["physical_min_m"]:.3f} | {_m(r["judge_allowed_m"])} | '
                     f'{r["contacts"]} | {r["min_clearance_m"]:.3f} |')
    if s.get('false_motor_faults'):
        causes = ', '.join(s.get('false_motor_fault_causes') or []) or 'not recorded'
        lines += ['', f'The wheel supervision latched MOTOR_FAULT {s["false_motor_faults"]} '
                  f'time(s) on healthy wheels (no fault injected; cause: {causes}); the bench '
                  f"reset it (FAULT_RESET) each time to go on. The supervision's trace of "
                  f'each: {", ".join(s.get("false_motor_fault_traces") or []) or "none"}.']
    if s['failed']:
        lines += ['', f'{len(s["failed"])} trial(s) without a braking word: '
                  + '; '.join(str(r.get('error', 'none within 5 s')) for r in s['failed'])]
    results.write_text(os.path.join(out_dir, 'reaction.md'), '\n'.join(lines))
    _plot(out_dir, rows, s)


def _plot(out_dir: str, rows: list[dict[str, Any]], s: dict[str, Any]) -> None:
    from m4k_bench.benchlib import plots
    plots.reaction(rows, s, os.path.join(out_dir, 'reaction.png'))


def main(argv: Sequence[str] | None = None) -> int:
    """Run the reaction bench alone (a few minutes); return 0 when every trial braked."""
    ap = argparse.ArgumentParser(prog='reaction', description=__doc__.split('\n\n')[0])
    ap.add_argument('--trials', type=int, default=50, help='reaction trials at the first '
                    'speed (default 50)')
    ap.add_argument('--speeds', type=float, nargs='+', default=[0.5, 1.0, 2.0],
                    metavar='V', help='commanded speeds, m/s (default 0.5 1.0 2.0: Table 2 top)')
    ap.add_argument('--speed-trials', type=int, default=5, help='stops at each further speed')
    ap.add_argument('--seed', type=int, default=None)
    ap.add_argument('--out', default=os.path.join('results', 'reaction'), metavar='DIR')
    from m4k_rt import rosargs
    args = rosargs.parse_args(ap, argv)
    if args.trials < 1 or args.speed_trials < 0 or any(not v > 0 for v in args.speeds):
        ap.error('--trials >= 1, --speed-trials >= 0, speeds > 0')
    s = run_reaction(args.out, trials=args.trials, speeds=args.speeds,
                     speed_trials=args.speed_trials, seed=args.seed,
                     progress=lambda m: print(m, file=sys.stderr, flush=True))
    print(f'reaction: p50 {_ms(s["reaction_p50_s"])} ms, p99 {_ms(s["reaction_p99_s"])} ms '
          f'over {s["trials"]} trials; {args.out}/reaction.md', file=sys.stderr)
    return 0 if not s['failed'] else 1


if __name__ == '__main__':
    sys.exit(main())
