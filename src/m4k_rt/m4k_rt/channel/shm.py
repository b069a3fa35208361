"""The RT side of a port, over the shm transport: :class:`RtShmSocket`.

The socket only does the rendezvous, access control, handshake and liveness. At link time the
RT side creates the link's rings (:mod:`m4k_rt.channel.shmring`) and passes their fds to the
peer with the handshake. It then sends by copying into the ring (plus one ``eventfd_write`` to
wake the NRT reader) and receives by reading the ring: no other system call per datagram. It
looks at the socket (peer gone, second opener) every :data:`SHM_LIVENESS_NS`. Message mode
only. Measured against the socket transport and not adopted as the default
(docs/design-notes.md, 9c).
"""

import errno
import os
import socket
import time
from typing import Any

from m4k_rt.channel.contract import check_mode, HANDSHAKE_SHM, SEND_FLAGS, XddpPortError
from m4k_rt.channel.port import RtXddpSocket
from m4k_rt.channel.shmring import (
    SHM_CORRUPT,
    shm_create,
    SHM_DROPPED,
    shm_geometry,
    SHM_TORN,
    ShmRegion,
    ShmRing,
)

SHM_LIVENESS_NS = 100_000_000  # the RT side looks at its socket (peer gone? opener?) this often
DEFAULT_SHM_SOCKET_JUNK = 8  # datagrams a peer wrongly sent on an shm link's socket, per look

_clock = time.monotonic_ns


class RtShmSocket(RtXddpSocket):
    """RT side of one port whose linked datagrams go through shared-memory rings."""

    transport = 'shm'
    handshake = HANDSHAKE_SHM

    def __init__(self, port: int, label: str | None = None, *, mode: str = 'message',
                 **kwargs: Any) -> None:
        if check_mode(mode) != 'message':
            raise XddpPortError('the shm transport carries datagrams: it needs message mode, '
                                'not {}'.format(mode), None, errno.EINVAL)
        self._region: ShmRegion | None = None
        self._tx: ShmRing | None = None  # RT -> NRT ring while linked
        self._rx: ShmRing | None = None  # NRT -> RT ring while linked
        self._efd = -1
        self._next_check = 0
        super().__init__(port, label, mode=mode, **kwargs)
        self._shm_slots = shm_geometry(self.poolsz, self.max_datagram)[0]

    def fileno(self) -> int:
        """Return, while linked, the eventfd the peer writes per datagram, else as the socket.

        Readable once the peer wrote; whoever waits on it resets it (os.eventfd_read).
        """
        region = self._region
        return region.efd_rt if region is not None else super().fileno()

    def _handshake(self, conn: socket.socket) -> None:
        region, mfd, offer = shm_create(self.port, self._shm_slots)
        try:
            socket.send_fds(conn, [offer], [mfd, region.efd, region.efd_rt], SEND_FLAGS)
        except OSError:
            region.close()
            raise
        finally:
            os.close(mfd)
        self._region = region
        self._tx = region.to_nrt
        self._rx = region.to_rt
        self._efd = region.efd
        self._next_check = _clock() + SHM_LIVENESS_NS

    def _unlink(self) -> None:
        region = self._region
        if region is not None:
            # Fresh rings for the next peer: a restarted peer never sees this one's data.
            self._region = self._tx = self._rx = None
            self._efd = -1
            region.close()

    def send(self, data: bytes | bytearray | memoryview) -> bool:
        """Send one datagram without blocking; return False when it was dropped (counted)."""
        c = self.counters
        if not 0 < len(data) <= self.max_datagram:
            c.dropped_oversize += 1
            return False
        tx = self._tx
        if tx is None or _clock() >= self._next_check:
            return self._send_slow(data)
        if tx.put(data):  # no system call but the wake of the NRT reader
            try:
                os.eventfd_write(self._efd, 1)
            except OSError:
                pass  # only at 2**64 - 2 pending wakes; the datagram is in anyway
            c.sent += 1
            return True
        c.dropped_full += 1
        return False

    def _send_slow(self, data: bytes | bytearray | memoryview) -> bool:
        """Look at the socket first (peer gone? opener?), then send if linked."""
        c = self.counters
        self._check()
        tx = self._tx
        if tx is None:
            c.dropped_no_peer += 1
            return False
        if not tx.put(data):
            c.dropped_full += 1
            return False
        try:
            os.eventfd_write(self._efd, 1)
        except OSError:
            pass
        c.sent += 1
        return True

    def recv_into(self, buf: bytearray | memoryview) -> int:
        """Receive one pending datagram into ``buf`` from the ring; return 0 if none.

        No system call, but a look at the socket every SHM_LIVENESS_NS (which accepts a
        waiting opener). A datagram larger than ``buf`` is skipped and counted
        ``dropped_oversize``.
        """
        rx = self._rx
        if rx is None or _clock() >= self._next_check:
            self._check()
            return 0 if self._rx is None else self._recv_counted(buf, 0)
        n = rx.get_into(buf)
        if n > 0:
            self.counters.received += 1
            return n
        if n == 0:
            return 0
        return self._recv_counted(buf, n)

    def _recv_counted(self, buf: bytearray | memoryview, n: int) -> int:
        """Count what the ring's reader reported (``n`` < 0) and read on, or read (``n`` 0)."""
        c = self.counters
        rx = self._rx
        assert rx is not None
        while True:
            if n > 0:
                c.received += 1
                return n
            if n == SHM_DROPPED:
                c.dropped_oversize += 1
            elif n == SHM_TORN:
                c.torn += 1
                return 0
            elif n == SHM_CORRUPT:
                c.malformed += 1
            elif n < 0:  # SHM_TORN_WAIT: the same slot, already counted
                return 0
            n = rx.get_into(buf)
            if n == 0:
                return 0

    def _check(self) -> None:
        """Accept or refuse an opener, notice a peer gone (system calls)."""
        self._next_check = _clock() + SHM_LIVENESS_NS
        for fd, _ in self._poll.poll(0):
            if fd == self._lfd:
                self._accept_pending()  # a second opener is refused; a hung-up peer replaced
                continue
            peer = self._peer
            if peer is None or fd != peer.fileno():
                continue
            for _ in range(DEFAULT_SHM_SOCKET_JUNK):
                try:
                    junk = peer.recv(64, socket.MSG_DONTWAIT)
                except BlockingIOError:
                    break
                except OSError:  # ECONNRESET
                    junk = b''
                if not junk:
                    self._drop_peer()  # EOF: the peer is gone; its rings go with it
                    break
                self.counters.malformed += 1  # a peer writing the socket, not its ring
