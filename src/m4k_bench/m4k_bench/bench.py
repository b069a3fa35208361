"""bench: the paper's evidence in repeated rounds (``make bench``, ``make bench QUICK=1``).

Sets itself up (cyclictest from rt-tests, stress-ng: installed with apt-get when missing and
root, else it says what to install), holds ``/dev/cpu_dma_latency`` at 0 µs for the whole run
(every condition gets the same treatment), then runs, with a progress display:

1. **rounds** (5, 3 with ``--quick``), the order of the conditions reversed every other round:
   the Python floor (bare SCHED_FIFO timerfd loops at the task set's rates), cyclictest alone
   idle, m4k full stack idle, the actuator alone, the plain-ROS baseline idle, then under
   stress-ng: cyclictest alone, m4k, the baseline; the XDDP round trip on the tasks' receive
   path. Every m4k and baseline condition runs with cyclictest *concurrently*, at the
   actuator's period and priority. m4k conditions run end to end: cmd_vel over DDS -> bridge
   -> XDDP -> actuator (+ driver_host on simulated devices). Both executives run side by side
   (issue 42): the frame executive idle and under stress-ng, and a fault-injected slow sonar
   body under each (``m4k_bench.slowbody``), with the floors in the frame's structure too; every
   m4k run reports the driver host's wheel-command drops per 10 000 by reason
   (``benchlib.hostdrops``), and a condition whose cyclictest reference shows the host
   stalling gives no verdict (``benchlib.validity``). One more full-stack run per round
   has rt_core's cycle profile on (``m4k_rt.cycleprof``): the per-task breakdown of a cycle
   (wake, drain + decode, control, encode + send, timing record, rusage) in the report;
2. **scaling**, in every round (the rates reversed every other round): the actuator alone and
   with the task set at 100, 250, 500 and 1000 Hz, each with cyclictest at the same rate;
3. cmd_vel -> WHEEL_CMD latency;
4. the guard's reaction (:mod:`m4k_bench.reaction`, also ``reaction`` alone): stop line crossed
   on ground truth -> first braking DAC word, on the simulator's clock (50 trials, 10 with
   ``--quick``), and the stopping distance at 0.5, 1.0 and 2.0 m/s against the physics.

Every ratio is computed per round and reported as the median with min-max over the rounds;
the verdict is on the median. The RT hardening rt_core obtained (RT_STATUS) is recorded per
run; a degraded run is labelled so and left out of the m4k ratios. A stall that sets a maximum
is checked against the concurrent cyclictest. Writes ``results/<UTC timestamp>/`` (report.md,
readme_snippet.md, rounds.json, summary.json, PNGs, raw per-round samples) and points
``results/latest`` at it; ``--publish DIR`` copies the report, JSON and figures there (a full
run publishes to docs/results/bench by default).
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
import threading
from typing import AbstractSet, Any, Callable, Sequence

import numpy as np

from m4k_bench.benchlib import (
    analysis,
    hostdrops,
    plots,
    report,
    results,
    rounds,
    stack,
    system,
)
from m4k_bench.benchlib import progress as progress_mod
from m4k_rt import config as rt_config_mod
from m4k_rt import cycleprof, rosargs

__all__ = ['main', 'plan_durations']

ACTUATOR = 'actuator'
PERIOD_NS = 10_000_000
PRIORITY = 90
# Samples released in the first second of every run are left out of the statistics (and
# reported separately): threads starting, first-touch page faults, DDS discovery, first calls.
WARMUP_S = 1.0
RATES_HZ = (100, 250, 500, 1000)
PUBLISH_DIR = os.path.join('docs', 'results', 'bench')

FULL = {'rounds': 5, 'condition_s': 30.0, 'floor_s': 10.0, 'scaling_s': 6.0, 'rtt_n': 2000,
        'cmd_trials': 60, 'reaction_trials': 50, 'reaction_speed_trials': 5}
QUICK = {'rounds': 3, 'condition_s': 6.0, 'floor_s': 4.0, 'scaling_s': 4.0, 'rtt_n': 500,
         'cmd_trials': 10, 'reaction_trials': 10, 'reaction_speed_trials': 2}
# One round, in this order (reversed every other round).
CONDITIONS = ('ct_idle', 'm4k_idle', 'm4k_frame_idle', 'm4k_live', 'm4k_alone', 'baseline_idle',
              'm4k_slow_threads', 'm4k_slow_frame',
              'fleet_idle', 'ct_stress', 'm4k_stress', 'm4k_frame_stress', 'baseline_stress')
# The three-robot fleet (m4k_bench.fleetdrops) beyond the condition's seconds: three stacks
# starting (7-8 s measured on two shared cores), the 3 s standstill, the stop.
FLEET_START_S = 15.0
# The executives side by side (m4k_rt.frame): the frame conditions run the same stack with
# runtime.executive: frame. The slow conditions inject a body overrun (m4k_bench.slowbody).
FRAME_OVERLAY = {'runtime': {'executive': 'frame'}}
SLOW_BODY = 'sonar:15:10'       # the sonar body spins 15 ms of CPU every 10th cycle (0.3 s)
SCALING_TARGET_HZ = 1000   # the scaling target's rate (analysis.TARGETS)
PHASES = ('floor', *CONDITIONS, 'floor_paired', 'breakdown', 'rtt', 'scaling', 'cmdlat',
          'reaction')


def plan_durations(quick: bool, duration: float | None, condition: float | None,
                   nrounds: int | None = None) -> dict[str, Any]:
    """Return the run plan: rounds, seconds per condition / floor / scaling run, counts."""
    plan = dict(QUICK if quick else FULL)
    for key, value in (('condition_s', duration), ('condition_s', condition)):
        if value is not None:
            if not value > 0:
                raise ValueError('durations must be > 0 s, got {!r}'.format(value))
            plan[key] = float(value)
    if nrounds is not None:
        if nrounds < 1:
            raise ValueError('--rounds must be >= 1, got {!r}'.format(nrounds))
        plan['rounds'] = nrounds
    return plan


def estimate_s(plan: dict[str, Any], skip: AbstractSet[str] = frozenset()) -> float:
    """Return a rough wall-time estimate of the plan (start-up of each run included)."""
    per_cond = plan['condition_s'] + WARMUP_S + 5.0
    per_round = sum(per_cond for c in CONDITIONS if c not in skip)
    per_round += 0 if 'fleet_idle' in skip else FLEET_START_S
    # the bare floor and the channel floors
    per_round += 0 if 'floor' in skip else \
        (3 + len(analysis.CHANNEL_FLOORS)) * (plan['floor_s'] + 2.0)
    per_round += 0 if 'breakdown' in skip else per_cond
    per_round += 0 if 'floor_paired' in skip else per_cond
    per_round += 0 if 'rtt' in skip else plan['rtt_n'] * 2 * 1e-4 + 2.0
    per_round += 0 if 'scaling' in skip else 2 * len(RATES_HZ) * (
        plan['scaling_s'] + WARMUP_S + 5) + plan['scaling_s'] + 3
    total = plan['rounds'] * per_round
    total += 0 if 'cmdlat' in skip else plan['cmd_trials'] * 0.4 + 10.0
    total += 0 if 'reaction' in skip else plan['reaction_trials'] * 2.5 + 2 * plan[
        'reaction_speed_trials'] * 6.0 + 30.0
    return total


def _parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog='bench', description=__doc__.splitlines()[0])
    ap.add_argument('--quick', action='store_true',
                    help='{rounds} rounds of {condition_s:g} s per condition'.format(**QUICK))
    ap.add_argument('--duration', type=float, default=None,
                    help='seconds per condition (default {:g}, quick {:g})'.format(
                        FULL['condition_s'], QUICK['condition_s']))
    ap.add_argument('--condition-duration', type=float, default=None,
                    help='same as --duration (kept for old command lines)')
    ap.add_argument('--rounds', type=int, default=None,
                    help='rounds (default {}, quick {})'.format(FULL['rounds'],
                                                                QUICK['rounds']))
    ap.add_argument('--rtt-n', type=int, default=None,
                    help='round trips per transport and round (default {:g}, quick {:g})'
                    .format(FULL['rtt_n'], QUICK['rtt_n']))
    ap.add_argument('--cmd-trials', type=int, default=None,
                    help='cmd_vel latency trials (default {:g}, quick {:g})'.format(
                        FULL['cmd_trials'], QUICK['cmd_trials']))
    ap.add_argument('--reaction-trials', type=int, default=None,
                    help='guard reaction trials at the first speed (default {:g}, quick {:g})'
                    .format(FULL['reaction_trials'], QUICK['reaction_trials']))
    ap.add_argument('--reaction-speed-trials', type=int, default=None,
                    help='guard reaction trials at each higher speed (default {:g}, quick {:g})'
                    .format(FULL['reaction_speed_trials'], QUICK['reaction_speed_trials']))
    ap.add_argument('--rates', default=','.join(str(r) for r in RATES_HZ), metavar='HZ,HZ',
                    help='actuator rates of the scaling phase (default %(default)s)')
    ap.add_argument('--rt-config', default=None, metavar='FILE',
                    help='config overlay for rt_core in every m4k run (e.g. CPU pinning)')
    ap.add_argument('--results', default='results', help='results root directory')
    ap.add_argument('--publish', default=None, metavar='DIR',
                    help='also copy report, JSON and figures to DIR (default for a full run: '
                    '{}; "" to skip)'.format(PUBLISH_DIR))
    ap.add_argument('--skip', default='', help='comma list of phases to skip: ' +
                    ', '.join(PHASES))
    ap.add_argument('--only', default='', help='comma list of the phases to run (every other '
                    'one skipped; not published unless --publish says where), e.g. cmdlat')
    ap.add_argument('--no-install', action='store_true',
                    help='do not apt-get install missing rt-tests / stress-ng')
    args = rosargs.parse_args(ap, argv)
    for opt in ('skip', 'only'):
        unknown = sorted(set(filter(None, getattr(args, opt).split(','))) - set(PHASES))
        if unknown:
            ap.error('--{}: unknown phase(s) {!r}; valid: {}'.format(opt, unknown,
                                                                    ', '.join(PHASES)))
    if args.only:
        if args.skip:
            ap.error('--only and --skip: give one of them')
        only = set(filter(None, args.only.split(',')))
        args.skip = ','.join(ph for ph in PHASES if ph not in only)
        if args.publish is None:        # a part of the bench is not the bench's results
            args.publish = ''
    try:
        args.plan = plan_durations(args.quick, args.duration, args.condition_duration,
                                   args.rounds)
    except ValueError as exc:
        ap.error(str(exc))
    for key in ('rtt_n', 'cmd_trials', 'reaction_trials', 'reaction_speed_trials'):
        value = getattr(args, key)
        if value is not None:
            if value < 1:
                ap.error('--{} must be >= 1, got {!r}'.format(key.replace('_', '-'), value))
            args.plan[key] = value
    try:
        args.rates_hz = tuple(int(r) for r in args.rates.split(',') if r)
    except ValueError:
        ap.error('--rates: expected a comma list of integers, got {!r}'.format(args.rates))
    if not args.rates_hz or min(args.rates_hz) < 1 or max(args.rates_hz) > 2000:
        ap.error('--rates: every rate must be 1..2000 Hz, got {!r}'.format(args.rates))
    if args.publish is None:
        args.publish = '' if args.quick else PUBLISH_DIR
    return args


def _periods(series: Any) -> np.ndarray:
    """Return consecutive-cycle periods (ns) of a TaskSeries."""
    rel, start, exp = (np.asarray(a, dtype=np.int64) for a in (
        series.t_rel, series.t_start, series.expirations))
    if rel.size < 2:
        return np.empty(0, dtype=np.int64)
    consecutive = np.diff(rel) == exp[1:] * series.period_ns
    return np.diff(start)[consecutive]


def _read_json(path: str) -> Any:
    try:
        with open(path, encoding='utf-8') as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def _link_latest(root: str, outdir: str) -> None:
    link = os.path.join(root, 'latest')
    tmp = link + '.tmp'
    if os.path.lexists(tmp):
        os.unlink(tmp)
    os.symlink(os.path.basename(outdir), tmp)
    os.replace(tmp, link)


def _both(a: Callable[[], None], b: Callable[[], None]) -> Callable[[], None]:
    """Return a callable that calls ``a`` then ``b``."""
    def call() -> None:
        a()
        b()
    return call


class _FloorBeside:
    """The Python floor in a thread, started with the measured run (``seconds`` 0: off).

    Run beside the stack and the concurrent cyclictest, the floor pays for the same co-load
    as rt_core does in the same window, so the loop-cost ratio compares like with like.
    """

    def __init__(self, bench: 'Bench', seconds: float, probe: bool = False) -> None:
        self.bench = bench
        self.seconds = seconds
        self.probe = probe
        self.result: dict[str, Any] | None = None
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        if self.seconds <= 0 or self._thread is not None:
            return
        self._thread = threading.Thread(target=self._run, name='bench-floor', daemon=True)
        self._thread.start()

    def _run(self) -> None:
        self.result = self.bench._floor(self.seconds, self.probe)

    def join(self) -> dict[str, Any] | None:
        if self._thread is not None:
            self._thread.join(self.seconds + 90.0)
        return self.result


class _Concurrent:
    """cyclictest in a thread, started by ``start()`` (called when the measured run starts)."""

    def __init__(self, seconds: float, interval_us: int, enabled: bool) -> None:
        self.seconds = seconds
        self.interval_us = interval_us
        self.enabled = enabled
        self.result: dict[str, Any] | None = None
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        if not self.enabled or self._thread is not None:
            return
        self._thread = threading.Thread(target=self._run, name='bench-cyclictest', daemon=True)
        self._thread.start()

    def _run(self) -> None:
        from m4k_bench import core_bench
        self.result = core_bench.run_cyclictest(self.seconds, priority=PRIORITY,
                                                interval_us=self.interval_us)

    def join(self) -> dict[str, Any] | None:
        if self._thread is not None:
            self._thread.join(self.seconds + 90.0)
        r = self.result
        if r is None:
            return None
        if 'error' in r:
            return {'error': r['error']}
        return {k: v for k, v in r.items() if k != 'command'}


class Bench:
    """One bench run: rounds, scaling, the summary."""

    def __init__(self, args: argparse.Namespace) -> None:
        """Create the results directory and the private runtime directory."""
        self.args = args
        self.plan = args.plan
        self.skip = set(filter(None, args.skip.split(',')))
        now = datetime.datetime.now(datetime.timezone.utc)
        self.stamp = results.stamp(now)
        self.outdir = results.stamped_dir(args.results, when=self.stamp)
        os.makedirs(os.path.join(self.outdir, 'raw'))
        self.logs = os.path.join(self.outdir, 'logs')
        self.tmp = tempfile.mkdtemp(prefix='m4k-bench-')
        self.env = dict(os.environ)
        # A private ROS graph: the bench's cmd_vel must not reach a robot stack running here.
        self.env.setdefault('ROS_DOMAIN_ID', str(random.randint(101, 160)))
        self.env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
        os.environ.update({k: self.env[k] for k in ('ROS_DOMAIN_ID',
                                                    'ROS_AUTOMATIC_DISCOVERY_RANGE')})
        per_round = len([c for c in ('floor', *CONDITIONS, 'floor_paired', 'breakdown', 'rtt')
                         if c not in self.skip]) + (
            0 if 'floor' in self.skip else len(analysis.CHANNEL_FLOORS) + 2)
        per_round += 0 if 'scaling' in self.skip else 2 * len(args.rates_hz) + (
            SCALING_TARGET_HZ in args.rates_hz)
        steps = 2 + self.plan['rounds'] * per_round + (0 if 'cmdlat' in self.skip else 1) + (
            0 if 'reaction' in self.skip else 1)
        self.progress = progress_mod.Progress(steps)
        self.periods: dict[str, list[np.ndarray]] = {}
        self.tables: dict[str, Any] = {}          # per round: the m4k_idle recorder summary
        self.rounds: list[dict[str, Any]] = []
        self.summ: dict[str, Any] = {
            'schema': 2,
            'run': {'started_utc': now.isoformat(timespec='seconds'),
                    'mode': 'quick' if args.quick else 'full', 'plan': self.plan,
                    'estimate_s': estimate_s(self.plan, self.skip),
                    'reproduce': 'make bench' + (' QUICK=1' if args.quick else '') + (
                        ' DURATION={:g}'.format(args.duration) if args.duration else '')
                    if not args.rt_config else 'bench {}--rt-config {}'.format(
                        '--quick ' if args.quick else '', args.rt_config),
                    'rt_config': args.rt_config, 'results_dir': self.outdir},
            'skipped': {}, 'notes': [], 'files': [], 'warmup_s': WARMUP_S,
        }
        self.frame_tasks: tuple[str, ...] = ()
        self.task_rates = self._task_rates()

    # -- helpers ------------------------------------------------------------------------------
    def _note(self, text: str) -> None:
        self.summ['notes'].append(text)
        self.progress.log(text)

    def _rundir(self, name: str) -> str:
        return os.path.join(self.tmp, name)

    def _task_rates(self) -> dict[str, dict[str, Any]]:
        """Return the configured task set: name -> period (ns), priority, offset (ns), cpu."""
        try:
            cfg = rt_config_mod.load(self.args.rt_config)
        except Exception as exc:  # noqa: BLE001 -- reported; the floor is then skipped
            self._note('could not read the task set for the floor: {}'.format(exc))
            return {}
        self.frame_tasks = cfg.runtime.frame_tasks
        return {t.name: {'period_ns': t.period_ns, 'priority': t.priority,
                         'offset_ns': t.offset_ns, 'cpu': t.cpu}
                for t in cfg.tasks if t.enabled}

    def _executive_overlay(self, executive: str) -> str | None:
        """Return the rt_core --config for a run under ``executive`` (threads: the user's)."""
        if executive == 'threads':
            return self.args.rt_config
        return self._overlay(None, FRAME_OVERLAY, 'executive_frame.yaml')

    def _overlay(self, actuator_period_ms: float | None,
                 extra: dict[str, Any] | None = None, name: str = '') -> str | None:
        """Return the rt_core --config for a run: the user's overlay (+ actuator period)."""
        if actuator_period_ms is None and extra is None:
            return self.args.rt_config
        import yaml

        from m4k_rt import yamlload
        data: dict[str, Any] = {}
        if self.args.rt_config:
            with open(self.args.rt_config, encoding='utf-8') as f:
                data = yamlload.load(f) or {}
        if actuator_period_ms is not None:
            data = rt_config_mod.deep_merge(data, {'tasks': {ACTUATOR: {
                'period_ms': actuator_period_ms}}})
        if extra is not None:
            data = rt_config_mod.deep_merge(data, extra)
        path = os.path.join(self.tmp, name or 'actuator_{:g}ms.yaml'.format(
            actuator_period_ms or 0.0))
        with open(path, 'w', encoding='utf-8') as f:
            yaml.safe_dump(data, f)
        return path

    def _m4k(self, key: str, tag: str, seconds: float, *, tasks: str | None = None,
             period_ns: int = PERIOD_NS, with_ct: bool = True,
             rt_config: str | None = None, profile: bool = False,
             floor_beside: bool = False, probe: bool = False,
             live: bool = False, slow_body: str | None = None) -> dict[str, Any] | None:
        ct = _Concurrent(seconds + WARMUP_S, period_ns // 1000, with_ct and self.has_ct)
        fl = _FloorBeside(self, seconds if floor_beside else 0.0, probe)
        env = self.env
        if slow_body:   # fault injection: one task's body overruns now and then
            env = dict(env, M4K_BODY_MODULES='m4k_bench.slowbody', M4K_SLOW_BODY=slow_body)
        prof_path = os.path.join(self.outdir, 'raw', tag + '_cycle_profile.json')
        if profile:     # rt_core times the parts of every cycle (m4k_rt.cycleprof)
            env = dict(env, **{cycleprof.ENV: os.path.abspath(prof_path)})
        run = stack.run_m4k(seconds + WARMUP_S, self._rundir(tag), self.logs, tag, tasks=tasks,
                            driver_host=self.has_host, env=env,
                            progress=self.progress.update,
                            rt_config=rt_config if rt_config else self.args.rt_config,
                            on_started=_both(ct.start, fl.start), live=live)
        ct_res = ct.join()
        fl_res = fl.join()
        for e in run.errors:
            self._note('{}: {}'.format(tag, e))
        warm = analysis.trim_warmup(run.recorder.tasks.values(), int(WARMUP_S * 1e9))
        paths = run.recorder.write(os.path.join(self.outdir, 'raw', tag))
        self.summ['files'] += [os.path.relpath(p, self.outdir) for p in paths.values()]
        summ = run.recorder.summary()
        act = next((t for t in summ['tasks'] if t['name'] == ACTUATOR), None)
        if act is None:
            self.summ['skipped'][tag] = 'no actuator samples received'
            return None
        status = summ.get('rt_status')
        rates = [1e9 / (t['period_ms'] * 1e6) for t in summ['tasks'] if t['period_ms'] > 0]
        res = dict(act)
        if run.live_view is not None:
            res['live_view'] = run.live_view
        res.update(
            hardening=rounds.hardening_label(status),
            cyclictest=ct_res,
            cpu_percent=run.cpu_percent,
            cpu_per_cycle_us=rounds.cpu_per_cycle_us(run.cpu_s, run.cpu_window_s, rates),
            utilization={k: summ[k]['total'] for k in ('utilization', 'utilization_p999')
                         if k in summ},
            verdicts={k: summ[k]['verdict'] for k in ('utilization', 'utilization_p999')
                      if k in summ},
            warmup=warm,
            task_response_p50_us={t['name']: t['response_us']['p50'] for t in summ['tasks']},
            task_misses={t['name']: {'overruns': t['overruns'],
                                     'deadline_misses': t['deadline_misses']}
                         for t in summ['tasks']},
            interference=analysis.interference(run.recorder.tasks, ACTUATOR)
            if tasks is None else None,
        )
        res['stalls'] = self._stalls(res, ct_res, period_ns)
        # Wheel commands the driver host did not serve, by reason (m4k_drivers.host).
        res['host_drops'] = hostdrops.read(os.path.join(self.logs, tag + '.driver_host.log'))
        # ... and those lost before they reached it (the RT side's motor port counters)
        res['motor_port_drops'] = hostdrops.rt_side(run.recorder.port_stats.get('motor'))
        if floor_beside:
            res['floor'] = fl_res
        if profile:
            res['cycle_profile'] = _read_json(prof_path)
            if res['cycle_profile'] is None:
                self._note('{}: rt_core wrote no cycle profile'.format(tag))
            else:
                self.summ['files'].append(os.path.relpath(prof_path, self.outdir))
        if key == 'm4k_idle':
            self.tables[tag] = summ
        self.periods.setdefault(key, []).append(_periods(run.recorder.tasks[ACTUATOR]))
        return res

    @staticmethod
    def _stalls(res: dict[str, Any], ct: dict[str, Any] | None,
                period_ns: int) -> list[dict[str, Any]]:
        ct_max = ct.get('max') if ct else None
        out = []
        for metric in ('latency_us', 'response_us'):
            a = rounds.attribute_stall((res.get(metric) or {}).get('max'), ct_max,
                                       period_ns / 1e3)
            if a is not None:
                out.append(dict(a, metric=metric))
        return out

    def _baseline(self, key: str, tag: str, seconds: float) -> dict[str, Any] | None:
        csv_path = os.path.join(self.outdir, 'raw', tag + '.csv')
        ct = _Concurrent(seconds + WARMUP_S, PERIOD_NS // 1000, self.has_ct)
        res = stack.run_baseline(seconds + WARMUP_S, csv_path, self.logs, tag, env=self.env,
                                 progress=self.progress.update, on_started=ct.start)
        ct_res = ct.join()
        if not res['csv']:
            self.summ['skipped'][tag] = 'baseline wrote no timing (exit {}): {}'.format(
                res['exit'], ' | '.join(res['log_tail']))
            self._note(self.summ['skipped'][tag])
            return None
        self.summ['files'].append(os.path.relpath(csv_path, self.outdir))
        rows = analysis.load_samples_csv(csv_path).get('baseline', [])
        series = analysis.series_from_rows('baseline', PERIOD_NS, rows)
        warm = analysis.trim_warmup([series], int(WARMUP_S * 1e9))
        c = analysis.condition_summary(series)
        if c is None:
            self.summ['skipped'][tag] = 'baseline recorded no callbacks'
            return None
        c = dict(c, cyclictest=ct_res, warmup=warm)
        c['stalls'] = self._stalls(c, ct_res, PERIOD_NS)
        self.periods.setdefault(key, []).append(_periods(series))
        return c

    def _fleet(self, tag: str, seconds: float) -> dict[str, Any] | None:
        """Run the three-robot fleet (:mod:`m4k_bench.fleetdrops`): its drops and load."""
        if not self.has_host:
            self.summ['skipped'][tag] = 'm4k_drivers.host is not installed'
            return None
        from m4k_bench import fleetdrops
        res = fleetdrops.run_fleet(seconds, self.logs, env=self.env, tag=tag,
                                   progress=self.progress.update)
        for e in res['errors']:
            self._note('{}: {}'.format(tag, e))
        return res

    def _cyclictest_alone(self, seconds: float,
                          period_us: int = PERIOD_NS // 1000) -> dict[str, Any] | None:
        ct = _Concurrent(seconds, period_us, self.has_ct)
        ct.start()
        r = ct.join()
        return None if r is None else {'latency_us': r} if 'error' not in r else r

    def _floor(self, seconds: float, probe: bool = False,
               channel: str = 'none', frame: bool = False) -> dict[str, Any] | None:
        if not self.task_rates:
            return None
        from m4k_bench.benchlib import floor
        ts = list(self.task_rates.values())
        # frame: the frame executive's structure (its tasks in one thread, back to back)
        in_frame = [i for i, n in enumerate(self.task_rates) if n in self.frame_tasks] \
            if frame else []
        out = floor.run_floor_child([int(t['period_ns']) for t in ts],
                                    [int(t['priority']) for t in ts],
                                    [int(t['offset_ns']) for t in ts], seconds, self.env,
                                    probe=probe, channel=channel,
                                    cpus=[t['cpu'] for t in ts], frame=in_frame)
        if isinstance(out, str):
            self._note(out)
            return None
        return out

    def _rtt(self, n: int, tag: str) -> dict[str, Any] | None:
        from m4k_bench import xddp_bench
        try:
            return xddp_bench.run_rtt(n, self._rundir(tag))
        except (OSError, RuntimeError) as exc:
            self._note('XDDP round trip failed: {}'.format(exc))
            return None

    # -- the run ------------------------------------------------------------------------------
    def run(self) -> int:
        """Run every phase not skipped; write the results; return the exit code."""
        p = self.progress
        plan = self.plan
        p.phase('set-up: tools and machine (estimated run: {:.0f} min)'.format(
            self.summ['run']['estimate_s'] / 60.0))
        tools = system.ensure_tools(self.progress.log, install=not self.args.no_install)
        self.summ['machine'] = system.machine_info()
        busy = system.busy_note(self.summ['machine'])
        if busy:
            self._note(busy)
        self.summ['tools'] = tools
        self.has_host = stack.module_available('m4k_drivers.host')
        if not self.has_host:
            self._note('m4k_drivers.host is not installed: m4k runs without the driver host')
        self.has_ct = tools.get('cyclictest') is not None
        self.stress_bin = tools.get('stress-ng')
        self.summ['stress_command'] = ' '.join(
            ['stress-ng', *system.STRESS_ARGS, '--timeout', '<run>s'])
        try:
            with system.DmaLatency() as dma:
                self.summ['cpu_dma_latency'] = {'held': dma.held, 'error': dma.error}
                for k in range(plan['rounds']):
                    self._round(k)
                if 'cmdlat' not in self.skip:
                    p.phase('cmd_vel -> WHEEL_CMD latency ({} trials)'.format(
                        plan['cmd_trials']))
                    self._cmdlat(plan['cmd_trials'])
                if 'reaction' not in self.skip:
                    p.phase('guard reaction: stop line -> braking DAC word ({} trials)'.format(
                        plan['reaction_trials']))
                    self._reaction(plan['reaction_trials'], plan['reaction_speed_trials'])
        finally:
            shutil.rmtree(self.tmp, ignore_errors=True)
        p.phase('analysis, plots, report')
        self._finish()
        p.done('bench: results in {} (report.md, readme_snippet.md, summary.json)'.format(
            self.outdir))
        return 0

    def _round(self, k: int) -> None:
        p = self.progress
        plan = self.plan
        cond_s = plan['condition_s']
        run_s = cond_s + WARMUP_S + 3.0
        rnd: dict[str, Any] = {'round': k}
        self.rounds.append(rnd)
        order = list(CONDITIONS) if k % 2 == 0 else list(reversed(CONDITIONS))
        pre = 'round {}/{}: '.format(k + 1, plan['rounds'])
        if 'floor' not in self.skip:
            p.phase(pre + 'Python floor (bare timerfd loops)', plan['floor_s'] + 2.0)
            rnd['floor'] = self._floor(plan['floor_s'])
            # What the channel alone costs above the floor: its socket calls, or the same
            # datagrams through shared memory (floor.py --channel).
            for ch in analysis.CHANNEL_FLOORS:
                p.phase(pre + "Python floor + a task cycle's {} traffic".format(ch),
                        plan['floor_s'] + 2.0)
                rnd['floor_' + ch] = self._floor(plan['floor_s'], channel=ch)
            # The same two denominators in the frame executive's structure.
            for key, ch in (('floor_frame', 'none'), ('floor_frame_socket', 'socket')):
                p.phase(pre + 'Python floor, frame structure{}'.format(
                    '' if ch == 'none' else ' + socket traffic'), plan['floor_s'] + 2.0)
                rnd[key] = self._floor(plan['floor_s'], channel=ch, frame=True)
        runs: dict[str, tuple[str, Callable[[], Any]]] = {
            'ct_idle': ('cyclictest alone, idle', lambda: self._cyclictest_alone(cond_s)),
            'm4k_idle': ('m4k full stack, idle', lambda: self._m4k(
                'm4k_idle', 'r{}_m4k_idle'.format(k), cond_s)),
            'm4k_frame_idle': ('m4k full stack, frame executive, idle', lambda: self._m4k(
                'm4k_frame_idle', 'r{}_m4k_frame_idle'.format(k), cond_s,
                rt_config=self._executive_overlay('frame'))),
            'm4k_slow_threads': ('m4k full stack, a slow sonar body, thread per task',
                                 lambda: self._m4k('m4k_slow_threads',
                                                   'r{}_m4k_slow_threads'.format(k), cond_s,
                                                   slow_body=SLOW_BODY)),
            'm4k_slow_frame': ('m4k full stack, a slow sonar body, frame executive',
                               lambda: self._m4k('m4k_slow_frame', 'r{}_m4k_slow_frame'.format(k),
                                                 cond_s, slow_body=SLOW_BODY,
                                                 rt_config=self._executive_overlay('frame'))),
            'm4k_live': ('m4k full stack + live view with a viewer, idle', lambda: self._m4k(
                'm4k_live', 'r{}_m4k_live'.format(k), cond_s, live=True)),
            'm4k_alone': ('m4k actuator alone, idle', lambda: self._m4k(
                'm4k_alone', 'r{}_m4k_alone'.format(k), cond_s, tasks=ACTUATOR)),
            'baseline_idle': ('plain-ROS baseline, idle', lambda: self._baseline(
                'baseline_idle', 'r{}_baseline_idle'.format(k), cond_s)),
            'ct_stress': ('cyclictest alone, stress-ng', lambda: self._cyclictest_alone(cond_s)),
            'm4k_stress': ('m4k full stack, stress-ng', lambda: self._m4k(
                'm4k_stress', 'r{}_m4k_stress'.format(k), cond_s)),
            'm4k_frame_stress': ('m4k full stack, frame executive, stress-ng', lambda: self._m4k(
                'm4k_frame_stress', 'r{}_m4k_frame_stress'.format(k), cond_s,
                rt_config=self._executive_overlay('frame'))),
            'baseline_stress': ('plain-ROS baseline, stress-ng', lambda: self._baseline(
                'baseline_stress', 'r{}_baseline_stress'.format(k), cond_s)),
            'fleet_idle': ('three-robot fleet, all driven: wheel-command drops',
                           lambda: self._fleet('r{}_fleet'.format(k), cond_s)),
        }
        for cond in order:
            if cond in self.skip:
                continue
            label, fn = runs[cond]
            p.phase(pre + label, run_s + (FLEET_START_S if cond == 'fleet_idle' else 0.0))
            if cond.endswith('_stress'):
                if not self.stress_bin:
                    self.summ['skipped'][cond] = 'stress-ng missing'
                    continue
                with system.stress(self.stress_bin, run_s + 60.0):
                    rnd[cond] = fn()
            else:
                rnd[cond] = fn()
        if 'floor_paired' not in self.skip:
            p.phase(pre + 'm4k full stack, idle, with the Python floor beside it', run_s)
            rnd['m4k_floor_paired'] = self._m4k(
                'm4k_floor_paired', 'r{}_m4k_floor_paired'.format(k), cond_s, floor_beside=True)
        if 'breakdown' not in self.skip:
            p.phase(pre + 'm4k full stack, idle, cycle breakdown (profiled)', run_s)
            # A probed floor beside it: the cold/warm A-B of one decode inside a periodic
            # loop, next to the same stack (floor.py --probe).
            rnd['m4k_profiled'] = self._m4k('m4k_profiled', 'r{}_m4k_profiled'.format(k),
                                            cond_s, with_ct=False, profile=True,
                                            floor_beside=True, probe=True)
        if 'rtt' not in self.skip:
            p.phase(pre + "XDDP round trip, tasks' receive path ({} each)".format(
                plan['rtt_n']))
            rnd['rtt'] = self._rtt(plan['rtt_n'], 'r{}_rtt'.format(k))
        if 'scaling' not in self.skip:
            self._scaling(k)

    def _scaling(self, k: int) -> None:
        """Round ``k`` of the scaling sweep: every rate, alone and with the task set."""
        rows = self.summ.setdefault('scaling', [])
        s = self.plan['scaling_s']
        rates = list(self.args.rates_hz)
        if k % 2:
            rates.reverse()
        pre = 'round {}/{}: '.format(k + 1, self.plan['rounds'])
        for hz in rates:
            period_ms = 1000.0 / hz
            overlay = self._overlay(period_ms)
            # cyclictest alone at the target's rate, the same round: the stricter denominator
            ct_alone: dict[str, Any] = {}
            if hz == SCALING_TARGET_HZ:
                self.progress.phase(pre + 'scaling: cyclictest alone at {} Hz'.format(hz),
                                    s + 3.0)
                ct_alone = (self._cyclictest_alone(s, int(round(1e6 / hz))) or {}).get(
                    'latency_us') or {}
            for tasks, label in ((ACTUATOR, 'alone'), (None, 'task set')):
                self.progress.phase(pre + 'scaling: actuator at {} Hz, {}'.format(hz, label),
                                    s + WARMUP_S + 3.0)
                r = self._m4k('scaling', 'r{}_scale_{}hz_{}'.format(
                    k, hz, 'alone' if tasks else 'set'), s, tasks=tasks,
                    period_ns=int(round(1e9 / hz)), rt_config=overlay)
                ct = (r or {}).get('cyclictest') or {}
                lat = (r or {}).get('latency_us') or {}
                rows.append({'round': k, 'rate_hz': hz, 'set': label,
                             'release_p99_us': lat.get('p99'),
                             'release_p999_us': lat.get('p999'),
                             'cyclictest_p99_us': ct.get('p99'),
                             'ratio_p99': analysis.ratio(lat.get('p99'), ct.get('p99')),
                             'cyclictest_alone_p99_us': ct_alone.get('p99'),
                             'ratio_p99_alone': analysis.ratio(lat.get('p99'),
                                                               ct_alone.get('p99')),
                             'cpu_per_cycle_us': (r or {}).get('cpu_per_cycle_us'),
                             'overruns': (r or {}).get('overruns'),
                             'deadline_misses': (r or {}).get('deadline_misses'),
                             'hardening_ok': (r or {}).get('hardening', {}).get('ok')})
                row = rows[-1]
                both = (row['ratio_p99'], row['ratio_p99_alone'])
                row['ratio_p99_stricter'] = None if None in both else max(both)

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

    def _reaction(self, trials: int, speed_trials: int) -> None:
        from m4k_bench import reaction
        out = os.path.join(self.outdir, 'reaction')
        try:
            res = reaction.run_reaction(out, trials=trials, speed_trials=speed_trials,
                                        progress=self.progress.update, env=self.env)
            self.summ['files'] += [os.path.join('reaction', n) for n in (
                'reaction.md', 'reaction.json', 'reaction.csv', 'reaction.png')]
        except (OSError, RuntimeError, ImportError, ValueError) as exc:
            res = {'error': '{}: {}'.format(type(exc).__name__, exc)}
            self._note('guard reaction: {}'.format(res['error']))
        self.summ['reaction'] = res

    def _finish(self) -> None:
        s = self.summ
        s['rounds'] = self.rounds
        s['ratios'] = analysis.round_ratios(self.rounds)
        s['targets'] = analysis.evaluate_targets(s['ratios'], s.get('scaling') or [])
        s['loop_cost'] = analysis.loop_cost(self.rounds)
        s['table1_round'], s['table1'] = analysis.median_round_table(
            self.rounds, self.tables)
        try:
            from m4k_bench import core_bench
            from m4k_bench.benchlib import loopparts
            s['loop_cost']['bookkeeping_us'] = core_bench.machinery_overhead(20_000)
            s['loop_cost']['parts_us'] = loopparts.measure_parts(2000)
        except Exception as exc:  # noqa: BLE001 -- a part of the report, not the run
            s['loop_cost']['bookkeeping_us'] = {'error': str(exc)}
        periods = {k: np.concatenate(v) for k, v in self.periods.items()
                   if k in plots.COLORS and v}
        if periods:
            plots.fig10(periods, PERIOD_NS, os.path.join(self.outdir, 'fig10_periodicity.png'))
            s['files'].append('fig10_periodicity.png')
        if s.get('scaling'):
            plots.scaling(s['scaling'], os.path.join(self.outdir, 'scaling.png'))
            s['files'].append('scaling.png')
        s['method'] = report.method_lines(s, self.env.get('ROS_DOMAIN_ID'))
        s['files'] = sorted(set(s['files']) | {'report.md', 'summary.json', 'rounds.json',
                                               'readme_snippet.md'})
        with open(os.path.join(self.outdir, 'rounds.json'), 'w', encoding='utf-8') as f:
            json.dump(self.rounds, f, indent=1, default=str)   # a list of rounds, not a summary
            f.write('\n')
        s = results.write_json(os.path.join(self.outdir, 'summary.json'), s)
        with open(os.path.join(self.outdir, 'report.md'), 'w', encoding='utf-8') as f:
            f.write(report.render(s))
        with open(os.path.join(self.outdir, 'readme_snippet.md'), 'w', encoding='utf-8') as f:
            f.write(report.readme_snippet(s, self.args.publish or PUBLISH_DIR))
        _link_latest(self.args.results, self.outdir)
        if self.args.publish:
            os.makedirs(self.args.publish, exist_ok=True)
            for name in ('report.md', 'readme_snippet.md', 'summary.json', 'rounds.json',
                         'fig10_periodicity.png', 'scaling.png'):
                src = os.path.join(self.outdir, name)
                if os.path.exists(src):
                    shutil.copy2(src, os.path.join(self.args.publish, name))
            self.progress.log('published to {}'.format(self.args.publish))


def main(argv: Sequence[str] | None = None) -> int:
    """Run the bench; return 0 when it produced a report."""
    args = _parse_args(argv)
    return Bench(args).run()


if __name__ == '__main__':
    sys.exit(main())
