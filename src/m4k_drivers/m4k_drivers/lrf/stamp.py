"""Scan acquisition stamps from the URG's own ms counter (pure: numbers in, numbers out).

The URG stamps each scan with its 24-bit millisecond timer at step 0 (SCIP 2.0 spec
C-42-03320B, "Time Stamp").  A scan reaches the host one transfer later, and USB, the kernel
and the reader thread add a delay that varies from scan to scan but is never negative.  So,
as urg_node2 does, the host-receive time minus the sensor time is an upper bound of the clock
offset, and the *smallest* such difference over a window is the best estimate of it (the
scan that was delayed least).  The two clocks drift (the sensor's crystal, tens of ppm), so
the estimator also tracks the slope of that lower envelope: it takes the minimum over each
half of the window and fits the line through the two minima.

``ScanStamper.update(sensor_ms, host_ns)`` takes the *unwrapped* sensor time
(:class:`m4k_drivers.lrf.scip.TimestampUnwrapper` handles the 24-bit wrap every 4.66 h) and the
host CLOCK_MONOTONIC when the scan was received, and returns the host time at which step 0 was
measured; it is never later than the receive time.  ``reset()`` after a reconnect (the sensor
timer may have restarted).
"""

from __future__ import annotations

from collections import deque

__all__ = ['ScanStamper']


class ScanStamper:
    """Offset-and-drift estimator mapping sensor ms onto host CLOCK_MONOTONIC ns."""

    def __init__(self, window: int = 100, max_drift: float = 1e-3) -> None:
        if isinstance(window, bool) or not isinstance(window, int) or window < 2:
            raise ValueError(f'stamp window must be an int >= 2 scans, got {window!r}')
        if not 0.0 <= max_drift < 0.1:
            raise ValueError(f'max_drift must be in [0, 0.1), got {max_drift!r}')
        self.window = window
        self.max_drift = max_drift
        self._pairs: deque[tuple[int, int]] = deque(maxlen=window)   # (sensor ns, offset ns)
        self.offset_ns = 0
        self.drift = 0.0
        self._ref_ns = 0

    def reset(self) -> None:
        """Forget the history (new connection, or the sensor timer was reset)."""
        self._pairs.clear()
        self.offset_ns = 0
        self.drift = 0.0
        self._ref_ns = 0

    @property
    def samples(self) -> int:
        """Return how many scans the estimate rests on."""
        return len(self._pairs)

    def update(self, sensor_ms: int, host_ns: int) -> int:
        """Feed one scan (unwrapped sensor ms, host receive ns); return its acquisition ns."""
        sensor_ns = sensor_ms * 1_000_000
        if self._pairs and sensor_ns < self._pairs[-1][0]:
            self.reset()           # the sensor's clock went back: a new epoch
        self._pairs.append((sensor_ns, host_ns - sensor_ns))
        pairs = list(self._pairs)
        half = len(pairs) // 2
        if half >= 1 and pairs[-1][0] > pairs[0][0]:
            a = min(pairs[:half], key=lambda p: p[1])
            b = min(pairs[half:], key=lambda p: p[1])
            drift = (b[1] - a[1]) / (b[0] - a[0]) if b[0] != a[0] else 0.0
            # A slope beyond any crystal's tolerance is a delay burst, not drift.
            self.drift = max(-self.max_drift, min(self.max_drift, drift))
            self._ref_ns, self.offset_ns = b
        else:
            self._ref_ns, self.offset_ns = pairs[-1]
        # The lower envelope, extrapolated from the newer minimum to this scan; a scan can
        # not have been measured after it arrived, whatever the estimate says.
        offset = self.offset_ns + round(self.drift * (sensor_ns - self._ref_ns))
        return min(sensor_ns + offset, host_ns)
