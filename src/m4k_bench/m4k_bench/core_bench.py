"""core_bench: measure how periodic a 10 ms Python RT task is, alone and in the task set.

One run prints, side by side (ratios in one run matter on a noisy VM, absolute numbers less):

1. the ``actuator`` task (10 ms, prio 90) of ``rt_core --echo`` alone: release latency and
   periodicity jitter p50/p99/p99.9/max;
2. the same task with the full five-task set (echo bodies, NRT echo peers in this process);
3. ``cyclictest -m -p 90 -i 10000`` for the same time, as the C baseline;
4. the XDDP round trip (:func:`m4k_bench.xddp_bench.run_rtt`) when available;
5. the per-cycle cost of the task machinery itself (timer bookkeeping, ring, rusage);
6. the cycle breakdown of every task of the set (:mod:`m4k_rt.cycleprof`, one more run of
   the echo set with the profile on): wake, drain + decode, control, encode + send, record,
   rusage, in µs per cycle.

``run()`` returns everything as a dict for the full bench tool. This is a benchmark, not a test.
"""

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from typing import Any, cast, Sequence

import numpy as np

from m4k_bench import recorder
from m4k_bench.benchlib import results
from m4k_bench.echo_peer import EchoPeer
from m4k_bringup.child import Child, Output, Stopping
from m4k_rt import channel, config, cycleprof, rosargs, timing
from m4k_rt.task import RtTask
from m4k_rt.timerfd import TimerFd

__all__ = ['machinery_overhead', 'main', 'parse_cyclictest_hist', 'run', 'run_core',
           'run_cyclictest']

CYCLICTEST = '/usr/bin/cyclictest'
WARMUP_CYCLES = 1  # a task's first cycle runs every code path for the first time


def run_core(duration_s: float, runtime_dir: str, task_names: list[str] | None,
             focus: str = 'actuator', profile: bool = False) -> dict[str, Any]:
    """Run ``rt_core --echo`` for ``duration_s`` with echo peers; return the focus task's stats.

    ``profile``: rt_core times the parts of every cycle; the breakdown is ``cycle_profile``.
    """
    cfg = config.load()
    chosen = [t for t in cfg.tasks if task_names is None or t.name in task_names]
    labels = [lb for t in chosen if t.body != 'monitor' for lb in t.ports]
    argv = [sys.executable, '-m', 'm4k_rt.rt_core', '--echo', '--duration', str(duration_s)]
    if task_names:
        argv += ['--tasks', ','.join(task_names)]
    env = dict(os.environ, M4K_RUNTIME_DIR=runtime_dir)
    prof_path = os.path.join(os.path.dirname(runtime_dir), 'cycle_profile.json')
    if profile:
        env[cycleprof.ENV] = prof_path
    rec = recorder.Recorder(warmup_cycles=WARMUP_CYCLES)
    with EchoPeer(labels, runtime_dir):
        link = channel.NrtLink('status', runtime_dir, retry_interval=0.05)
        child = Child('rt_core', argv, env,
                      output=Output(pipes=('stderr',), log_path=os.devnull, log_header=False),
                      stopping=Stopping(timeout=10.0)).start()
        proc = child.proc
        assert proc is not None and proc.stderr is not None  # stderr piped
        try:
            while child.alive():
                data = link.read(0.2)
                if data:
                    rec.feed(data)
            while True:  # the final batch, shipped after the tasks stopped
                data = link.read(0.5)
                if not data:
                    break
                rec.feed(data)
            err = proc.stderr.read()
        finally:
            child.stop()          # SIGTERM, 10 s, SIGKILL; closes the pipe
            link.close()
    summ = rec.summary()
    focus_t = next((t for t in summ['tasks'] if t['name'] == focus), None)
    prof = None
    if profile and os.path.exists(prof_path):
        with open(prof_path, encoding='utf-8') as f:
            prof = json.load(f)
    return {'tasks': [t['name'] for t in summ['tasks']], 'exit_code': child.returncode,
            'cycle_profile': prof,
            'focus': focus, 'latency_us': focus_t and focus_t['latency_us'],
            'jitter_us': focus_t and focus_t['jitter_us'],
            'response_us': focus_t and focus_t['response_us'],
            'overruns': focus_t and focus_t['overruns'],
            'nvcsw_extra': focus_t and focus_t['nvcsw_extra'],
            'summary': summ, 'stderr_tail': err.strip().splitlines()[-8:]}


def parse_cyclictest_hist(text: str) -> dict[str, Any]:
    """Parse a cyclictest ``-h`` histogram (one thread) into µs percentiles and max."""
    bins: list[tuple[int, int]] = []
    stats: dict[str, int] = {}
    for line in text.splitlines():
        m = re.match(r'#\s*(Min|Avg|Max) Latencies:\s*(\d+)', line)
        if m:
            stats[m.group(1).lower()] = int(m.group(2))
            continue
        m = re.match(r'#\s*Histogram Overflows:\s*(\d+)', line)
        if m:
            stats['overflows'] = int(m.group(1))
            continue
        if line.startswith('#') or not line.strip():
            continue
        parts = line.split()
        if len(parts) >= 2 and parts[0].isdigit() and parts[1].isdigit():
            bins.append((int(parts[0]), int(parts[1])))
    total = sum(c for _, c in bins) + stats.get('overflows', 0)
    out: dict[str, Any] = {'n': total, 'min': stats.get('min'), 'avg': stats.get('avg'),
                           'max': stats.get('max'), 'overflows': stats.get('overflows', 0)}
    for name, q in (('p50', 0.5), ('p99', 0.99), ('p999', 0.999)):
        target, acc, val = q * total, 0, None
        for us, c in bins:
            acc += c
            if acc >= target and c:
                val = us
                break
        out[name] = val if val is not None else stats.get('max')
    return out


def run_cyclictest(duration_s: float, priority: int = 90,
                   interval_us: int = 10_000) -> dict[str, Any] | None:
    """Run cyclictest at the task's period and priority; None when it is not installed."""
    exe = CYCLICTEST if os.path.exists(CYCLICTEST) else shutil.which('cyclictest')
    if not exe:
        return None
    loops = max(1, int(duration_s * 1e6 / interval_us))
    with tempfile.NamedTemporaryFile('r', suffix='.hist') as hist:
        cmd = [exe, '-m', '-p', str(priority), '-i', str(interval_us), '-l', str(loops), '-q',
               '-h', '20000', '--histfile={}'.format(hist.name)]
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=duration_s + 60,
                             check=False)
        if res.returncode != 0:
            return {'error': res.stderr.strip() or 'exit {}'.format(res.returncode)}
        out = parse_cyclictest_hist(open(hist.name).read())
    out['command'] = ' '.join(cmd[:-1])
    return out


def machinery_overhead(n: int = 100_000) -> dict[str, float]:
    """Measure the per-cycle cost of RtTask's bookkeeping (clock, ring, rusage), in µs.

    The timer read is replaced by a stub so only the Python work of a cycle is timed.
    """
    class _Stub:
        closed = False

        def read(self) -> int:
            return 1

    t = RtTask('bench', 1, 1_000_000, lambda ctx: None, ring_capacity=1024)
    t._tfd = cast(TimerFd, _Stub())  # noqa: SLF001 -- deliberate: bypass the kernel wait
    t.rusage.start()
    per = np.empty(5)
    for k in range(per.size):
        t0 = time.perf_counter_ns()
        for _ in range(n // per.size):
            t.wait_period()
        per[k] = (time.perf_counter_ns() - t0) / (n // per.size)
    return {'per_cycle_us_min': float(per.min()) / 1e3,
            'per_cycle_us_median': float(np.median(per)) / 1e3}


def run(duration_s: float = 10.0, rtt_n: int = 2000) -> dict[str, Any]:
    """Run every part of the benchmark; return the results dict."""
    base = tempfile.mkdtemp(prefix='m4k-bench-')
    rdir = os.path.join(base, 'm4k')
    try:
        res: dict[str, Any] = {'duration_s': duration_s}
        res['alone'] = run_core(duration_s, rdir, ['actuator'])
        res['full_set'] = run_core(duration_s, rdir, None)
        res['breakdown'] = run_core(duration_s, rdir, None, profile=True)['cycle_profile']
        res['cyclictest'] = run_cyclictest(duration_s)
        try:
            from m4k_bench import xddp_bench
        except ImportError:
            res['xddp_rtt'] = None
        else:
            res['xddp_rtt'] = xddp_bench.run_rtt(rtt_n, os.path.join(base, 'rtt'))
        res['machinery'] = machinery_overhead()
        res['liu_layland_bound_5'] = timing.liu_layland_bound(5)
        return res
    finally:
        shutil.rmtree(base, ignore_errors=True)


def _row(label: str, lat: dict | None, jit: dict | None) -> str:
    def f(d: dict | None, k: str) -> str:
        v = None if d is None else d.get(k)
        return '{:>8.1f}'.format(v) if isinstance(v, (int, float)) else '{:>8}'.format('-')
    return '{:<34}{}{}{}{}  |{}{}{}{}'.format(
        label, f(lat, 'p50'), f(lat, 'p99'), f(lat, 'p999'), f(lat, 'max'),
        f(jit, 'p50'), f(jit, 'p99'), f(jit, 'p999'), f(jit, 'max'))


def format_report(res: dict[str, Any]) -> str:
    """Format the results as a text table."""
    lines = ['10 ms task, {:g} s per run (us; first {} cycle(s) of each task excluded as '
             'warm-up)'.format(res['duration_s'], WARMUP_CYCLES),
             '{:<34}{:>8}{:>8}{:>8}{:>8}  |{:>8}{:>8}{:>8}{:>8}'.format(
                 'release latency / jitter', 'p50', 'p99', 'p99.9', 'max',
                 'p50', 'p99', 'p99.9', 'max')]
    for key, label in (('alone', 'm4k actuator alone'), ('full_set', 'm4k actuator, 5-task set')):
        r = res[key]
        lines.append(_row(label, r['latency_us'], r['jitter_us']))
    ct = res['cyclictest']
    if ct is None:
        lines.append('cyclictest: not installed ({} missing)'.format(CYCLICTEST))
    elif 'error' in ct:
        lines.append('cyclictest failed: {}'.format(ct['error']))
    else:
        lines.append(_row('cyclictest -m -p90 -i10000', ct, None))
    for key in ('alone', 'full_set'):
        r = res[key]
        if r['response_us']:
            lines.append('{}: response p50 {:.1f} us max {:.1f} us, overruns {}, csw vol+ {}, '
                         'rt_core exit {}'.format(key, r['response_us']['p50'],
                                                  r['response_us']['max'], r['overruns'],
                                                  r['nvcsw_extra'], r['exit_code']))
    u = res['full_set']['summary'].get('utilization')
    if u:
        lines.append('5-task set: utilization {:.2f} % (Liu-Layland bound {:.1f} %): {}'.format(
            u['total'] * 100, u['liu_layland_bound'] * 100, u['verdict']))
    rtt = res.get('xddp_rtt')
    if rtt is None:
        lines.append('XDDP round trip: m4k_bench.xddp_bench not available')
    else:
        x = rtt['xddp']
        lines.append('XDDP round trip (us): ' + ', '.join(
            '{} {:.1f}'.format(k, v) for k, v in x.items() if isinstance(v, (int, float))))
    m = res['machinery']
    lines.append('task machinery per cycle: {:.2f} us (median of 5 runs; min {:.2f})'.format(
        m['per_cycle_us_median'], m['per_cycle_us_min']))
    lines += format_breakdown(res.get('breakdown'))
    return '\n'.join(lines) + '\n'


def format_breakdown(prof: dict[str, Any] | None) -> list[str]:
    """Format an rt_core cycle profile (``m4k_rt.cycleprof``) as a table, µs per cycle."""
    if not prof or not prof.get('tasks'):
        return ['cycle breakdown: not measured']
    cols = (*cycleprof.PARTS, 'thread CPU')
    lines = ['cycle breakdown, echo bodies (us per cycle; wake = thread CPU - timed parts; '
             'echo bodies receive and send without the timed port readers/writers, so their '
             'I/O is in control; the robot bodies: bench, "Cycle breakdown")',
             '{:<10}'.format('task') + ''.join('{:>11}'.format(c) for c in cols)]
    for name, t in prof['tasks'].items():
        parts = t.get('parts_us') or {}
        vals = [parts.get(k) for k in cycleprof.PARTS] + [t.get('thread_cpu_per_cycle_us')]
        lines.append('{:<10}'.format(name) + ''.join(
            '{:>11.1f}'.format(v) if isinstance(v, (int, float)) else '{:>11}'.format('-')
            for v in vals))
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark, print the table, optionally write JSON."""
    ap = argparse.ArgumentParser(prog='core_bench', description=__doc__.splitlines()[0])
    ap.add_argument('--duration', type=float, default=10.0, help='seconds per run')
    ap.add_argument('--rtt', type=int, default=2000, help='XDDP round trips')
    ap.add_argument('--json', metavar='FILE', help='also write the results dict as JSON')
    args = rosargs.parse_args(ap, argv)
    res = run(args.duration, args.rtt)
    sys.stdout.write(format_report(res))
    if args.json:
        results.write_json(args.json, res)
    return 0


if __name__ == '__main__':
    sys.exit(main())
