"""The Python floor of an RT loop: bare SCHED_FIFO timerfd threads doing nothing else.

Each thread does what every m4k task cycle must do and nothing more: wait on its absolute
timerfd (wake), read the expiration count (read), read the clock (clock read). Run with the
same periods, priorities, phases and CPU pinning (``--cpus``, the tasks' ``cpu:``) as the task
set, in a process hardened like rt_core
(SCHED_FIFO, mlockall, gc frozen and off, the same switch interval), its process CPU per cycle
(thread CPU time from the first wake to the last, summed over the threads, over the cycles
run) is the least any Python task loop can cost on this machine; the bench reports m4k's CPU per
cycle divided by it.

With ``--probe`` every cycle also runs one probe call twice after the wake -- decoding a
VELOCITY_CMD datagram with ``protocol.decode_from``, as the actuator does -- and times each call
with the thread's CPU clock: the first call is the cold one (the first code after the sleep, as
in a task), the second the same code warm. The medians of both over the run test the "cold
caches after every sleep" hypothesis inside a periodic loop (a probed floor's CPU per cycle is
not the floor's; the bench runs it apart).

With ``--channel socket`` every cycle also makes the system calls a device task's channel
makes on the XDDP emulation's Unix sockets, and nothing else (no m4k code): a ``poll(0)`` and two
``recv_into`` of the two datagrams the thread sent itself in the cycle before, a ``poll(0)`` that
finds the socket empty, two non-blocking ``send`` -- the traffic of an actuator or IMU cycle (a
request to the driver host, the state to the bridge, one reply in). ``--channel shm`` moves the
same two datagrams through a shared mapping with ``pack_into`` / ``unpack_from`` instead (no
system call). Their CPU per cycle is what the channel alone costs above the floor: the least an
RT loop that talks over that channel can cost, whatever its Python does.

Run as a child process (``python -m m4k_bench.benchlib.floor --periods-ms 10,10,20 ...``); it
prints one JSON line: CPU µs per cycle, cycles and thread CPU per thread, and the release
latency (µs, from the missed release, as cyclictest) per thread.
"""

from __future__ import annotations

import argparse
from array import array
import gc
import json
import mmap
import os
import select
import socket
import struct
import sys
import threading
import time
from typing import Callable, Sequence

from m4k_rt import sched, timing
from m4k_rt.timerfd import monotonic_ns, TimerFd

__all__ = ['CHANNELS', 'main', 'run_floor', 'run_floor_child']

CHANNELS = ('none', 'socket', 'shm')
_DATAGRAM = 48                            # bytes: a WHEEL_CMD-sized datagram


def _probe_call() -> Callable[[], object]:
    """Return the probe: decode one VELOCITY_CMD datagram (the actuator's receive path)."""
    from m4k_rt import protocol
    buf = bytearray(protocol.encode(protocol.Kind.VELOCITY_CMD, 1, 1, 0.25, 0.0))
    n = len(buf)
    decode = protocol.decode_from

    def call() -> object:
        return decode(buf, n)
    return call


def _channel_call(channel: str) -> tuple[Callable[[], int] | None, Callable[[], None]]:
    """Return one cycle's channel traffic (None for ``none``) and its clean-up."""
    if channel == 'none':
        return None, lambda: None
    if channel == 'socket':
        a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        b.setblocking(False)
        p = select.poll()
        p.register(b, select.POLLIN)
        poll, recv_into, send = p.poll, b.recv_into, a.send
        out, rbuf = bytes(_DATAGRAM), bytearray(4096)
        flags = socket.MSG_DONTWAIT | socket.MSG_NOSIGNAL

        def sock() -> int:
            got = 0
            if poll(0):                       # the two datagrams of the cycle before
                got = recv_into(rbuf) + recv_into(rbuf)
            poll(0)                           # the port found empty
            send(out, flags)                  # the request to the driver host
            send(out, flags)                  # the state to the bridge
            return got

        def close() -> None:
            a.close()
            b.close()
        return sock, close
    if channel == 'shm':
        region = mmap.mmap(-1, 4096)
        st = struct.Struct('<IIqdddddd')     # 64 bytes: header and six fields
        pack, unpack = st.pack_into, st.unpack_from
        seq = [0]

        def shm() -> int:
            n = seq[0] + 1
            seq[0] = n
            got = unpack(region, 128)[1] + unpack(region, 192)[1]   # the cycle before's two
            pack(region, 128, 1, n, 0, 0.1, 0.2, 0.0, 0.0, 0.0, 0.0)   # two datagrams out
            pack(region, 192, 2, n, 0, 0.1, 0.2, 0.0, 0.0, 0.0, 0.0)
            return got
        return shm, region.close
    raise ValueError('channel {!r}: expected one of {}'.format(channel, ', '.join(CHANNELS)))


def _loop(period_ns: int, priority: int, first_ns: int, stop_ns: int, out: dict,
          probe: bool = False, channel: str = 'none', pin: int | None = None) -> None:
    try:
        sched.set_thread_fifo(priority)
        out['fifo'] = True
    except sched.SchedError:
        out['fifo'] = False
    if pin is not None:                       # pinned as the task set pins its task
        try:
            sched.set_thread_affinity(pin)
            out['cpu'] = pin
            out['affinity'] = sorted(os.sched_getaffinity(0))   # the kernel's view
        except sched.SchedError as exc:
            out['affinity_error'] = str(exc)
    cap = int((stop_ns - first_ns) // period_ns) + 2
    rel_a, start_a, exp_a = array('q', bytes(8 * cap)), array('q', bytes(8 * cap)), \
        array('q', bytes(8 * cap))
    tfd = TimerFd()
    tfd.set_abs(first_ns, period_ns)
    rel = first_ns - period_ns
    n = 0
    read = tfd.read
    clock = monotonic_ns
    cpu = time.thread_time_ns
    c0 = 0
    call = _probe_call() if probe else None
    io, io_close = _channel_call(channel)
    cold_a, warm_a = array('q', bytes(8 * cap)), array('q', bytes(8 * cap))
    try:
        while n < cap:
            if n == 1:
                c0 = cpu()                    # after the first wake: start-up not counted
            exp = read()                      # wake + read
            t = clock()                       # clock read
            if io is not None:
                io()                          # --channel: the channel's traffic
            if call is not None:
                p0 = cpu()
                call()                        # cold: the first code after the sleep
                p1 = cpu()
                call()                        # warm: the same code again, same cycle
                cold_a[n], warm_a[n] = p1 - p0, cpu() - p1
            rel += exp * period_ns
            rel_a[n], start_a[n], exp_a[n] = rel, t, exp
            n += 1
            if t >= stop_ns:
                break
        c1 = cpu()
    finally:
        tfd.close()
        io_close()
    if call is not None and n > 2:
        cold = timing.describe([v * 1e-3 for v in cold_a[1:n]])
        warm = timing.describe([v * 1e-3 for v in warm_a[1:n]])
        out['probe_us'] = {'cold_p50': cold.p50, 'warm_p50': warm.p50,
                           'cold_p99': cold.p99, 'warm_p99': warm.p99, 'n': n - 1}
    lat = timing.release_latency(rel_a[:n], start_a[:n], exp_a[:n], period_ns) * 1e-3
    stats = timing.describe(lat)
    out.update(cycles=n, cpu_ns=c1 - c0, cpu_cycles=n - 1,
               latency_us={'p50': stats.p50, 'p99': stats.p99, 'p999': stats.p999,
                           'max': stats.max})


def _frame_loop(periods_ns: Sequence[int], priority: int, first_ns: int, stop_ns: int,
                out: dict, channel: str = 'none', pin: int | None = None) -> None:
    """Run the frame executive's floor: one timerfd at the shortest period.

    The due cycles run back to back (m4k_rt.frame's schedule), each a clock read (+ the
    channel's traffic).
    """
    from m4k_rt.frame import releases
    try:
        sched.set_thread_fifo(priority)
        out['fifo'] = True
    except sched.SchedError:
        out['fifo'] = False
    if pin is not None:
        try:
            sched.set_thread_affinity(pin)
        except sched.SchedError as exc:
            out['affinity_error'] = str(exc)
    frame = min(periods_ns)
    divisors = [p // frame for p in sorted(periods_ns)]
    tfd = TimerFd()
    tfd.set_abs(first_ns, frame)
    io, io_close = _channel_call(channel)
    read, clock, cpu = tfd.read, monotonic_ns, time.thread_time_ns
    k, frames, cycles, c0, cyc0 = -1, 0, 0, 0, 0
    try:
        while True:
            if frames == 1:
                c0, cyc0 = cpu(), cycles          # after the first wake, as _loop
            exp = read()
            k_now = 0 if k < 0 else k + exp
            for d in divisors:
                if releases(k, k_now, d)[0]:
                    t = clock()
                    if io is not None:
                        io()
                    cycles += 1
            k = k_now
            frames += 1
            if t >= stop_ns:
                break
        c1 = cpu()
    finally:
        tfd.close()
        io_close()
    out.update(cycles=cycles, frames=frames, cpu_ns=c1 - c0, cpu_cycles=cycles - cyc0)


def run_floor(periods_ns: Sequence[int], priorities: Sequence[int],
              offsets_ns: Sequence[int], seconds: float, probe: bool = False,
              channel: str = 'none', cpus: Sequence[int | None] | None = None,
              frame: Sequence[int] = ()) -> dict:
    """Run one bare loop per period for ``seconds`` in this process; return the measurements.

    ``cpus``: the CPU each loop is pinned to (None: not pinned), as the task set's ``cpu``.
    ``frame``: indices of the loops one frame thread runs instead (the frame executive's
    structure, :func:`_frame_loop`); the others keep a thread each.
    """
    if cpus is None:
        cpus = [None] * len(periods_ns)
    rep = sched.harden(priority=max(priorities), cpu_dma_latency=False)
    gc.collect()
    gc.freeze()
    gc.disable()
    now = monotonic_ns()
    base = timing.first_release(now + 200_000_000, max(periods_ns))
    stop = base + int(seconds * 1e9)
    own = [i for i in range(len(periods_ns)) if i not in set(frame)]
    outs: list[dict] = [{'period_ns': periods_ns[i]} for i in own]
    threads = [threading.Thread(target=_loop, args=(
        periods_ns[i], priorities[i], base + offsets_ns[i], stop, out, probe, channel, cpus[i]),
        daemon=True) for i, out in zip(own, outs, strict=True)]
    if frame:
        fout: dict = {'periods_ns': [periods_ns[i] for i in frame]}
        outs.append(fout)
        first = min(frame, key=lambda i: (periods_ns[i], -priorities[i]))
        threads.append(threading.Thread(target=_frame_loop, args=(
            [periods_ns[i] for i in frame], priorities[first], base, stop, fout, channel,
            cpus[first]), daemon=True))
    cpu0 = time.process_time()
    t0 = time.monotonic()
    for t in threads:
        t.start()
    for t in threads:
        t.join(seconds + 30.0)
    wall = time.monotonic() - t0
    cpu_ns = sum(o.get('cpu_ns', 0) for o in outs)
    cycles = sum(o.get('cpu_cycles', 0) for o in outs)
    probes = [o['probe_us'] for o in outs if 'probe_us' in o]
    return {'cpu_per_cycle_us': cpu_ns * 1e-3 / cycles if cycles else None,
            'probe_us': _weighted_probe(probes) if probes else None,
            'process_cpu_s': time.process_time() - cpu0, 'wall_s': wall, 'seconds': seconds,
            'channel': channel, 'mem_locked': rep.mem_locked, 'cpus': list(cpus),
            'fifo': all(o.get('fifo') for o in outs), 'frame': list(frame),
            'threads': outs}


def _weighted_probe(probes: Sequence[dict]) -> dict:
    """Return the threads' probe medians weighted by their cycles, and cold ÷ warm."""
    total = sum(p['n'] for p in probes)
    out = {k: sum(p[k] * p['n'] for p in probes) / total
           for k in ('cold_p50', 'warm_p50', 'cold_p99', 'warm_p99')}
    out['cold_over_warm_p50'] = out['cold_p50'] / out['warm_p50'] if out['warm_p50'] else None
    out['n'] = total
    return out


def run_floor_child(periods_ns: Sequence[int], priorities: Sequence[int],
                    offsets_ns: Sequence[int], seconds: float,
                    env: dict[str, str] | None = None, probe: bool = False,
                    channel: str = 'none',
                    cpus: Sequence[int | None] | None = None,
                    frame: Sequence[int] = ()) -> dict | str:
    """Run the floor in a child process (hardened like rt_core); return its JSON or why not."""
    import subprocess

    from m4k_bench.benchlib import stack
    argv = stack.entry_argv(
        'm4k_bench.benchlib.floor',
        '--periods-ms', ','.join('{:g}'.format(p / 1e6) for p in periods_ns),
        '--priorities', ','.join(str(p) for p in priorities),
        '--offsets-ms', ','.join('{:g}'.format(o / 1e6) for o in offsets_ns),
        '--seconds', str(seconds), '--channel', channel, *(['--probe'] if probe else []),
        *(['--frame', ','.join(str(i) for i in frame)] if frame else []),
        *(['--cpus', format_cpus(cpus)] if cpus and any(c is not None for c in cpus) else []))
    try:
        p = subprocess.run(argv, capture_output=True, text=True, timeout=seconds + 60,
                           env=env, check=False)
    except subprocess.TimeoutExpired:
        return 'floor: timed out'
    if p.returncode != 0 or not p.stdout.strip():
        return 'floor: exit {}: {}'.format(p.returncode, p.stderr.strip()[-300:])
    out: dict = json.loads(p.stdout.strip().splitlines()[-1])
    return out


def format_cpus(cpus: Sequence[int | None]) -> str:
    """Return the ``--cpus`` text of a list of CPUs (None: '-', not pinned)."""
    return ','.join('-' if c is None else str(c) for c in cpus)


def parse_cpus(text: str, n: int) -> list[int | None]:
    """Parse ``--cpus`` (``''``: none pinned) for ``n`` loops; ValueError names what is wrong."""
    if not text:
        return [None] * n
    items = text.split(',')
    if len(items) != n:
        raise ValueError('--cpus has {} entries for {} loops'.format(len(items), n))
    out: list[int | None] = []
    for item in items:
        item = item.strip()
        if item == '-':
            out.append(None)
        elif item.isdigit():
            out.append(int(item))
        else:
            raise ValueError("--cpus: {!r} is neither a CPU index >= 0 nor '-'".format(item))
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Parse the task set, run the floor loops, print one JSON line."""
    ap = argparse.ArgumentParser(prog='floor', description=__doc__.splitlines()[0])
    ap.add_argument('--periods-ms', required=True, help='comma list of periods (ms)')
    ap.add_argument('--priorities', required=True, help='comma list of priorities')
    ap.add_argument('--offsets-ms', default='', help='comma list of release offsets (ms)')
    ap.add_argument('--seconds', type=float, default=5.0)
    ap.add_argument('--probe', action='store_true',
                    help='time a cold and a warm decode in every cycle (the cache A-B)')
    ap.add_argument('--channel', choices=CHANNELS, default='none',
                    help="add a task cycle's channel traffic: its socket calls, or the same "
                         'datagrams through shared memory')
    ap.add_argument('--cpus', default='',
                    help="comma list of the CPU each loop is pinned to, '-' for none (the task "
                         "set's cpu:); default: none pinned")
    ap.add_argument('--frame', default='', help='comma list of loop indices one frame thread '
                    'runs back to back (the frame executive), default: none')
    args = ap.parse_args(argv)
    frame = [int(x) for x in args.frame.split(',') if x]
    periods = [int(float(x) * 1e6) for x in args.periods_ms.split(',')]
    prios = [int(x) for x in args.priorities.split(',')]
    offs = [int(float(x) * 1e6) for x in args.offsets_ms.split(',')] if args.offsets_ms \
        else [0] * len(periods)
    try:
        cpus = parse_cpus(args.cpus, len(periods))
    except ValueError as exc:
        ap.error(str(exc))
    if not len(periods) == len(prios) == len(offs):
        ap.error('--periods-ms, --priorities and --offsets-ms differ in length')
    json.dump(run_floor(periods, prios, offs, args.seconds, args.probe, args.channel, cpus,
                        frame),
              sys.stdout)
    sys.stdout.write('\n')
    sys.stdout.flush()
    os._exit(0)  # daemon timer threads: leave at once


if __name__ == '__main__':
    sys.exit(main())
