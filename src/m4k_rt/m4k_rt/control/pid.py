"""Wheel-speed PI controller with feed-forward and anti-windup (pure).

Output is a normalized motor command in [-limit, limit] (``dac.command_to_code`` turns it into
a DAC code). The feed-forward term ``kff * setpoint`` does most of the work (``kff`` is the
inverse of the wheel speed that full-scale command produces); the PI part corrects for load,
friction and model error.

Anti-windup, selectable:

* ``'clamping'`` (conditional integration): the integrator does not move while the output is
  saturated and the error pushes further into saturation.
* ``'back_calculation'``: the integrator is driven back by ``kt * (u_sat - u)`` so that it
  tracks the saturated output; ``kt`` defaults to ``ki / kp`` (tracking time = Ti).

Integral separation on braking (``band``, rad/s): while the wheel turns faster than its
setpoint by more than ``band`` (``|measured| > |setpoint|``), the integrator does not move.
Saturation is not the only windup: braking from 1 m/s to a stop after a guard trip (or a
release) stays inside the output range, and integrating that transient's large error left
the integrator holding a reverse command that backed the robot up once the wheels reached
the setpoint. An underspeed error (a load, a stalled wheel) is integrated as before -- the
stall supervision relies on the output saturating against it.
"""

from __future__ import annotations

import math

ANTI_WINDUP_MODES = ('clamping', 'back_calculation')


class PidError(ValueError):
    """Raised for invalid controller parameters."""


class WheelSpeedPI:
    """PI speed controller with feed-forward, output saturation and anti-windup."""

    __slots__ = ('kp', 'ki', 'kff', 'kt', 'limit', 'anti_windup', 'integral', 'saturated',
                 'band', '_back_calc', 'breakaway_rate', 'breakaway_effort',
                 'breakaway_still')

    def __init__(self, kp: float, ki: float, kff: float = 0.0, *, limit: float = 1.0,
                 anti_windup: str = 'clamping', kt: float | None = None,
                 band: float = math.inf, breakaway_rate: float = 0.0,
                 breakaway_effort: float = 0.0, breakaway_still: float = 0.0) -> None:
        for name, value in (('kp', kp), ('ki', ki), ('kff', kff)):
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0.0:
                raise PidError(f'{name} must be a finite number >= 0, got {value!r}')
        if not isinstance(limit, (int, float)) or not math.isfinite(limit) or limit <= 0.0:
            raise PidError(f'limit must be a finite number > 0, got {limit!r}')
        if anti_windup not in ANTI_WINDUP_MODES:
            raise PidError(f'anti_windup must be one of {ANTI_WINDUP_MODES}, got {anti_windup!r}')
        if kt is None:
            kt = ki / kp if kp > 0.0 else 0.0
        if not isinstance(kt, (int, float)) or not math.isfinite(kt) or kt < 0.0:
            raise PidError(f'kt must be a finite number >= 0, got {kt!r}')
        if isinstance(band, bool) or not isinstance(band, (int, float)) or math.isnan(band) \
                or band <= 0.0:
            raise PidError(f'band must be a number > 0 (inf: always integrate), got {band!r}')
        self.kp = float(kp)
        self.ki = float(ki)
        self.kff = float(kff)
        self.kt = float(kt)
        self.limit = float(limit)
        self.anti_windup = anti_windup
        self.band = float(band)
        self._back_calc = anti_windup == 'back_calculation'
        for name, value in (('breakaway_rate', breakaway_rate),
                            ('breakaway_effort', breakaway_effort),
                            ('breakaway_still', breakaway_still)):
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0.0:
                raise PidError(f'{name} must be a finite number >= 0, got {value!r}')
        self.breakaway_rate = float(breakaway_rate)
        self.breakaway_effort = float(breakaway_effort)
        self.breakaway_still = float(breakaway_still)   # a measured speed that is noise
        self.integral = 0.0
        self.saturated = False

    def reset(self) -> None:
        """Clear the integrator."""
        self.integral = 0.0
        self.saturated = False

    def update(self, setpoint: float, measured: float, dt: float,
               starting: bool = False) -> float:
        """Return the saturated command for one control period of ``dt`` seconds.

        ``starting``: the wheel has not yet been seen turning its setpoint's way (break-away).
        """
        error = setpoint - measured
        base = self.kff * setpoint + self.kp * error
        integral = self.integral
        if (-self.band <= error <= self.band) or abs(measured) <= abs(setpoint):
            integral += self.ki * error * dt
        s = 1.0 if setpoint > 0.0 else -1.0
        if starting and self.breakaway_rate > 0.0 and setpoint != 0.0 \
                and -self.breakaway_still <= measured <= self.breakaway_still:
            # only while it reads no motion beyond a count of noise: motion its setpoint's way
            # pauses the boost (the 3 counts that end it lag the wheel); motion the other way
            # is a reversal (the plain PI has error enough) or an encoder counting against
            # the effort (a sign flip, swapped channels: more effort only runs it away)
            boosted = self.integral + s * self.breakaway_rate * dt
            cap = s * self.breakaway_effort - base        # the integral at the capped output
            if s > 0.0:
                integral = max(integral, min(boosted, cap))
            else:
                integral = min(integral, max(boosted, cap))
        u = base + integral
        lim = self.limit
        if u > lim:
            u_sat = lim
        elif u < -lim:
            u_sat = -lim
        else:
            u_sat = u
        self.saturated = u_sat != u
        if (u_sat < 0.0 < setpoint and measured <= 0.0) or \
                (u_sat > 0.0 > setpoint and measured >= 0.0):
            # Not turning the setpoint's way: never push against it (see the module notes).
            self.integral = -base
            self.saturated = False
            return 0.0
        if self.saturated:
            if self._back_calc:
                integral += self.kt * (u_sat - u) * dt
            elif error * u > 0.0:
                # Error drives further into saturation: freeze the integrator.
                integral = self.integral
        self.integral = integral
        return u_sat
