"""Echo body and its NRT echo peer: the RT machinery exercised without any device.

RT side (``make_echo``): each cycle, on every port of the task, drain the replies (each one is
decoded and validated, a bad one is counted) and send one REQUEST (id = cycle, arg = task
index). NRT side (``python -m m4k_rt.tasks.echo LABEL...``): one thread per port label writes
every datagram it reads straight back, re-linking when the RT side restarts.
"""

import argparse
import sys
import threading
from typing import Any, Mapping, Sequence

from m4k_rt import protocol, rosargs
from m4k_rt.config import TaskConfig
from m4k_rt.stopsignals import StopSignals
from m4k_rt.tasks.interfaces import CycleContext, RtPort

__all__ = ['EchoBody', 'EchoPeer', 'main', 'make_echo']

_REQUEST = protocol.Kind.REQUEST


class EchoBody:
    """Per-cycle echo: drain replies, send one REQUEST per port."""

    def __init__(self, socks: Sequence[RtPort], index: int, max_datagram: int = 4096) -> None:
        """Preallocate the receive and send buffers."""
        self.socks = list(socks)
        self.index = index
        self._rbuf = bytearray(max_datagram)
        self._rview = memoryview(self._rbuf)
        self._sbuf = bytearray(protocol.encoded_size(_REQUEST))
        self._sview = memoryview(self._sbuf)
        self.seq = 0
        self.sent = 0
        self.dropped = 0
        self.replies = 0
        self.malformed = 0

    def __call__(self, ctx: CycleContext) -> None:
        """Run one cycle."""
        buf, view = self._rbuf, self._rview
        for s in self.socks:
            while True:
                n = s.recv_into(buf)
                if n <= 0:
                    break
                try:
                    protocol.decode(view[:n])
                except protocol.ProtocolError:
                    self.malformed += 1
                    s.count_malformed()
                else:
                    self.replies += 1
            protocol.encode_into(self._sbuf, 0, _REQUEST, self.seq, ctx.t_start,
                                 ctx.cycles & 0xFFFFFFFF, self.index)
            self.seq = (self.seq + 1) & 0xFFFFFFFF
            if s.send(self._sview):
                self.sent += 1
            else:
                self.dropped += 1


def make_echo(task: TaskConfig, ports: Mapping[str, RtPort], shared: Any) -> EchoBody:
    """Build the echo body over all of the task's ports."""
    max_dg = getattr(getattr(getattr(shared, 'config', None), 'runtime', None),
                     'max_datagram', 4096)
    return EchoBody([ports[label] for label in task.ports], task.index, max_dg)


class EchoPeer:
    """NRT echo peer: one thread per label, writing back whatever it reads."""

    def __init__(self, labels: Sequence[int | str], runtime_dir: str | None = None) -> None:
        """Prepare (not start) one re-linking endpoint per label."""
        from m4k_rt import channel  # NRT side only: keep the RT import graph free of it
        self._links = [channel.NrtLink(lb, runtime_dir, retry_interval=0.05) for lb in labels]
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._serve, args=(lk,), daemon=True,
                                          name='echo:{}'.format(lk.port_or_label))
                         for lk in self._links]
        self.echoed = 0

    def start(self) -> 'EchoPeer':
        """Start serving."""
        for t in self._threads:
            t.start()
        return self

    def _serve(self, link: Any) -> None:
        while not self._stop.is_set():
            data = link.read(0.1)
            if data is None:
                if not link.linked:
                    self._stop.wait(0.02)
                continue
            if link.write(data):
                self.echoed += 1

    def stop(self, timeout: float = 2.0) -> None:
        """Stop the threads and close the endpoints."""
        self._stop.set()
        for t in self._threads:
            t.join(timeout)
        for lk in self._links:
            lk.close()

    def __enter__(self) -> 'EchoPeer':
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def main(argv: Sequence[str] | None = None) -> int:
    """Run an NRT echo peer on the given port labels until SIGINT/SIGTERM."""
    stop = StopSignals().install()  # first: a stop during start-up ends it cleanly, too
    ap = argparse.ArgumentParser(description='NRT echo peer for the echo task bodies.')
    ap.add_argument('labels', nargs='+', help='port labels (or numbers) to serve')
    ap.add_argument('--runtime-dir', default=None)
    args = rosargs.parse_args(ap, argv)
    labels: list[int | str] = [int(x) if x.isdigit() else x for x in args.labels]
    done = stop.event
    peer = EchoPeer(labels, args.runtime_dir).start()
    sys.stderr.write('echo peer: serving {}\n'.format(', '.join(map(str, labels))))
    sys.stderr.flush()
    try:
        while not done.wait(0.5):
            pass
    finally:
        peer.stop()
    sys.stderr.write('echo peer: echoed {} datagrams\n'.format(peer.echoed))
    return 0


if __name__ == '__main__':
    sys.exit(main())
