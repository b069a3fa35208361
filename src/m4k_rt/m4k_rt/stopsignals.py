"""Stop signals (SIGINT, SIGTERM) that are never lost, not even during a process's start-up.

A process dies of a stop signal whenever one lands before it has a handler: the interpreter
starting, the imports, the configuration -- under load that is a second or more. A supervisor
that stops a child it has just restarted then sees exit code -15 instead of a clean stop, and
the child never ran its shutdown path (outputs safe). Two halves close that window:

* a supervisor starts its m4k children with the stop signals *blocked*
  (:func:`blocked_stop_signals` around ``Popen``): the mask survives ``fork`` and ``exec``, so a
  signal sent before the child is ready stays pending instead of killing it;
* every m4k executable calls :meth:`StopSignals.install` first thing in ``main()``: the handlers
  set an event, then the signals are unblocked, which delivers anything pending to them. Start-up
  code checks :attr:`StopSignals.stopping` between its steps and takes its shutdown path.

NRT only: no rclpy here (rclpy chains to these handlers when it installs its own).
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from typing import Any, Callable, Iterator

__all__ = ['STOP_SIGNALS', 'StopSignals', 'blocked_stop_signals', 'run_stoppable']

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class StopSignals:
    """Turn SIGINT/SIGTERM into an event; remember the first signal for the exit message."""

    def __init__(self) -> None:
        self.event = threading.Event()
        self.received: int | None = None
        self._old: dict[int, Any] = {}

    def install(self) -> 'StopSignals':
        """Install the handlers, then unblock the stop signals (delivering a pending one)."""
        for sig in STOP_SIGNALS:
            self._old[sig] = signal.signal(sig, self._on_signal)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
        return self

    def _on_signal(self, signum: int, frame: Any) -> None:
        if self.received is None:
            self.received = signum
        self.event.set()

    @property
    def stopping(self) -> bool:
        """Return True once a stop signal arrived (or :meth:`request` was called)."""
        return self.event.is_set()

    def request(self) -> None:
        """Ask for a stop from inside the process (same effect as a signal)."""
        self.event.set()

    @property
    def name(self) -> str:
        """Return the received signal's name ('SIGTERM'), or 'request' / 'none'."""
        if self.received is not None:
            return signal.Signals(self.received).name
        return 'request' if self.event.is_set() else 'none'

    def ignore(self) -> None:
        """Ignore further stop signals (during a bounded stop sequence)."""
        for sig in STOP_SIGNALS:
            signal.signal(sig, signal.SIG_IGN)

    def restore(self) -> None:
        """Put back the handlers that were installed before :meth:`install`."""
        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old.clear()


@contextlib.contextmanager
def blocked_stop_signals() -> Iterator[None]:
    """Block the stop signals in the calling thread (wrap ``Popen`` of an m4k child in this).

    The child inherits the mask and unblocks it once its handlers are installed; the parent's
    mask is restored on exit, which delivers any stop signal that reached the parent meanwhile.
    """
    old = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def run_stoppable(prog: str, body: Callable[[StopSignals], int], *, when_stopped: str = '') -> int:
    """Run ``body`` under freshly installed stop handlers; return its exit code.

    The one shape of an m4k executable's ``main``: the handlers come first (so a stop during
    start-up ends the process cleanly, too), the body gets them to poll, and when a stop signal
    ended it, one line says so: ``<prog>: stopped (SIGTERM)<when_stopped>[, exit code N]``.
    """
    signals = StopSignals().install()
    try:
        rc = body(signals)
    finally:
        signals.restore()
    if signals.stopping:
        sys.stderr.write('{}: stopped ({}){}{}\n'.format(
            prog, signals.name, when_stopped, '' if rc == 0 else ', exit code {}'.format(rc)))
        sys.stderr.flush()
    return rc
