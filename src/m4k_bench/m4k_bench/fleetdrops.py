"""fleetdrops: the driver host's wheel-command drops per 10 000 in the three-robot fleet.

    python -m m4k_bench.fleetdrops [--runs 3] [--duration 60] [--publish DIR]

Per run: three robots started as docs/nav2.md ("Several robots") starts them -- ``recipes
--robot rN --out DIR`` then ``bringup --robot rN --bridge-params DIR/nav2/nav2_params.yaml``,
each with its own runtime directory (its own simulated world, RT core and driver host) --
on this machine, on one ROS domain with localhost discovery. Once every robot's bridge
reports its motor port linked (``/rN/rt_status``), all three are driven over ``/rN/cmd_vel``
for ``--duration`` s (r1 forward and back, r2 turning, r3 a slow creep:
:func:`m4k_bench.benchlib.fleetagg.command`), with a progress line; then every bringup gets
SIGTERM (its ordered stop: bridge, driver host, rt_core, sim_robot) and each robot's driver
host log is read (:mod:`m4k_bench.benchlib.hostdrops`): motor drops per 10 000 per robot and
pooled, host's own apart from the simulation's, by reason; the RT side's send-side drops from
the last ``rt_status`` of each robot. Also recorded: the 1-min load average at the end of the
drive, the share of the machine's CPUs busy during it, and the cores each stack's processes
used -- three stacks need more than two cores, which is the point of the condition.

Localhost rather than network namespaces (test_fleet): the drops are a matter of CPU
scheduling, which namespaces do not change; localhost needs no root and runs inside ``make
bench``. ``make bench`` runs it once per round as the ``fleet_idle`` condition.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import random
import shutil
import signal
import sys
import tempfile
import threading
import time
from typing import Any, Callable, Sequence

from m4k_bench.benchlib import fleetagg, hostdrops, results
from m4k_bringup.child import Child, Output, Stopping
from m4k_rt import rosargs

__all__ = ['main', 'run_fleet']

START_TIMEOUT_S = 300.0     # three stacks starting on two shared cores
STOP_TIMEOUT_S = 60.0       # bringup's own ordered stop gives each child 8 s
CMD_PERIOD_S = 0.05         # 20 Hz, as the bench's commander
PUBLISH_DIR = os.path.join('docs', 'results', 'fleet-drops')
PLAIN_EVERY_S = 10.0        # progress lines when stderr is no terminal
SETTLE_S = 3.0              # standing still before the stop (> the host's 1 s drop-line period)


def _busy_ticks() -> tuple[int, int]:
    """Return (busy, total) jiffies of all CPUs (/proc/stat)."""
    with open('/proc/stat', encoding='ascii') as f:
        vals = [int(x) for x in f.readline().split()[1:]]
    idle = vals[3] + (vals[4] if len(vals) > 4 else 0)
    return sum(vals) - idle, sum(vals)


def _tree(root: int) -> dict[int, tuple[float, str]]:
    """Return pid -> (CPU seconds, state letter) of ``root`` and every descendant (one scan)."""
    parent: dict[int, int] = {}
    seen: dict[int, tuple[float, str]] = {}
    tck = os.sysconf('SC_CLK_TCK')
    for name in os.listdir('/proc'):
        if not name.isdigit():
            continue
        try:
            with open('/proc/{}/stat'.format(name), 'rb') as f:
                stat = f.read()
        except OSError:
            continue
        fields = stat[stat.rfind(b')') + 2:].split()
        parent[int(name)] = int(fields[1])
        seen[int(name)] = ((int(fields[11]) + int(fields[12])) / tck, fields[0].decode())
    out, todo = {}, [root]
    while todo:
        pid = todo.pop()
        if pid in seen:
            out[pid] = seen[pid]
        todo += [p for p, pp in parent.items() if pp == pid]
    return out


def _tree_cpu(root: int) -> dict[int, float]:
    """Return pid -> CPU seconds of ``root`` and every descendant."""
    return {pid: cpu for pid, (cpu, _) in _tree(root).items()}


def _tree_states(root: int) -> str:
    """Return what ``root`` and its descendants are doing: 'pid state wchan command' each.

    Taken when a bringup has not stopped in time, before the SIGKILL: which of its children
    it still waits for, and where each sleeps.
    """
    rows = []
    for pid, (_, state) in sorted(_tree(root).items()):
        try:
            with open('/proc/{}/wchan'.format(pid), encoding='ascii', errors='replace') as f:
                wchan = f.read().strip() or '-'
            with open('/proc/{}/cmdline'.format(pid), 'rb') as f:
                cmd = f.read().replace(b'\0', b' ').decode(errors='replace').strip()
        except OSError:
            continue
        rows.append('{} {} {} {}'.format(pid, state, wchan, cmd[:100]))
    return '; '.join(rows)


class _Ros:
    """One rclpy node: a cmd_vel publisher and an rt_status subscription per robot."""

    def __init__(self, robots: Sequence[str]) -> None:
        from geometry_msgs.msg import Twist
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        from m4k_msgs.msg import RtStatus

        self.ctx = Context()
        rclpy.init(context=self.ctx, args=[])
        self.node = rclpy.create_node('m4k_fleetdrops', context=self.ctx)
        self.twist = Twist
        self.pubs = {r: self.node.create_publisher(Twist, '/{}/cmd_vel'.format(r), 10)
                     for r in robots}
        self.motor: dict[str, Any] = {}      # robot -> its latest motor XddpPort
        for r in robots:
            self.node.create_subscription(RtStatus, '/{}/rt_status'.format(r),
                                          self._on_status(r), 10)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, name='fleet-ros', daemon=True)
        self.thread.start()

    def _on_status(self, robot: str) -> Callable[[Any], None]:
        def on(msg: Any) -> None:
            for p in msg.ports:
                if p.label == 'motor':
                    self.motor[robot] = p
        return on

    def _spin(self) -> None:
        while not self.stop.is_set():
            self.ex.spin_once(timeout_sec=0.1)

    def linked(self, robot: str) -> bool:
        p = self.motor.get(robot)
        return p is not None and bool(p.linked)

    def send(self, robot: str, v: float, w: float) -> None:
        msg = self.twist()
        msg.linear.x, msg.angular.z = float(v), float(w)
        self.pubs[robot].publish(msg)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5.0)
        self.ex.shutdown()
        self.node.destroy_node()
        self.ctx.try_shutdown()


def _start_robot(robot: str, work: str, log_dir: str, env: dict[str, str], tag: str) -> Child:
    """Write the robot's recipes and start its bringup as docs/nav2.md says."""
    from m4k_bringup import bringup, recipes
    rdir = os.path.join(work, 'recipes-' + robot)
    with contextlib.redirect_stdout(io.StringIO()):     # it lists the files it wrote
        code = recipes.main(['--robot', robot, '--out', rdir])
    if code != 0:
        raise RuntimeError('recipes --robot {} failed'.format(robot))
    rt = os.path.join(work, 'rt-' + robot)
    os.makedirs(rt, mode=0o700)
    argv = bringup.bringup_argv() + ['--no-status', '--robot', robot, '--bridge-params',
                                     os.path.join(rdir, 'nav2', 'nav2_params.yaml')]
    return Child('{}.{}'.format(tag, robot), argv,
                 # XDG_STATE_HOME: the flight recorder's dumps (a guard stop) go to the run's
                 # directory, never rotating the user's own out of ~/.local/state/m4k
                 dict(env, M4K_RUNTIME_DIR=rt, PYTHONUNBUFFERED='1',
                      XDG_STATE_HOME=os.path.join(work, 'state-' + robot)),
                 output=Output(log_path=os.path.join(log_dir, '{}.{}.log'.format(tag, robot))),
                 stopping=Stopping(sig=signal.SIGTERM, timeout=STOP_TIMEOUT_S,
                                   must_end=True)).start()


def run_fleet(duration_s: float, log_dir: str, *, env: dict[str, str] | None = None,
              tag: str = 'fleet', robots: Sequence[str] = fleetagg.ROBOTS,
              progress: Callable[[str], None] | None = None,
              start_timeout_s: float = START_TIMEOUT_S) -> dict[str, Any]:
    """Run the fleet once: start, drive ``duration_s``, stop, read the drops. Return a dict.

    ``env`` must carry the ROS domain (ROS_DOMAIN_ID, localhost discovery) the fleet is to use;
    this process's rclpy node joins it too.
    """
    env = dict(env or os.environ)
    os.environ.update({k: env[k] for k in ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE')
                       if k in env})
    os.makedirs(log_dir, exist_ok=True)
    work = tempfile.mkdtemp(prefix='m4k-fleet-')    # short: Unix sockets live there
    out: dict[str, Any] = {'robots': list(robots), 'duration_s': duration_s, 'errors': [],
                           'work_dir': work}
    kids: dict[str, Child] = {}
    ros: _Ros | None = None
    rt_ports: dict[str, Any] = {}
    t_begin = time.monotonic()
    out['load_before'] = _loadavg()[0]     # what else ran here (the 1-min average)
    try:
        ros = _Ros(robots)
        for r in robots:
            kids[r] = _start_robot(r, work, log_dir, env, tag)
        while not all(ros.linked(r) for r in robots):
            dead = [r for r, k in kids.items() if not k.alive()]
            if dead or time.monotonic() - t_begin > start_timeout_s:
                out['errors'].append('not up within {:.0f} s: {}'.format(
                    time.monotonic() - t_begin, ', '.join(
                        '{}{}'.format(r, ' (exited)' if r in dead else '')
                        for r in robots if not ros.linked(r))))
                return out
            if progress is not None:
                progress('starting: {} of {} motor ports linked'.format(
                    sum(ros.linked(r) for r in robots), len(robots)))
            time.sleep(0.5)
        out['start_s'] = time.monotonic() - t_begin
        cpu0 = {r: _tree_cpu(k.pid) for r, k in kids.items()}
        busy0, all0 = _busy_ticks()
        sent = dict.fromkeys(robots, 0)
        out['cmd_vel_sent'] = sent
        t0 = time.monotonic()
        out['drive_utc'] = [time.time()]       # to place a drop line of the logs in or out
        nxt = t0
        note = t0
        while (now := time.monotonic()) - t0 < duration_s:
            for r in robots:
                ros.send(r, *fleetagg.command(r, now - t0))
                sent[r] += 1
            if progress is not None and now >= note:
                note = now + 1.0
                progress('driving {:.0f}/{:.0f} s, load {}'.format(
                    now - t0, duration_s, _loadavg()[0]))
            dead = [r for r, k in kids.items() if not k.alive()]
            if dead:
                out['errors'].append('bringup of {} exited while driving'.format(dead))
                break
            nxt += CMD_PERIOD_S
            time.sleep(max(0.0, nxt - time.monotonic()))
        wall = time.monotonic() - t0
        busy1, all1 = _busy_ticks()
        cpu1 = {r: _tree_cpu(k.pid) for r, k in kids.items()}
        cores = {r: sum(v - cpu0[r].get(p, 0.0) for p, v in cpu1[r].items()) / wall
                 for r in robots}
        load1, load5, _ = _loadavg()
        out['drive_s'] = wall
        out['drive_utc'].append(time.time())
        out['load'] = {'load_1min': load1, 'load_5min': load5, 'cpus': os.cpu_count(),
                       'busy_percent': 100.0 * (busy1 - busy0) / max(1, all1 - all0),
                       'stack_cores': cores, 'stacks_cores': sum(cores.values())}
        # Still, then a pause longer than the host's drop-line period (1 s) before the stop:
        # every drop while driving is logged before the stop signal, the stop's own after it.
        settle = time.monotonic() + SETTLE_S
        while time.monotonic() < settle:
            for r in robots:
                ros.send(r, 0.0, 0.0)
                sent[r] += 1
            time.sleep(CMD_PERIOD_S)
        rt_ports = dict(ros.motor)
        out['stop_utc'] = time.time()
    finally:
        _stop_all(kids, out)
        if ros is not None:
            ros.close()
        shutil.rmtree(work, ignore_errors=True)
    host, running, bridge = {}, {}, {}
    stop_utc = out.get('stop_utc', time.time())
    for r in robots:
        try:
            with open(os.path.join(log_dir, '{}.{}.log'.format(tag, r)), encoding='utf-8',
                      errors='replace') as f:
                text = f.read()
        except OSError:
            text = ''
        host[r] = fleetagg.device_totals(text)
        running[r] = fleetagg.device_totals(fleetagg.before(text, stop_utc))
        bridge[r] = dict(fleetagg.bridge_counts(text),
                         cmd_vel_sent=out.get('cmd_vel_sent', {}).get(r, 0))
    out['bridge'] = bridge
    out['drops'] = fleetagg.run_summary(host, {r: hostdrops.rt_side(rt_ports.get(r))
                                               for r in robots}, running)
    return out


def _stop_all(kids: dict[str, Child], out: dict[str, Any]) -> None:
    """SIGTERM every bringup at once, then wait for each (its ordered stop)."""
    for k in kids.values():
        if k.alive():
            k.send_signal(signal.SIGTERM)
    for r, k in kids.items():
        stuck: list[str] = []

        def snapshot(_timeout: float, pid: int = k.pid, stuck: list[str] = stuck) -> None:
            stuck.append(_tree_states(pid))
        code = k.stop(on_escalate=snapshot)
        if code not in (0, -signal.SIGTERM, None):
            out['errors'].append('bringup {} exited {}{}: {}'.format(
                r, code, ' (still running at the kill: {})'.format(stuck[0]) if stuck else '',
                ' | '.join(k.tail(12))))


def _loadavg() -> tuple[float, float, float]:
    with open('/proc/loadavg', encoding='ascii') as f:
        a, b, c = (float(x) for x in f.read().split()[:3])
    return a, b, c


def _parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog='fleetdrops', description=__doc__.splitlines()[0])
    ap.add_argument('--runs', type=int, default=3, help='runs (default %(default)s)')
    ap.add_argument('--duration', type=float, default=60.0,
                    help='seconds of driving per run (default %(default)s)')
    ap.add_argument('--results', default='results', help='results root directory')
    ap.add_argument('--publish', default='', metavar='DIR',
                    help='also copy report.md and summary.json to DIR (e.g. {})'.format(
                        PUBLISH_DIR))
    ap.add_argument('--robots', default=','.join(fleetagg.ROBOTS), metavar='R,R',
                    help='the robots to run (default %(default)s; one robot alone: the CPU '
                    'one stack takes when it has the machine)')
    args = rosargs.parse_args(ap, argv)
    if args.runs < 1 or not args.duration > 0:
        ap.error('--runs must be >= 1 and --duration > 0')
    args.robots = tuple(r for r in args.robots.split(',') if r)
    unknown = set(args.robots) - set(fleetagg.ROBOTS)
    if unknown or not args.robots:
        ap.error('--robots: a comma list of {}, got {!r}'.format(
            ', '.join(fleetagg.ROBOTS), ','.join(sorted(unknown)) or args.robots))
    return args


METHOD = [
    'Each robot as docs/nav2.md starts one of several: `recipes --robot rN --out DIR`, then '
    '`bringup --robot rN --bridge-params DIR/nav2/nav2_params.yaml` with its own '
    'M4K_RUNTIME_DIR (own simulated world, RT core, driver host, bridge); no Nav2 nodes. '
    'All three on this machine, one ROS domain, localhost discovery.',
    'Driving starts once every robot reports its motor port linked on /rN/rt_status: r1 '
    '±0.25 m/s (2 s each way: 0.5 m, short of the guard before the obstacle 1.5 m ahead), r2 '
    '0.6 rad/s on the spot, r3 ±0.05 m/s, at 20 Hz.',
    "Drops: each robot's driver host log (`motor: drops served=N <reason>=k ...`, the last "
    'line of every host process); the counters cover the whole life of the stack, start-up '
    "and stop included. `stale_device` is the simulation's share (sim_robot answering late "
    "over the sim bus); the other reasons are the host's own. Pooled = the three robots' "
    'counters summed. After the drive the robots stand still for {:g} s, then every bringup '
    'gets SIGTERM; drops logged after that are the stop\'s ("at the stop"), and "before the '
    'stop signal" is the rate without them, over the same commands.'.format(SETTLE_S),
    "RT side: the motor port's counters in each robot's last rt_status before the stop "
    '(queue full, no host linked).',
    'Bridge: the cmd_vel messages this tool sent each robot (drive and standstill), those its '
    'bridge dropped as processed more than cmd_vel_timeout after they arrived (cmd_vel_late, '
    "a starved bridge), and the collision guard's stops (the flight recorder's guard_stop "
    'dumps): upstream of the wheel commands, not in the drop rates above.',
    "CPU: /proc/stat busy share of all CPUs over the drive; each stack's cores = CPU seconds "
    'of its bringup and every descendant over the drive ÷ its wall time.',
]


def main(argv: Sequence[str] | None = None) -> int:
    """Run the fleet ``--runs`` times; write report.md and summary.json; return 0 if all ran."""
    args = _parse_args(argv)
    env = dict(os.environ)
    env.setdefault('ROS_DOMAIN_ID', str(random.randint(101, 160)))
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    started = time.strftime('%Y-%m-%dT%H:%M:%S', time.gmtime())
    outdir = results.stamped_dir(os.path.join(args.results, 'fleet-drops'))
    logs = os.path.join(outdir, 'logs')
    runs = []
    for i in range(args.runs):
        head = 'fleetdrops run {}/{}: '.format(i + 1, args.runs)

        shown = [0.0]

        def show(note: str, head: str = head, shown: list[float] = shown) -> None:
            # one redrawn line on a terminal; in a log, a line every PLAIN_EVERY_S
            if sys.stderr.isatty():
                sys.stderr.write('\r\x1b[K' + head + note)
            elif time.monotonic() - shown[0] >= PLAIN_EVERY_S:
                shown[0] = time.monotonic()
                sys.stderr.write(head + note + '\n')
            sys.stderr.flush()
        res = run_fleet(args.duration, logs, env=env, tag='run{}'.format(i + 1),
                        robots=args.robots, progress=show)
        pooled = (res.get('drops') or {}).get('pooled') or {}
        sys.stderr.write('\n{}{} host + {} sim per 10 000 ({} of {}), load {}{}\n'.format(
            head, fleetagg._f(pooled.get('host_per_10k')),
            fleetagg._f(pooled.get('sim_per_10k')), pooled.get('dropped'),
            pooled.get('commands'), (res.get('load') or {}).get('load_1min'),
            ''.join('; ' + e for e in res['errors'])))
        runs.append(res)
    doc = {'command': 'python -m m4k_bench.fleetdrops --runs {} --duration {:g}{}'.format(
        args.runs, args.duration, '' if args.robots == fleetagg.ROBOTS
        else ' --robots ' + ','.join(args.robots)), 'started_utc': started,
        'duration_s': args.duration,
        'ros_domain_id': env['ROS_DOMAIN_ID'], 'runs': runs,
        'summary': fleetagg.summarize(runs), 'method': METHOD,
        'notes': [e for r in runs for e in r['errors']]}
    doc = results.write_json(os.path.join(outdir, 'summary.json'), doc)
    results.write_text(os.path.join(outdir, 'report.md'), fleetagg.render(doc))
    sys.stderr.write('fleetdrops: results in {}\n'.format(outdir))
    if args.publish:
        for name in ('report.md', 'summary.json'):
            os.makedirs(args.publish, exist_ok=True)
            shutil.copy2(os.path.join(outdir, name), os.path.join(args.publish, name))
    return 0 if all(not r['errors'] for r in runs) else 1


if __name__ == '__main__':
    sys.exit(main())
