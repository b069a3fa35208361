"""fuzz: throw random and mutated datagrams at every XDDP port of a running RT task set.

Benchmark-style (prints counts, exits 0 only when nothing was lost): the robot's RT task set
runs in this process exactly as ``rt_core`` builds it -- the configured bodies, real XDDP
ports, one SCHED_FIFO thread per task released by its timerfd -- and a separate sender process
per port writes ``--count`` datagrams (default 100 000) through the NRT side. The datagram
stream is a pure function of (seed, port), so this process regenerates it and knows, for every
datagram, what the RT side must do with it:

* longer than the body's receive buffer -> ``dropped_oversize`` on the socket;
* rejected by ``protocol.decode`` -> ``malformed`` on the socket;
* valid, but a kind the port does not carry -> the body's ``unexpected`` counter;
* valid and expected -> consumed by the body.

After each port the RT counters must match the prediction exactly, every task must still be
cycling, and no body may have raised. The tasks run at their configured periods and
priorities (``--period-ms`` shortens them all for a quick look); over the whole campaign every
task's cycle count must be within 1 % of elapsed time ÷ its period (at least one cycle of
slack: the window does not start on a release) and the fuzzing must cause no overrun
(:func:`cycle_verdict`). A body drains at most ``tasks.portio.DRAIN_MAX`` datagrams per cycle,
so a port gets ``min(--count, what its owner can drain in --seconds-per-port)`` datagrams: 1e5
on the 1 s monitor's port would take an hour. Writes ``report.md`` and ``results.json`` to
``--results`` (default docs/results/fuzz).

Usage::

    python -m m4k_bench.fuzz [--count 100000] [--seconds-per-port 8] [--ports cmd,motor]
    python -m m4k_bench.fuzz send LABEL COUNT SEED   # the sender (started by the above)
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import random
import struct
import subprocess
import sys
import time
from typing import Any, Iterator, Mapping, Sequence

from m4k_rt import config, protocol, rosargs, sched, tasks, xddp
from m4k_rt.protocol import Kind
from m4k_rt.task import RtTask
from m4k_rt.tasks.portio import PortReader

__all__ = ['ACCEPTS', 'Expectation', 'PortResult', 'RtHarness', 'classify', 'cycle_verdict',
           'datagrams', 'main', 'mutate', 'port_count', 'valid_datagram']

CYCLE_TOLERANCE = 0.01   # cycles during the campaign within 1 % of elapsed / period
DRAIN_SHARE = 0.8        # use at most 80 % of a body's drain capacity per port


def port_count(count: int, seconds: float, period_ns: int, drain_max: int) -> int:
    """Return how many datagrams a port gets: ``count`` at most, else what fits the time.

    The owning body drains at most ``drain_max`` per cycle; at ``DRAIN_SHARE`` of that the
    RT side keeps up and the sender does not time out on a full socket.
    """
    fits = int(seconds * 1e9 / period_ns * drain_max * DRAIN_SHARE)
    return max(1, min(count, fits))


def cycle_verdict(elapsed_ns: int, period_ns: int, cycles: int,
                  overruns: int) -> dict[str, Any]:
    """Judge one task over the fuzz campaign: cycles vs elapsed / period, and no overrun.

    Tolerance: 1 % of the expected count, at least one cycle (the window is not aligned with
    the releases, so one cycle more or less is the window's, not the task's).
    """
    expected = elapsed_ns / period_ns
    slack = max(CYCLE_TOLERANCE * expected, 1.0)
    ok_cycles = abs(cycles - expected) <= slack
    return {'expected': expected, 'cycles': cycles, 'slack': slack, 'overruns': overruns,
            'ok': ok_cycles and overruns == 0}

K = Kind
# What each port's RT body consumes (docs/internals.md, "Ports"); anything else valid is
# "unexpected". Ports the RT side only writes accept nothing.
ACCEPTS: Mapping[str, frozenset[int]] = {
    'status': frozenset(), 'stat': frozenset(),
    'cmd': frozenset({K.VELOCITY_CMD, K.E_STOP, K.ODOM_RESET}),
    'motor': frozenset({K.ENCODERS, K.DEVICE_STATUS}),
    'imu': frozenset({K.IMU, K.DEVICE_STATUS}), 'imu_out': frozenset(),
    'led': frozenset({K.DEVICE_STATUS}), 'led_in': frozenset({K.LED}),
    'sonar': frozenset({K.SONAR, K.DEVICE_STATUS}), 'sonar_out': frozenset(),
    'lrf': frozenset({K.LASER_SCAN, K.DEVICE_STATUS}), 'lrf_out': frozenset(),
}

_F64 = (0.0, -0.0, 1.0, -1.0, 0.25, 2.0, -2.0, 1e308, -1e308, 5e-324, -5e-324, 1e-9, 3.4e38,
        math.pi, 1e6, -1e6)
_F32 = (0.0, -0.0, 1.0, -1.0, 0.25, 5.6, 0.02, 3.4e38, -3.4e38, 1e-45, 1e6, math.pi, 1e-3)
_NONFINITE = (math.nan, math.inf, -math.inf, -math.nan)


def _f64(rng: random.Random) -> float:
    return rng.choice(_F64) if rng.random() < 0.5 else rng.gauss(0.0, 10.0)


def _f32(rng: random.Random) -> float:
    return rng.choice(_F32) if rng.random() < 0.5 else rng.uniform(-100.0, 100.0)


def _u(rng: random.Random, bits: int) -> int:
    return rng.choice((0, 1, (1 << bits) - 1, rng.getrandbits(bits)))


def _fields(rng: random.Random, kind: int) -> tuple[Any, ...]:
    f, g, u = _f64, _f32, _u
    if kind == K.VELOCITY_CMD:
        return (f(rng), f(rng))
    if kind == K.ODOMETRY:
        return tuple(f(rng) for _ in range(9)) + (u(rng, 32),)
    if kind == K.WHEEL_CMD:
        return (rng.randint(0, 1023), rng.randint(0, 1023), rng.randint(0, 1))
    if kind == K.ENCODERS:
        return (rng.randint(0, 4095), rng.randint(0, 4095), f(rng), f(rng), u(rng, 8))
    if kind == K.IMU:
        return tuple(f(rng) for _ in range(10)) + (u(rng, 8),)
    if kind == K.SONAR:
        return (abs(g(rng)), rng.randint(0, 3))
    if kind == K.LASER_SCAN:
        n = rng.choice((0, 1, 2, 683, rng.randint(0, protocol.MAX_SCAN_RANGES)))
        ranges = [rng.choice((0, 19, 20, 65535, rng.getrandbits(16))) for _ in range(n)]
        return tuple(g(rng) for _ in range(6)) + (rng.randint(0, 0xFFFFFF), ranges)
    if kind == K.LED:
        return (u(rng, 8), u(rng, 8), u(rng, 8), u(rng, 8), rng.randint(0, 1))
    if kind == K.TASK_STATS:
        n = rng.choice((0, 1, rng.randint(0, protocol.MAX_STATS_SAMPLES)))
        rows = [(rng.getrandbits(62), rng.getrandbits(62), rng.getrandbits(62), u(rng, 32))
                for _ in range(n)]
        return ('fuzz', u(rng, 8), rng.randint(-5, 99), rng.randint(-1, 3), u(rng, 32),
                u(rng, 32), u(rng, 32), u(rng, 32), u(rng, 32), u(rng, 32), rows)
    if kind == K.REQUEST:
        return (u(rng, 32), u(rng, 32))
    if kind == K.RT_STATUS:
        return tuple(rng.randint(0, 1) for _ in range(4)) + (u(rng, 32), u(rng, 32), u(rng, 32))
    if kind == K.DEVICE_STATUS:
        return ('dev', u(rng, 8), rng.randint(0, 3), u(rng, 32), u(rng, 32))
    if kind == K.PORT_STATS:
        return ('port', u(rng, 16), rng.randint(0, 1)) + tuple(u(rng, 64) for _ in range(7))
    if kind == K.E_STOP:
        return (rng.randint(0, 1),)
    if kind == K.ODOM_RESET:
        return (u(rng, 32),)
    if kind == K.FORBIDDEN_SITE:
        return ('fuzz', u(rng, 8), rng.choice(sorted(protocol.EVENT_NAMES)), u(rng, 32),
                u(rng, 32), u(rng, 32), '/fuzz/' * rng.randint(0, 12) + 'body.py', 'cycle')
    if kind == K.TASK_HEALTH:
        return ('fuzz', u(rng, 8)) + tuple(u(rng, 32) for _ in range(6)) + (
            rng.randint(0, 1), u(rng, 8))
    raise ValueError('no field generator for kind {!r}'.format(kind))


def valid_datagram(rng: random.Random, kind: int | None = None) -> bytes:
    """Return a well-formed datagram of ``kind`` (random kind when None) with edgy values."""
    kind = rng.choice(list(Kind)) if kind is None else kind
    while True:  # a value outside the layout (f32 overflow, a range) -> draw again
        try:
            return protocol.encode(kind, rng.getrandbits(32), rng.getrandbits(63),
                                   *_fields(rng, kind))
        except protocol.ProtocolError:
            continue


def mutate(rng: random.Random, data: bytes) -> bytes:
    """Return ``data`` damaged one way: bit flips, cut, extension, header or float poison."""
    b = bytearray(data)
    op = rng.randrange(9)
    if op == 0:                                           # flip 1..8 bits
        for _ in range(rng.randint(1, 8)):
            b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
    elif op == 1:                                         # truncate
        del b[rng.randrange(1, len(b)):]
    elif op == 2:                                         # extend
        b += rng.randbytes(rng.randint(1, 64))
    elif op == 3:                                         # magic / version
        b[rng.choice((0, 1, 2))] = rng.getrandbits(8)
    elif op == 4:                                         # another (or unknown) kind
        b[3] = rng.choice([int(k) for k in Kind] + [0, max(Kind) + 1, 63, 255])  # + unknown
    elif op == 5 and len(b) >= 24:                        # NaN / inf into a double slot
        off = rng.randrange(16, len(b) - 7)
        struct.pack_into('<d', b, off, rng.choice(_NONFINITE))
    elif op == 6 and len(b) >= 20:                        # NaN / inf into a float slot
        off = rng.randrange(16, len(b) - 3)
        struct.pack_into('<f', b, off, rng.choice(_NONFINITE))
    elif op == 7:                                         # random payload behind the header
        b[16:] = rng.randbytes(max(0, len(b) - 16))
    elif len(b) >= 4:                                     # a random u32 anywhere (counts)
        struct.pack_into('<I', b, rng.randrange(len(b) - 3), rng.getrandbits(32))
    return bytes(b) if b else b'\x00'


def one_datagram(rng: random.Random, accepts: Sequence[int] = ()) -> bytes:
    """Return one fuzz datagram: valid, mutated valid, random bytes or oversize.

    Half of the valid and mutated ones are of a kind in ``accepts`` (what the port takes), so
    the bodies' handling of valid-but-extreme values gets exercised, not only the decoder.
    """
    r = rng.random()
    kind = rng.choice(accepts) if accepts and rng.random() < 0.5 else None
    if r < 0.25:
        return valid_datagram(rng, kind)
    if r < 0.80:
        return mutate(rng, valid_datagram(rng, kind))
    if r < 0.99:
        n = rng.choice((1, 15, 16, 17, rng.randint(1, 128)))
        head = struct.pack('<HBB', protocol.MAGIC, protocol.VERSION, rng.getrandbits(8))
        data = rng.randbytes(n)
        return (head + data[4:]) if rng.random() < 0.5 and n > 4 else data
    return rng.randbytes(rng.randint(4097, 6000))


def _seed(seed: int, label: str) -> int:
    return seed * 1_000_003 + sum(ord(c) * 31 ** i for i, c in enumerate(label))


def datagrams(label: str, count: int, seed: int) -> Iterator[bytes]:
    """Yield the deterministic fuzz stream of one port (same in sender and checker)."""
    rng = random.Random(_seed(seed, label))
    accepts = sorted(ACCEPTS.get(label, ()))
    for _ in range(count):
        yield one_datagram(rng, accepts)


def classify(data: bytes, accepts: frozenset[int], bufsize: int) -> str:
    """Return what the RT side must do with ``data``: oversize/malformed/unexpected/accepted."""
    if len(data) > bufsize:
        return 'oversize'
    try:
        hdr, _ = protocol.decode(data)
    except protocol.ProtocolError:
        return 'malformed'
    return 'accepted' if hdr.kind in accepts else 'unexpected'


@dataclasses.dataclass
class Expectation:
    """Predicted outcome counts of one port's fuzz stream."""

    sent: int = 0
    oversize: int = 0
    malformed: int = 0
    unexpected: int = 0
    accepted: int = 0


def expect(label: str, count: int, seed: int, bufsize: int) -> Expectation:
    """Classify the fuzz stream of ``label`` without sending it."""
    e = Expectation()
    acc = ACCEPTS.get(label, frozenset())
    for d in datagrams(label, count, seed):
        e.sent += 1
        what = classify(d, acc, bufsize)
        setattr(e, what, getattr(e, what) + 1)
    return e


class RtHarness:
    """The configured RT task set, built and run in this process the way rt_core does."""

    def __init__(self, overlay: str | None = None, period_ms: float | None = None,
                 runtime_dir: str | None = None) -> None:
        from m4k_rt import rt_core  # the monitor body registers itself on import
        cfg = config.load(overlay, body_exists=tasks.body_exists)
        if period_ms is not None:
            ns = int(period_ms * 1e6)
            cfg = dataclasses.replace(cfg, tasks=tuple(
                dataclasses.replace(t, period_ns=ns) for t in cfg.tasks))
        self.cfg = cfg
        rt = cfg.runtime
        self.runtime_dir = xddp.ensure_runtime_dir(runtime_dir or rt.runtime_dir, rt.group)
        self.shared = rt_core.SharedState(cfg, sched.Hardening())
        self.ports: dict[str, xddp.RtXddpSocket] = {}
        self.owner: dict[str, RtTask] = {}
        try:
            for i, t in enumerate(cfg.tasks):
                ports = {}
                for label in t.ports:
                    ports[label] = self.ports[label] = xddp.rt_xddp_bind(
                        cfg.ports[label], label, poolsz=rt.poolsz, max_datagram=rt.max_datagram,
                        runtime_dir=self.runtime_dir, max_ports=rt.max_ports, group=rt.group)
                body = tasks.get_factory(t.body)(t, ports, self.shared)
                task = RtTask(t.name, t.priority, t.period_ns, body, index=i,
                              ring_capacity=rt.ring_capacity)
                self.shared.tasks.append(task)
                for label in t.ports:
                    self.owner[label] = task
        except BaseException:
            self.close()
            raise

    def start(self) -> 'RtHarness':
        """Start every task thread."""
        for t in self.shared.tasks:
            t.start()
        return self

    def reader_size(self, label: str) -> int:
        """Return the receive buffer size the owning body uses on ``label``."""
        body = self.owner[label].body
        sock = self.ports[label]
        for v in vars(body).values() if hasattr(body, '__dict__') else ():
            for r in v if isinstance(v, (list, tuple)) else (v,):
                if isinstance(r, PortReader) and r.sock is sock:
                    return len(r.buf)
        return self.cfg.runtime.max_datagram

    def unexpected(self, label: str) -> int:
        """Return the owning body's count of valid datagrams of a kind it does not take."""
        return int(getattr(self.owner[label].body, 'unexpected', 0))

    def settled(self, label: str, sent: int, timeout: float) -> bool:
        """Wait until the RT side has taken every datagram sent to ``label``."""
        c = self.ports[label].counters
        end = time.monotonic() + timeout
        while c.received + c.dropped_oversize < sent:
            if time.monotonic() > end:
                return False
            time.sleep(0.01)
        time.sleep(0.05)  # let the owning task finish decoding what it drained last
        return True

    def close(self) -> None:
        """Stop the tasks and close every port."""
        for t in self.shared.tasks:
            t.stop()
        for t in self.shared.tasks:
            t.join(2.0)
        for s in self.ports.values():
            s.close()
        self.ports.clear()

    def __enter__(self) -> 'RtHarness':
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclasses.dataclass
class PortResult:
    """Predicted and observed counts of one fuzzed port, and whether they agree."""

    label: str
    port: int
    expected: Expectation
    received: int
    oversize: int
    malformed: int
    unexpected: int
    body_errors: int
    cycles_during: int
    overruns_during: int     # all tasks, while this port was fuzzed
    seconds: float
    ok: bool
    problems: list[str]


def send(label: str, count: int, seed: int, runtime_dir: str | None = None,
         timeout: float = 30.0, hold: Any = None) -> int:
    """Write the fuzz stream of ``label`` through the NRT side; return datagrams written.

    The link stays open until ``hold()`` returns: closing a Unix socket that still has unread
    datagrams (the RT side's own sends) resets the connection, and the RT side would then
    drop what it had not drained yet -- in-flight loss of a dying peer, not what this measures.
    """
    n = 0
    with xddp.nrt_xddp_open(label, wait=10.0, runtime_dir=runtime_dir) as ep:
        for d in datagrams(label, count, seed):
            ep.write(d, timeout)
            n += 1
        if hold is not None:
            hold()
    return n


def fuzz_port(h: RtHarness, label: str, count: int, seed: int,
              timeout: float = 30.0, exp: Expectation | None = None) -> PortResult:
    """Fuzz one port of a running harness and compare the RT counters with the prediction.

    ``exp`` may be precomputed (:func:`expect`) so the classification does not compete with
    the RT threads for the interpreter while they run.
    """
    sock = h.ports[label]
    task = h.owner[label]
    if exp is None:
        exp = expect(label, count, seed, h.reader_size(label))
    ovr0 = sum(t.overruns for t in h.shared.tasks)
    c0 = dataclasses.replace(sock.counters)
    unexp0, err0, cyc0 = h.unexpected(label), task.body_errors, task.cycles
    t0 = time.monotonic()
    problems = []
    env = dict(os.environ, M4K_RUNTIME_DIR=h.runtime_dir)
    proc = subprocess.Popen([sys.executable, '-m', 'm4k_bench.fuzz', 'send', label,
                             str(count), str(seed)], env=env, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdin is not None and proc.stdout is not None and proc.stderr is not None
    try:
        line = proc.stdout.readline()  # 'sent N' once every datagram is written
        if not line.startswith('sent '):
            problems.append('sender failed: {}'.format(proc.stderr.read().strip()[-300:]))
        elif not h.settled(label, exp.sent, 10.0):
            problems.append('RT side did not take every datagram within 10 s')
    finally:
        proc.stdin.close()  # lets the sender close its link
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()
    c = sock.counters
    res = PortResult(
        label, sock.port, exp, c.received - c0.received, c.dropped_oversize - c0.dropped_oversize,
        c.malformed - c0.malformed, h.unexpected(label) - unexp0, task.body_errors - err0,
        task.cycles - cyc0, sum(t.overruns for t in h.shared.tasks) - ovr0,
        time.monotonic() - t0, False, problems)
    for name, want, got in (('oversize', exp.oversize, res.oversize),
                            ('malformed', exp.malformed, res.malformed),
                            ('unexpected', exp.unexpected, res.unexpected),
                            ('received', exp.sent - exp.oversize, res.received)):
        if want != got:
            problems.append('{}: expected {}, counted {}'.format(name, want, got))
    if res.body_errors:
        problems.append('{} body errors, last {!r} at {}'.format(
            res.body_errors, task.last_error, task.last_error_site))
    dead = [t.name for t in h.shared.tasks if not t.is_alive()]
    if dead:
        problems.append('tasks not running: {}'.format(', '.join(dead)))
    res.ok = not problems
    return res


def _parse(argv: Sequence[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog='fuzz', description=__doc__.split('\n')[0])
    ap.add_argument('--count', type=int, default=100_000, help='datagrams per port')
    ap.add_argument('--seed', type=int, default=1)
    ap.add_argument('--period-ms', type=float, default=0.0,
                    help='period of every task during the run (default 0: as configured)')
    ap.add_argument('--seconds-per-port', type=float, default=8.0,
                    help="time budget per port at its owner's drain rate (default 8)")
    ap.add_argument('--results', default=os.path.join('docs', 'results', 'fuzz'),
                    help='directory for report.md and results.json ("" to skip)')
    ap.add_argument('--ports', default='', help='comma-separated labels (default: all)')
    ap.add_argument('--config', default=None, help='user overlay YAML')
    ap.add_argument('--json', default=None, metavar='FILE', help='write the results as JSON')
    return rosargs.parse_args(ap, argv)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the fuzz campaign (or, as ``fuzz send``, one port's sender); return the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ['send']:
        label, count, seed = argv[1], int(argv[2]), int(argv[3])

        def hold() -> None:
            print('sent {}'.format(count), flush=True)
            sys.stdin.read()  # until the checker closes our stdin
        send(label, count, seed, hold=hold)
        return 0
    args = _parse(argv)
    rd = xddp.default_runtime_dir()
    results = []
    h = RtHarness(args.config, args.period_ms or None, rd)
    labels = [x for x in args.ports.split(',') if x] or list(h.ports)
    from m4k_rt.tasks.portio import DRAIN_MAX
    counts = {label: port_count(args.count, args.seconds_per_port, h.owner[label].period_ns,
                                DRAIN_MAX) for label in labels}
    try:
        exps = {label: expect(label, counts[label], args.seed, h.reader_size(label))
                for label in labels}
    except BaseException:
        h.close()
        raise
    with h:
        time.sleep(1.0)  # past the first releases: start-up is not the fuzzing's
        snap0 = {t.name: (t.cycles, t.overruns) for t in h.shared.tasks}
        t_begin = time.monotonic_ns()
        print('fuzz: {} datagrams per port, seed {}, periods {}, ports {}'.format(
            args.count, args.seed, '{} ms'.format(args.period_ms) if args.period_ms
            else 'as configured', ', '.join(labels)), flush=True)
        head = '{:<10} {:>4} {:>8} {:>9} {:>9} {:>10} {:>9} {:>7} {:>8} {:>6} {:>6}  {}'
        print(head.format('PORT', 'NUM', 'SENT', 'MALFORMED', 'OVERSIZE', 'UNEXPECTED',
                          'ACCEPTED', 'ERRORS', 'CYCLES', 'OVR', 'SEC', 'RESULT'), flush=True)
        for label in labels:
            r = fuzz_port(h, label, counts[label], args.seed, exp=exps[label])
            results.append(r)
            print(head.format(label, r.port, r.expected.sent, r.malformed, r.oversize,
                              r.unexpected, r.expected.accepted, r.body_errors, r.cycles_during,
                              r.overruns_during, '{:.1f}'.format(r.seconds),
                              'ok' if r.ok else 'LOST: ' + '; '.join(r.problems)), flush=True)
        elapsed = time.monotonic_ns() - t_begin
        verdicts = {t.name: dict(cycle_verdict(elapsed, t.period_ns, t.cycles - snap0[t.name][0],
                                               t.overruns - snap0[t.name][1]),
                                 period_ms=t.period_ns / 1e6, priority=t.priority,
                                 fifo=t.fifo)
                    for t in h.shared.tasks}
        tasks_end = {t.name: {'cycles': t.cycles, 'overruns': t.overruns,
                              'deadline_misses': t.deadline_misses,
                              'body_errors': t.body_errors} for t in h.shared.tasks}
    total = sum(r.expected.sent for r in results)
    bad = sum(r.expected.sent - r.expected.accepted for r in results)
    print('fuzz: {} datagrams, {} bad ({} malformed, {} oversize, {} unexpected), lost {}'.format(
        total, bad, sum(r.malformed for r in results), sum(r.oversize for r in results),
        sum(r.unexpected for r in results), sum(0 if r.ok else 1 for r in results)))
    for name, v in verdicts.items():
        print('task {}: {} cycles while fuzzing, expected {:.1f} (+-{:.1f}), overruns {}: {}'
              .format(name, v['cycles'], v['expected'], v['slack'], v['overruns'],
                      'ok' if v['ok'] else 'FAIL'))
    out = {'count': args.count, 'seed': args.seed, 'period_ms': args.period_ms,
           'seconds_per_port': args.seconds_per_port, 'elapsed_s': elapsed / 1e9,
           'ports': [dataclasses.asdict(r) for r in results], 'tasks': tasks_end,
           'cycle_verdicts': verdicts}
    if args.json:
        with open(args.json, 'w') as f:
            json.dump(out, f, indent=1)
    if args.results:
        _write_results(args.results, out)
    ok = all(r.ok for r in results) and all(v['ok'] for v in verdicts.values())
    return 0 if ok else 1


def _write_results(outdir: str, out: dict[str, Any]) -> None:
    os.makedirs(outdir, exist_ok=True)
    with open(os.path.join(outdir, 'results.json'), 'w') as f:
        json.dump(out, f, indent=1)
    periods = ('at {:g} ms periods'.format(out['period_ms']) if out['period_ms']
               else 'at its configured periods and priorities')
    lines = ['# m4k fuzz', '',
             '`make fuzz` (`fuzz --count {}`): the configured RT task set {} with its real XDDP '
             'ports; a sender process per port writes a deterministic stream of valid, mutated, '
             'random and oversize datagrams; {:.0f} s in all.'.format(
                 out['count'], periods, out['elapsed_s']), '',
             '| port | sent | malformed | oversize | unexpected | accepted | body errors | '
             'result |', '|---|---|---|---|---|---|---|---|']
    for p in out['ports']:
        e = p['expected']
        lines.append('| {} | {} | {} | {} | {} | {} | {} | {} |'.format(
            p['label'], e['sent'], p['malformed'], p['oversize'], p['unexpected'],
            e['accepted'], p['body_errors'], 'ok' if p['ok'] else '; '.join(p['problems'])))
    lines += ['', '| task | period (ms) | cycles while fuzzing | expected | overruns | result |',
              '|---|---|---|---|---|---|']
    for name, v in out['cycle_verdicts'].items():
        lines.append('| {} | {:g} | {} | {:.1f} ± {:.1f} | {} | {} |'.format(
            name, v['period_ms'], v['cycles'], v['expected'], v['slack'], v['overruns'],
            'ok' if v['ok'] else 'FAIL'))
    with open(os.path.join(outdir, 'report.md'), 'w') as f:
        f.write('\n'.join(lines) + '\n')


if __name__ == '__main__':
    sys.exit(main())
