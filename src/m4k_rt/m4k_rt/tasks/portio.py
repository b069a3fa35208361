"""Per-port receive/send helpers for RT task bodies: preallocated buffers, counted drops.

``PortReader.next()`` drains one valid datagram at a time from a non-blocking RT XDDP socket
into a preallocated buffer and decodes it; a datagram that ``protocol.decode`` rejects is
counted on the socket (``count_malformed``) and skipped, so bad input never reaches control
code. ``PortWriter.send()`` encodes into its own preallocated buffer with a per-port sequence
number. Nothing here blocks or allocates more than the decoded NamedTuple and a memoryview.
"""

from __future__ import annotations

import time
from typing import Any, Callable

from m4k_rt import cycleprof
from m4k_rt.protocol import (
    decode_from,
    encode_into,
    FIXED_PACKERS,
    Kind,
    MAGIC,
    MAX_DATAGRAM,
    PACK_ERRORS,
    ProtocolError,
    SEQ_MASK,
    VERSION,
)
from m4k_rt.tasks.interfaces import CycleContext, RtPort

__all__ = ['DRAIN_MAX', 'DeviceTaskBody', 'PortReader', 'PortWriter']

_DEVICE_STATUS = Kind.DEVICE_STATUS
_HOST_DROPS = Kind.HOST_DROPS
_REQUEST = Kind.REQUEST

# Upper bound of datagrams one body reads from one port per cycle: a flooding peer costs a
# bounded amount of CPU; the rest waits for the next cycle (or overflows the socket buffer).
DRAIN_MAX = 32


class PortReader:
    """Drain and decode datagrams from one RT XDDP socket."""

    __slots__ = ('sock', 'buf', 'view', 'length', 'received', 'budget')

    def __new__(cls, *args: Any, **kwargs: Any) -> PortReader:
        """Return a timed reader when the cycle profile is on (decided at start-up)."""
        if cls is PortReader and cycleprof.enabled():
            cls = _TimedPortReader
        return object.__new__(cls)

    def __init__(self, sock: RtPort, size: int = MAX_DATAGRAM) -> None:
        self.sock = sock
        self.buf = bytearray(size)
        self.view = memoryview(self.buf)
        self.length = 0          # size of the last valid datagram (its bytes: view[:length])
        self.received = 0        # valid datagrams
        self.budget = DRAIN_MAX

    def start_cycle(self) -> None:
        """Reset the per-cycle drain budget."""
        self.budget = DRAIN_MAX

    def next(self) -> tuple[Any, Any] | None:
        """Return the next valid (Header, payload), or None when drained or over budget."""
        sock = self.sock
        while self.budget > 0:
            self.budget -= 1
            n = sock.recv_into(self.buf)
            if n <= 0:
                self.budget = 0
                return None
            try:
                result = decode_from(self.buf, n)
            except ProtocolError:
                sock.count_malformed()
                continue
            self.length = n
            self.received += 1
            return result
        return None

    def raw(self) -> memoryview:
        """Return the bytes of the last valid datagram (valid until the next ``next``)."""
        return self.view[:self.length]

    def discard(self) -> int:
        """Drain this cycle's budget of datagrams nobody should send here; return how many.

        For a port the RT side only writes (``imu_out``, ``sonar_out``, ``lrf_out``): what a
        peer writes anyway is counted, never used, and draining also links a (re)started peer
        now rather than at the next datagram forwarded.
        """
        self.start_cycle()
        n = 0
        while self.next() is not None:
            n += 1
        return n


class PortWriter:
    """Encode and send datagrams on one RT XDDP socket."""

    __slots__ = ('sock', 'buf', 'view', 'seq', 'sent', 'dropped', 'encode_errors')

    def __new__(cls, *args: Any, **kwargs: Any) -> PortWriter:
        """Return a timed writer when the cycle profile is on (decided at start-up)."""
        if cls is PortWriter and cycleprof.enabled():
            cls = _TimedPortWriter
        return object.__new__(cls)

    def __init__(self, sock: RtPort, size: int = 128) -> None:
        self.sock = sock
        self.buf = bytearray(size)
        self.view = memoryview(self.buf)
        self.seq = 0
        self.sent = 0
        self.dropped = 0         # no peer / peer's buffer full (the socket counts why)
        self.encode_errors = 0

    def send(self, kind: int, stamp_ns: int, *fields: Any) -> bool:
        """Encode one datagram and send it; return False when it was not sent (counted)."""
        fixed = FIXED_PACKERS.get(kind)
        if fixed is not None:   # every kind a task sends: one pack_into, the bytes of encode_into
            pack, n = fixed
            try:
                pack(self.buf, 0, MAGIC, VERSION, kind, self.seq, stamp_ns, *fields)
            except PACK_ERRORS:
                self.encode_errors += 1
                return False
        else:
            try:
                n = encode_into(self.buf, 0, kind, self.seq, stamp_ns, *fields)
            except ProtocolError:
                self.encode_errors += 1
                return False
        self.seq = (self.seq + 1) & SEQ_MASK
        if self.sock.send(self.view[:n]):
            self.sent += 1
            return True
        self.dropped += 1
        return False

    def forward(self, data: memoryview) -> bool:
        """Send already validated datagram bytes unchanged (the sender's seq and stamp kept)."""
        return self._count(self.sock.send(data))

    def _count(self, ok: bool) -> bool:
        if ok:
            self.sent += 1
        else:
            self.dropped += 1
        return ok


class _TimedPortReader(PortReader):
    """A PortReader adding its time to the calling task's cycle profile (``cycleprof``)."""

    __slots__ = ()

    def next(self) -> tuple[Any, Any] | None:
        t0 = _clock()
        got = PortReader.next(self)
        prof = cycleprof.current()
        if prof is not None:
            prof.drain_ns += _clock() - t0
            prof.drain_calls += 1
        return got


class _TimedPortWriter(PortWriter):
    """A PortWriter adding its time to the calling task's cycle profile (``cycleprof``)."""

    __slots__ = ()

    def send(self, kind: int, stamp_ns: int, *fields: Any) -> bool:
        t0 = _clock()
        ok = PortWriter.send(self, kind, stamp_ns, *fields)
        self._add(t0)
        return ok

    def forward(self, data: memoryview) -> bool:
        t0 = _clock()
        ok = PortWriter.forward(self, data)
        self._add(t0)
        return ok

    @staticmethod
    def _add(t0: int) -> None:
        prof = cycleprof.current()
        if prof is not None:
            prof.send_ns += _clock() - t0
            prof.send_calls += 1


_clock = time.monotonic_ns


class DeviceTaskBody:
    """The ports and counters the imu, sonar and lrf bodies share.

    Each talks to its device handler on one port (requests out, replies and DEVICE_STATUS in)
    and forwards readings to the bridge on another, which it only writes (``discard`` drains
    what the bridge sends there anyway).
    """

    def __init__(self, dev_sock: RtPort, out_sock: RtPort, state: Any,
                 clock: Callable[[], int] = time.monotonic_ns) -> None:
        self.state = state
        self._dev_in = PortReader(dev_sock)
        self._dev_out = PortWriter(dev_sock)
        self._out = PortWriter(out_sock)
        self._out_in = PortReader(out_sock, 256)
        self._clock = clock
        self.cycles = 0
        self.unexpected = 0

    def _poll_device(self, ctx: CycleContext | None, reading: int, device: str,
                     request_arg: int) -> None:
        """Run one request/reply cycle: take the replies to the last request, then ask again.

        The sonar and the laser are polled alike (the reply to one cycle's REQUEST arrives
        within it or early in the next, so the body never waits): each datagram of kind
        ``reading`` goes to :meth:`_on_reading`, DEVICE_STATUS is recorded for ``device``,
        anything else is counted unexpected; what the bridge sent on the output port is
        drained and counted (it only reads that port).
        """
        now = ctx.t_start if ctx is not None else self._clock()
        reader = self._dev_in
        reader.start_cycle()
        while (got := reader.next()) is not None:
            hdr, msg = got
            if hdr.kind == reading:
                self._on_reading(hdr, msg, now)
            elif hdr.kind == _DEVICE_STATUS:
                self.state.record_device_status(device, msg, now)
            elif hdr.kind == _HOST_DROPS:
                self.state.record_host_drops(device, msg, now)
            else:
                self.unexpected += 1
        self.unexpected += self._out_in.discard()   # the bridge only reads this port
        self._dev_out.send(_REQUEST, now, self.cycles & 0xFFFFFFFF, request_arg)
        self.cycles += 1

    def _on_reading(self, hdr: Any, msg: Any, now: int) -> None:
        """Handle one reading of a polled device (bodies that use :meth:`_poll_device`)."""
        raise NotImplementedError
