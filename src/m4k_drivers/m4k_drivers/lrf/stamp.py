"""Scan acquisition stamps from the URG's own ms counter (pure: numbers in, numbers out).

The URG stamps each scan with its 24-bit millisecond timer as the mirror passes the reference
step -- taken here as step 0, the start of the sweep (SCIP 2.0 spec C-42-03320B, "Time Stamp";
urg_node2's ``get_angular_time_offset`` reads it as the direction straight behind the sensor,
128 steps earlier on the URG-04LX: docs/real-robot.md).  The scan is sent only once the mirror
has passed the last requested step, and it takes its transfer time on the link; USB, the kernel
and the reader thread add a delay that varies from scan to scan but is never negative.

So host receive minus sensor stamp = clock offset + a *constant* latency (sweep to the last
step + transfer, ~90 ms for AMAX 725) + a variable delay.  The smallest such difference over
a window (the scan delayed least) removes the variable part only: the lower envelope, whose
slope tracks the drift of the two clocks (the sensor's crystal, tens of ppm): the minimum over
each half of the window, the line through the two minima.  The constant part is removed as
urg_node2's ``calibrate_system_latency`` does: :meth:`ScanStamper.calibrate` takes the clock
offset measured at connect in time-adjust mode (TM0, TM1 request/reply midpoints, TM2); while
the first window fills, the latency is the envelope minus that offset, then it is frozen and
the envelope carries the drift.  A sensor that refuses TM falls back on ``known_latency_ns``
(the driver sets the sweep term it knows from the scan geometry; the transfer stays in).

``ScanStamper.update(sensor_ms, host_ns)`` takes the *unwrapped* sensor time
(:class:`m4k_drivers.lrf.scip.TimestampUnwrapper` handles the 24-bit wrap every 4.66 h) and the
host CLOCK_MONOTONIC when the scan was received, and returns the host time at which step 0 was
measured; it is never later than the receive time.  ``reset()`` after a reconnect (the sensor
timer may have restarted); it forgets the calibration too.
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
        self.known_latency_ns = 0                 # used without a calibration
        self.clock_offset_ns: int | None = None   # host - sensor, from calibrate()
        self.latency_ns: int | None = None        # envelope - clock offset (frozen when full)

    def reset(self) -> None:
        """Forget the history and the calibration (new connection, or a sensor timer reset)."""
        self._pairs.clear()
        self.offset_ns = 0
        self.drift = 0.0
        self._ref_ns = 0
        self.clock_offset_ns = None
        self.latency_ns = None

    def calibrate(self, clock_offset_ns: int) -> None:
        """Take ``host ns - sensor ns`` measured directly (TM1 at connect) as the clock offset."""
        self.clock_offset_ns = int(clock_offset_ns)
        self.latency_ns = None

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
        if self.clock_offset_ns is None:
            latency = self.known_latency_ns
            self.latency_ns = None
        else:
            if self.latency_ns is None or len(self._pairs) < self.window:
                self.latency_ns = offset - self.clock_offset_ns
            latency = self.latency_ns
        return min(sensor_ns + offset - latency, host_ns)
