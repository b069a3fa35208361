"""fuzz: throw random and mutated datagrams at every XDDP port of the real rt_core process.

Benchmark-style (prints progress and counts; exit 0 only when every verdict holds). The real
``rt_core`` runs as its own process, as ``make run`` starts it -- the layered configuration,
SCHED_FIFO threads at the configured periods and priorities, mlockall -- in a runtime
directory of its own under the temp dir, with no driver host and no bridge: the fuzzer takes
the NRT side of every port. Everything it judges comes from what rt_core reports over XDDP:
PORT_STATS (per-port counters, on ``status``), TASK_STATS (every cycle's timing sample),
TASK_HEALTH (overruns, body errors, the bodies' ``unexpected`` counts, on ``stat``) and
RT_STATUS (hardening). Nothing is read from inside the RT process.

The fuzzer holds ``status`` and ``stat`` for the whole run (it must keep reading them); the
fuzz stream of those two ports goes through the same links, written between reads. Every
other port gets a sender process (``fuzz send LABEL COUNT SEED SECONDS``) that writes its
stream and keeps its link open until the RT side has taken every datagram. The stream is a
pure function of (seed, port) (:mod:`m4k_bench.fuzzstream`), so the checker predicts the RT
side's answer to each datagram; per port, the counter deltas (PORT_STATS received / malformed
/ dropped_oversize, TASK_HEALTH unexpected of the owning task) must equal the prediction
exactly. A port the RT side only writes (``status``, ``stat``, ``*_out``) is judged the same
way: its body drains and discards what a peer writes there, counting it.

Timing verdicts, per task, from the TASK_STATS samples: the cycles started during the campaign
within 1 % of campaign time ÷ period (at least one cycle), and no overrun caused by the
fuzzing. A quiet window of about the campaign's length, before it and in the same run,
measures what the machine does without fuzzing. Stall probes (:mod:`.benchlib.stallprobe`:
one process per CPU above every RT priority) see host stalls; an overrun that coincides with
a probe stall of at least half its lateness is counted as the host's, anything else as the
fuzzing's. rt_core must still run at the end and exit cleanly.

Each port's turn writes for ``--seconds-per-port`` (``--count`` datagrams at most): writes
block while the RT side has not drained the socket, so the owner's period, its drain budget
per cycle and the socket buffers set how many a port gets; the prediction classifies exactly
the datagrams written (a prefix of the seeded stream, so ``--seed`` replays it). Writes
``report.md`` and ``results.json`` to ``--results`` (default docs/results/fuzz).

Usage::

    python -m m4k_bench.fuzz [--count 100000] [--seed N] [--seconds-per-port 18] [--ports cmd]
    python -m m4k_bench.fuzz send LABEL COUNT SEED SECONDS   # a sender (started by the above)
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import shutil
import sys
import tempfile
import time
from typing import Any, Mapping, Sequence

from m4k_bench import fuzzlinks, fuzzstream, recorder
from m4k_bench.benchlib import provenance, results, stack, stallprobe
from m4k_bench.fuzzstream import ACCEPTS, Expectation

# rt_core registers the monitor body on import: config.load needs it to know that body.
from m4k_rt import channel, config, rosargs, rt_core, sched, tasks
from m4k_rt.tasks.portio import PortReader

__all__ = ['PortResult', 'cycle_verdict', 'judge_port', 'main', 'receive_sizes', 'run',
           'window_timing']

CYCLE_TOLERANCE = 0.01    # cycles during the campaign within 1 % of elapsed / period
HOST_SHARE = 0.5          # an overrun is the host's when a probe stalled >= half its lateness
STALL_TIMEOUT_S = 30.0    # no datagram taken on the fuzzed port for this long: give up on it
PREDICT_CHUNK = 500       # datagrams classified between two reads of status/stat


def cycle_verdict(elapsed_ns: int, period_ns: int, cycles: int,
                  overruns: int) -> dict[str, Any]:
    """Judge one task over a window: cycles vs elapsed / period, and no overrun.

    Tolerance: 1 % of the expected count, at least one cycle (the window is not aligned with
    the releases, so one cycle more or less is the window's, not the task's). ``overruns``
    are the ones to hold against the task (the caller leaves out the host's).
    """
    expected = elapsed_ns / period_ns
    slack = max(CYCLE_TOLERANCE * expected, 1.0)
    ok_cycles = abs(cycles - expected) <= slack
    return {'expected': expected, 'cycles': cycles, 'slack': slack, 'overruns': overruns,
            'ok': ok_cycles and overruns == 0}


def window_timing(series: recorder.TaskSeries, start_ns: int, end_ns: int,
                  stalls: Sequence[stallprobe.Stall]) -> dict[str, Any]:
    """Count one task's cycles, overruns and deadline misses started in ``[start, end)``.

    Each overrun (a wake-up serving more than one release) is late by ``start`` minus the
    first release it served; it is the host's when one CPU's stall probe was stalled for at
    least ``HOST_SHARE`` of that lateness between the release before it and its start
    (:func:`.benchlib.stallprobe.explained_by`). ``missing_samples`` counts releases between
    consecutive samples that no sample accounts for (a TASK_STATS batch the fuzzer missed).
    """
    p = series.period_ns
    cycles = overruns = misses = missing = 0
    host: list[dict[str, Any]] = []
    own: list[dict[str, Any]] = []
    prev_rel = None
    for rel, start, end, exp in zip(series.t_rel, series.t_start, series.t_end,
                                    series.expirations, strict=True):
        if start < start_ns or start >= end_ns:
            prev_rel = rel
            continue
        cycles += 1
        if prev_rel is not None and p:
            missing += max(0, (rel - prev_rel) // p - exp)
        prev_rel = rel
        if end > rel + p:
            misses += 1
        if exp > 1:
            overruns += exp - 1
            late = start - (rel - (exp - 1) * p)     # from the first release it served
            s = stallprobe.explained_by(rel - exp * p, start, int(HOST_SHARE * late), stalls)
            row = {'t_s': (rel - start_ns) / 1e9, 'missed': exp - 1, 'late_ms': late / 1e6}
            if s is None:
                own.append(row)
            else:
                host.append(dict(row, stall_cpu=s[0], stall_ms=s[1] / 1e6))
    return {'cycles': cycles, 'overruns': overruns, 'deadline_misses': misses,
            'missing_samples': missing,
            'host_overruns': sum(r['missed'] for r in host),
            'own_overruns': sum(r['missed'] for r in own), 'host': host, 'own': own}


def receive_sizes(cfg: config.RtConfig) -> dict[str, int]:
    """Return, per port label, the receive buffer of the body that drains it.

    Built as rt_core builds it -- the configured bodies on their ports, bound in a scratch
    runtime directory and never started -- so the prediction follows the code: a datagram
    longer than the buffer is ``dropped_oversize``.
    """
    rt = cfg.runtime
    scratch = tempfile.mkdtemp(prefix='m4k-fz-')
    shared = rt_core.SharedState(cfg, sched.Hardening())
    socks: list[Any] = []
    sizes: dict[str, int] = {}
    try:
        for t in cfg.tasks:
            ports = {}
            for label in t.ports:
                s = channel.rt_xddp_bind(cfg.ports[label], label, poolsz=rt.poolsz,
                                      max_datagram=rt.max_datagram, runtime_dir=scratch,
                                      max_ports=rt.max_ports, group=rt.group,
                                      transport=rt.transport)
                socks.append(s)
                ports[label] = shared.ports[label] = s
            body = tasks.get_factory(t.body)(t, ports, shared)
            readers = [r for v in vars(body).values()
                       for r in (v if isinstance(v, (list, tuple)) else (v,))
                       if isinstance(r, PortReader)]
            for label, s in ports.items():
                mine = [len(r.buf) for r in readers if r.sock is s]
                sizes[label] = mine[0] if mine else rt.max_datagram
    finally:
        for s in socks:
            s.close()
        shutil.rmtree(scratch, ignore_errors=True)
    return sizes


@dataclasses.dataclass
class PortResult:
    """Predicted and observed counts of one fuzzed port, and whether they agree."""

    label: str
    port: int
    owner: str
    expected: Expectation
    received: int
    oversize: int
    malformed: int
    unexpected: int
    seconds: float
    ok: bool
    problems: list[str]


def judge_port(exp: Expectation, received: int, oversize: int, malformed: int,
               unexpected: int) -> list[str]:
    """Return what disagrees between the prediction and the RT side's counter deltas."""
    problems = []
    for name, want, got in (('oversize', exp.oversize, oversize),
                            ('malformed', exp.malformed, malformed),
                            ('unexpected', exp.unexpected, unexpected),
                            ('received', exp.sent - exp.oversize, received)):
        if want != got:
            problems.append('{}: expected {}, counted {}'.format(name, want, got))
    return problems


def _say(msg: str) -> None:
    print(msg, flush=True)


@dataclasses.dataclass
class _Turn:
    """What one port's turn needs: where, whose, how much, and how to predict it."""

    label: str
    port: int
    owner: str
    bufsize: int
    count: int
    seconds: float
    seed: int
    accepts: Mapping[str, frozenset[int]]


def _fuzz_port(obs: fuzzlinks.Observer, turn: _Turn, env: Mapping[str, str],
               monitor_period_s: float) -> PortResult:
    """Fuzz one port of the running rt_core; judge the counter deltas against the prediction.

    The stream is written for ``turn.seconds`` (``turn.count`` at most); the prediction is the
    classification of the datagrams actually written.
    """
    label = turn.label
    base = obs.taken(label)
    unexp0 = obs.unexpected(turn.owner) or 0
    t0 = time.monotonic()
    problems: list[str] = []
    sender = None
    if label in fuzzlinks.MONITOR_PORTS:
        obs.stream(label, fuzzstream.datagrams(label, turn.count, turn.seed), turn.seconds)
    else:
        sender = fuzzlinks.Sender(label, turn.count, turn.seed, turn.seconds, env)
    pred = fuzzstream.Predictor(label, turn.seed, turn.bufsize, turn.count, turn.accepts)
    exp: Expectation | None = None
    last_taken, last_move, next_note = 0, t0, t0 + 5.0
    settled_at = None
    try:
        while True:
            obs.pump(0.05)
            now = time.monotonic()
            if obs.lost:
                problems.append('status link lost: {}'.format(obs.lost))
                break
            if sender is not None:
                sender.check()
                if sender.error:
                    problems.append(sender.error)
                    break
            if exp is None:
                # Classify while the sender writes, a chunk per pass, so this loop keeps
                # reading status/stat: a long pause here would overflow their sockets and
                # lose monitor batches (samples).
                done = sender.done if sender is not None else not obs.streaming
                written = sender.sent if sender is not None else obs.written
                if pred.advance(PREDICT_CHUNK) >= written and done:
                    exp = pred.expectation(written)
            c = obs.taken(label)
            taken = (c[0] - base[0]) + (c[1] - base[1])
            if taken != last_taken:
                last_taken, last_move = taken, now
            elif now - last_move > STALL_TIMEOUT_S + monitor_period_s:
                problems.append('RT side took {} datagrams, then nothing for {:.0f} s'
                                .format(taken, now - last_move))
                break
            if now >= next_note:
                next_note = now + 5.0
                _say('  {}: {} taken by the RT side, {:.0f} s'.format(label, taken, now - t0))
            if exp is not None and taken >= exp.sent and settled_at is None:
                settled_at = obs.batches
            # The batch that showed the last datagram taken may still be open here (its
            # RT_STATUS not read yet), and its TASK_HEALTH may have been taken on the other
            # CPU while the owning body was between draining (PORT_STATS counts) and adding
            # up its unexpected count. Two more closed batches: the second was composed a
            # whole monitor period after the drain, when that body's cycle had long ended.
            if settled_at is not None and obs.batches >= settled_at + 2:
                break
    finally:
        if sender is not None:
            sender.release()
    c = obs.taken(label)
    unexp = obs.unexpected(turn.owner)
    res = PortResult(label, turn.port, turn.owner, exp or Expectation(), c[0] - base[0],
                     c[1] - base[1], c[2] - base[2], (unexp or 0) - unexp0,
                     time.monotonic() - t0, False, problems)
    if exp is not None and not problems:
        problems += judge_port(exp, res.received, res.oversize, res.malformed, res.unexpected)
    res.ok = not problems
    return res


def _parse(argv: Sequence[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog='fuzz', description=__doc__.split('\n')[0])
    ap.add_argument('--count', type=int, default=100_000, help='datagrams per port (at most)')
    ap.add_argument('--seed', type=int, default=None, help='stream seed (default: random)')
    ap.add_argument('--seconds-per-port', type=float, default=18.0,
                    help='seconds of writing per port (default 18; --count caps it)')
    ap.add_argument('--quiet-s', type=float, default=None,
                    help='quiet window before the campaign (default: the estimated campaign '
                    'length)')
    ap.add_argument('--results', default=os.path.join('docs', 'results', 'fuzz'),
                    help='directory for report.md and results.json ("" to skip)')
    ap.add_argument('--ports', default='', help='comma-separated labels (default: all)')
    ap.add_argument('--config', default=None, help='user overlay YAML (rt_core --config)')
    ap.add_argument('--json', default=None, metavar='FILE', help='write the results as JSON')
    return rosargs.parse_args(ap, argv)


def _sender_main(argv: Sequence[str]) -> int:
    label, count, seed, seconds = argv[0], int(argv[1]), int(argv[2]), float(argv[3])

    def hold(n: int) -> None:
        print('sent {}'.format(n), flush=True)
        sys.stdin.read()  # until the checker closes our stdin
    fuzzlinks.send(label, count, seed, seconds=seconds, hold=hold)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Run the fuzz campaign (or, as ``fuzz send``, one port's sender); return the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ['send']:
        return _sender_main(argv[1:])
    args = _parse(argv)
    if args.seed is None:
        args.seed = int.from_bytes(os.urandom(4), 'little')
    out = run(args)
    if args.json:
        results.write_json(args.json, out, indent=1)
    if args.results:
        _write_results(args.results, out)
    _say('fuzz: {} (seed {}; replay: make fuzz SEED={})'.format(
        'all verdicts hold' if out['ok'] else 'FAILED: ' + '; '.join(out['failures']),
        args.seed, args.seed))
    return 0 if out['ok'] else 1


def _plan(args: argparse.Namespace, cfg: config.RtConfig,
          accepts: Mapping[str, frozenset[int]]) -> list[_Turn]:
    owner = {label: t for t in cfg.tasks for label in t.ports}
    labels = [x for x in args.ports.split(',') if x] or sorted(owner, key=lambda x: cfg.ports[x])
    unknown = [x for x in labels if x not in owner]
    if unknown:
        raise SystemExit('fuzz: unknown port(s) {} (configured: {})'.format(
            ', '.join(unknown), ', '.join(sorted(owner))))
    sizes = receive_sizes(cfg)
    return [_Turn(label, cfg.ports[label], owner[label].name, sizes[label], args.count,
                  args.seconds_per_port, args.seed, accepts) for label in labels]


def run(args: argparse.Namespace,
        accepts: Mapping[str, frozenset[int]] = ACCEPTS) -> dict[str, Any]:
    """Run the whole campaign against a fresh rt_core; return the results dict."""
    t_run = time.monotonic()
    cfg = config.load(args.config, body_exists=tasks.body_exists)
    _say('fuzz: seed {} (replay: make fuzz SEED={}), up to {} datagrams per port'.format(
        args.seed, args.seed, args.count))
    turns = _plan(args, cfg, accepts)
    monitor_s = next((t.period_ns for t in cfg.tasks if t.body == 'monitor'), 10**9) / 1e9
    # Each turn: a sender's start-up (an interpreter, about 2 s on this machine kind), its
    # seconds of writing, classifying what it wrote, then up to two monitor batches.
    estimate = len(turns) * (args.seconds_per_port + 3.0 + 2.0 * monitor_s)
    quiet_s = estimate if args.quiet_s is None else args.quiet_s
    runtime_dir = tempfile.mkdtemp(prefix='m4k-fuzz-')
    env = dict(os.environ, M4K_RUNTIME_DIR=runtime_dir)
    probes = stallprobe.StallProbes()
    rt_args = ['--config', args.config] if args.config else []
    core = stack.start_child('rt_core', stack.entry_argv('m4k_rt.rt_core', *rt_args),
                             os.path.join(runtime_dir, 'logs'), env)
    failures: list[str] = []
    results: list[PortResult] = []
    obs = None
    windows: dict[str, tuple[int, int]] = {}
    try:
        obs = fuzzlinks.Observer(runtime_dir)
        if not obs.wait_batches(2, 30.0 + 3 * monitor_s):
            raise RuntimeError('no monitor batch from rt_core: ' + ' | '.join(core.tail()))
        _say('fuzz: rt_core pid {} running ({}); quiet window {:.0f} s, then {} ports for '
             '{:g} s each (campaign about {:.0f} s)'.format(
                 core.pid, _hardening(obs.rec.rt_status), quiet_s, len(turns),
                 args.seconds_per_port, estimate))
        q0 = time.monotonic_ns()
        next_note = time.monotonic() + 15.0
        while time.monotonic_ns() - q0 < quiet_s * 1e9 and not obs.lost:
            obs.pump(0.1)
            if time.monotonic() >= next_note:
                next_note += 15.0
                _say('  quiet: {:.0f}/{:.0f} s'.format((time.monotonic_ns() - q0) / 1e9,
                                                        quiet_s))
        windows['quiet'] = (q0, time.monotonic_ns())
        head = '{:<10} {:>4} {:>7} {:>9} {:>8} {:>10} {:>8} {:>6}  {}'
        _say(head.format('PORT', 'NUM', 'SENT', 'MALFORMED', 'OVERSIZE', 'UNEXPECTED',
                         'ACCEPTED', 'SEC', 'RESULT'))
        c0 = time.monotonic_ns()
        for turn in turns:
            r = _fuzz_port(obs, turn, env, monitor_s)
            results.append(r)
            _say(head.format(r.label, r.port, r.expected.sent, r.malformed, r.oversize,
                             r.unexpected, r.expected.accepted, '{:.1f}'.format(r.seconds),
                             'ok' if r.ok else 'FAIL: ' + '; '.join(r.problems)))
            if not core.alive() or obs.lost:
                break
        windows['campaign'] = (c0, time.monotonic_ns())
        # The samples of the last cycles arrive with the next batch or two.
        obs.wait_batches(2, 5.0 + 3 * monitor_s)
    except (RuntimeError, OSError) as exc:
        failures.append('campaign aborted: {}'.format(exc))
    finally:
        alive = core.alive()
        if obs is not None:
            obs.close()
        code = core.stop(grace_s=15.0)
        stalls = probes.stop()
    log = core.tail(12)
    shutil.rmtree(runtime_dir, ignore_errors=True)
    out = _summarize(args, cfg, obs, results, windows, stalls, probes, alive, code, log,
                     failures, quiet_s)
    out['wall_s'] = time.monotonic() - t_run
    return out


def _hardening(st: Any) -> str:
    if st is None:
        return 'no RT_STATUS yet'
    return '{}, memory {}, {}'.format('SCHED_FIFO' if st.policy else 'NOT FIFO',
                                      'locked' if st.mem_locked else 'NOT locked',
                                      'degraded' if st.degraded else 'not degraded')


def _summarize(args: argparse.Namespace, cfg: config.RtConfig, obs: fuzzlinks.Observer | None,
               results: list[PortResult], windows: Mapping[str, tuple[int, int]],
               stalls: list[stallprobe.Stall], probes: stallprobe.StallProbes, alive: bool,
               code: int | None, log: list[str], failures: list[str],
               quiet_s: float) -> dict[str, Any]:
    failures = list(failures)
    for r in results:
        if not r.ok:
            failures.append('port {}: {}'.format(r.label, '; '.join(r.problems)))
    if not alive:
        failures.append('rt_core was not running at the end (exit {})'.format(code))
    elif code != 0:
        failures.append('rt_core exited {} on SIGTERM'.format(code))
    st = obs.rec.rt_status if obs is not None else None
    tasks_out: dict[str, Any] = {}
    for t in cfg.tasks:
        series = obs.rec.tasks.get(t.name) if obs is not None else None
        if series is None or 'campaign' not in windows:
            failures.append('task {}: no timing samples'.format(t.name))
            continue
        row: dict[str, Any] = {'period_ms': t.period_ns / 1e6, 'priority': t.priority}
        for w, (a, b) in windows.items():
            row[w] = window_timing(series, a, b, stalls)
            row[w]['seconds'] = (b - a) / 1e9
        camp = row['campaign']
        v = cycle_verdict(windows['campaign'][1] - windows['campaign'][0], t.period_ns,
                          camp['cycles'], camp['own_overruns'])
        h = series.health
        row.update(verdict=v, body_errors=None if h is None else h.body_errors,
                   lost_samples=None if h is None else h.lost_samples,
                   fifo=None if h is None else bool(h.fifo))
        if camp['missing_samples']:
            v['ok'] = False
            failures.append('task {}: {} samples of the campaign never arrived'.format(
                t.name, camp['missing_samples']))
        if h is None or h.body_errors:
            v['ok'] = False
            failures.append('task {}: body errors {}'.format(
                t.name, 'unknown' if h is None else h.body_errors))
        if not v['ok'] and not camp['missing_samples']:
            failures.append('task {}: {} cycles (expected {:.1f} ± {:.1f}), {} overruns not '
                            "the host's".format(t.name, v['cycles'], v['expected'],
                                                 v['slack'], v['overruns']))
        tasks_out[t.name] = row
    if st is None or not st.policy or not st.mem_locked or st.degraded:
        failures.append('rt_core not hardened: {}'.format(_hardening(st)))
    win_stalls = {w: [s for s in stalls if a <= s[2] and s[1] < b]
                  for w, (a, b) in windows.items()}
    return {
        'seed': args.seed, 'count': args.count, 'seconds_per_port': args.seconds_per_port,
        'config': args.config, 'quiet_s': quiet_s,
        'provenance': provenance.provenance(),     # commit, machine (results writer's)
        'rt_status': None if st is None else dict(st._asdict()),
        # What rt_core could not send to the fuzzer's own links (its socket full): lost
        # batches, which show as missing samples above.
        'observer_dropped_full': {
            label: ps.dropped_full for label, ps in (
                obs.rec.port_stats.items() if obs is not None else ())
            if label in fuzzlinks.MONITOR_PORTS},
        'windows_s': {w: (b - a) / 1e9 for w, (a, b) in windows.items()},
        'probes': {'info': probes.info, 'summary': probes.summary,
                   'threshold_ms': probes.threshold_ns / 1e6,
                   'stalls': {w: [{'cpu': s[0], 't_s': (s[1] - windows[w][0]) / 1e9,
                                   'ms': (s[2] - s[1]) / 1e6} for s in ss]
                              for w, ss in win_stalls.items()}},
        'ports': [dataclasses.asdict(r) for r in results], 'tasks': tasks_out,
        'rt_core': {'alive_at_end': alive, 'exit': code, 'log_tail': log},
        'failures': failures, 'ok': not failures,
    }


def _write_results(outdir: str, out: dict[str, Any]) -> None:
    out = results.write_json(os.path.join(outdir, 'results.json'), out, indent=1)
    from m4k_bench.fuzzreport import format_report
    with open(os.path.join(outdir, 'report.md'), 'w') as f:
        f.write(format_report(out))


if __name__ == '__main__':
    sys.exit(main())
