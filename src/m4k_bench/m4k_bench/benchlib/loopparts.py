"""The parts of an RT task cycle, each timed alone in a tight loop (CPU µs per call).

The kernel wait is measured by the floor (:mod:`m4k_bench.benchlib.floor`); the rest of a cycle
is made of these parts, timed here on the real objects the tasks use:

* ``clock``: ``timerfd.monotonic_ns`` (t_start, t_end);
* ``drain_decode``: ``PortReader.next`` receiving and decoding one VELOCITY_CMD from a real RT
  XDDP socket (the NRT peer's write is outside the timed section);
* ``drain_empty``: ``PortReader.next`` on an empty socket (every port, every cycle);
* ``encode_send``: ``PortWriter.send`` of one WHEEL_CMD to a real peer;
* ``timing_record``: ``SampleRing.record``;
* ``rusage``: ``ThreadRusage.update`` divided by ``task.RUSAGE_EVERY`` (as often as it runs).

A body's control part is its measured response minus its ports' parts. Numbers only: what a
part costs here, on this interpreter, in a loop with warm caches.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import threading
import time
from typing import Callable

from m4k_rt import channel, modeswitch, protocol, task, timing
from m4k_rt.tasks.portio import PortReader, PortWriter
from m4k_rt.timerfd import monotonic_ns

__all__ = ['measure_parts']


def _best(fn: Callable[[], object], n: int, reps: int = 5,
          between: Callable[[], object] | None = None) -> float:
    """Return the lowest mean µs per call of ``fn`` over ``reps`` runs of ``n`` calls."""
    best = float('inf')
    clock = time.perf_counter_ns
    for _ in range(reps):
        if between is None:
            t0 = clock()
            for _ in range(n):
                fn()
            best = min(best, (clock() - t0) / n)
        else:
            total = 0
            for _ in range(n):
                between()
                t0 = clock()
                fn()
                total += clock() - t0
            best = min(best, total / n)
    return best / 1e3


def measure_parts(n: int = 2000) -> dict[str, float]:
    """Time every part of a cycle; return µs per call (per cycle for rusage)."""
    base = tempfile.mkdtemp(prefix='m4kp')
    rundir = os.path.join(base, 'rt')
    channel.ensure_runtime_dir(rundir)
    rt = channel.rt_xddp_bind(30, 'parts', runtime_dir=rundir)
    ep = None
    try:
        opened: list[channel.NrtXddpEndpoint] = []
        opener = threading.Thread(target=lambda: opened.append(
            channel.nrt_xddp_open(30, wait=10.0, runtime_dir=rundir)), daemon=True)
        opener.start()
        end = time.monotonic() + 10.0
        while opener.is_alive() and time.monotonic() < end:
            rt.poll_peer()    # the RT side accepts the opener, as a task's drain would
            time.sleep(0.001)
        opener.join(1.0)
        if not opened:
            raise RuntimeError('loop parts: the NRT peer did not link')
        ep = opened[0]
        reader = PortReader(rt)
        writer = PortWriter(rt)
        cmd = protocol.encode(protocol.Kind.VELOCITY_CMD, 1, monotonic_ns(), 0.25, 0.0)

        def feed() -> None:
            ep.write(cmd)
            reader.start_cycle()

        def drained() -> None:
            try:
                while True:
                    ep.read(0.0)
            except TimeoutError:
                pass

        ring = timing.SampleRing(4096)
        ru = modeswitch.ThreadRusage()
        ru.start()
        def drain_empty() -> None:
            reader.start_cycle()
            reader.next()

        out = {
            'clock': _best(monotonic_ns, n * 10),
            'drain_decode': _best(reader.next, n, between=feed),
            'drain_empty': _best(drain_empty, n),
            'encode_send': _best(lambda: writer.send(protocol.Kind.WHEEL_CMD, 0, 512, 512, 0),
                                 n, between=drained),
            'timing_record': _best(lambda: ring.record(1, 2, 3, 1), n * 10),
            'rusage': _best(lambda: ru.update(5), n) / task.RUSAGE_EVERY,
        }
        return out
    finally:
        if ep is not None:
            ep.close()
        rt.close()
        shutil.rmtree(base, ignore_errors=True)
