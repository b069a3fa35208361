"""The driver host's drop counters -> one diagnostic per device (pure: no ROS types).

The driver host counts every datagram from the RT side it does not serve, and every reply the
link does not take, by reason (``protocol.HOST_DROP_REASONS``) and sends them as HOST_DROPS
with each DEVICE_STATUS; the RT monitor forwards the last report of each device on ``status``,
stamped with the time the RT side received it (docs/internals.md, "HOST_DROPS forwarding").

The counters are cumulative since the host process started.  :class:`HostDropMonitor` keeps
the reports of the last window (the bridge's ``stats_window``) and judges the difference:
OK when no counter moved in the window, WARN when one did (with the drops per second over
the window), STALE when nothing was forwarded within the stale timeout (RT side gone) or the
last report the RT side got is older than the window (driver host gone: its counts no longer
cover the window judged; the device's own ``m4k_drivers: <device>`` status says so sooner).
Counters that go back mean a new host process: its counts all happened since it started, so
they are judged against zero.
"""

from __future__ import annotations

import collections
from typing import Any, Iterator

from m4k_rt import protocol

__all__ = ['HostDropMonitor']

_NS = 1e-9


class _Device:
    """One device's reports within the window: (RT arrival ns, served, *reasons)."""

    def __init__(self) -> None:
        self.rows: collections.deque[tuple[int, ...]] = collections.deque()
        self.rx_ns = 0          # bridge's CLOCK_MONOTONIC of the last report

    def add(self, d: protocol.HostDrops, stamp_ns: int, rx_ns: int, window_ns: int) -> None:
        row = (stamp_ns, *d[1:])
        last = self.rows[-1] if self.rows else None
        if last is not None and (any(n < o for n, o in zip(row[1:], last[1:], strict=True))
                                 or stamp_ns < last[0]):
            # A new host process (its counters start at 0): judge its counts against zero.
            self.rows.clear()
            self.rows.append((last[0],) + (0,) * (len(row) - 1))
        self.rows.append(row)
        self.rx_ns = rx_ns
        # Keep one report at or before the window's start: the baseline of the differences.
        while len(self.rows) > 2 and self.rows[1][0] <= stamp_ns - window_ns:
            self.rows.popleft()


class HostDropMonitor:
    """Accumulate HOST_DROPS reports and judge them (``RtMonitor`` makes the statuses)."""

    def __init__(self, window_s: float, stale_s: float) -> None:
        self.window_ns = int(window_s * 1e9)
        self.stale_ns = int(stale_s * 1e9)
        self.devices: dict[str, _Device] = {}

    def feed(self, d: protocol.HostDrops, rx_ns: int, stamp_ns: int) -> None:
        """Account one report; ``stamp_ns`` is when the RT side received it."""
        dev = self.devices.get(d.device)
        if dev is None:
            dev = self.devices[d.device] = _Device()
        dev.add(d, stamp_ns, rx_ns, self.window_ns)

    def levels(self, now_ns: int) -> Iterator[tuple[str, int, str, dict[str, Any]]]:
        """Yield (device, level, message, values) for every device that reported.

        Key-values: ``served`` and every reason (cumulative, since the host started),
        ``window_s`` (the span judged), ``window_drops``, ``window_drops_per_s``, ``age_s``
        (since the RT side got the last report).
        """
        for name, dev in sorted(self.devices.items()):
            first, last = dev.rows[0], dev.rows[-1]
            moved = [(reason, n - o) for reason, n, o in zip(
                protocol.HOST_DROP_REASONS, last[2:], first[2:], strict=True) if n != o]
            drops = sum(n for _, n in moved)
            span = (last[0] - first[0]) * _NS
            rate = drops / span if span > 0 else 0.0
            age = max(now_ns - last[0], 0) * _NS
            values: dict[str, Any] = {'served': last[1]}
            values.update(zip(protocol.HOST_DROP_REASONS, last[2:], strict=True))
            values.update(window_s=span, window_drops=drops, window_drops_per_s=rate,
                          age_s=age)
            if now_ns - dev.rx_ns > self.stale_ns:
                level = protocol.LEVEL_STALE
                msg = 'nothing forwarded by the RT process for {:.1f} s'.format(
                    (now_ns - dev.rx_ns) * _NS)
            elif now_ns - last[0] > self.window_ns:
                level = protocol.LEVEL_STALE
                msg = 'no drop report from the driver host for {:.1f} s'.format(age)
            elif drops:
                level = protocol.LEVEL_WARN
                msg = '{} dropped in the last {:.1f} s ({:.3g}/s): {}'.format(
                    drops, span, rate, ', '.join('{} {}'.format(r, n) for r, n in moved))
            else:
                level = protocol.LEVEL_OK
                msg = 'no drops in the last {:.1f} s ({} since the host started)'.format(
                    span, sum(last[2:]))
            yield name, level, msg, values
