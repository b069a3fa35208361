"""Echo body: the RT machinery exercised without any device.

Each cycle, on every port of the task, drain the replies (each one is decoded and validated, a
bad one is counted) and send one REQUEST (id = cycle, arg = task index). Its NRT peer, which
writes every datagram straight back, is :mod:`m4k_bench.echo_peer` (``echo_peer LABEL...``).
"""

from typing import Any, Mapping, Sequence

from m4k_rt import protocol
from m4k_rt.config import TaskConfig
from m4k_rt.tasks.interfaces import CycleContext, RtPort

__all__ = ['EchoBody', 'make_echo']

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
