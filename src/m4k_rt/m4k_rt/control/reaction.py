"""t_react, the guard's reaction time: the one derivation, from the configuration (pure).

    t_react = sensor part + RT part + actuation part

* **sensor part**: ``2 x T_sensor`` (+ ``guard.laser_scan_time`` for the laser). A point that
  appears just after the sensor looked at it is sampled up to one task period later, and the
  device task hands that reading on up to one more period after that (each cycle drains the
  reply to the previous cycle's request). The URG stamps the start of its sweep and sends
  after it: a point at the sweep's end reaches the handler one scan time later. For the
  guard's stop zone (``timeouts=True``) the sensor part is never shorter than the longest
  staleness timeout of a guard sensor in use (``guard.laser_timeout``,
  ``guard.sonar_timeout``): the guard acts on a reading until it is that old (aged from its
  acquisition), so a point that appears just after a reading was taken may go unseen that
  long when the next reading is late.
* **RT part**: the actuator's period (it acts at its next cycle), ``guard.pipeline_latency``
  (the datagram hops driver host -> RT -> actuator -> motor service) and
  ``guard.scheduling_allowance`` (the wake-up latency of the tasks on their host: measured,
  not hoped for; the scenario judge holds the guard to exactly this figure and adds none).
* **actuation part**: ``guard.amplifier_lag``, from the zero DAC word to the wheels'
  deceleration. The only part a measurement on the base can replace: ``calibrate`` writes
  this key and nothing else of t_react, so a calibrated robot still pays its sensors' delay.

There is no key that replaces the whole sum. rt_core (the guard's stop zone and the stated
top speed), the bridge's statement of them and the scenario judge all call
:func:`reaction`; the judge passes its own actuation figure (the shipped declaration), so what
``calibrate`` writes cannot loosen the bound it is judged against.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

__all__ = ['Reaction', 'reaction', 'SENSORS']

SENSORS = ('laser', 'sonar')


@dataclass(frozen=True)
class Reaction:
    """The three parts of t_react (s) and the sensor whose delay sets the first."""

    sensor: str
    sensor_part: float
    rt_part: float
    actuation_part: float

    @property
    def total(self) -> float:
        """Return t_react (s): sensor part + RT part + actuation part."""
        return self.sensor_part + self.rt_part + self.actuation_part

    def text(self) -> str:
        """Return the sum in words, for start-up lines and reports."""
        return '{:.3f} s = {} {:.3f} + RT {:.3f} + actuation {:.3f}'.format(
            self.total, self.sensor, self.sensor_part, self.rt_part, self.actuation_part)


def reaction(guard: Any, sensor: str, sensor_period: float, actuator_period: float,
             actuation: float | None = None, timeouts: bool = False) -> Reaction:
    """Return t_react for ``sensor`` (``laser`` / ``sonar``) from ``control.guard`` settings.

    ``sensor_period`` is the sensor task's period and ``actuator_period`` the actuator's (s).
    ``actuation`` replaces ``guard.amplifier_lag`` (the judge's own figure); None: the
    configured (possibly calibrated) value. ``timeouts``: the guard's stop zone, whose sensor
    part covers the staleness timeouts of the guard sensors in use. Raise ValueError for an
    unknown sensor or a negative period.
    """
    if sensor not in SENSORS:
        raise ValueError('sensor must be one of {}, got {!r}'.format(SENSORS, sensor))
    if not (sensor_period >= 0.0 and actuator_period >= 0.0):
        raise ValueError('periods must be >= 0 s, got {!r} and {!r}'.format(
            sensor_period, actuator_period))
    sensor_part = 2.0 * sensor_period
    if sensor == 'laser':
        sensor_part += float(guard.laser_scan_time)
    if timeouts:
        longest = max(float(guard.laser_timeout) if guard.use_laser else 0.0,
                      float(guard.sonar_timeout) if guard.use_sonar else 0.0)
        if longest > sensor_part:
            sensor_part = longest
    rt_part = actuator_period + float(guard.pipeline_latency) + float(
        guard.scheduling_allowance)
    act = float(guard.amplifier_lag) if actuation is None else float(actuation)
    return Reaction(sensor, sensor_part, rt_part, act)
