"""A simulated LED strip: remembers what was shown, with timestamps, for the host and bridge."""

from __future__ import annotations

from collections import deque
import threading
import time
from typing import Callable

from m4k_drivers.led import protocol as p

__all__ = ['SimLed']


class SimLed:
    """Records every colour shown (bounded history of (t_ns, LedColor)) and the last one."""

    def __init__(self, clock: Callable[[], int] = time.monotonic_ns, history: int = 1000) -> None:
        self.clock = clock
        self.history: deque[tuple[int, p.LedColor]] = deque(maxlen=history)
        self.last = p.OFF
        self.shown = 0
        self.closed = False
        self._lock = threading.Lock()

    def show(self, color: p.LedColor) -> None:
        """Record ``color`` as shown now."""
        if self.closed:
            raise OSError(9, 'Bad file descriptor')
        with self._lock:
            self.history.append((self.clock(), color))
            self.last = color
            self.shown += 1

    def snapshot(self) -> list[tuple[int, p.LedColor]]:
        """Return a copy of the history."""
        with self._lock:
            return list(self.history)

    def close(self) -> None:
        """Mark closed."""
        self.closed = True
