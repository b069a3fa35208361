"""Benchmark the XDDP emulation's round trip against a raw Unix SOCK_SEQPACKET ping-pong.

Both measurements use the same shape: a measuring thread in this process (SCHED_FIFO when
permitted) sends a 32-byte datagram to an echoing peer in a child process, waits in one
blocking ``poll`` on the socket until the echo is readable, then receives it. The XDDP run
receives the way every RT task body does (:class:`m4k_rt.tasks.portio.PortReader`):
``RtXddpSocket.recv_into`` -- non-blocking, a ``poll(0)`` for openers and the counters -- after
``RtXddpSocket.send``; the echo is an ``NrtXddpEndpoint``. The raw run waits in the same
``poll`` and then calls ``recv_into`` on a plain non-blocking SOCK_SEQPACKET socket, so the
difference is the emulation's own cost on the tasks' path (the wait itself stands in for the
task's timerfd wake-up and is the same on both sides). Timing is reported, never asserted.

``--transport shm`` runs the XDDP side over the shared-memory rings instead: the measuring
thread waits in the same ``poll`` on the port's fd (with shm, the eventfd the peer writes per
datagram; reset after the wait) and receives from the ring; the raw run is unchanged.
"""

import argparse
import os
import select
import signal
import socket
import sys
import tempfile
import threading
import time
from typing import Callable

from m4k_bringup.child import Child, Launch, Output, Stopping
from m4k_rt import channel, rosargs

_PAYLOAD = bytes(range(32))
_WARMUP = 50
_REPLY_TIMEOUT_MS = 2000
_PKG_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _percentiles(samples_ns: list[int]) -> dict[str, float]:
    s = sorted(samples_ns)
    n = len(s)

    def pick(q: float) -> float:
        return s[min(n - 1, int(q * (n - 1) + 0.5))] / 1000.0

    return {'n': n, 'p50_us': pick(0.5), 'p99_us': pick(0.99), 'max_us': s[-1] / 1000.0,
            'min_us': s[0] / 1000.0}


def _spawn(*args: str, cpu: int | None = None) -> Child:
    """Start an echo peer; its first stdout line says it is ready.

    It exits when the link closes; :meth:`Child.stop` SIGKILLs one that did not.
    """
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(filter(None, [_PKG_ROOT, env.get('PYTHONPATH')]))
    return Child('echo peer', [sys.executable, '-m', 'm4k_bench.xddp_bench', *args], env,
                 output=Output(pipes=('stdout',)),
                 stopping=Stopping(sig=signal.SIGKILL),
                 launch=Launch(cpu=cpu)).start()


def _echo_xddp(port: int, runtime_dir: str) -> None:
    ep = channel.nrt_xddp_open(port, wait=30.0, runtime_dir=runtime_dir)
    print('ready', flush=True)
    try:
        while True:
            ep.write(ep.read())
    except BrokenPipeError:
        pass
    finally:
        ep.close()


def _echo_raw(path: str) -> None:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    sock.connect(path)
    print('ready', flush=True)
    buf = bytearray(65536)  # same buffering as NrtXddpEndpoint.read, for a fair baseline
    view = memoryview(buf)
    try:
        while True:
            n = sock.recv_into(buf)
            if not n:
                break
            sock.sendall(bytes(view[:n]))
    finally:
        sock.close()


def _in_rt_thread(body: Callable[[], list[int]], priority: int,
                  cpu: int | None = None) -> tuple[list[int], bool]:
    """Run ``body`` in a thread at SCHED_FIFO ``priority`` if permitted, pinned to ``cpu``."""
    out: dict[str, object] = {}

    def run() -> None:
        if cpu is not None:
            os.sched_setaffinity(0, {cpu})
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
            out['fifo'] = True
        except (PermissionError, OSError):
            out['fifo'] = False
        try:
            out['samples'] = body()
        except BaseException as exc:  # re-raised in the caller's thread
            out['error'] = exc

    thread = threading.Thread(target=run, name='xddp-bench-rt')
    thread.start()
    thread.join()
    if 'error' in out:
        raise out['error']  # type: ignore[misc]
    return out['samples'], bool(out['fifo'])  # type: ignore[return-value]


def _xddp_rtt(n: int, runtime_dir: str, port: int, priority: int,
              cpu: int | None, transport: str = 'socket') -> tuple[list[int], bool]:
    rt = channel.rt_xddp_bind(port, runtime_dir=runtime_dir, transport=transport)
    peer = _spawn('--echo-xddp', str(port), '--runtime-dir', runtime_dir, cpu=cpu)
    try:
        deadline = time.monotonic() + 30.0
        while not rt.poll_peer():
            if time.monotonic() > deadline or not peer.alive():
                raise RuntimeError('XDDP echo peer did not link')
            time.sleep(0.001)
        assert peer.proc is not None and peer.proc.stdout is not None
        peer.proc.stdout.readline()

        def body() -> list[int]:
            buf = bytearray(rt.max_datagram)
            clock = time.monotonic_ns
            readable = select.poll()
            wake_fd = rt.fileno()
            readable.register(wake_fd, select.POLLIN)
            wait = readable.poll
            shm = transport == 'shm'
            samples = []
            for i in range(n + _WARMUP):
                t0 = clock()
                if not rt.send(_PAYLOAD):
                    raise RuntimeError('XDDP send dropped: {}'.format(rt.counters.as_dict()))
                if not wait(_REPLY_TIMEOUT_MS):
                    raise RuntimeError('no XDDP echo within {} ms'.format(_REPLY_TIMEOUT_MS))
                if shm:
                    os.eventfd_read(wake_fd)
                if not rt.recv_into(buf):
                    raise RuntimeError('XDDP echo signalled but not received: {}'.format(
                        rt.counters.as_dict()))
                t1 = clock()
                if i >= _WARMUP:
                    samples.append(t1 - t0)
            return samples

        return _in_rt_thread(body, priority, cpu)
    finally:
        rt.close()
        peer.wait(5.0)
        peer.stop()


def _raw_rtt(n: int, runtime_dir: str, priority: int,
             cpu: int | None) -> tuple[list[int], bool]:
    path = os.path.join(runtime_dir, 'bench-raw.sock')
    if os.path.exists(path):
        os.unlink(path)
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    peer = None
    try:
        listener.bind(path)
        listener.listen(1)
        peer = _spawn('--echo-raw', path, cpu=cpu)
        listener.settimeout(30.0)
        conn, _ = listener.accept()
        conn.setblocking(False)
        assert peer.proc is not None and peer.proc.stdout is not None
        peer.proc.stdout.readline()

        def body() -> list[int]:
            clock = time.monotonic_ns
            buf = bytearray(4096)
            readable = select.poll()
            readable.register(conn.fileno(), select.POLLIN)
            wait = readable.poll
            samples = []
            for i in range(n + _WARMUP):
                t0 = clock()
                conn.send(_PAYLOAD)
                if not wait(_REPLY_TIMEOUT_MS) or not conn.recv_into(buf):
                    raise RuntimeError('no raw echo within {} ms'.format(_REPLY_TIMEOUT_MS))
                t1 = clock()
                if i >= _WARMUP:
                    samples.append(t1 - t0)
            return samples

        try:
            return _in_rt_thread(body, priority, cpu)
        finally:
            conn.close()
    finally:
        listener.close()
        if os.path.exists(path):
            os.unlink(path)
        if peer is not None:
            peer.wait(5.0)
            peer.stop()


def run_rtt(n: int, runtime_dir: str | None, *, port: int = 31, priority: int = 80,
            cpu: int | None = -1, transport: str = 'socket') -> dict:
    """Measure ``n`` XDDP and raw SEQPACKET round trips; return µs percentiles for both.

    Both transports run with the measuring thread and the echo peer pinned to the same CPU
    (``cpu=-1``: the last one; ``None``: no pinning). Unpinned, the result depends on whether
    the scheduler puts the two on one CPU (a context switch each way) or on two (a
    cross-CPU wake-up each way, tens of microseconds on a VM), and the ratio measures that
    placement instead of the transports.
    """
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError('n must be a positive int, got {!r}'.format(n))
    runtime_dir = channel.ensure_runtime_dir(runtime_dir)
    if cpu == -1:
        cpu = max(os.sched_getaffinity(0))
    xddp_samples, fifo = _xddp_rtt(n, runtime_dir, port, priority, cpu, transport)
    raw_samples, _ = _raw_rtt(n, runtime_dir, priority, cpu)
    xs = _percentiles(xddp_samples)
    rs = _percentiles(raw_samples)
    return {'xddp': xs, 'raw': rs, 'sched_fifo': fifo, 'payload_bytes': len(_PAYLOAD),
            'cpu': cpu, 'transport': transport,
            'p50_ratio': xs['p50_us'] / rs['p50_us'] if rs['p50_us'] else float('nan')}


def main(argv: list[str] | None = None) -> int:
    """Run the round-trip benchmark and print a small table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('-n', type=int, default=5000, help='round trips per transport')
    parser.add_argument('--runtime-dir', default=None,
                        help='runtime directory (default: a fresh temporary one)')
    parser.add_argument('--port', type=int, default=31, help='XDDP port to use')
    parser.add_argument('--cpu', type=int, default=-1,
                        help='CPU for the measuring thread and the echo peer (-1: the last '
                        'one; -2: no pinning)')
    parser.add_argument('--transport', choices=channel.TRANSPORTS, default='socket',
                        help='XDDP transport of the measured port (default %(default)s)')
    parser.add_argument('--echo-xddp', type=int, metavar='PORT', help=argparse.SUPPRESS)
    parser.add_argument('--echo-raw', metavar='PATH', help=argparse.SUPPRESS)
    args = rosargs.parse_args(parser, argv)
    if args.echo_xddp is not None:
        _echo_xddp(args.echo_xddp, args.runtime_dir)
        return 0
    if args.echo_raw is not None:
        _echo_raw(args.echo_raw)
        return 0
    with tempfile.TemporaryDirectory(prefix='m4kb') as tmp:
        result = run_rtt(args.n, args.runtime_dir or os.path.join(tmp, 'rt'), port=args.port,
                         cpu=None if args.cpu == -2 else args.cpu, transport=args.transport)
    print('round trip of a {}-byte datagram, n={}, RT thread SCHED_FIFO: {}, CPU: {}, XDDP '
          'transport: {}'.format(result['payload_bytes'], args.n, result['sched_fifo'],
                                 result['cpu'], args.transport))
    print('{:<10}{:>10}{:>10}{:>10}{:>10}'.format('transport', 'min us', 'p50 us', 'p99 us',
                                                  'max us'))
    for name in ('xddp', 'raw'):
        r = result[name]
        print('{:<10}{:>10.1f}{:>10.1f}{:>10.1f}{:>10.1f}'.format(
            name, r['min_us'], r['p50_us'], r['p99_us'], r['max_us']))
    print('xddp/raw p50 ratio: {:.2f}'.format(result['p50_ratio']))
    return 0


if __name__ == '__main__':
    sys.exit(main())
