"""The wheel supervision's fault trace: its inputs of the last cycles, frozen at a latch (pure).

A latched motor fault stops the robot; whoever meets one -- on a healthy wheel or a broken one
-- needs to see what the supervision saw in the cycles before it, not only the cause's name.
:class:`SupervisionTrace` keeps one row per supervised actuator cycle in a preallocated ring
(RT: no allocation but the floats themselves); at a latch :meth:`SupervisionTrace.freeze`
copies the ring, oldest row first, into a second preallocated table and then publishes the
fault's number. The monitor reads that table and ships it as FAULT_TRACE datagrams (one per
row, ``protocol.FaultTrace``); the bridge writes it to a file (``m4k_bridge.faulttrace``).
A row holds the values in ``protocol.TRACE_FLOAT_FIELDS`` order and ``protocol.TraceFlag``
bits.
"""

from __future__ import annotations

from array import array
from typing import Sequence

from m4k_rt.protocol import TRACE_FLOAT_FIELDS

__all__ = ['SupervisionTrace', 'TRACE_ROWS', 'WIDTH']

# 0.64 s of 10 ms actuator cycles: every symptom time (at most 0.3 s by default) and the
# cycles before its symptom began.
TRACE_ROWS = 64
WIDTH = len(TRACE_FLOAT_FIELDS)
_VALUES = WIDTH - 10                 # the floats before the ten symptom times


class SupervisionTrace:
    """A ring of supervision rows and the copy frozen at the last latch.

    ``fault`` is the number of the fault frozen last (0: none yet); it is written after the
    frozen rows, so a reader that sees it change reads a complete table (and re-reads when it
    changed again meanwhile).
    """

    __slots__ = ('capacity', 'n', '_t', '_v', '_f', 'frozen_t', 'frozen_v', 'frozen_f', 'rows',
                 'cause', 'fault')

    def __init__(self, capacity: int = TRACE_ROWS) -> None:
        if capacity < 1:
            raise ValueError(f'trace capacity must be >= 1, got {capacity}')
        self.capacity = capacity
        self.n = 0                                  # rows recorded since start
        self._t = array('q', bytes(8 * capacity))
        self._v = array('d', bytes(8 * capacity * WIDTH))
        self._f = array('B', bytes(capacity))
        self.frozen_t = array('q', bytes(8 * capacity))
        self.frozen_v = array('d', bytes(8 * capacity * WIDTH))
        self.frozen_f = array('B', bytes(capacity))
        self.rows = 0
        self.cause = 0
        self.fault = 0

    def record(self, now_ns: int, flags: int, values: Sequence[float],
               times: Sequence[float]) -> None:
        """Append one cycle's row; the oldest row is overwritten once the ring is full.

        ``values``: the row's first 13 floats in TRACE_FLOAT_FIELDS order (setpoints to still
        bounds), ``times`` the 10 symptom times that follow them.
        """
        cap = self.capacity
        i = self.n % cap
        self._t[i] = now_ns
        self._f[i] = flags
        v = self._v
        o = i * WIDTH
        for k in range(_VALUES):
            v[o + k] = values[k]
        o += _VALUES
        for k in range(WIDTH - _VALUES):
            v[o + k] = times[k]
        self.n += 1

    def freeze(self, fault: int, cause: int) -> None:
        """Copy the ring, oldest row first, as the trace of fault number ``fault``."""
        cap = self.capacity
        rows = min(self.n, cap)
        start = (self.n - rows) % cap
        head = min(rows, cap - start)            # rows from start to the ring's end
        tail = rows - head                       # rows wrapped to its beginning
        self.frozen_t[:head] = self._t[start:start + head]
        self.frozen_f[:head] = self._f[start:start + head]
        self.frozen_v[:head * WIDTH] = self._v[start * WIDTH:(start + head) * WIDTH]
        if tail:
            self.frozen_t[head:rows] = self._t[:tail]
            self.frozen_f[head:rows] = self._f[:tail]
            self.frozen_v[head * WIDTH:rows * WIDTH] = self._v[:tail * WIDTH]
        self.rows = rows
        self.cause = cause
        self.fault = fault                       # published last

    def row(self, i: int) -> tuple[int, int, tuple[float, ...]]:
        """Return frozen row ``i`` (0: the oldest) as (t_ns, flags, values)."""
        if not 0 <= i < self.rows:
            raise IndexError(f'trace row {i} outside [0, {self.rows})')
        return (self.frozen_t[i], self.frozen_f[i],
                tuple(self.frozen_v[i * WIDTH:(i + 1) * WIDTH]))
