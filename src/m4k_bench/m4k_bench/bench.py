"""bench: the paper's evidence in one run (``make bench``, ``make bench QUICK=1``).

Sets itself up (cyclictest from rt-tests, stress-ng: installed with apt-get when missing and
root, else it says what to install), then, with a progress display:

1. Table 1 -- the full stack on simulated devices (rt_core + driver_host) for ``--duration``
   seconds: per task period / response / release latency avg, max, min, std, p50, p99, p99.9,
   overruns, deadline misses, mode-switch analogue counters (Markdown + CSV);
2. the utilization test (measured worst-case response / period, total, Liu-Layland bound,
   verdict) and exact response-time analysis; the RT process's CPU share;
3. Fig. 10 -- the actuator task's periodicity: m4k idle, m4k under stress-ng, the plain-ROS
   baseline (``baseline``: the same control in an rclpy timer) idle and under stress-ng;
4. cyclictest at the actuator's period and priority in the same conditions, run right before
   the m4k run of each condition; the ratios;
5. the XDDP round trip vs a raw Unix-socket ping-pong; cmd_vel -> WHEEL_CMD latency.

Writes ``results/<UTC timestamp>/`` (report.md, PNGs, raw CSVs, summary.json) and points
``results/latest`` at it. Targets are a benchmark's, not a test's: the report says plainly
which are met and which are not, and why.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import random
import shutil
import sys
import tempfile
from typing import Any, Sequence

import numpy as np

from m4k_bench.benchlib import analysis, plots, report, stack, system
from m4k_bench.benchlib import progress as progress_mod

__all__ = ['main', 'plan_durations']

ACTUATOR = 'actuator'
PERIOD_NS = 10_000_000
PRIORITY = 90
# Samples released in the first second of every run are left out of the statistics (and
# reported separately): threads starting, first-touch page faults, DDS discovery, first calls.
WARMUP_S = 1.0

FULL = {'table1_s': 180.0, 'condition_s': 60.0, 'rtt_n': 5000, 'cmd_trials': 100}
QUICK = {'table1_s': 15.0, 'condition_s': 8.0, 'rtt_n': 1000, 'cmd_trials': 15}
PHASES = ('cyclictest_idle', 'table1', 'alone', 'baseline_idle', 'cyclictest_stress',
          'm4k_stress', 'baseline_stress', 'rtt', 'cmdlat')


def plan_durations(quick: bool, duration: float | None,
                   condition: float | None) -> dict[str, Any]:
    """Return the run plan: Table 1 seconds, per-condition seconds, RTT count, trials."""
    plan = dict(QUICK if quick else FULL)
    if duration is not None:
        if not duration > 0:
            raise ValueError('--duration must be > 0 s, got {!r}'.format(duration))
        plan['table1_s'] = float(duration)
        plan['condition_s'] = min(plan['condition_s'], float(duration))
    if condition is not None:
        if not condition > 0:
            raise ValueError('--condition-duration must be > 0 s, got {!r}'.format(condition))
        plan['condition_s'] = float(condition)
    return plan


def _parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog='bench', description=__doc__.splitlines()[0])
    ap.add_argument('--quick', action='store_true',
                    help='smoke run: {table1_s:g} s Table 1, {condition_s:g} s per condition '
                    '(about 2 minutes)'.format(**QUICK))
    ap.add_argument('--duration', type=float, default=None,
                    help='Table 1 run in seconds (default {:g}; also caps each condition)'
                    .format(FULL['table1_s']))
    ap.add_argument('--condition-duration', type=float, default=None,
                    help='seconds per Fig. 10 / cyclictest condition (default {:g})'.format(
                        FULL['condition_s']))
    ap.add_argument('--rtt-n', type=int, default=None,
                    help='round trips per transport (default {:g}, quick {:g})'.format(
                        FULL['rtt_n'], QUICK['rtt_n']))
    ap.add_argument('--cmd-trials', type=int, default=None,
                    help='cmd_vel latency trials (default {:g}, quick {:g})'.format(
                        FULL['cmd_trials'], QUICK['cmd_trials']))
    ap.add_argument('--rt-config', default=None, metavar='FILE',
                    help='config overlay for rt_core in every m4k run (e.g. CPU pinning)')
    ap.add_argument('--results', default='results', help='results root directory')
    ap.add_argument('--skip', default='', help='comma list of phases to skip: ' +
                    ', '.join(PHASES))
    ap.add_argument('--no-install', action='store_true',
                    help='do not apt-get install missing rt-tests / stress-ng')
    args = ap.parse_args(argv)
    unknown = sorted(set(filter(None, args.skip.split(','))) - set(PHASES))
    if unknown:
        ap.error('--skip: unknown phase(s) {!r}; valid: {}'.format(unknown, ', '.join(PHASES)))
    try:
        args.plan = plan_durations(args.quick, args.duration, args.condition_duration)
    except ValueError as exc:
        ap.error(str(exc))
    for key in ('rtt_n', 'cmd_trials'):
        value = getattr(args, key)
        if value is not None:
            if value < 1:
                ap.error('--{} must be >= 1, got {!r}'.format(key.replace('_', '-'), value))
            args.plan[key] = value
    return args


def _actuator_periods(rows: Any) -> np.ndarray:
    """Return consecutive-cycle periods (ns) of (t_rel, t_start, exp) arrays."""
    rel, start, exp = (np.asarray(a, dtype=np.int64) for a in rows)
    if rel.size < 2:
        return np.empty(0, dtype=np.int64)
    consecutive = np.diff(rel) == exp[1:] * PERIOD_NS
    return np.diff(start)[consecutive]


def _link_latest(root: str, outdir: str) -> None:
    link = os.path.join(root, 'latest')
    tmp = link + '.tmp'
    if os.path.lexists(tmp):
        os.unlink(tmp)
    os.symlink(os.path.basename(outdir), tmp)
    os.replace(tmp, link)


class Bench:
    """One bench run: the phases, their results, the summary."""

    def __init__(self, args: argparse.Namespace) -> None:
        """Create the results directory and the private runtime directory."""
        self.args = args
        self.plan = args.plan
        self.skip = set(filter(None, args.skip.split(',')))
        now = datetime.datetime.now(datetime.timezone.utc)
        self.stamp = now.strftime('%Y%m%dT%H%M%SZ')
        os.makedirs(args.results, exist_ok=True)
        self.outdir = os.path.join(args.results, self.stamp)
        n = 1
        while os.path.exists(self.outdir):
            n += 1
            self.outdir = os.path.join(args.results, '{}-{}'.format(self.stamp, n))
        os.makedirs(os.path.join(self.outdir, 'raw'))
        self.logs = os.path.join(self.outdir, 'logs')
        self.tmp = tempfile.mkdtemp(prefix='m4k-bench-')
        self.env = dict(os.environ)
        # A private ROS graph: the bench's cmd_vel must not reach a robot stack running here.
        self.env.setdefault('ROS_DOMAIN_ID', str(random.randint(101, 160)))
        self.env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
        os.environ.update({k: self.env[k] for k in ('ROS_DOMAIN_ID',
                                                    'ROS_AUTOMATIC_DISCOVERY_RANGE')})
        steps = len([p for p in PHASES if p not in self.skip]) + 2
        self.progress = progress_mod.Progress(steps)
        self.periods: dict[str, np.ndarray] = {}
        self.summ: dict[str, Any] = {
            'schema': 1,
            'run': {'started_utc': now.isoformat(timespec='seconds'),
                    'mode': 'quick' if args.quick else 'full',
                    'table1_s': self.plan['table1_s'], 'condition_s': self.plan['condition_s'],
                    'reproduce': 'make bench' + (' QUICK=1' if args.quick else '') + (
                        ' DURATION={:g}'.format(args.duration) if args.duration else '')
                    if not args.rt_config else 'bench {}--rt-config {}'.format(
                        '--quick ' if args.quick else '', args.rt_config),
                    'rt_config': args.rt_config,
                    'results_dir': self.outdir},
            'conditions': {}, 'cyclictest': {}, 'skipped': {}, 'notes': [], 'files': [],
            'warmup': {'seconds': WARMUP_S},
        }

    # -- helpers ------------------------------------------------------------------------------
    def _note(self, text: str) -> None:
        self.summ['notes'].append(text)
        self.progress.log(text)

    def _rundir(self, name: str) -> str:
        return os.path.join(self.tmp, name)

    def _m4k(self, cond: str, seconds: float, *, tasks: str | None = None,
             keep_table1: bool = False) -> None:
        run = stack.run_m4k(seconds + WARMUP_S, self._rundir(cond), self.logs, cond,
                            tasks=tasks, driver_host=self.has_host, env=self.env,
                            progress=self.progress.update, rt_config=self.args.rt_config)
        for e in run.errors:
            self._note('{}: {}'.format(cond, e))
        self.summ['warmup'][cond] = analysis.trim_warmup(run.recorder.tasks.values(),
                                                         int(WARMUP_S * 1e9))
        if tasks is None:
            self.summ.setdefault('interference', {})[cond] = analysis.interference(
                run.recorder.tasks, ACTUATOR)
        paths = run.recorder.write(os.path.join(self.outdir, 'raw', cond))
        self.summ['files'] += [os.path.relpath(p, self.outdir) for p in paths.values()]
        summ = run.recorder.summary()
        act = next((t for t in summ['tasks'] if t['name'] == ACTUATOR), None)
        if act is None:
            self.summ['skipped'][cond] = 'no actuator samples received'
            return
        self.summ['conditions'][cond] = act
        series = run.recorder.tasks[ACTUATOR]
        self.periods[cond] = _actuator_periods((series.t_rel, series.t_start,
                                                series.expirations))
        if keep_table1:
            self.summ['table1'] = summ
            self.summ['rt_cpu_percent'] = run.cpu_percent
            self.summ['rt_cpu_window_s'] = run.cpu_window_s
            self.summ['commands_sent'] = run.commands_sent
            self.summ['odometry_received'] = run.odometry_received

    def _baseline(self, cond: str, seconds: float) -> None:
        csv_path = os.path.join(self.outdir, 'raw', cond + '.csv')
        res = stack.run_baseline(seconds + WARMUP_S, csv_path, self.logs, cond, env=self.env,
                                 progress=self.progress.update)
        if not res['csv']:
            self.summ['skipped'][cond] = 'baseline wrote no timing (exit {}): {}'.format(
                res['exit'], ' | '.join(res['log_tail']))
            self._note(self.summ['skipped'][cond])
            return
        self.summ['files'].append(os.path.relpath(csv_path, self.outdir))
        rows = analysis.load_samples_csv(csv_path).get('baseline', [])
        series = analysis.series_from_rows('baseline', PERIOD_NS, rows)
        self.summ['warmup'][cond] = analysis.trim_warmup([series], int(WARMUP_S * 1e9))
        c = analysis.condition_summary(series)
        if c is None:
            self.summ['skipped'][cond] = 'baseline recorded no callbacks'
            return
        self.summ['conditions'][cond] = c
        self.periods[cond] = _actuator_periods((series.t_rel, series.t_start,
                                                series.expirations))

    def _cyclictest(self, cond: str, seconds: float) -> None:
        from m4k_bench import core_bench
        res = core_bench.run_cyclictest(seconds, priority=PRIORITY,
                                        interval_us=PERIOD_NS // 1000)
        if res is None or 'error' in res:
            why = 'cyclictest missing' if res is None else res['error']
            self.summ['cyclictest'][cond] = {'error': why}
            self.summ['cyclictest']['error'] = why
            return
        self.summ['cyclictest']['command'] = res.pop('command', '')
        self.summ['cyclictest'][cond] = {'latency_us': res}

    # -- the run ------------------------------------------------------------------------------
    def run(self) -> int:
        """Run every phase not skipped; write the results; return the exit code."""
        p = self.progress
        plan = self.plan
        p.phase('set-up: tools and machine')
        tools = system.ensure_tools(self.progress.log, install=not self.args.no_install)
        self.summ['machine'] = system.machine_info()
        busy = system.busy_note(self.summ['machine'])
        if busy:
            self._note(busy)
        self.summ['tools'] = tools
        self.has_host = stack.module_available('m4k_drivers.host')
        if not self.has_host:
            self._note('m4k_drivers.host is not installed: m4k runs without the driver host')
        has_ct = tools.get('cyclictest') is not None
        has_stress = tools.get('stress-ng') is not None
        cond_s = plan['condition_s']
        run_s = cond_s + WARMUP_S + 2.0    # what a run takes, start-up and wind-down included
        stress_cmd = ' '.join(['stress-ng', *system.STRESS_ARGS, '--timeout', '<run>s'])
        self.summ['stress_command'] = stress_cmd
        try:
            if 'cyclictest_idle' not in self.skip:
                p.phase('cyclictest idle (prio {}, 10 ms)'.format(PRIORITY), cond_s)
                if has_ct:
                    self._cyclictest('idle', cond_s)
            if 'table1' not in self.skip:
                p.phase('Table 1: full stack, idle', plan['table1_s'] + WARMUP_S + 2.0)
                self._m4k('m4k_idle', plan['table1_s'], keep_table1=True)
            if 'alone' not in self.skip:
                p.phase('actuator task alone, idle', run_s)
                self._m4k('m4k_alone', cond_s, tasks=ACTUATOR)
            if 'baseline_idle' not in self.skip:
                p.phase('plain-ROS baseline, idle', run_s)
                self._baseline('baseline_idle', cond_s)
            for phase, label, fn in (
                    ('cyclictest_stress', 'cyclictest under stress-ng',
                     lambda: self._cyclictest('stress', cond_s) if has_ct else None),
                    ('m4k_stress', 'full stack under stress-ng',
                     lambda: self._m4k('m4k_stress', cond_s)),
                    ('baseline_stress', 'plain-ROS baseline under stress-ng',
                     lambda: self._baseline('baseline_stress', cond_s))):
                if phase in self.skip:
                    continue
                p.phase(label, run_s)
                if not has_stress:
                    self.summ['skipped'][phase] = 'stress-ng missing'
                    continue
                with system.Stress(tools['stress-ng'], cond_s + 60.0):
                    fn()
            if 'rtt' not in self.skip:
                p.phase('XDDP round trip vs raw socket ({} each)'.format(plan['rtt_n']))
                self._rtt(plan['rtt_n'])
            if 'cmdlat' not in self.skip:
                p.phase('cmd_vel -> WHEEL_CMD latency ({} trials)'.format(plan['cmd_trials']))
                self._cmdlat(plan['cmd_trials'])
        finally:
            shutil.rmtree(self.tmp, ignore_errors=True)
        p.phase('analysis, plots, report')
        self._finish()
        p.done('bench: results in {} (report.md, summary.json)'.format(self.outdir))
        return 0

    def _rtt(self, n: int) -> None:
        from m4k_bench import xddp_bench
        try:
            self.summ['xddp_rtt'] = xddp_bench.run_rtt(n, self._rundir('rtt'))
        except (OSError, RuntimeError) as exc:
            self.summ['xddp_rtt'] = {'error': str(exc)}
            self._note('XDDP round trip failed: {}'.format(exc))

    def _cmdlat(self, trials: int) -> None:
        from m4k_bench.benchlib import cmdlat
        try:
            res = cmdlat.run_cmd_latency(trials, self._rundir('cmdlat'), self.logs, env=self.env,
                                         progress=self.progress.update)
        except (OSError, RuntimeError, ImportError) as exc:
            res = {'error': '{}: {}'.format(type(exc).__name__, exc)}
        samples = res.pop('samples_ns', None)
        if samples:
            path = os.path.join(self.outdir, 'raw', 'cmd_latency.csv')
            with open(path, 'w', encoding='utf-8') as f:
                f.write('trial,to_cycle_ns,to_probe_ns\n')
                for i, (a, b) in enumerate(zip(samples['to_cycle'], samples['to_probe'],
                                               strict=True)):
                    f.write('{},{},{}\n'.format(i, a, b))
            self.summ['files'].append(os.path.relpath(path, self.outdir))
        if res.get('error'):
            self._note('cmd_vel latency: {}'.format(res['error']))
        self.summ['cmd_latency'] = res

    def _finish(self) -> None:
        s = self.summ
        s['ratios'] = analysis.compute_ratios(s)
        for key, val in s['ratios'].items():
            if val is None:
                s['skipped'].setdefault(key, 'an input of this ratio was not measured')
        s['targets'] = analysis.evaluate_targets(s)
        if self.periods:
            plots.fig10(self.periods, PERIOD_NS, os.path.join(self.outdir,
                                                               'fig10_periodicity.png'))
            s['files'].append('fig10_periodicity.png')
            for cond, per in self.periods.items():
                path = os.path.join(self.outdir, 'raw', 'periods_{}.csv'.format(cond))
                np.savetxt(path, per, fmt='%d', header='period_ns', comments='')
                s['files'].append(os.path.relpath(path, self.outdir))
        s['method'] = [
            'm4k runs: `rt_core` (+ `driver_host`, sim backends) in a private runtime dir; the '
            'bench is the NRT peer of `status` (TASK_STATS recorded with '
            '`m4k_rt.recorder.Recorder`) and of `cmd` (VELOCITY_CMD at 20 Hz: 0.25 m/s '
            'forward 4 s, back 4 s).',
            'Baseline runs: `baseline` (m4k_bench.baseline), the same controller and motor '
            'handler in a 10 ms rclpy timer (steady clock, SCHED_OTHER), the same velocity '
            'profile published on cmd_vel; per-callback timing written as CSV at exit.',
            'Stress: `{}` (CPU on both vCPUs, 256 MiB memory thrasher, sync I/O) started '
            '1 s before and stopped right after each stressed run.'.format(
                s.get('stress_command', '')),
            'rt_cpu_percent: utime + stime of the rt_core process from /proc/<pid>/stat, from '
            'the first TASK_STATS batch until the end of the Table 1 run, over that wall time.',
            'five_tasks_over_alone_p99: actuator release latency p99 in the Table 1 run over '
            'the same in `rt_core --tasks actuator`.',
            'Every run lasts its nominal duration plus {:g} s; samples released in that first '
            'second are excluded from all statistics (raw CSVs keep everything for the '
            'baseline; the m4k samples.csv files are written after the trim).'.format(WARMUP_S),
            'ROS isolation: ROS_DOMAIN_ID={}, localhost discovery.'.format(
                self.env.get('ROS_DOMAIN_ID')),
        ]
        s['files'] = sorted(set(s['files']) | {'report.md', 'summary.json'})
        with open(os.path.join(self.outdir, 'summary.json'), 'w', encoding='utf-8') as f:
            json.dump(s, f, indent=2, default=str)
            f.write('\n')
        with open(os.path.join(self.outdir, 'report.md'), 'w', encoding='utf-8') as f:
            f.write(report.render(s))
        _link_latest(self.args.results, self.outdir)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the bench; return 0 when it produced a report."""
    args = _parse_args(argv)
    return Bench(args).run()


if __name__ == '__main__':
    sys.exit(main())
