"""The myAHRS+ DATA READY output (J3-1, ``INT``) read as GPIO edge events: the sample's time.

WithRobot's pin table names J3-1 "DATA READY interrupt output" but not its polarity or pulse
width, so the edge that marks a new sample is configured (``drdy_edge``) and checked on the
board.  The line is requested with one edge and its event clock re-requested as
CLOCK_MONOTONIC (python-periphery asks for CLOCK_REALTIME; :func:`request_monotonic_edges`),
so the kernel's edge timestamp is on the clock the RT side stamps with.  Where that is not
possible the edges are still waited on, but no stamp is taken from them (a wall-clock step
would move it): the sample is then timed on arrival, as when polling.
"""

from __future__ import annotations

from typing import Any

from m4k_drivers.handler import wrap_os_error

__all__ = ['DataReady', 'open_drdy']


class DataReady:
    """One DATA READY line: wait for the newest edge, return its CLOCK_MONOTONIC time."""

    def __init__(self, line: Any, where: str, monotonic: bool) -> None:
        self.line = line
        self.where = where
        self.monotonic = monotonic
        self.edges = 0

    def wait(self, timeout_s: float) -> tuple[bool, int | None]:
        """Return (an edge came, its time ns or None) -- the newest of the pending edges.

        An edge already queued since the last call counts (the sample it announced has not
        been read yet); otherwise wait up to ``timeout_s`` for one.
        """
        try:
            last = self._drain()
            if last is None and self.line.poll(timeout_s):
                last = self._drain()
        except OSError as exc:
            raise wrap_os_error(exc, self.where, 'data-ready edge') from exc
        if last is None:
            return False, None
        return True, (last if self.monotonic else None)

    def _drain(self) -> int | None:
        last = None
        while self.line.poll(0.0):
            last = int(self.line.read_event().timestamp)
            self.edges += 1
        return last

    def close(self) -> None:
        """Release the line, ignoring errors."""
        try:
            self.line.close()
        except OSError:
            pass


def open_drdy(chip: str, line: int, edge: str) -> DataReady:
    """Request the DATA READY line as an input with ``edge`` ('rising' or 'falling') events."""
    from periphery import GPIO

    from m4k_drivers.sonar.real import request_monotonic_edges
    where = f'{chip} line {line} (IMU data-ready, {edge})'
    try:
        gpio = GPIO(chip, line, 'in', edge=edge)
    except OSError as exc:
        raise wrap_os_error(exc, where) from exc
    mono = request_monotonic_edges(gpio, rising=edge == 'rising', falling=edge == 'falling')
    return DataReady(gpio, where, mono)
