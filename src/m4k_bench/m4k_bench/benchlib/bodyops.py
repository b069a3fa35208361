"""Python opcodes and calls per cycle of the RT task bodies: a count, not a clock.

On a shared VM the CPU per cycle of the full stack swings more than a trim of the loop can move
it (docs/design-notes.md, 9b). What a trim changes exactly is how much Python a cycle runs, so
this counts it: each body (actuator, imu, sonar, led) is built on real RT XDDP sockets with real
NRT peers, fed what its device sends every cycle (ENCODERS, and a VELOCITY_CMD every fifth
cycle; an IMU sample; a SONAR reading; nothing for the LED), and called under ``sys.settrace``
with opcode events on. The result per body: Python opcodes and Python function calls per body
call, in total and per function (``file:function``). C calls (system calls, ``struct``) are not
opcodes and are not counted. Each body runs on a virtual clock that advances one period per
cycle (the bodies' own ``clock`` argument; its peers stamp with the same clock), so the branches
that read the time (the controller's dt clamp, the freshness checks, the LED's blink phase) take
the same way every run: the same code gives the same counts on any machine, however loaded.

Run ``python -m m4k_bench.benchlib.bodyops [--cycles N] [--functions]``; to compare two
versions, put one first on ``PYTHONPATH`` (as ``loop_ab`` does).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import threading
import time
from types import FrameType
from typing import Any, Callable, Sequence

from m4k_rt import channel, protocol
from m4k_rt.control.params import control_params
from m4k_rt.protocol import Kind
from m4k_rt.tasks.actuator import ActuatorBody
from m4k_rt.tasks.imu import ImuBody
from m4k_rt.tasks.led import LedBody
from m4k_rt.tasks.sonar import SonarBody
from m4k_rt.tasks.state import RobotState

__all__ = ['BODIES', 'count_ops', 'main']

BODIES = ('actuator', 'imu', 'sonar', 'led')
_PERIOD_NS = 10_000_000


def _link(port: int, rundir: str) -> tuple[channel.RtXddpSocket, channel.NrtXddpEndpoint]:
    rt = channel.rt_xddp_bind(port, runtime_dir=rundir)
    got: list[channel.NrtXddpEndpoint] = []
    opener = threading.Thread(target=lambda: got.append(
        channel.nrt_xddp_open(port, wait=10.0, runtime_dir=rundir)), daemon=True)
    opener.start()
    end = time.monotonic() + 10.0
    while opener.is_alive() and time.monotonic() < end:
        rt.poll_peer()
        time.sleep(0.001)
    opener.join(1.0)
    if not got:
        rt.close()
        raise RuntimeError('bodyops: the NRT peer of port {} did not link'.format(port))
    return rt, got[0]


def _drain(ep: channel.NrtXddpEndpoint) -> None:
    try:
        while True:
            ep.read(0.0)
    except TimeoutError:
        pass


class _Clock:
    """A virtual monotonic clock: one period further each cycle, whatever the machine does."""

    def __init__(self) -> None:
        self.t = 1_000 * 1_000_000_000     # a fixed start: the blink phase is the same each run

    def __call__(self) -> int:
        return self.t


def _rig(name: str, a: channel.RtXddpSocket, ea: channel.NrtXddpEndpoint, b: channel.RtXddpSocket,
         eb: channel.NrtXddpEndpoint, state: RobotState,
         clock: _Clock) -> tuple[Callable[..., object], Callable[[int], None]]:
    """Return the body and its per-cycle feed (what its peers send before cycle ``k``)."""
    if name == 'actuator':
        body: Callable[..., object] = ActuatorBody(a, b, state, control_params(None), 0.01,
                                                   clock=clock)

        def feed(k: int) -> None:
            now = clock()
            state.sonar_range, state.sonar_rx_ns = 2.0, now   # a wall 2 m ahead, fresh
            state.laser_front_min, state.laser_rx_ns = 3.0, now
            angle = 0.02 * k
            eb.write(protocol.encode(Kind.ENCODERS, k, k * _PERIOD_NS, 100, 100, angle, angle,
                                     0))
            if k % 5 == 0:
                ea.write(protocol.encode(Kind.VELOCITY_CMD, k, now, 0.25, 0.1))
        return body, feed
    if name == 'imu':
        body = ImuBody(a, b, state, clock=clock)

        def feed(k: int) -> None:
            ea.write(protocol.encode(Kind.IMU, k, clock(), 1.0, 0.0, 0.0, 0.0, 0.0,
                                     0.0, 0.0, 0.0, 0.0, 9.8, 0))
        return body, feed
    if name == 'sonar':
        body = SonarBody(a, b, state, clock=clock)

        def feed(k: int) -> None:
            ea.write(protocol.encode(Kind.SONAR, k, clock(), 1.5, 0))
        return body, feed
    if name == 'led':
        return LedBody(a, b, state, clock=clock), lambda k: None
    raise ValueError('unknown body {!r} (one of {})'.format(name, ', '.join(BODIES)))


def _tracer(ops: list[int], per: dict[str, int]) -> Callable[[FrameType, str, Any], Any]:
    """Return a trace function counting opcodes (ops[0], per function) and calls (ops[1])."""
    def tracer(frame: FrameType, event: str, arg: Any) -> Any:
        frame.f_trace_opcodes = True
        if event == 'opcode':
            ops[0] += 1
            code = frame.f_code
            key = '{}:{}'.format(os.path.basename(code.co_filename), code.co_name)
            per[key] = per.get(key, 0) + 1
        elif event == 'call':
            ops[1] += 1
        return tracer
    return tracer


def count_ops(names: Sequence[str] = BODIES, cycles: int = 200,
              warmup: int = 50) -> dict[str, dict[str, Any]]:
    """Return, per body: opcodes and calls per call, cycles counted, opcodes per function."""
    base = tempfile.mkdtemp(prefix='m4k-bodyops-')
    rundir = os.path.join(base, 'rt')
    channel.ensure_runtime_dir(rundir)
    socks: list[channel.RtXddpSocket] = []
    peers: list[channel.NrtXddpEndpoint] = []
    out: dict[str, dict[str, Any]] = {}
    try:
        port = 1
        for name in names:
            a, ea = _link(port, rundir)
            b, eb = _link(port + 1, rundir)
            port += 2
            socks += [a, b]
            peers += [ea, eb]
            state = RobotState()
            clock = _Clock()
            body, feed = _rig(name, a, ea, b, eb, state, clock)
            for k in range(1, warmup + 1):        # links, first calls, the odometry baseline
                clock.t += _PERIOD_NS
                feed(k)
                body(None)
                _drain(ea)
                _drain(eb)
            ops = [0, 0]
            per: dict[str, int] = {}
            tracer = _tracer(ops, per)
            for k in range(warmup + 1, warmup + cycles + 1):
                clock.t += _PERIOD_NS
                feed(k)
                sys.settrace(tracer)
                try:
                    body(None)
                finally:
                    sys.settrace(None)
                _drain(ea)
                _drain(eb)
            out[name] = {'opcodes': ops[0] / cycles, 'calls': ops[1] / cycles,
                         'cycles': cycles, 'body_cycles': getattr(body, 'cycles', None),
                         'functions': {k: v / cycles for k, v in sorted(
                             per.items(), key=lambda kv: -kv[1])}}
        return out
    finally:
        for ep in peers:
            ep.close()
        for s in socks:
            s.close()
        shutil.rmtree(base, ignore_errors=True)


def main(argv: Sequence[str] | None = None) -> int:
    """Count and print the opcodes and calls per cycle of the bodies."""
    ap = argparse.ArgumentParser(prog='bodyops', description=__doc__.splitlines()[0])
    ap.add_argument('--cycles', type=int, default=200, help='cycles counted per body')
    ap.add_argument('--functions', action='store_true', help='also opcodes per function')
    ap.add_argument('--bodies', default=','.join(BODIES), help='comma list of bodies')
    args = ap.parse_args(argv)
    if args.cycles < 1:
        ap.error('--cycles must be >= 1')
    res = count_ops([b for b in args.bodies.split(',') if b], args.cycles)
    for name, r in res.items():
        sys.stdout.write('{:9s} {:7.1f} opcodes {:5.1f} calls per cycle\n'.format(
            name, r['opcodes'], r['calls']))
        if args.functions:
            for fn, n in r['functions'].items():
                sys.stdout.write('    {:7.1f}  {}\n'.format(n, fn))
    return 0


if __name__ == '__main__':
    sys.exit(main())
