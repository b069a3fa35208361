"""Progress display: one updating line on a TTY, plain lines otherwise (logs, CI, pipes)."""

from __future__ import annotations

import sys
import time
from typing import TextIO

__all__ = ['Progress', 'format_line']


def format_line(step: int, steps: int, name: str, elapsed_s: float, total_s: float | None,
                note: str = '', width: int = 24) -> str:
    """Return ``[3/9] name  [#####.....]  12/60 s  note`` (pure)."""
    head = '[{}/{}] {}'.format(step, steps, name)
    if total_s:
        frac = min(max(elapsed_s / total_s, 0.0), 1.0)
        filled = int(round(frac * width))
        bar = '[{}{}] {:.0f}/{:.0f} s'.format('#' * filled, '.' * (width - filled),
                                               elapsed_s, total_s)
    else:
        bar = '{:.0f} s'.format(elapsed_s)
    return '  '.join(x for x in (head, bar, note) if x)


class Progress:
    """Phase-by-phase progress for a known number of steps."""

    def __init__(self, steps: int, stream: TextIO | None = None,
                 tty: bool | None = None, plain_every_s: float = 15.0) -> None:
        """Write to ``stream`` (stderr); ``tty`` None = ask the stream."""
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty() if tty is None else tty
        self.steps = steps
        self.step = 0
        self.name = ''
        self.total_s: float | None = None
        self.t0 = time.monotonic()
        self.plain_every_s = plain_every_s
        self._last_plain = 0.0
        self._width = 0

    def phase(self, name: str, total_s: float | None = None) -> None:
        """Start the next phase (expected to take about ``total_s`` seconds)."""
        self._finish_line()
        self.step += 1
        self.name = name
        self.total_s = total_s
        self.t0 = time.monotonic()
        self._last_plain = self.t0
        if not self.tty:
            self._write(format_line(self.step, self.steps, name, 0.0, total_s) + '\n')
        else:
            self.update()

    def update(self, note: str = '') -> None:
        """Refresh the line (TTY) or print a plain line every ``plain_every_s``."""
        now = time.monotonic()
        line = format_line(self.step, self.steps, self.name, now - self.t0, self.total_s, note)
        if self.tty:
            pad = max(self._width - len(line), 0)
            self._width = len(line)
            self._write('\r' + line + ' ' * pad)
        elif now - self._last_plain >= self.plain_every_s:
            self._last_plain = now
            self._write(line + '\n')

    def log(self, message: str) -> None:
        """Print a message on its own line (the progress line is redrawn after it)."""
        self._finish_line()
        self._write('bench: ' + message + '\n')

    def done(self, message: str = '') -> None:
        """End the display."""
        self._finish_line()
        if message:
            self._write(message + '\n')

    def _finish_line(self) -> None:
        if self.tty and self._width:
            self._write('\n')
            self._width = 0

    def _write(self, text: str) -> None:
        self.stream.write(text)
        self.stream.flush()
