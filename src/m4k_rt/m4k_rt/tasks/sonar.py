"""Sonar task body (30 ms): trigger the US-100, publish the range to the guard and the bridge.

Ports: ``sonar`` (driver host: REQUEST trigger out, SONAR and DEVICE_STATUS in) and
``sonar_out`` (bridge: SONAR out). Pipeline: each cycle drains the reply to the previous
trigger (an echo takes up to ~30 ms for 5 m, so a reply arrives within the cycle or early in
the next; the body never waits for it), records it in the shared state for the actuator's
collision guard, forwards it unchanged, then sends this cycle's trigger.

What reaches the guard:

* status OK -> ``sonar_range`` = the range less how far the body's front face is ahead of the
  sonar (``guard.front_offset``: 0 on the front face), ``sonar_rx_ns`` = when the ping went
  out: the datagram's stamp (the driver host's CLOCK_MONOTONIC when it had the echo) less the
  echo's flight time, never later than now -- the guard ages the reading from there;
* status NO_ECHO (nothing within range) -> ``sonar_range`` = inf, stamp refreshed likewise: a
  valid "free ahead" reading;
* both also as one :class:`~m4k_rt.control.sightings.SonarSighting` in ``sonar_sighting``
  (one reference store: the actuator files it in the guard's obstacle memory);
* status TIMEOUT / FAULT -> counted, the stamp is *not* refreshed. Repeated failures make the
  reading stale after ``control.guard.sonar_timeout`` and the guard then applies its stale
  policy (default: stop forward motion).
"""

from __future__ import annotations

import math
import time
from typing import Any, Callable, Mapping

from m4k_rt.config import TaskConfig
from m4k_rt.control.guard import front_offset
from m4k_rt.control.sightings import SonarSighting, SPEED_OF_SOUND
from m4k_rt.protocol import Kind, SONAR_NO_ECHO, SONAR_OK
from m4k_rt.tasks.actuator import raw_section
from m4k_rt.tasks.interfaces import CycleContext, RtPort
from m4k_rt.tasks.portio import DeviceTaskBody
from m4k_rt.tasks.state import robot_state, RobotState

__all__ = ['SonarBody', 'make_sonar', 'TRIGGER']

TRIGGER = 1   # REQUEST.arg asking the sonar handler for one measurement
_SONAR = Kind.SONAR
_INF = math.inf


class SonarBody(DeviceTaskBody):
    """Per-cycle body of the sonar task."""

    def __init__(self, dev_sock: RtPort, out_sock: RtPort, state: RobotState,
                 clock: Callable[[], int] = time.monotonic_ns, front: float = 0.0) -> None:
        super().__init__(dev_sock, out_sock, state, clock)
        self.front = front     # m the body's front face is ahead of the sonar
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
        self._poll_device(ctx, _SONAR, 'sonar', TRIGGER)

    def _on_reading(self, hdr: Any, msg: Any, now: int) -> None:
        """Give the guard one range (or "nothing within range"), then forward it."""
        state = self.state
        status = msg.status
        state.sonar_status = status
        if status == SONAR_OK or status == SONAR_NO_ECHO:
            rng = msg.range_m if status == SONAR_OK else _INF
            acq = hdr.stamp_ns
            if rng != _INF:
                acq -= int(2.0e9 * rng / SPEED_OF_SOUND)   # the ping, not the echo's return
            if acq > now:
                acq = now      # a stamp from the future is not younger than now
            d = rng - self.front
            d = d if d > 0.0 else 0.0
            self.readings += 1
            state.sonar_sighting = SonarSighting(self.readings, acq, d, rng)
            state.sonar_range = d
            state.sonar_rx_ns = acq
        else:
            self.failed += 1
        self._out.forward(self._dev_in.raw())


def make_sonar(task: TaskConfig, ports: Mapping[str, RtPort], shared: Any) -> SonarBody:
    """Build the sonar body from its ``sonar``/``sonar_out`` ports."""
    return SonarBody(ports['sonar'], ports['sonar_out'], robot_state(shared),
                     front=front_offset(raw_section(task, shared, 'robot'), 'sonar'))
