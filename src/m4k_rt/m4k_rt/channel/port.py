"""The RT side of a port, over the socket transport: :class:`RtXddpSocket`.

The RT side binds port N (a listening socket ``<runtime_dir>/xddp<N>``, optionally labelled by
a symlink ``label.<label>``) and never blocks: accept, send and receive are non-blocking, and a
datagram that cannot be delivered (no peer, full queue, oversize) is dropped and counted. At
most one NRT peer is linked: on connect the RT side answers one handshake byte, linked or busy
(then closed). Either side may restart; the other one notices (EOF, EPIPE, ECONNRESET), counts
it and re-links.

Message mode (``SOCK_SEQPACKET``) keeps datagram boundaries; stream mode (``SOCK_STREAM``)
carries bytes. ``max_datagram`` is kept at most ``poolsz // 2`` so every send fits a single
kernel buffer and is all-or-nothing in both modes.

Every datagram here is a ``send``/``recv`` on the linked Unix socket: :meth:`send` and
:meth:`recv_into` know no other transport. The shm transport is a subclass that overrides
them and the link hooks (:mod:`m4k_rt.channel.shm`); :mod:`m4k_rt.channel.transports` picks
one.
"""

import errno
import os
import select
import socket
import stat

from m4k_rt.channel.contract import (
    check_label,
    check_mode,
    check_port,
    check_sizes,
    DEFAULT_MAX_DATAGRAM,
    DEFAULT_MAX_PORTS,
    DEFAULT_POOLSZ,
    HANDSHAKE_BUSY,
    HANDSHAKE_OK,
    MODES,
    SEND_FLAGS,
    XddpBusyError,
    XddpCounters,
    XddpError,
)
from m4k_rt.channel.rundir import ensure_runtime_dir, gid_of, port_path, socket_alive


class RtXddpSocket:
    """RT side of one port: a non-blocking listener with at most one linked NRT peer.

    Not thread-safe: one RT task owns a port. After close() it stays harmless (sends are
    dropped and counted, receives return 0).
    """

    transport = 'socket'
    handshake = HANDSHAKE_OK  # the byte that tells an opener it is linked over this transport

    def __init__(self, port: int, label: str | None = None, *, mode: str = 'message',
                 poolsz: int = DEFAULT_POOLSZ, max_datagram: int = DEFAULT_MAX_DATAGRAM,
                 runtime_dir: str | None = None, max_ports: int = DEFAULT_MAX_PORTS,
                 group: str | int | None = None) -> None:
        check_mode(mode)
        check_sizes(poolsz, max_datagram)
        self.port = check_port(port, max_ports)
        self.label = None if label is None else check_label(label)
        self.mode = mode
        self.poolsz = poolsz
        self.max_datagram = max_datagram
        self.counters = XddpCounters()
        self._gid = gid_of(group)
        self.runtime_dir = ensure_runtime_dir(runtime_dir, group)
        self.path = port_path(port, self.runtime_dir, max_ports)
        self.label_path = None if label is None else port_path(label, self.runtime_dir)
        self._recv_flags = socket.MSG_DONTWAIT | (
            socket.MSG_TRUNC if mode == 'message' else 0)
        self._rbuf = bytearray(max_datagram)
        self._peer: socket.socket | None = None
        self._ever_linked = False
        self._inode: tuple[int, int] | None = None
        self._listener = self._bind()
        self._lfd = self._listener.fileno()
        self._lpoll = select.poll()  # listener only: is an opener waiting?
        self._lpoll.register(self._lfd, select.POLLIN)
        self._poll = select.poll()  # listener + peer: anything to do at all?
        self._poll.register(self._lfd, select.POLLIN)
        self._ppoll = select.poll()  # peer only: hung up?
        try:
            self._link_label()
        except BaseException:
            self.close()
            raise

    def _bind(self) -> socket.socket:
        path = self.path
        try:
            st = os.lstat(path)
        except FileNotFoundError:
            st = None
        if st is not None:
            if not stat.S_ISSOCK(st.st_mode):
                raise XddpError('{!r} exists and is not a socket: refusing to replace it'.format(
                    path), path, errno.EEXIST)
            if socket_alive(path):
                raise XddpBusyError('port {} is already bound by a live process: {}'.format(
                    self.port, path), path, errno.EADDRINUSE)
            try:
                os.unlink(path)  # stale: its RT process died without closing
            except FileNotFoundError:
                pass
        sock = socket.socket(socket.AF_UNIX,
                             MODES[self.mode] | socket.SOCK_NONBLOCK | socket.SOCK_CLOEXEC)
        try:
            self._set_buffers(sock)
            sock.bind(path)
            if self._gid is not None:
                os.chown(path, -1, self._gid)
            os.chmod(path, 0o660 if self._gid is not None else 0o600)
            st = os.stat(path)
            self._inode = (st.st_dev, st.st_ino)
            sock.listen(8)
        except OSError as exc:
            sock.close()
            if self._inode is not None:
                os.unlink(path)
            raise XddpError('cannot bind port {} at {!r}: {}'.format(
                self.port, path, exc.strerror or exc), path, exc.errno) from exc
        return sock

    def _link_label(self) -> None:
        lpath = self.label_path
        if lpath is None:
            return
        target = os.path.basename(self.path)
        try:
            current: str | None = os.readlink(lpath)
        except FileNotFoundError:
            current = None
        except OSError as exc:
            raise XddpError('label path {!r} exists and is not a symlink'.format(lpath),
                            lpath, exc.errno) from exc
        if current is not None and current != target and socket_alive(
                os.path.join(self.runtime_dir, current)):
            raise XddpBusyError('label {!r} is used by live port {!r}: {}'.format(
                self.label, current, lpath), lpath, errno.EADDRINUSE)
        tmp = '{}.tmp{}'.format(lpath, os.getpid())
        try:
            os.symlink(target, tmp)
            os.replace(tmp, lpath)  # atomic: openers never see a missing label
        except OSError as exc:
            raise XddpError('cannot create label {!r}: {}'.format(lpath, exc.strerror),
                            lpath, exc.errno) from exc

    def _set_buffers(self, sock: socket.socket) -> None:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, self.poolsz)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, self.poolsz)

    @property
    def closed(self) -> bool:
        """Return True once closed."""
        return self._lfd < 0

    @property
    def connected(self) -> bool:
        """Return True while an NRT peer is linked."""
        return self._peer is not None

    def fileno(self) -> int:
        """Return the linked peer's fd, else the listener's (for bounded waits)."""
        peer = self._peer
        return peer.fileno() if peer is not None else self._lfd

    def poll_peer(self) -> bool:
        """Accept a waiting opener (or refuse it when busy); return True when linked."""
        if self._lpoll.poll(0):
            self._accept_pending()
        return self._peer is not None

    def _accept_pending(self) -> None:
        while True:
            try:
                conn, _ = self._listener.accept()
            except OSError:  # nothing pending (EAGAIN), or EMFILE & co: retried next call
                return
            if self._peer is not None and self._ppoll.poll(0):
                self._drop_peer()  # hung up: let the new opener replace it right away
            if self._peer is not None:
                # Counted before the opener is told: whoever sees XddpBusyError sees the count.
                self.counters.busy_rejects += 1
                try:
                    conn.send(HANDSHAKE_BUSY, SEND_FLAGS)
                except OSError:
                    pass
                conn.close()
                continue
            try:
                conn.setblocking(False)
                self._set_buffers(conn)
                self._handshake(conn)
            except OSError:  # the opener is already gone (or no memory for its link)
                conn.close()
                continue
            self._peer = conn
            fd = conn.fileno()
            self._poll.register(fd, select.POLLIN)
            self._ppoll.register(fd, select.POLLHUP)
            if self._ever_linked:
                self.counters.peer_restarts += 1
            self._ever_linked = True

    def _handshake(self, conn: socket.socket) -> None:
        """Tell a new peer it is linked (raise OSError when it is gone already)."""
        conn.send(self.handshake, SEND_FLAGS)

    def _unlink(self) -> None:
        """Release what the transport keeps per link (nothing for the socket)."""

    def _drop_peer(self, count: bool = True) -> None:
        peer = self._peer
        if peer is None:
            return
        self._peer = None
        self._unlink()
        fd = peer.fileno()
        self._poll.unregister(fd)
        self._ppoll.unregister(fd)
        peer.close()
        if count:
            self.counters.peer_lost += 1

    def send(self, data: bytes | bytearray | memoryview) -> bool:
        """Send one datagram without blocking; return False when it was dropped (counted)."""
        n = len(data)
        c = self.counters
        if not 0 < n <= self.max_datagram:
            c.dropped_oversize += 1
            return False
        peer = self._peer
        if peer is None:
            if self._lpoll.poll(0):
                self._accept_pending()
            peer = self._peer
            if peer is None:
                c.dropped_no_peer += 1
                return False
        try:
            sent = peer.send(data, SEND_FLAGS)
        except BlockingIOError:
            c.dropped_full += 1
            return False
        except OSError as exc:
            if exc.errno == errno.EMSGSIZE:
                c.dropped_oversize += 1
                return False
            self._drop_peer()
            c.dropped_no_peer += 1
            return False
        if sent != n:  # cannot happen while max_datagram <= poolsz // 2; never count it sent
            c.dropped_full += 1
            return False
        c.sent += 1
        return True

    def recv_into(self, buf: bytearray | memoryview) -> int:
        """Receive one pending datagram into ``buf`` without blocking; return 0 if none.

        Accepts a waiting opener first. A message-mode datagram larger than ``buf`` is
        discarded and counted ``dropped_oversize``; in stream mode up to ``len(buf)`` bytes
        are returned.
        """
        poll = self._poll.poll
        lfd = self._lfd
        while True:
            events = poll(0)  # one syscall and no exception when idle
            if not events:
                return 0
            if len(events) > 1 or events[0][0] == lfd:
                self._accept_pending()  # an opener waits (alone or next to peer data)
            peer = self._peer
            if peer is None:
                return 0
            try:
                n = peer.recv_into(buf, 0, self._recv_flags)
            except BlockingIOError:
                return 0
            except OSError:  # ECONNRESET
                self._drop_peer()
                return 0
            if n == 0:  # EOF (empty datagrams are never sent by our endpoints)
                self._drop_peer()
                return 0
            if n > len(buf):  # discarded: look again
                self.counters.dropped_oversize += 1
                continue
            self.counters.received += 1
            return n

    def recv(self) -> bytes | None:
        """Receive one pending datagram as bytes, or None (allocates: not for RT loops)."""
        n = self.recv_into(self._rbuf)
        return bytes(self._rbuf[:n]) if n else None

    def count_malformed(self) -> None:
        """Count a received datagram that failed to decode."""
        self.counters.malformed += 1

    def close(self) -> None:
        """Close the peer and the listener; remove our socket file and label."""
        self._drop_peer(count=False)
        listener = self.__dict__.pop('_listener', None)
        if listener is None:
            return
        # Afterwards the pollers are empty: send() drops (no peer), recv_into() returns 0.
        self._lpoll.unregister(self._lfd)
        self._poll.unregister(self._lfd)
        self._lfd = -1
        listener.close()
        ours = False
        try:
            st = os.lstat(self.path)
            if (st.st_dev, st.st_ino) == self._inode:
                os.unlink(self.path)
                ours = True
        except OSError:
            pass
        if ours and self.label_path is not None:
            try:
                if os.readlink(self.label_path) == os.path.basename(self.path):
                    os.unlink(self.label_path)
            except OSError:
                pass

    def __enter__(self) -> 'RtXddpSocket':
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return '<{} port={} label={!r} mode={} connected={}>'.format(
            type(self).__name__, self.port, self.label, self.mode, self.connected)

