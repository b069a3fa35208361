"""The fuzzer's links to rt_core: its ``status``/``stat`` observer and the per-port senders.

:class:`Observer` is the NRT side of the two monitor ports for the whole run: it reads every
monitor batch into a :class:`m4k_bench.recorder.Recorder` and writes the fuzz stream of those two
ports itself, between reads. :class:`Sender` runs ``fuzz send LABEL COUNT SEED SECONDS`` (the
NRT side of any other port, :func:`send`) as a process of its own.
"""

from __future__ import annotations

import select
import signal
import sys
import time
from typing import Callable, Iterator, Mapping

from m4k_bench import fuzzstream, recorder
from m4k_bringup.child import Child, Output, Stopping
from m4k_rt import channel, protocol

__all__ = ['MONITOR_PORTS', 'Observer', 'Sender', 'send']

MONITOR_PORTS = ('status', 'stat')


class Observer:
    """The fuzzer's NRT side of ``status`` and ``stat``: every monitor batch, and their streams.

    :meth:`pump` reads whatever the RT side sent (into a :class:`m4k_bench.recorder.Recorder`:
    TASK_STATS samples, TASK_HEALTH, RT_STATUS, PORT_STATS) and, while :meth:`stream` is
    active, writes the fuzz stream of one of these two ports whenever its socket has room.
    ``batches`` counts monitor batches (RT_STATUS on ``status`` closes one).
    """

    def __init__(self, runtime_dir: str, wait_s: float = 30.0) -> None:
        """Open both ports (waiting up to ``wait_s`` for rt_core to bind them)."""
        self.rec = recorder.Recorder()
        self.eps: dict[str, channel.NrtXddpEndpoint] = {}
        self.batches = 0
        self.lost: str | None = None
        self._poll = select.poll()
        self._by_fd: dict[int, str] = {}
        self._out: tuple[str, Iterator[bytes]] | None = None
        self._pending: bytes | None = None
        self._out_end = 0.0
        self.written = 0
        try:
            for label in MONITOR_PORTS:
                ep = channel.nrt_xddp_open(label, wait=wait_s, runtime_dir=runtime_dir)
                self.eps[label] = ep
                self._by_fd[ep.fileno()] = label
                self._poll.register(ep.fileno(), select.POLLIN)
        except BaseException:
            self.close()
            raise

    def stream(self, label: str, data: Iterator[bytes], seconds: float) -> None:
        """Write ``data`` to ``label`` (a monitor port) between reads, for ``seconds`` at most."""
        self._out = (label, data)
        self._out_end = time.monotonic() + seconds
        self._pending = None
        self.written = 0
        self._poll.modify(self.eps[label].fileno(), select.POLLIN | select.POLLOUT)

    @property
    def streaming(self) -> bool:
        """Tell whether a stream still has datagrams to write."""
        return self._out is not None

    def _end_stream(self) -> None:
        if self._out is not None:
            self._poll.modify(self.eps[self._out[0]].fileno(), select.POLLIN)
        self._out = None
        self._pending = None

    def pump(self, timeout_s: float) -> None:
        """Wait up to ``timeout_s`` for traffic; read all that is ready, write what fits."""
        if self.lost:
            time.sleep(timeout_s)
            return
        for fd, ev in self._poll.poll(int(timeout_s * 1000)):
            label = self._by_fd[fd]
            if ev & (select.POLLIN | select.POLLHUP | select.POLLERR):
                self._read(label)
            if ev & select.POLLOUT and self._out is not None and self._out[0] == label:
                self._write(label)

    def _read(self, label: str) -> None:
        ep = self.eps[label]
        for _ in range(256):
            try:
                data = ep.read(0.0)
            except TimeoutError:
                return
            except OSError as exc:
                self.lost = '{}: {}'.format(label, exc)
                self._poll.unregister(ep.fileno())
                return
            kind = self.rec.feed(data)
            if kind == protocol.Kind.RT_STATUS and label == 'status':
                self.batches += 1

    def _write(self, label: str) -> None:
        assert self._out is not None
        ep = self.eps[label]
        for _ in range(64):
            if self._pending is None:
                if time.monotonic() >= self._out_end:
                    self._end_stream()
                    return
                self._pending = next(self._out[1], None)
                if self._pending is None:
                    self._end_stream()
                    return
            try:
                ep.write(self._pending, 0.001)
            except TimeoutError:
                return
            except OSError as exc:
                self.lost = '{}: {}'.format(label, exc)
                self._end_stream()
                return
            self._pending = None
            self.written += 1

    def taken(self, label: str) -> tuple[int, int, int]:
        """Return the RT side's (received, dropped_oversize, malformed) of ``label`` so far."""
        ps = self.rec.port_stats.get(label)
        return (0, 0, 0) if ps is None else (ps.received, ps.dropped_oversize, ps.malformed)

    def unexpected(self, task: str) -> int | None:
        """Return the latest TASK_HEALTH ``unexpected`` count of ``task`` (None: none yet)."""
        ts = self.rec.tasks.get(task)
        return None if ts is None or ts.health is None else ts.health.unexpected

    def wait_batches(self, n: int, timeout_s: float) -> bool:
        """Pump until ``n`` more monitor batches arrived; False on timeout or a lost link."""
        goal = self.batches + n
        end = time.monotonic() + timeout_s
        while self.batches < goal and not self.lost:
            if time.monotonic() > end:
                return False
            self.pump(0.05)
        return not self.lost

    def close(self) -> None:
        """Close both links (the RT side counts a lost peer)."""
        for ep in self.eps.values():
            ep.close()
        self.eps.clear()


def send(label: str, count: int, seed: int, runtime_dir: str | None = None,
         timeout: float = 30.0, seconds: float | None = None,
         hold: Callable[[int], None] | None = None) -> int:
    """Write the fuzz stream of ``label`` through the NRT side; return datagrams written.

    Stops after ``count`` datagrams or ``seconds``, whichever comes first: the writes block
    while the RT side has not drained the socket, so the time bounds the port's turn and
    ``count`` caps it. The link stays open until ``hold(n)`` returns: closing a Unix socket
    that still has unread datagrams (the RT side's own sends) resets the connection, and the
    RT side would then drop what it had not drained yet -- in-flight loss of a dying peer, not
    what this measures.
    """
    n = 0
    end = None if seconds is None else time.monotonic() + seconds
    with channel.nrt_xddp_open(label, wait=10.0, runtime_dir=runtime_dir) as ep:
        for d in fuzzstream.datagrams(label, count, seed):
            if end is not None and time.monotonic() >= end:
                break
            ep.write(d, timeout)
            n += 1
        if hold is not None:
            hold(n)
    return n


class Sender:
    """The sender process of one port (a :class:`m4k_bringup.child.Child`) and its stream.

    ``done`` once it wrote its whole stream, ``sent`` how much; ``error`` when it failed.
    """

    def __init__(self, label: str, count: int, seed: int, seconds: float,
                 env: Mapping[str, str]) -> None:
        self.child = Child(
            'fuzz send ' + label,
            [sys.executable, '-m', 'm4k_bench.fuzz', 'send', label, str(count), str(seed),
             str(seconds)],
            env,
            output=Output(pipes=('stdin', 'stdout', 'stderr')),
            stopping=Stopping(sig=signal.SIGKILL)).start()
        proc = self.child.proc
        assert proc is not None
        self.proc = proc
        self.error: str | None = None
        self.done = False
        self.sent = 0
        self._poll = select.poll()
        assert self.proc.stdout is not None
        self._poll.register(self.proc.stdout.fileno(), select.POLLIN)

    def check(self) -> None:
        """Notice the sender's 'sent N' line, or its death."""
        if self.done or self.error or not self._poll.poll(0):
            return
        assert self.proc.stdout is not None and self.proc.stderr is not None
        line = self.proc.stdout.readline()
        if line.startswith('sent '):
            self.sent = int(line.split()[1])
            self.done = True
        else:
            self.child.wait(10.0)
            self.error = 'sender failed: {}'.format(self.proc.stderr.read().strip()[-300:])

    def release(self) -> None:
        """Let the sender close its link and exit (SIGKILLed after 30 s); close its pipes."""
        assert self.proc.stdin is not None
        try:
            self.proc.stdin.close()
        except OSError:
            pass
        self.child.wait(30.0)
        self.child.stop()
