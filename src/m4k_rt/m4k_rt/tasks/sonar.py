"""Sonar task body (30 ms): trigger the US-100, publish the range to the guard and the bridge.

Ports: ``sonar`` (driver host: REQUEST trigger out, SONAR and DEVICE_STATUS in) and
``sonar_out`` (bridge: SONAR out). Pipeline: each cycle drains the reply to the previous
trigger (an echo takes up to ~30 ms for 5 m, so a reply arrives within the cycle or early in
the next; the body never waits for it), records it in the shared state for the actuator's
collision guard, forwards it unchanged, then sends this cycle's trigger.

What reaches the guard:

* status OK -> ``sonar_range`` = the range, ``sonar_rx_ns`` = now;
* status NO_ECHO (nothing within range) -> ``sonar_range`` = inf, stamp refreshed: a valid
  "free ahead" reading;
* status TIMEOUT / FAULT -> counted, the stamp is *not* refreshed. Repeated failures make the
  reading stale after ``control.guard.sonar_timeout`` and the guard then applies its stale
  policy (default: stop forward motion).
"""

from __future__ import annotations

import math
import time
from typing import Any, Callable, Mapping

from m4k_rt.config import TaskConfig
from m4k_rt.protocol import Kind, SONAR_NO_ECHO, SONAR_OK
from m4k_rt.tasks.interfaces import CycleContext, RtPort
from m4k_rt.tasks.portio import DeviceTaskBody
from m4k_rt.tasks.state import robot_state, RobotState

__all__ = ['SonarBody', 'make_sonar', 'TRIGGER']

TRIGGER = 1   # REQUEST.arg asking the sonar handler for one measurement
_SONAR = Kind.SONAR
_DEVICE_STATUS = Kind.DEVICE_STATUS
_REQUEST = Kind.REQUEST
_INF = math.inf


class SonarBody(DeviceTaskBody):
    """Per-cycle body of the sonar task."""

    def __init__(self, dev_sock: RtPort, out_sock: RtPort, state: RobotState,
                 clock: Callable[[], int] = time.monotonic_ns) -> None:
        super().__init__(dev_sock, out_sock, state, clock)
        self.readings = 0
        self.failed = 0

    @property
    def counters(self) -> Mapping[str, int]:
        """Return a snapshot of the body's counters (NRT use)."""
        return {'cycles': self.cycles, 'readings': self.readings, 'failed': self.failed,
                'unexpected': self.unexpected, 'forwarded': self._out.sent,
                'triggers': self._dev_out.sent}

    def __call__(self, ctx: CycleContext | None = None) -> None:
        """Run one sonar cycle."""
        now = ctx.t_start if ctx is not None else self._clock()
        state = self.state
        reader = self._dev_in
        reader.start_cycle()
        while (got := reader.next()) is not None:
            hdr, msg = got
            if hdr.kind == _SONAR:
                status = msg.status
                state.sonar_status = status
                if status == SONAR_OK:
                    state.sonar_range = msg.range_m
                    state.sonar_rx_ns = now
                    self.readings += 1
                elif status == SONAR_NO_ECHO:
                    state.sonar_range = _INF
                    state.sonar_rx_ns = now
                    self.readings += 1
                else:
                    self.failed += 1
                self._out.forward(reader.raw())
            elif hdr.kind == _DEVICE_STATUS:
                state.record_device_status('sonar', msg, now)
            else:
                self.unexpected += 1
        self.unexpected += self._out_in.discard()   # the bridge only reads this port
        self._dev_out.send(_REQUEST, now, self.cycles & 0xFFFFFFFF, TRIGGER)
        self.cycles += 1


def make_sonar(task: TaskConfig, ports: Mapping[str, RtPort], shared: Any) -> SonarBody:
    """Build the sonar body from its ``sonar``/``sonar_out`` ports."""
    return SonarBody(ports['sonar'], ports['sonar_out'], robot_state(shared))
