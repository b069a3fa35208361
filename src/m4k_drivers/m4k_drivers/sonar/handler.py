"""Sonar handler: one measurement per request (REQUEST(trigger) -> SONAR)."""

from __future__ import annotations

from typing import Any, Callable, Protocol

from m4k_drivers.handler import DeviceHandler, DeviceProtocolError
from m4k_drivers.sonar import protocol as p

__all__ = ['SonarHandler', 'SonarTransport']


class SonarTransport(Protocol):
    """EdgeSonar (GPIO or sim) and IioSonar both provide this."""

    def measure(self, temp_c: float = 20.0, timeout_s: float = p.ECHO_TIMEOUT_S,
                ) -> p.SonarReading:
        """Ping once and return the reading."""

    def close(self) -> None:
        """Release the device."""


class SonarHandler(DeviceHandler):
    """Lifecycle handler for the US-100; read() pings once."""

    kind = 'sonar'

    def __init__(self, opener: Callable[[], SonarTransport], *, name: str = 'sonar',
                 temperature_c: float = 20.0, timeout_s: float = p.ECHO_TIMEOUT_S,
                 **kw: Any) -> None:
        super().__init__(name, **kw)
        self._opener = opener
        self.dev: SonarTransport | None = None
        self.temperature_c = temperature_c
        self.timeout_s = timeout_s
        self.no_echo = 0
        self.timeouts = 0
        self.invalid = 0          # unmeasurable echoes and clock-step discards

    def on_configure(self) -> None:
        """Request the lines / open the IIO attribute."""
        self.dev = self._opener()

    def on_read(self) -> p.SonarReading:
        """Measure once; count no-echo, timeout and invalid readings.

        An invalid reading is also recorded as a fault (DEVICE_STATUS level warn, fault count):
        a sensor that keeps failing to measure must be visible in diagnostics.
        """
        assert self.dev is not None
        reading = self.dev.measure(self.temperature_c, self.timeout_s)
        if reading.status == p.STATUS_NO_ECHO:
            self.no_echo += 1
        elif reading.status == p.STATUS_TIMEOUT:
            self.timeouts += 1
        elif reading.status == p.STATUS_FAULT:
            self.invalid += 1
            self.record_fault(DeviceProtocolError(
                f'{self.name}: unmeasurable echo (range {reading.range_m:.3f} m) or clock step '
                f'-- reported invalid'))
        return reading

    def on_cleanup(self) -> None:
        """Release the device."""
        if self.dev is not None:
            self.dev.close()
            self.dev = None
