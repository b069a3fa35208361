"""US-100 ultrasonic ranger in pulse (HC-SR04 compatible) mode (pure: edges in, metres out).

Trigger: a high pulse of at least 10 us on TRIG starts one measurement.  The sensor sends a
40 kHz burst, raises ECHO, and lowers it when the echo returns: range = c * width / 2 with the
speed of sound c = 331.3 * sqrt(1 + T / 273.15) m/s.  Usable range 0.02-4.5 m.  A pulse
outside that range is an unmeasurable echo -- no echo heard (a soft or angled surface), or too
close -- and is reported INVALID (``STATUS_FAULT``, NaN on /sonar), never as the maximum range:
"no echo" must not mean free space.  No edge at all within the timeout means the sensor did
not answer (``STATUS_TIMEOUT``).  ``STATUS_NO_ECHO`` stays in the datagram vocabulary but the
US-100 drivers never report it.  Status codes are the SONAR datagram's (docs/internals.md).
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
STATUS_NO_ECHO = SONAR_NO_ECHO    # "nothing within range": never claimed by the US-100 drivers
STATUS_TIMEOUT = SONAR_TIMEOUT    # no edges: sensor not answering
STATUS_FAULT = SONAR_FAULT        # invalid: unmeasurable echo, clock step, inconsistent edges


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
    if rng < min_m or rng > max_m:
        return SonarReading(rng, STATUS_FAULT)        # unmeasurable echo: invalid
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
