"""Stall probes: tell a host stall from an RT task's own overrun.

On a shared VM the host sometimes does not run a vCPU for milliseconds; every thread on it,
however high its priority, wakes late, and an RT task overruns through no fault of its own. A
probe is a separate process per CPU, pinned to it, SCHED_FIFO at a priority above every RT
task, doing nothing but wake on an absolute 1 ms timerfd. Nothing the RT process does can delay
it (it has its own interpreter, outranks the RT threads and never shares their CPU time), so a
probe wake-up later than ``threshold`` means the CPU itself did not run: a host (or kernel)
stall. An RT overrun during which one CPU's probe was stalled for at least half of the task's
lateness is the host's (:func:`explained_by`); any other is the RT process's own.

A probe prints one JSON line when ready, one per stall (``rel``: the release it missed first,
``wake``: when it ran, ns CLOCK_MONOTONIC) and a summary line on SIGTERM.

Run by :class:`StallProbes`; by hand: ``python -m m4k_bench.benchlib.stallprobe --cpu 0``.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
from typing import Any, Sequence

from m4k_bringup.child import Child, Output, Stopping
from m4k_rt import sched
from m4k_rt.timerfd import monotonic_ns, TimerFd

__all__ = ['Stall', 'StallProbes', 'explained_by', 'main']

PRIORITY = 99
PERIOD_NS = 1_000_000
THRESHOLD_NS = 1_000_000   # a wake-up this late (from its first missed release) is a stall

Stall = tuple[int, int, int]   # (cpu, start ns, end ns)


def explained_by(start_ns: int, end_ns: int, need_ns: int,
                 stalls: Sequence[Stall]) -> tuple[int, int] | None:
    """Return (cpu, stalled ns) when one CPU's probe stalls cover ``need_ns`` of the span.

    The span ``[start_ns, end_ns]`` is when an RT task should have run but did not. The RT
    threads are not pinned, so any CPU may be the one it was on; that CPU's probe must have
    been stalled for at least ``need_ns`` of the span (the caller passes a share of the task's
    lateness) -- a short stall that merely overlaps does not explain a long delay.
    """
    per_cpu: dict[int, int] = {}
    for cpu, a, b in stalls:
        overlap = min(b, end_ns) - max(a, start_ns)
        if overlap > 0:
            per_cpu[cpu] = per_cpu.get(cpu, 0) + overlap
    if not per_cpu:
        return None
    cpu, ns = max(per_cpu.items(), key=lambda kv: kv[1])
    return (cpu, ns) if ns >= need_ns else None


def _probe(cpu: int, period_ns: int, priority: int, threshold_ns: int) -> int:
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    info: dict[str, Any] = {'ready': True, 'cpu': cpu, 'pid': os.getpid()}
    try:
        sched.set_thread_affinity(cpu)
        sched.set_thread_fifo(priority)
        info['fifo'] = True
    except (sched.SchedError, ValueError) as exc:
        info['fifo'] = False
        info['error'] = str(exc)
    print(json.dumps(info), flush=True)
    tfd = TimerFd()
    rel = monotonic_ns() + period_ns
    tfd.set_abs(rel, period_ns)
    rel -= period_ns
    wakes = stalls = 0
    worst = 0
    while not stop.is_set():
        exp = tfd.read()
        now = monotonic_ns()
        first = rel + period_ns            # the first release this wake-up serves
        rel += exp * period_ns
        late = now - first
        wakes += 1
        worst = max(worst, late)
        if late > threshold_ns:
            stalls += 1
            print(json.dumps({'rel': first, 'wake': now, 'late': late}), flush=True)
    tfd.close()
    print(json.dumps({'wakes': wakes, 'stalls': stalls, 'max_late_ns': worst}), flush=True)
    return 0


class StallProbes:
    """One probe process per CPU of this process's affinity; collects their stalls."""

    def __init__(self, period_ns: int = PERIOD_NS, threshold_ns: int = THRESHOLD_NS,
                 priority: int = PRIORITY) -> None:
        """Start the probes now (each in its own session, stopped by its pid)."""
        self.threshold_ns = threshold_ns
        self.stalls: list[Stall] = []
        self.info: dict[int, dict[str, Any]] = {}
        self.summary: dict[int, dict[str, Any]] = {}
        self._lock = threading.Lock()
        self._procs: list[Child] = []
        self._threads: list[threading.Thread] = []
        for cpu in sorted(os.sched_getaffinity(0)):
            c = Child('stallprobe-{}'.format(cpu),
                      [sys.executable, '-m', 'm4k_bench.benchlib.stallprobe', '--cpu', str(cpu),
                       '--period-ns', str(period_ns), '--threshold-ns', str(threshold_ns),
                       '--priority', str(priority)],
                      output=Output(pipes=('stdout',), log_path=os.devnull, log_header=False),
                      stopping=Stopping(timeout=5.0)).start()
            self._procs.append(c)
            th = threading.Thread(target=self._read, args=(cpu, c.proc), daemon=True,
                                  name='stallprobe-{}'.format(cpu))
            th.start()
            self._threads.append(th)

    def _read(self, cpu: int, p: subprocess.Popen[str]) -> None:
        assert p.stdout is not None
        for line in p.stdout:
            try:
                d = json.loads(line)
            except ValueError:
                continue
            with self._lock:
                if 'rel' in d:
                    self.stalls.append((cpu, int(d['rel']), int(d['wake'])))
                elif 'ready' in d:
                    self.info[cpu] = d
                else:
                    self.summary[cpu] = d

    def ready(self) -> bool:
        """Tell whether every probe has started (and said whether it got SCHED_FIFO)."""
        with self._lock:
            return len(self.info) == len(self._procs)

    def snapshot(self) -> list[Stall]:
        """Return the stalls seen so far."""
        with self._lock:
            return list(self.stalls)

    def stop(self) -> list[Stall]:
        """Stop every probe (SIGTERM by pid, SIGKILL after 5 s); return all stalls seen."""
        for c in self._procs:
            if c.alive():
                c.send_signal(signal.SIGTERM)
        for c in self._procs:
            c.wait(5.0)
        for th in self._threads:
            th.join(5.0)
        for c in self._procs:
            c.stop()          # SIGKILL for one that did not end; closes its pipe
        return self.snapshot()


def main(argv: Sequence[str] | None = None) -> int:
    """Run one probe until SIGTERM."""
    ap = argparse.ArgumentParser(prog='stallprobe', description=__doc__.split('\n')[0])
    ap.add_argument('--cpu', type=int, required=True)
    ap.add_argument('--period-ns', type=int, default=PERIOD_NS)
    ap.add_argument('--threshold-ns', type=int, default=THRESHOLD_NS)
    ap.add_argument('--priority', type=int, default=PRIORITY)
    args = ap.parse_args(argv)
    return _probe(args.cpu, args.period_ns, args.priority, args.threshold_ns)


if __name__ == '__main__':
    sys.exit(main())
