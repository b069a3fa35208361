"""The bounds a scenario is judged against, derived from config/ (never tuned to a run).

Physics, not ramps. For a guard stop (``sonar`` / ``laser``) at ground-truth speed ``v``:

* the **stop line**: the guard must start braking when a surface inside the front face's band
  comes within ``stop_line(v)`` of the front face (:func:`stop_line`: the guard's configured
  stopping distance at that speed). The judge measures that on ground truth with exact geometry
  (:mod:`.geometry`) -- it never reads the guard, its log or any test hook;
* the **reach** past that line: at no ground-truth sample may the robot be further past the
  line at its true speed ``v`` of the moment than ``v * t_react + STOP_MARGIN_M``
  (:meth:`Bounds.reach`: the guard sees the line crossed ``t_react`` late, then brakes and the
  line falls faster than the gap), with ``t_react`` from :func:`m4k_rt.control.reaction.reaction`
  -- the guard's own derivation, so the judge allows no slack the guard does not take (its
  scheduling allowance and the URG's sweep are in the guard's t_react too) -- except for its
  actuation part: the judge takes the shipped declaration of ``guard.amplifier_lag``, never
  an overlay's (``calibrate`` writes that key; what it measures cannot loosen the judge):

  ======  ===================================================================
  cause   t_react (m4k_rt.control.reaction)
  ======  ===================================================================
  sonar   2 sonar periods + 1 actuator period + pipeline + scheduling + lag
  laser   2 lrf periods + one URG scan + 1 actuator period + pipeline
          + scheduling + lag
  ======  ===================================================================

  and ``a_brake`` the guard's ``brake_deceleration`` (at most ``mu * g``; with none
  configured, ``mu * g``). No ``v / max_deceleration`` ramp slack: the guard's stop bypasses
  the limiter's ramp. A straight approach's stopping distance from the line is
  ``v * t_react + v^2 / (2 a_brake) + STOP_MARGIN_M`` (:meth:`Bounds.stop_distance`).

and the guard's promise: at rest, a static obstacle is no nearer than ``stop_distance`` less
``STOP_MARGIN_M``.

For the other causes a stop *time* from the trigger to rest,
``t_detect + lag + v / a_brake + sched`` (sched: ``guard.scheduling_allowance``):

=====================  ==================================================  ==================
cause                  t_detect                                            trigger
=====================  ==================================================  ==================
sonar_unplugged        sonar_timeout + 2 sonar periods + echo timeout       the unplug
                       + 1 actuator (and the robot must STAY at rest)
laser_unplugged        laser_timeout + 2 lrf periods + 1 actuator (stays)   the unplug
bridge_killed          cmd_vel_timeout + 2 actuator; then the speed ramp    the kill
                       (``v / linear.max_deceleration`` replaces
                       ``v / a_brake``: the timeout zeroes the target)
driver_host_killed     heartbeat_hold_s, then the wheels coast on friction  the kill
                       (``v / world.robot.coast_decel_mps2`` replaces
                       ``v / a_brake``)
=====================  ==================================================  ==================

The "2 periods" of both unplug rows are the device task's pipeline (:func:`_pipeline`): a
reading the handler received just after a cycle's REQUEST answers the next REQUEST and reaches
the guard in the cycle after that, so the last reading before the unplug refreshes the sensor's
receive stamp up to two periods after it (the same two periods as ``t_react`` above).

Every scenario: the peak ground-truth deceleration must be physically possible, ``<= mu * g``
of the world's robot (:func:`traction_limit`).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any, Mapping

from m4k_drivers.sonar.protocol import ECHO_TIMEOUT_S
from m4k_drivers.world import REST_V  # m/s: at rest on ground truth

__all__ = ['Bounds', 'G', 'MEMORY_BIAS_M', 'REST_V', 'SAMPLE_S', 'STOP_MARGIN_M', 'bounds',
           'breakaway_speed', 'guard_params', 'judge_reaction', 'sched', 'stop_line',
           'traction_limit']

SAMPLE_S = 0.02      # the runner samples the simulator's truth every 20 ms
G = 9.80665          # m/s^2, standard gravity
# The judge's own tolerance on a guard stop: the interpolation of the 20 ms samples at the
# crossing (linear in travelled) and the 1 ms simulation step. Far below the 0.1 m a weakened
# guard loses (the negative control), so a guard acting 10 cm late fails.
STOP_MARGIN_M = 0.02
# The obstacle memory keeps the nearest reading of a noisy sensor, so the guard's release band
# on ground truth sits lower by about three of its noise sd (the simulated US-100: 3 mm): a
# stop this much beyond the band is the guard's own line (person_0_5 stood 5 mm beyond it).
MEMORY_BIAS_M = 0.01
# Rubber tyres on a hard floor: mu about 0.5-0.7 (issue 28). Used only when the world's robot
# states no friction coefficient of its own (then its traction limit is the upper end, 0.7 g).
DEFAULT_MU = 0.7
# The wheels stay at rest after an unplug stop: at most this far on ground truth.
STAY_M = 0.01
UNPLUG_CAUSES = ('sonar_unplugged', 'laser_unplugged')


@dataclass(frozen=True)
class Bounds:
    """What one scenario is held to."""

    distance_tol: float           # m
    stop_s: float | None          # s from trigger to rest (the non-guard causes)
    t_react: float | None         # s, guard stops: sensor + actuator latency
    a_brake: float                # m/s^2 the stop may assume
    max_decel: float              # m/s^2: mu * g of the world's robot
    stays_stopped: bool = False   # the unplug causes: at rest until the end of the run
    breakaway_speed: float = math.inf   # m/s at the rim: the break-away cap's (below)

    def stop_distance(self, v: float) -> float | None:
        """Return the stopping distance from the stop line at ``v`` on a straight approach.

        ``v t_react + v^2 / (2 a_brake) + STOP_MARGIN_M`` (guard stops; None for the
        others): what the reaction bench holds a hard approach to.
        """
        if self.t_react is None:
            return None
        return abs(v) * self.t_react + v * v / (2.0 * self.a_brake) + STOP_MARGIN_M

    def reach(self, v: float) -> float:
        """Return how far past the stop line at speed ``v`` the robot may get (guard stops).

        ``v t_react + STOP_MARGIN_M``: the guard sees the line crossed ``t_react`` late;
        from then on it brakes, and the line falls faster than the gap.
        """
        return abs(v) * (self.t_react or 0.0) + STOP_MARGIN_M


def _period(raw: Mapping[str, Any], task: str) -> float:
    return float(raw['tasks'][task]['period_ms']) / 1000.0


def _robot(raw: Mapping[str, Any]) -> Any:
    """Return the world's robot as the simulator builds it (m4k_drivers.world)."""
    from m4k_drivers.world import RobotParams, WorldConfig
    robot = RobotParams.from_control(dict(raw.get('control') or {}),
                                     (raw.get('robot') or {}).get('body'))
    return WorldConfig.from_dict(dict(raw.get('world') or {}), robot=robot).robot


def traction_limit(raw: Mapping[str, Any]) -> float:
    """Return ``mu * g`` (m/s^2) of the world's robot: the most any braking can give."""
    robot = _robot(raw)
    mu = next((float(getattr(robot, k)) for k in ('mu', 'traction_mu', 'tyre_mu', 'friction_mu')
               if getattr(robot, k, None) is not None), DEFAULT_MU)
    return mu * G


def guard_params(raw: Mapping[str, Any]) -> Any:
    """Return the ``control.guard`` settings of a layered configuration."""
    from m4k_rt.control.params import control_params
    return control_params(raw.get('control')).guard


def _lag(raw: Mapping[str, Any]) -> float:
    """Return the hops and the amplifier's response after the actuator's cycle (s).

    The amplifier's is the shipped declaration's (:func:`judge_reaction`), not an overlay's.
    """
    from m4k_rt.control.params import control_params
    return float(guard_params(raw).pipeline_latency) + float(
        control_params({}).guard.amplifier_lag)


def sched(raw: Mapping[str, Any]) -> float:
    """Return the scheduling allowance (s): the guard's own ``guard.scheduling_allowance``."""
    return float(guard_params(raw).scheduling_allowance)


def judge_reaction(raw: Mapping[str, Any], sensor: str, timeouts: bool = False) -> float:
    """Return the t_react the judge holds a stop ``sensor`` sees to (s).

    The guard's derivation (:func:`m4k_rt.control.reaction.reaction`: sensor part + RT part +
    actuation part) on the configured periods, with the actuation part of the shipped
    declaration of ``guard.amplifier_lag`` -- independent of what ``calibrate`` wrote.
    ``timeouts``: the guard's stop zone (its sensor part covers the sensors' timeouts); False:
    the delay of the sensor that saw the obstacle, reporting on time (a stop's own bound).
    """
    from m4k_rt.control.params import control_params
    from m4k_rt.control.reaction import reaction
    return reaction(guard_params(raw), sensor,
                    _period(raw, 'lrf' if sensor == 'laser' else 'sonar'),
                    _period(raw, 'actuator'),
                    actuation=control_params({}).guard.amplifier_lag, timeouts=timeouts).total


def _pipeline(raw: Mapping[str, Any], task: str) -> float:
    """Return how long after its handler received a reading the device task hands it on (s).

    Two periods at worst: each cycle drains the reply to the previous cycle's REQUEST, and the
    handler answers a REQUEST with the newest reading it holds -- one received just after a
    REQUEST waits for the next one, and its reply for the cycle after that.
    """
    return 2 * _period(raw, task)


def _guard_decel(raw: Mapping[str, Any]) -> float | None:
    """Return ``guard.brake_deceleration``: what the guard's stop assumes the drive gives."""
    a = getattr(guard_params(raw), 'brake_deceleration', None)
    return None if a is None else float(a)


def stop_line(raw: Mapping[str, Any], v: float) -> float:
    """Return the guard's stopping distance ahead of the front face at speed ``v``.

    The speed-aware stop zone ``d(v) = v t_react + v^2 / (2 a_brake) + stop_distance``
    restated from the specification -- never read from the guard: ``t_react`` from
    :func:`judge_reaction` for the slowest front sensor in use (the laser, else the sonar).
    A configuration without ``brake_deceleration`` (the fixed-distance guard):
    ``stop_distance``.
    """
    g = guard_params(raw)
    a = _guard_decel(raw)
    if a is None or v <= 0.0:
        return g.stop_distance
    t = judge_reaction(raw, 'laser' if g.use_laser else 'sonar', timeouts=True) if (
        g.use_laser or g.use_sonar) else 0.0
    return abs(v) * t + v * v / (2.0 * a) + g.stop_distance


TURN_WANDER = 0.01   # m: the centre of a robot turning in place wanders by the wheels' slip and
#                     unequal lags (a turn started and stopped at 1.5 rad/s: a few mm)


def bounds(raw: Mapping[str, Any], v: float, cause: str | None,
           turning: bool = False) -> Bounds:
    """Return the bounds for forward speed ``v`` and stop ``cause`` from the layered config.

    ``turning``: a command turns (w != 0): the distance tolerance is at least ``TURN_WANDER``.
    """
    from m4k_rt.control.params import control_params
    p = control_params(raw.get('control'))
    accel = p.linear.max_acceleration
    decel = p.linear.max_deceleration or accel
    tol = v * v / (2.0 * min(accel, decel))
    if turning and tol < TURN_WANDER:
        tol = TURN_WANDER
    ta = _period(raw, 'actuator')
    mu_g = traction_limit(raw)
    a_brake = min(_guard_decel(raw) or mu_g, mu_g)
    brake = v / a_brake
    g = p.guard
    t_react: float | None = None
    stop: float | None = None
    lag = _lag(raw)
    if cause in ('sonar', 'laser'):
        t_react = judge_reaction(raw, cause)
    elif cause == 'sonar_unplugged':
        stop = g.sonar_timeout + _pipeline(raw, 'sonar') + ECHO_TIMEOUT_S + ta + lag + brake
    elif cause == 'laser_unplugged':
        stop = g.laser_timeout + _pipeline(raw, 'lrf') + ta + lag + brake
    elif cause == 'bridge_killed':
        # the command timeout zeroes the *target*: the speed limiter ramps it down at
        # linear.max_deceleration (m4k_rt.control.base, step 2) -- not the guard's hard stop
        stop = p.cmd_vel_timeout + 2 * ta + lag + v / min(decel, a_brake)
    elif cause == 'driver_host_killed':
        motor = (raw.get('devices') or {}).get('motor') or {}
        coast = float(_robot(raw).coast_decel_mps2)
        hold = float(motor.get('heartbeat_hold_s', 0.05)) if motor.get('heartbeat', True) \
            else math.inf
        stop = hold + v / coast
    if stop is not None:
        stop += sched(raw)
    return Bounds(tol, stop, t_react, a_brake, mu_g, cause in UNPLUG_CAUSES,
                  breakaway_speed(p))


def breakaway_speed(p: Any) -> float:
    """Return the rim speed (m/s) the wheel PI's break-away cap drives a wheel to.

    A wheel that reads still while its setpoint is not zero -- a frozen encoder, a blocked
    wheel -- gets the break-away boost up to ``pi.breakaway_effort`` (normalized); on a free
    wheel that effort settles at ``breakaway_effort x full_scale_wheel_speed`` (the DAC's
    full-scale speed: the feed-forward's own scale) times the wheel radius. The supervision
    judges such a wheel by that effort and must latch before the wheel gets there, so a creep
    scenario's faulty wheel stays below it: 0.30 m/s with the shipped settings, where the
    fault used to run the wheel to full scale (2.0 m/s).
    """
    return p.pi.breakaway_effort * p.full_scale_wheel_speed * p.wheel_radius
