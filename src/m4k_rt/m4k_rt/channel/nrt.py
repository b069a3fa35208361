"""The NRT side's way in: :func:`nrt_xddp_open` (like ``open("/dev/rtpN")``) and :class:`NrtLink`.

The NRT side opens a port by number or label and gets an endpoint
(:mod:`m4k_rt.channel.endpoint`) over the transport the RT side answered with. Before it
links it checks the runtime directory (:func:`m4k_rt.channel.rundir.check_runtime_dir`).
:class:`NrtLink` wraps it for peers that must never fail on a missing or restarting RT side:
it re-opens on its own and counts links, re-links and losses.
"""

import errno
import os
import socket
import time

from m4k_rt.channel.contract import (
    check_mode,
    DEFAULT_HANDSHAKE_TIMEOUT,
    DEFAULT_MAX_PORTS,
    HANDSHAKE_BUSY,
    MODES,
    XddpBusyError,
    XddpError,
    XddpNotBoundError,
    XddpPortError,
)
from m4k_rt.channel.endpoint import NrtXddpEndpoint
from m4k_rt.channel.rundir import check_runtime_dir, port_path
from m4k_rt.channel.transports import (
    ANSWER_FDS,
    ANSWER_SIZE,
    answered,
    check_transport,
    nrt_endpoint_class,
)

_OPEN_RETRY_S = 0.02


class _NotBoundYet(Exception):
    def __init__(self, err: int, why: str) -> None:
        super().__init__(why)
        self.err = err


def _connect(path: str, mode: str | None, timeout: float) -> tuple[socket.socket, str]:
    for name in (mode,) if mode else ('message', 'stream'):
        sock = socket.socket(socket.AF_UNIX, MODES[name] | socket.SOCK_CLOEXEC)
        try:
            sock.settimeout(timeout)
            sock.connect(path)
        except OSError as exc:
            sock.close()
            if exc.errno == errno.EPROTOTYPE and mode is None:
                continue  # the RT side is in the other mode
            if exc.errno in (errno.ENOENT, errno.ECONNREFUSED):
                raise _NotBoundYet(exc.errno, exc.strerror or '') from None
            if exc.errno == errno.EPROTOTYPE:
                raise XddpPortError('{} is not bound in {} mode'.format(path, mode),
                                    path, exc.errno) from None
            raise XddpError('cannot connect to {}: {}'.format(path, exc.strerror or exc),
                            path, exc.errno) from exc
        return sock, name
    raise XddpError('{} is neither a message nor a stream socket'.format(path), path,
                    errno.EPROTOTYPE)


def nrt_xddp_open(port_or_label: int | str, *, wait: float | None = 0.0,
                  runtime_dir: str | None = None, max_ports: int = DEFAULT_MAX_PORTS,
                  mode: str | None = None,
                  handshake_timeout: float = DEFAULT_HANDSHAKE_TIMEOUT,
                  group: str | int | None = None,
                  transport: str | None = None) -> NrtXddpEndpoint:
    """Open the NRT side of a port by number or label (like ``open('/dev/rtpN')``).

    ``wait=0`` fails fast with XddpNotBoundError, ``None`` waits forever, a float waits that
    many seconds for the RT side to bind. ``mode=None`` detects message or stream mode.
    ``transport=None`` takes the transport the RT side offers; ``'socket'`` or ``'shm'``
    refuses the other one with XddpPortError.
    Raise XddpBusyError when another NRT peer is linked, XddpError when the runtime
    directory fails :func:`check_runtime_dir` (with the configured ``group``).
    """
    if mode is not None:
        check_mode(mode)
    if transport is not None:
        check_transport(transport)
    path = port_path(port_or_label, runtime_dir, max_ports)
    check_runtime_dir(os.path.dirname(path), group)
    deadline = None if wait is None else time.monotonic() + wait
    while True:
        try:
            return _open_once(port_or_label, path, mode, handshake_timeout, transport)
        except _NotBoundYet as exc:
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                raise XddpNotBoundError('nothing bound at port {!r} ({}): {}'.format(
                    port_or_label, path, exc), path, exc.err) from None
            pause = _OPEN_RETRY_S if deadline is None else min(_OPEN_RETRY_S, deadline - now)
            time.sleep(pause)


def _open_once(port_or_label: int | str, path: str, mode: str | None,
               handshake_timeout: float, transport: str | None) -> NrtXddpEndpoint:
    sock, found_mode = _connect(path, mode, handshake_timeout)
    try:
        sock.settimeout(handshake_timeout)
        # Message mode: the whole answer (one byte, or the byte and an offer with its fds).
        # Stream mode: one byte, the RT side's data may follow right behind it.
        msg, fds, flags, _ = socket.recv_fds(
            sock, ANSWER_SIZE if found_mode == 'message' else 1, ANSWER_FDS)
    except TimeoutError:
        sock.close()
        raise XddpError('RT side of {} did not accept within {}s'.format(
            path, handshake_timeout), path, errno.ETIMEDOUT) from None
    except OSError as exc:
        sock.close()
        raise _NotBoundYet(exc.errno or errno.ECONNRESET, 'reset during handshake') from None
    answer = msg[:1]
    linked = answered(answer)
    if linked is not None and transport in (None, linked):
        try:
            return nrt_endpoint_class(linked).from_handshake(sock, path, found_mode, msg, fds,
                                                             flags)
        except BaseException:
            sock.close()
            raise
    for fd in fds:
        os.close(fd)
    sock.close()
    if linked is not None:
        raise XddpPortError('port {!r} ({}) is served over the {} transport; this peer was '
                            'opened for {}'.format(port_or_label, path, linked, transport),
                            path, errno.EPROTONOSUPPORT)
    if answer == HANDSHAKE_BUSY:
        raise XddpBusyError('port {!r} already has an NRT peer: {}'.format(
            port_or_label, path), path, errno.EBUSY)
    raise _NotBoundYet(errno.ECONNRESET, 'closed during handshake')


class NrtLink:
    """Auto re-linking NRT endpoint: reads/writes never raise on a missing or lost RT side."""

    def __init__(self, port_or_label: int | str, runtime_dir: str | None = None, *,
                 retry_interval: float = 0.5, max_ports: int = DEFAULT_MAX_PORTS,
                 mode: str | None = None, write_timeout: float | None = 1.0,
                 handshake_timeout: float = DEFAULT_HANDSHAKE_TIMEOUT,
                 group: str | int | None = None, transport: str | None = None) -> None:
        port_path(port_or_label, runtime_dir, max_ports)  # validate now, not on first use
        self.transport = transport
        self.port_or_label = port_or_label
        self.runtime_dir = runtime_dir
        self.group = group
        self.retry_interval = retry_interval
        self.max_ports = max_ports
        self.mode = mode
        self.write_timeout = write_timeout
        self.handshake_timeout = handshake_timeout
        self.links = 0  # successful opens
        self.relinks = 0  # opens after the first
        self.lost = 0  # links that broke
        self.last_error: Exception | None = None
        self._ep: NrtXddpEndpoint | None = None
        self._next_try = 0.0

    @property
    def linked(self) -> bool:
        """Return True while linked to the RT side."""
        return self._ep is not None

    def _link(self) -> NrtXddpEndpoint | None:
        ep = self._ep
        if ep is not None:
            return ep
        now = time.monotonic()
        if now < self._next_try:
            return None
        self._next_try = now + self.retry_interval
        try:
            ep = nrt_xddp_open(self.port_or_label, wait=0.0, runtime_dir=self.runtime_dir,
                               max_ports=self.max_ports, mode=self.mode,
                               handshake_timeout=self.handshake_timeout, group=self.group,
                               transport=self.transport)
        except OSError as exc:  # not bound, busy, permission: keep trying, keep the reason
            self.last_error = exc
            return None
        self._ep = ep
        if self.links:
            self.relinks += 1
        self.links += 1
        return ep

    def _unlink(self, exc: Exception) -> None:
        self.last_error = exc
        self.lost += 1
        if self._ep is not None:
            self._ep.close()
        self._ep = None
        self._next_try = 0.0  # the RT side may already be back: retry at once

    def read(self, timeout: float | None = None) -> bytes | None:
        """Return the next datagram, or None if none arrived (or no link) within ``timeout``."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            ep = self._link()
            now = time.monotonic()
            remaining = None if deadline is None else max(0.0, deadline - now)
            if ep is not None:
                try:
                    return ep.read(remaining)
                except TimeoutError:
                    return None
                except OSError as exc:  # BrokenPipeError and anything else: relink
                    self._unlink(exc)
                    continue
            if remaining is not None and remaining <= 0.0:
                return None
            pause = max(0.0, self._next_try - now)
            time.sleep(pause if remaining is None else min(pause, remaining))

    def write(self, data: bytes | bytearray | memoryview) -> bool:
        """Write one datagram; return False when not linked, lost or timed out."""
        ep = self._link()
        if ep is None:
            return False
        try:
            ep.write(data, self.write_timeout)
        except TimeoutError:
            return False
        except OSError as exc:
            self._unlink(exc)
            return False
        return True

    def fileno(self) -> int:
        """Return the current endpoint's fd, or -1 when unlinked."""
        return self._ep.fileno() if self._ep is not None else -1

    def close(self) -> None:
        """Close the current link."""
        if self._ep is not None:
            self._ep.close()
            self._ep = None

    def __enter__(self) -> 'NrtLink':
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

