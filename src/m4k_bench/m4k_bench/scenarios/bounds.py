"""The bounds a scenario is judged against, derived from config/ (never tuned to a run).

* distance: the true path within ``v^2 / (2 a)`` of the commanded distance -- what the speed
  limiter's ramps may take or give (``control.linear.max_acceleration`` / ``max_deceleration``);
* stop time, from the moment the robot must react (the *trigger*) to the first ground-truth
  instant at rest (< ``REST_V``, the simulator's ``rest_since_ns``), for each cause:

  =====================  ==================================================  ==================
  cause                  latency before the guard / watchdog acts             trigger
  =====================  ==================================================  ==================
  sonar                  2 sonar periods (pipelined ping) + 1 actuator        front clearance <
                                                                              stop_distance
  laser                  2 lrf periods + one URG scan (60 / SCAN rpm)          the same
                         + 1 actuator
  sonar_unplugged        sonar_timeout + 2 sonar periods + echo timeout       the unplug
                         + 1 actuator
  laser_unplugged        laser_timeout + 1 lrf period + 1 actuator            the unplug
  bridge_killed          cmd_vel_timeout + 2 actuator                         the kill
  driver_host_killed     heartbeat_hold_s (the amplifiers lose enable), then  the kill
                         the wheels coast on friction: v / world.robot.
                         coast_decel_mps2 (no braking: this replaces the
                         v / max_deceleration below)
  =====================  ==================================================  ==================

  plus (but for the coasting driver host) the braking ``v / max_deceleration`` (the guard's stop
  bypasses the ramp, so this bounds it from above). The rest instant is the simulator's own
  (``rest_since_ns``, 1 ms steps), not the runner's sampling.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any, Mapping

from m4k_drivers.sonar.protocol import ECHO_TIMEOUT_S
from m4k_drivers.world import REST_V  # m/s: at rest on ground truth

__all__ = ['Bounds', 'REST_V', 'SAMPLE_S', 'bounds']

SAMPLE_S = 0.02      # the runner samples the simulator's truth every 20 ms
URG_SCAN_S = 0.1     # URG-04LX: 600 rpm (PP SCAN)


@dataclass(frozen=True)
class Bounds:
    """What one scenario is held to."""

    distance_tol: float           # m
    stop_s: float | None          # s from trigger to rest
    trigger_clearance: float | None   # m ahead of the front face (obstacle stops)


def _period(raw: Mapping[str, Any], task: str) -> float:
    return float(raw['tasks'][task]['period_ms']) / 1000.0


def bounds(raw: Mapping[str, Any], v: float, cause: str | None) -> Bounds:
    """Return the bounds for forward speed ``v`` and stop ``cause`` from the layered config."""
    from m4k_rt.control.params import control_params
    p = control_params(raw.get('control'))
    accel = p.linear.max_acceleration
    decel = p.linear.max_deceleration or accel
    tol = v * v / (2.0 * min(accel, decel))
    ta = _period(raw, 'actuator')
    brake = v / decel
    g = p.guard
    trigger = None
    stop: float | None = None
    if cause == 'sonar':
        trigger = g.stop_distance       # the guard measures from the body's front face
        stop = 2 * _period(raw, 'sonar') + ta + brake
    elif cause == 'laser':
        trigger = g.stop_distance
        stop = 2 * _period(raw, 'lrf') + URG_SCAN_S + ta + brake
    elif cause == 'sonar_unplugged':
        stop = g.sonar_timeout + 2 * _period(raw, 'sonar') + ECHO_TIMEOUT_S + ta + brake
    elif cause == 'laser_unplugged':
        stop = g.laser_timeout + _period(raw, 'lrf') + ta + brake
    elif cause == 'bridge_killed':
        stop = p.cmd_vel_timeout + 2 * ta + brake
    elif cause == 'driver_host_killed':
        from m4k_drivers.world import RobotParams, WorldConfig
        motor = (raw.get('devices') or {}).get('motor') or {}
        # The coast-down is friction alone, derived from the robot as built (world.robot).
        robot = RobotParams.from_control(raw.get('control'), (raw.get('robot') or {}).get('body'))
        coast = WorldConfig.from_dict({'robot': (raw.get('world') or {}).get('robot') or {}},
                                      robot=robot).robot.coast_decel_mps2
        hold = float(motor.get('heartbeat_hold_s', 0.05)) if motor.get('heartbeat', True) \
            else math.inf
        stop = hold + v / coast
    return Bounds(tol, stop, trigger)
