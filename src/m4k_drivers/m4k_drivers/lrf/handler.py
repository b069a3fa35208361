"""Lifecycle handler of the URG laser for the driver host.

``LrfHandler`` (a :class:`m4k_drivers.handler.DeviceHandler`) is built around an *opener*, like
every other handler: a callable returning the :class:`~m4k_drivers.lrf.urg.UrgDriver` of the
configured port.  configure() opens it and runs the SCIP connect sequence, activate() starts the
MD stream (``mode: stream``, default) or does nothing (``mode: poll``: each read() sends one
GD), read() returns :class:`LrfReading` (stream mode: the next scan not returned before,
waiting up to 1.5 scan times, else a counted UrgTimeoutError -- never the same scan twice;
``fresh`` marks a new scan), deactivate() stops the stream, cleanup() closes the port.

Which port, real or simulated, is the backend's business (:mod:`m4k_drivers.lrf.backends`):
the handler never picks one.
"""

from __future__ import annotations

import logging
from typing import Any, Callable, NamedTuple

import numpy as np

from m4k_drivers.handler import DeviceHandler
from m4k_drivers.lrf import scip
from m4k_drivers.lrf.urg import UrgDriver, UrgScan, UrgTimeoutError

__all__ = ['MODES', 'LrfHandler', 'LrfReading']

MODES = ('stream', 'poll')


class LrfReading(NamedTuple):
    """One laser reading handed to the host: ranges in mm (values < 20: URG error codes)."""

    ranges_mm: np.ndarray
    geometry: scip.ScanGeometry
    device_stamp: int          # raw 24-bit device ms counter
    stamp_ms: int              # unwrapped device ms
    host_stamp_ns: int         # CLOCK_MONOTONIC when received
    seq: int
    fresh: bool                # False: the same scan as the previous read()
    stamp_ns: int = 0          # CLOCK_MONOTONIC of the first value (m4k_drivers.lrf.stamp)


class LrfHandler(DeviceHandler):
    """URG-04LX handler: the :class:`UrgDriver` its opener returns, streamed or polled."""

    kind = 'lrf'

    def __init__(self, opener: Callable[[], UrgDriver], *, name: str = 'lrf',
                 mode: str = 'stream', logger: logging.Logger | None = None,
                 **kwargs: Any) -> None:
        super().__init__(name, logger=logger, **kwargs)
        if mode not in MODES:
            raise ValueError(f'{name}.mode: must be one of {", ".join(MODES)}, got {mode!r}')
        self._opener = opener
        self.mode = mode
        self.driver: UrgDriver | None = None
        self._last_seq = 0

    def on_configure(self) -> None:
        """Open the port and run the SCIP connect sequence."""
        self._last_seq = 0
        self.driver = self._opener()
        self.driver.open()

    def on_activate(self) -> None:
        """Start the MD stream (stream mode)."""
        assert self.driver is not None
        if self.mode == 'stream':
            self.driver.start_stream()

    def on_read(self) -> LrfReading:
        """Return the latest scan (stream) or poll one (GD)."""
        assert self.driver is not None
        scan: UrgScan | None
        if self.mode == 'poll':
            scan = self.driver.get_scan()
        else:
            # Only a scan not returned before: handing out the last one again would let the
            # host send stale ranges under a new stamp (e.g. while the laser is unplugged).
            # A live URG delivers one every scan_time, so waiting 1.5 of them is enough.
            g = self.driver.geometry
            first = self._last_seq == 0
            wait = self.driver.timeout if first or g is None else 1.5 * g.scan_time
            scan = self.driver.wait_scan(self._last_seq, wait)
            if scan is None:
                raise UrgTimeoutError(f'{self.name}: no new scan from {self.driver.port!r} within '
                                      f'{wait:.2f} s')
        return self._reading(scan)

    def _reading(self, scan: UrgScan) -> LrfReading:
        fresh = scan.seq != self._last_seq
        self._last_seq = scan.seq
        return LrfReading(scan.ranges_mm, scan.geometry, scan.device_stamp, scan.stamp_ms,
                          scan.host_stamp_ns, scan.seq, fresh, scan.stamp_ns)

    def on_deactivate(self) -> None:
        """Stop the stream (the laser goes off with QT)."""
        if self.driver is not None:
            self.driver.stop_stream()

    def on_cleanup(self) -> None:
        """Close the port; never raises."""
        if self.driver is not None:
            self.driver.close()
            self.driver = None
