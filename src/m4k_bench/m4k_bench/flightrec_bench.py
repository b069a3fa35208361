"""flightrec_bench: the RT tasks' timing with the flight recorder on and off, side by side.

``python -m m4k_bench.flightrec_bench [--rounds N] [--window-s S] [--results DIR]`` runs the
full stack (``bringup`` on the simulator) once per condition per round, in alternating order
(reversed every other round):

* ``on``: the flight recorder at its defaults, except ``min_interval`` 2 s, so that the
  stimulus below makes it dump every 5 s (a worst case: in service it dumps once per incident);
* ``off``: ``flight_recorder.enabled: false`` (no ring, no subscriptions, no dumps).

Each run warms up, then for ``--window-s`` drives ``cmd_vel`` at 20 Hz and engages and
releases ``e_stop`` every 5 s (so both conditions see the same commands and latch changes),
with the bridge's ``stats_window`` equal to the window: the ``rt_status`` published after the
window holds the RT process's own statistics of exactly those cycles -- release latency
(t_start - t_rel) and response time (t_end - t_start) per task, deadline misses, overruns.
It reports per round the on/off ratio of the actuator's p99 release latency and p99 response
time (and of every task's), and the median (min-max) over the rounds; writes
``summary.json`` and ``README.md`` to DIR (default ``docs/results/flightrec``). A benchmark,
not a test: on a shared machine only ratios taken in one run mean much.
"""

from __future__ import annotations

import argparse
import os
import random
import shutil
import statistics
import sys
import tempfile
import time
from typing import Any, Sequence

import yaml

from m4k_bench.benchlib import provenance, results
from m4k_bringup.bringup import bringup_argv
from m4k_bringup.child import Child, Output, Stopping
from m4k_rt import rosargs

__all__ = ['main', 'run_once']

ESTOP_EVERY_S = 5.0
ESTOP_HOLD_S = 1.0
CMD_PERIOD_S = 0.05


def _overlay(path: str, enabled: bool, window_s: float, dumps: str) -> None:
    doc = {'m4k_bridge': {'ros__parameters': {
        'stats_window': float(window_s),
        'flight_recorder': {'enabled': enabled, 'min_interval': 2.0, 'directory': dumps}}}}
    with open(path, 'w', encoding='utf-8') as f:
        yaml.safe_dump(doc, f)


def _task_stats(msg: Any) -> dict[str, Any]:
    out = {}
    for t in msg.tasks:
        out[t.name] = {
            'samples': int(t.release_latency.samples),
            'release_p50_us': t.release_latency.p50 * 1e6,
            'release_p99_us': t.release_latency.p99 * 1e6,
            'release_max_us': t.release_latency.max * 1e6,
            'response_p50_us': t.response_time.p50 * 1e6,
            'response_p99_us': t.response_time.p99 * 1e6,
            'response_max_us': t.response_time.max * 1e6,
            'deadline_misses': int(t.deadline_misses), 'overruns': int(t.overruns)}
    return out


def run_once(enabled: bool, window_s: float, warmup_s: float, env: dict[str, str],
             keep_logs: str | None = None) -> dict[str, Any]:
    """Run the stack once; return the RT tasks' statistics over the window and the dumps."""
    from geometry_msgs.msg import Twist
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import Bool

    from m4k_msgs.msg import RtStatus

    tmp = tempfile.mkdtemp(prefix='m4k-flightrec-bench-')
    dumps = os.path.join(tmp, 'dumps')
    overlay = os.path.join(tmp, 'overlay.yaml')
    _overlay(overlay, enabled, window_s, dumps)
    env = dict(env, M4K_RUNTIME_DIR=os.path.join(tmp, 'rt'))
    log_path = os.path.join(tmp, 'bringup.log')
    # bringup stops its own children on SIGTERM: 40 s for that, then SIGKILL.
    proc = Child('bringup', bringup_argv(overlay) + ['--no-status'], env,
                 output=Output(log_path=log_path),
                 stopping=Stopping(timeout=40.0, must_end=True)).start()
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node('flightrec_bench', context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    got: list[tuple[float, Any]] = []
    node.create_subscription(RtStatus, 'rt_status', lambda m: got.append((time.monotonic(), m)),
                             10)
    cmd = node.create_publisher(Twist, 'cmd_vel', 10)
    stop = node.create_publisher(Bool, 'e_stop', 10)
    res: dict[str, Any] = {'flight_recorder': enabled}
    try:
        deadline = time.monotonic() + 90
        while not (got and len(got[-1][1].tasks) >= 5):
            if time.monotonic() > deadline or not proc.alive():
                raise RuntimeError('the stack did not come up:\n' + open(
                    log_path, errors='replace').read()[-3000:])
            ex.spin_once(timeout_sec=0.1)
        end = time.monotonic() + warmup_s
        while time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        twist = Twist()
        twist.linear.x = 0.2
        t0 = time.monotonic()
        end = t0 + window_s
        next_cmd = t0
        engaged = False
        estops = 0
        while time.monotonic() < end:
            now = time.monotonic()
            phase = (now - t0) % ESTOP_EVERY_S
            want = ESTOP_EVERY_S - ESTOP_HOLD_S <= phase
            if want != engaged:
                stop.publish(Bool(data=want))
                engaged = want
                estops += want
            if now >= next_cmd:
                cmd.publish(twist)
                next_cmd += CMD_PERIOD_S
            ex.spin_once(timeout_sec=0.005)
        t_end = time.monotonic()
        stop.publish(Bool(data=False))
        deadline = t_end + 30
        while not (got and got[-1][0] > t_end + 0.05):
            if time.monotonic() > deadline:
                raise RuntimeError('no rt_status within 30 s after the window:\n' + open(
                    log_path, errors='replace').read()[-3000:])
            ex.spin_once(timeout_sec=0.05)
        res['tasks'] = _task_stats(got[-1][1])
        res['e_stops'] = estops
        res['dumps'] = sorted(os.listdir(dumps)) if os.path.isdir(dumps) else []
    finally:
        ex.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
        proc.stop()
        if keep_logs:
            os.makedirs(keep_logs, exist_ok=True)
            shutil.copy(log_path, os.path.join(keep_logs, 'bringup-{}-{}.log'.format(
                'on' if enabled else 'off', int(time.time()))))
        shutil.rmtree(tmp, ignore_errors=True)
    return res


def _ratio(on: Any, off: Any) -> float | None:
    if not isinstance(on, (int, float)) or not isinstance(off, (int, float)) or off <= 0:
        return None
    return float(on) / float(off)


def summarize(rounds: list[dict[str, Any]]) -> dict[str, Any]:
    """Return per-round on/off ratios per task and metric, and their median (min-max)."""
    metrics = ('release_p99_us', 'release_max_us', 'response_p99_us', 'response_max_us')
    tasks = sorted(set(rounds[0]['on']['tasks']) & set(rounds[0]['off']['tasks']))
    out: dict[str, Any] = {}
    for task in tasks:
        for m in metrics:
            vals = [_ratio(r['on']['tasks'].get(task, {}).get(m),
                           r['off']['tasks'].get(task, {}).get(m)) for r in rounds]
            ok = [v for v in vals if v is not None]
            out['{}.{}'.format(task, m)] = {
                'per_round': vals,
                'median': statistics.median(ok) if ok else None,
                'min': min(ok) if ok else None, 'max': max(ok) if ok else None}
    return out


def _readme(doc: dict[str, Any]) -> str:
    lines = ['# Flight recorder: RT-side cost', '',
             'Generated by `{}` at {}; {}.'.format(
                 doc['command'], provenance.text(doc['provenance']),
                 doc['provenance']['measured_utc']), '',
             'Each round runs the full stack on the simulator twice, flight recorder on and '
             'off, in alternating order; during a {:g} s window it drives cmd_vel at 20 Hz '
             'and engages/releases e_stop every {:g} s (the "on" run dumps a bag each time, '
             "min_interval 2 s). Numbers are the RT process's own statistics of the window "
             '(rt_status with stats_window = window). Ratio = on / off, per round; median '
             '(min-max) over {} rounds. 1.0 = no effect; the spread between rounds is the '
             "machine's noise.".format(doc['window_s'], ESTOP_EVERY_S, len(doc['rounds'])),
             '', '| task.metric | median on/off | min | max | per round |',
             '|---|---|---|---|---|']
    for key, v in doc['ratios'].items():
        if v['median'] is None:
            continue
        lines.append('| {} | {:.2f} | {:.2f} | {:.2f} | {} |'.format(
            key, v['median'], v['min'], v['max'], ', '.join(
                '{:.2f}'.format(x) if x is not None else '-' for x in v['per_round'])))
    lines += ['', '| round | condition | actuator release p99 [µs] | response p99 [µs] | '
              'deadline misses (all tasks) | dumps |', '|---|---|---|---|---|---|']
    for i, r in enumerate(doc['rounds']):
        for cond in ('on', 'off'):
            run = r[cond]
            act = run['tasks'].get('actuator', {})
            lines.append('| {} | {} | {:.0f} | {:.0f} | {} | {} |'.format(
                i + 1, cond, act.get('release_p99_us', float('nan')),
                act.get('response_p99_us', float('nan')),
                sum(t['deadline_misses'] for t in run['tasks'].values()), len(run['dumps'])))
    return '\n'.join(lines) + '\n'


def main(argv: Sequence[str] | None = None) -> int:
    """Run the rounds, print and write the summary; return the exit code."""
    ap = argparse.ArgumentParser(prog='flightrec_bench', description=__doc__.split('\n\n')[0])
    ap.add_argument('--rounds', type=int, default=3)
    ap.add_argument('--window-s', type=float, default=30.0)
    ap.add_argument('--warmup-s', type=float, default=5.0)
    ap.add_argument('--results', default=os.path.join('docs', 'results', 'flightrec'))
    ap.add_argument('--logs', help="keep each run's bringup log in this directory")
    args = rosargs.parse_args(ap, argv)
    if args.rounds < 1 or not args.window_s >= 5.0 or not args.warmup_s >= 0.0:
        ap.error('need --rounds >= 1, --window-s >= 5, --warmup-s >= 0')
    env = dict(os.environ)
    env.setdefault('ROS_DOMAIN_ID', str(random.randint(1, 200)))
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    os.environ.update(env)
    rounds = []
    for i in range(args.rounds):
        order = (True, False) if i % 2 == 0 else (False, True)
        r = {}
        for enabled in order:
            res = run_once(enabled, args.window_s, args.warmup_s, env, keep_logs=args.logs)
            r['on' if enabled else 'off'] = res
            act = res['tasks'].get('actuator', {})
            print('round {} flight recorder {}: actuator release p99 {:.0f} us, response p99 '
                  '{:.0f} us, dumps {}'.format(i + 1, 'on' if enabled else 'off',
                                               act.get('release_p99_us', float('nan')),
                                               act.get('response_p99_us', float('nan')),
                                               len(res['dumps'])), flush=True)
        rounds.append(r)
    doc = {'command': 'python -m m4k_bench.flightrec_bench --rounds {} --window-s {:g}'.format(
               args.rounds, args.window_s),
           'provenance': provenance.provenance(), 'window_s': args.window_s,
           'rounds': rounds, 'ratios': summarize(rounds)}
    results.write_json(os.path.join(args.results, 'summary.json'), doc, indent=1)
    results.write_text(os.path.join(args.results, 'README.md'), _readme(doc))
    print(_readme(doc))
    return 0


if __name__ == '__main__':
    sys.exit(main())
