"""One reader thread per XDDP port, handing datagrams to the ROS executor thread.

Why threads and not an executor timer: opening a port waits for the RT side's handshake, which
the RT task answers when it next polls -- up to one period (1 s for the monitor's ``status``
port). Done in a timer, that wait would stall every ROS callback, cmd_vel included. So each
port gets a :class:`PortPump` thread that owns its :class:`m4k_rt.channel.NrtLink` exclusively
(NrtLink is not thread-safe): it links and re-links, waits in ``select`` on the link and an
eventfd, drains received datagrams into a callback, and writes what the executor queued with
:meth:`PortPump.send`. The executor thread never touches a socket and never blocks on one.

Hand-off: the callback (the node's) appends to a ``collections.deque`` (append/popleft are
atomic) and triggers an rclpy guard condition, which wakes the executor to drain the queue.
"""

from __future__ import annotations

import collections
import os
import select
import threading
import time
from typing import Callable, Optional

from m4k_rt import channel

__all__ = ['PortPump']

_DRAIN_MAX = 64          # datagrams read per wake-up before looking at the outbox again
_IDLE_WAIT_S = 0.5       # select timeout while linked (a stop request wakes it anyway)


class PortPump:
    """Own one NrtLink in a thread: deliver what arrives, send what is queued."""

    def __init__(self, role: str, port: int | str, deliver: Callable[[str, bytes, int], None],
                 runtime_dir: str | None = None, retry_interval: float = 0.5,
                 outbox_size: int = 16, group: str | None = None,
                 preamble: Optional[Callable[[], bytes | None]] = None) -> None:
        """Create the pump (not started); ``preamble`` is called on every new link.

        It runs in the pump thread and returns a datagram to write first on that link, before
        anything queued (the e-stop re-assertion), or None.
        """
        self.role = role
        self._preamble = preamble
        self._links_seen = 0
        self.preambles_sent = 0
        self.port = port
        self._deliver = deliver
        self._link = channel.NrtLink(port, runtime_dir, retry_interval=retry_interval,
                                  handshake_timeout=2.0, group=group)
        self._retry = retry_interval
        self._outbox: collections.deque[bytes] = collections.deque()
        self._outbox_size = outbox_size
        self._efd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name='m4k_bridge:' + role,
                                        daemon=True)
        # Counters, written by the pump thread only (read from others: ints are atomic).
        self.received = 0
        self.sent = 0
        self.dropped_unlinked = 0    # sends while no RT peer was linked
        self.dropped_overflow = 0    # sends queued faster than the RT side takes them
        self.last_rx_ns = 0          # CLOCK_MONOTONIC of the last datagram (0 = never)
        self.error: BaseException | None = None

    @property
    def linked(self) -> bool:
        """Return True while the RT side of the port is linked."""
        return self._link.linked

    @property
    def links(self) -> int:
        """Return how many times the port was (re)linked."""
        return self._link.links

    @property
    def lost(self) -> int:
        """Return how many links broke (RT side restarted or stopped)."""
        return self._link.lost

    @property
    def last_link_error(self) -> str:
        """Return why the last link attempt failed ('' when none)."""
        e = self._link.last_error
        return '' if e is None else str(e)

    def start(self) -> None:
        """Start the pump thread."""
        self._thread.start()

    def send(self, data: bytes) -> None:
        """Queue one datagram for the RT side (never blocks; oldest dropped when full)."""
        if len(self._outbox) >= self._outbox_size:
            self._outbox.popleft()
            self.dropped_overflow += 1
        self._outbox.append(data)
        self._wake()

    def _wake(self) -> None:
        try:
            os.eventfd_write(self._efd, 1)
        except (BlockingIOError, OSError):
            pass  # counter saturated or closed: the thread is awake or gone anyway

    def _clear_wake(self) -> None:
        try:
            os.eventfd_read(self._efd)
        except BlockingIOError:
            pass

    def _on_link(self) -> None:
        # First on every new link, in this thread, before the outbox: nothing queued can
        # overtake it.
        links = self._link.links
        if links == self._links_seen:
            return
        self._links_seen = links
        if self._preamble is None:
            return
        data = self._preamble()
        if data is not None and self._link.write(data):
            self.preambles_sent += 1

    def _flush(self) -> None:
        while self._outbox:
            if not self._link.linked:
                # Never link from here (NrtLink.write would): a new link must start with the
                # preamble, which only the linking path below sends.
                self.dropped_unlinked += len(self._outbox)
                self._outbox.clear()
                return
            self._on_link()
            data = self._outbox.popleft()
            if self._link.write(data):
                self.sent += 1
            else:
                self.dropped_unlinked += 1

    def _drain(self, first: bytes | None) -> None:
        data = first
        n = 0
        while data is not None:
            self.received += 1
            now = time.monotonic_ns()
            self.last_rx_ns = now
            self._deliver(self.role, data, now)
            n += 1
            if n >= _DRAIN_MAX:
                return
            data = self._link.read(0.0)

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                fd = self._link.fileno()
                if fd < 0:
                    # Link attempt: returns at once when nothing is bound; waits for the
                    # handshake (bounded) when the RT side is there.
                    self._drain(self._link.read(0.0))
                    if self._link.linked:
                        self._on_link()
                    else:
                        if self._outbox:
                            self.dropped_unlinked += len(self._outbox)
                            self._outbox.clear()
                        select.select([self._efd], [], [], self._retry)
                        self._clear_wake()
                    continue
                ready, _, _ = select.select([fd, self._efd], [], [], _IDLE_WAIT_S)
                if self._efd in ready:
                    self._clear_wake()
                self._flush()
                if fd in ready:
                    self._drain(self._link.read(0.0))
        except BaseException as exc:  # noqa: BLE001 -- reported by the node, thread ends
            self.error = exc

    def close(self, final: bytes | None = None, timeout: float = 3.0) -> None:
        """Stop the thread, send ``final`` (e.g. a zero command) if linked, close the link."""
        self._stop.set()
        self._wake()
        if self._thread.is_alive():
            self._thread.join(timeout)
        if not self._thread.is_alive():
            # The thread is gone: the link is ours now.
            self._flush()
            if final is not None and self._link.linked and self._link.write(final):
                self.sent += 1
            self._link.close()
            os.close(self._efd)
