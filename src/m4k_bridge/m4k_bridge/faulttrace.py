"""A latched motor fault's supervision trace, from FAULT_TRACE rows to a CSV file (no ROS).

The RT monitor sends, once per latched fault, the wheel supervision's inputs of the cycles
before it (``m4k_rt.control.trace``), one FAULT_TRACE datagram per row, oldest first.
:class:`TraceCollector` puts a fault's rows together; :func:`write_csv` writes them as
``fault_trace_<UTC time>_<fault number>.csv`` (one row per cycle, ``t_ms`` relative to the
latching cycle, the flags as words) in the flight recorder's directory, keeping the newest
:data:`KEEP` files; :func:`statement` is the line the bridge logs with it. The bridge and
the benches that play its role share these.
"""

from __future__ import annotations

import csv
import os
import threading
import time
from typing import Callable, Sequence

from m4k_bridge.flightrec_store import stamp, unused_path
from m4k_rt import protocol
from m4k_rt.control.supervision import cause_text

__all__ = ['KEEP', 'TraceCollector', 'TraceWriter', 'statement', 'write_csv']

KEEP = 50          # trace files kept in the directory (the newest; about 20 KB each)
_PREFIX = 'fault_trace_'
_FLAG_NAMES = tuple((int(f), str(f.name).lower()) for f in protocol.TraceFlag)


class TraceCollector:
    """Assemble the rows of one fault at a time; a row of another fault starts over."""

    def __init__(self) -> None:
        self._fault: int | None = None
        self._rows: dict[int, protocol.FaultTrace] = {}
        self.incomplete = 0      # rows or traces given up (a row lost, a newer fault's began)

    def feed(self, row: protocol.FaultTrace) -> list[protocol.FaultTrace] | None:
        """Take one row; return the whole trace (oldest first) when this row completed it."""
        if row.row >= row.rows:               # not a row of its own trace: dropped
            self.incomplete += 1
            return None
        if row.fault != self._fault:
            if self._rows:
                self.incomplete += 1
            self._fault = row.fault
            self._rows = {}
        self._rows[row.row] = row
        if len(self._rows) < row.rows:       # (keys are distinct rows below rows)
            return None
        rows = [self._rows[i] for i in range(row.rows)]
        self._rows = {}
        self._fault = None
        return rows


def _flags(bits: int) -> str:
    return '|'.join(name for bit, name in _FLAG_NAMES if bits & bit)


def write_csv(rows: Sequence[protocol.FaultTrace], directory: str,
              wall_ns: int | None = None, keep: int = KEEP) -> str:
    """Write one fault's trace to ``directory``; return the file's path.

    The oldest ``fault_trace_*.csv`` files beyond ``keep`` are removed.
    """
    wall_ns = time.time_ns() if wall_ns is None else wall_ns
    os.makedirs(directory, exist_ok=True)
    # (the same second and number twice: another rt_core run)
    path = unused_path(os.path.join(directory, f'{_PREFIX}{stamp(wall_ns)}_{rows[-1].fault}'),
                       '.csv')
    t_end = rows[-1].t_ns
    fields = protocol.TRACE_FLOAT_FIELDS
    tmp = path + '.partial'
    with open(tmp, 'w', newline='') as f:
        out = csv.writer(f)
        out.writerow(['t_ms', *fields, 'flags'])
        for r in rows:
            out.writerow(['{:.1f}'.format((r.t_ns - t_end) / 1e6),
                          *('{:.6g}'.format(getattr(r, name)) for name in fields),
                          _flags(r.flags)])
    os.replace(tmp, path)
    old = sorted(n for n in os.listdir(directory)
                 if n.startswith(_PREFIX) and n.endswith('.csv'))
    for name in old[:max(0, len(old) - keep)]:
        try:
            os.unlink(os.path.join(directory, name))
        except OSError:
            pass
    return path


def statement(rows: Sequence[protocol.FaultTrace], path: str) -> str:
    """Return the line logged with a written trace."""
    last = rows[-1]
    span_ms = (last.t_ns - rows[0].t_ns) / 1e6
    return ("motor fault {} ({}): the wheel supervision's last {} cycles ({:.0f} ms) are in "
            '{}'.format(last.fault, cause_text(last.cause), len(rows), span_ms, path))


class TraceWriter:
    """The bridge's use: collect rows; write each whole trace off the callback, then log it.

    ``log`` takes the statement (or the error when the file cannot be written); the write runs
    in a short thread of its own, so a datagram callback never waits for a disk.
    """

    def __init__(self, directory: str, log: Callable[[str], None]) -> None:
        self.directory = directory
        self.log = log
        self.collector = TraceCollector()
        self.written: list[str] = []
        self._threads: list[threading.Thread] = []

    def on_row(self, row: protocol.FaultTrace, stamp: int = 0, rx_ns: int = 0) -> bool:
        """Take one FAULT_TRACE row (a datagram handler: always True, the kind is expected)."""
        rows = self.collector.feed(row)
        if rows is not None:
            self._threads = [t for t in self._threads if t.is_alive()]
            t = threading.Thread(target=self._write, args=(rows, time.time_ns()), daemon=True,
                                 name='fault-trace')
            t.start()
            self._threads.append(t)
        return True

    def join(self, timeout_s: float = 5.0) -> None:
        """Wait for the traces being written (a bench's end)."""
        for t in self._threads:
            t.join(timeout_s)

    def _write(self, rows: list[protocol.FaultTrace], wall_ns: int) -> None:
        try:
            path = write_csv(rows, self.directory, wall_ns)
        except OSError as exc:
            self.log('motor fault {} ({}): its supervision trace not written: {}'.format(
                rows[-1].fault, cause_text(rows[-1].cause), exc))
            return
        self.written.append(path)
        self.log(statement(rows, path))
