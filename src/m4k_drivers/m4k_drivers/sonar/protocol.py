"""US-100 ultrasonic ranger in pulse (HC-SR04 compatible) mode (pure: edges in, metres out).

Trigger: a high pulse of at least 10 us on TRIG starts one measurement.  The sensor sends a
40 kHz burst, raises ECHO, and lowers it when the echo returns: range = c * width / 2 with the
speed of sound c = 331.3 * sqrt(1 + T / 273.15) m/s.  Usable range 0.02-4.5 m.

What a pulse means (the HC-SR04-compatible GPIO mode; the module lowers ECHO after ~38 ms when
no echo came back -- "If no echo is received the 'Echo' output will go LOW after 38ms"):

* width within 0.02-4.5 m -> ``STATUS_OK``, the range;
* longer than 4.5 m (up to the echo timeout) -> ``STATUS_NO_ECHO``: nothing within 4.5 m. This is
  the sensor's normal answer in a hall or a corridor, a valid reading (REP-117 +inf on /sonar)
  that keeps the guard's sonar fresh. A surface the burst does not come back from (a curtain,
  an oblique wall) looks the same: the laser is the guard's other witness;
* shorter than 0.02 m, zero, negative or not finite -> ``STATUS_FAULT``: no real echo is that
  short (the transducers ring for longer), so the reading is impossible, as is one taken across
  a clock step (:mod:`m4k_drivers.sonar.real`);
* no edge at all within ``ECHO_TIMEOUT_S`` -> ``STATUS_TIMEOUT``: the sensor did not answer
  (unplugged, dead).

FAULT and TIMEOUT do not refresh the guard: after ``control.guard.sonar_timeout`` the sonar is
stale and the guard's ``stale_policy`` applies (default stop).  Status codes are the SONAR
datagram's (docs/internals.md; docs/sensor-outcomes.md has the whole table).
"""

from __future__ import annotations

import math
from typing import Iterable, NamedTuple

from m4k_rt.protocol import SONAR_FAULT, SONAR_NO_ECHO, SONAR_OK, SONAR_TIMEOUT

__all__ = ['ECHO_TIMEOUT_S', 'MAX_RANGE_M', 'MIN_RANGE_M', 'STATUS_FAULT', 'STATUS_NO_ECHO',
           'STATUS_OK', 'STATUS_TIMEOUT', 'TRIGGER_S', 'Edge', 'SonarReading', 'edges_to_width',
           'pulse_to_range', 'range_to_pulse', 'speed_of_sound']

TRIGGER_S = 10e-6
MIN_RANGE_M = 0.02
MAX_RANGE_M = 4.5
ECHO_TIMEOUT_S = 0.06        # > the ~38 ms "no echo" pulse HC-SR04-style modules emit

# The SONAR datagram's status codes (m4k_rt.protocol).
STATUS_OK = SONAR_OK              # range valid
STATUS_NO_ECHO = SONAR_NO_ECHO    # "nothing within range": the long no-echo pulse
STATUS_TIMEOUT = SONAR_TIMEOUT    # no edges: sensor not answering
STATUS_FAULT = SONAR_FAULT        # invalid: impossible width, clock step


class Edge(NamedTuple):
    """One echo-line edge: 'rising' or 'falling' and its kernel timestamp (ns)."""

    edge: str
    timestamp: int


class SonarReading(NamedTuple):
    """A range in metres (0.0 unless measured) and a status code."""

    range_m: float
    status: int


def speed_of_sound(temp_c: float = 20.0) -> float:
    """Return the speed of sound in dry air at ``temp_c`` degrees Celsius, m/s."""
    return 331.3 * math.sqrt(1.0 + temp_c / 273.15)


def pulse_to_range(width_s: float | None, temp_c: float = 20.0,
                   min_m: float = MIN_RANGE_M, max_m: float = MAX_RANGE_M) -> SonarReading:
    """Convert an echo pulse width to a reading (None = no pulse seen -> timeout)."""
    if width_s is None:
        return SonarReading(0.0, STATUS_TIMEOUT)
    if not math.isfinite(width_s) or width_s <= 0.0:
        return SonarReading(0.0, STATUS_FAULT)
    rng = speed_of_sound(temp_c) * width_s / 2.0
    if rng < min_m:
        return SonarReading(rng, STATUS_FAULT)        # shorter than any real echo: impossible
    if rng > max_m:
        return SonarReading(rng, STATUS_NO_ECHO)      # the no-echo pulse: nothing within max_m
    return SonarReading(rng, STATUS_OK)


def range_to_pulse(range_m: float, temp_c: float = 20.0) -> float:
    """Return the echo pulse width for a target at ``range_m`` (the inverse, for the sim)."""
    return 2.0 * range_m / speed_of_sound(temp_c)


def edges_to_width(edges: Iterable[Edge]) -> float | None:
    """Return the width (s) of the first rising->falling pair, None if there is none."""
    rise: int | None = None
    for ev in edges:
        if ev.edge == 'rising':
            rise = ev.timestamp
        elif ev.edge == 'falling' and rise is not None:
            return (ev.timestamp - rise) * 1e-9
    return None
