"""The NRT side of a linked port: :class:`NrtXddpEndpoint` (socket), :class:`NrtShmEndpoint`.

Blocking reads and writes with timeouts, like ``read``/``write`` on Xenomai's ``/dev/rtpN``:
a read raises TimeoutError when nothing arrives in time and BrokenPipeError when the RT side
closed or died, and never returns b''. An endpoint is made by
:func:`m4k_rt.channel.nrt.nrt_xddp_open` from the RT side's handshake answer
(:meth:`NrtXddpEndpoint.from_handshake`).
"""

import errno
import os
import select
import socket
import time

from m4k_rt.channel.contract import PEER_GONE, XddpError
from m4k_rt.channel.shmring import shm_accept_offer, SHM_CORRUPT, SHM_DROPPED, SHM_OFFER, ShmRegion

_NRT_BUFSZ = 65536


class NrtXddpEndpoint:
    """NRT side of one port over the socket transport: blocking reads and writes."""

    transport = 'socket'
    answer_size = 1  # bytes of the RT side's handshake answer over this transport
    answer_fds = 0  # file descriptors that come with it

    def __init__(self, sock: socket.socket, path: str, mode: str) -> None:
        self._sock: socket.socket | None = sock
        self.path = path
        self.mode = mode
        self._buf = bytearray(_NRT_BUFSZ)
        self._flags = socket.MSG_TRUNC if mode == 'message' else 0

    @classmethod
    def from_handshake(cls, sock: socket.socket, path: str, mode: str, msg: bytes,
                       fds: list[int], flags: int) -> 'NrtXddpEndpoint':
        """Return the endpoint of a link the RT side answered; ``fds`` are none of ours."""
        for fd in fds:
            os.close(fd)
        return cls(sock, path, mode)

    def _live(self) -> socket.socket:
        if self._sock is None:
            raise XddpError('endpoint {!r} is closed'.format(self.path), self.path, errno.EBADF)
        return self._sock

    def read(self, timeout: float | None = None) -> bytes:
        """Return the next datagram (message mode) or available bytes (stream mode).

        Raise TimeoutError when nothing arrives within ``timeout`` seconds (None waits
        forever) and BrokenPipeError when the RT side closed or died; never return b''.
        """
        sock = self._live()
        sock.settimeout(timeout)
        try:
            n = sock.recv_into(self._buf, 0, self._flags)
        except (TimeoutError, BlockingIOError):
            raise TimeoutError(errno.ETIMEDOUT, 'nothing received on {} within {}s'.format(
                self.path, timeout)) from None
        except OSError as exc:
            if exc.errno in PEER_GONE:
                raise BrokenPipeError(errno.EPIPE, 'RT side of {} is gone'.format(
                    self.path)) from exc
            raise
        if n == 0:
            raise BrokenPipeError(errno.EPIPE, 'RT side of {} closed'.format(self.path))
        if n > len(self._buf):
            raise XddpError('datagram of {} bytes on {} exceeds the {}-byte read buffer'.format(
                n, self.path, len(self._buf)), self.path, errno.EMSGSIZE)
        return bytes(self._buf[:n])

    def write(self, data: bytes | bytearray | memoryview, timeout: float | None = None) -> None:
        """Write one datagram; raise BrokenPipeError when the RT side is gone."""
        if not len(data):
            raise ValueError('cannot write an empty datagram to {}'.format(self.path))
        sock = self._live()
        sock.settimeout(timeout)
        try:
            sock.sendall(data, socket.MSG_NOSIGNAL)
        except TimeoutError:
            raise TimeoutError(errno.ETIMEDOUT, 'write to {} blocked for {}s'.format(
                self.path, timeout)) from None
        except OSError as exc:
            if exc.errno in PEER_GONE:
                raise BrokenPipeError(errno.EPIPE, 'RT side of {} is gone'.format(
                    self.path)) from exc
            raise XddpError('cannot write {} bytes to {}: {}'.format(
                len(data), self.path, exc.strerror), self.path, exc.errno) from exc

    def fileno(self) -> int:
        """Return the fd for selectors / poll."""
        return self._live().fileno()

    @property
    def closed(self) -> bool:
        """Return True once closed."""
        return self._sock is None

    def close(self) -> None:
        """Close the endpoint (the RT side sees EOF and counts a lost peer)."""
        sock, self._sock = self._sock, None
        if sock is not None:
            sock.close()

    def __enter__(self) -> 'NrtXddpEndpoint':
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return '<{} {} mode={}{}>'.format(type(self).__name__, self.path, self.mode,
                                          ' closed' if self.closed else '')


class NrtShmEndpoint(NrtXddpEndpoint):
    """NRT side of one port over the shm transport: datagrams go through the link's rings.

    The socket only tells that the RT side is gone (EOF), and :meth:`fileno` is an epoll fd
    that is readable when a datagram was published or the RT side went away.
    """

    transport = 'shm'
    answer_size = 1 + SHM_OFFER.size  # the byte, then the region's geometry
    answer_fds = 3  # the memfd and the two eventfds

    def __init__(self, sock: socket.socket, path: str, mode: str, region: ShmRegion) -> None:
        super().__init__(sock, path, mode)
        self._region = region
        self._gone = False
        self._epoll: select.epoll | None = None
        try:
            self._epoll = select.epoll(2, select.EPOLL_CLOEXEC)
            self._epoll.register(region.efd, select.EPOLLIN)
            self._epoll.register(sock.fileno(), select.EPOLLIN | select.EPOLLRDHUP)
        except BaseException:
            region.close()
            if self._epoll is not None:
                self._epoll.close()
            raise
        self._spoll = select.poll()
        self._spoll.register(sock.fileno(), select.POLLIN | select.POLLRDHUP)

    @classmethod
    def from_handshake(cls, sock: socket.socket, path: str, mode: str, msg: bytes,
                       fds: list[int], flags: int) -> 'NrtXddpEndpoint':
        """Map the region the RT side offered with its answer (closes ``fds`` on failure)."""
        if flags & (socket.MSG_CTRUNC | socket.MSG_TRUNC):
            for fd in fds:
                os.close(fd)
            raise XddpError('shm offer of {} truncated'.format(path), path, errno.EPROTO)
        return cls(sock, path, mode, shm_accept_offer(msg, fds, path))

    def _shm_gone(self) -> None:
        """Look at the socket: EOF or reset means the RT side is gone (sets ``_gone``)."""
        sock = self._live()
        try:
            junk = sock.recv(64, socket.MSG_DONTWAIT)
        except BlockingIOError:
            return
        except OSError:  # ECONNRESET
            junk = b''
        if junk:
            raise XddpError('RT side of {} wrote {} bytes on the socket of an shm link'.format(
                self.path, len(junk)), self.path, errno.EPROTO)
        self._gone = True

    def read(self, timeout: float | None = None) -> bytes:
        """Return the next datagram; TimeoutError, BrokenPipeError as the socket endpoint."""
        self._live()
        assert self._epoll is not None
        ring = self._region.to_nrt
        efd = self._region.efd
        buf = self._buf
        wait = self._epoll.poll
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            n = ring.get_into(buf)
            if n > 0:
                return bytes(buf[:n])
            if n == SHM_DROPPED or n == SHM_CORRUPT:
                continue  # cannot come from our RT side; skipped, look at the next one
            if self._gone:  # what was published before the RT side went is delivered first
                raise BrokenPipeError(errno.EPIPE, 'RT side of {} is gone'.format(self.path))
            pause = -1.0 if deadline is None else max(0.0, deadline - time.monotonic())
            if n < 0:  # a slot not complete yet (weakly ordered stores): look again soon
                pause = 0.0002 if pause < 0 else min(pause, 0.0002)
            events = wait(pause)
            for fd, _ in events:
                if fd == efd:
                    try:
                        os.eventfd_read(efd)  # consumed before the ring is read again
                    except BlockingIOError:
                        pass
                else:
                    self._shm_gone()
            if not events and n == 0 and deadline is not None and time.monotonic() >= deadline:
                raise TimeoutError(errno.ETIMEDOUT, 'nothing received on {} within {}s'.format(
                    self.path, timeout))

    def write(self, data: bytes | bytearray | memoryview, timeout: float | None = None) -> None:
        """Write one datagram into the ring; raise BrokenPipeError when the RT side is gone."""
        if not len(data):
            raise ValueError('cannot write an empty datagram to {}'.format(self.path))
        self._live()
        ring = self._region.to_rt
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            if not self._gone and self._spoll.poll(0):
                self._shm_gone()
            if self._gone:
                raise BrokenPipeError(errno.EPIPE, 'RT side of {} is gone'.format(self.path))
            if ring.put(data):
                # The RT tasks read it at their next cycle; a waiting RT-side user wakes.
                os.eventfd_write(self._region.efd_rt, 1)
                return
            if deadline is not None and time.monotonic() >= deadline:
                raise TimeoutError(errno.ETIMEDOUT, 'write to {} blocked for {}s'.format(
                    self.path, timeout))
            time.sleep(0.0005)  # full: the RT side frees slots as it runs

    def fileno(self) -> int:
        """Return an epoll fd: readable on a published datagram or the RT side gone."""
        self._live()
        assert self._epoll is not None
        return self._epoll.fileno()

    def close(self) -> None:
        """Close the endpoint and unmap its rings (the RT side sees EOF)."""
        if self._sock is not None:
            if self._epoll is not None:
                self._epoll.close()
            self._region.close()
        super().close()
