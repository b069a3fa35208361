"""Identification arithmetic for ``calibrate`` (pure: numbers in, numbers out, no I/O).

The motor model identified is the one the RT controller assumes (``m4k_rt.control``), plus
what it does not model:

* steady state, per wheel and direction: ``speed = k * (x - c)`` for WHEEL_CMD code
  ``512 + x`` beyond the dead band, 0 inside it.  ``c`` is where the speed line crosses zero
  (forward ``c_fwd > c_back``); their midpoint is the amplifier's zero error, in command codes,
  which the DAC zero trim cancels; half their distance is the dead band;
  ``k * 511`` is ``full_scale_wheel_speed`` (the feed-forward slope: the speed code 1023
  would give without the dead band; the PI integrator covers the dead band);
* dynamics: a first-order lag ``tau`` from command to wheel speed.  It comes from the wheel
  *angle* (integrated, so little noise): after a step from a steady speed ``w1`` to ``w2`` at
  ``t0`` the angle approaches the line ``theta(t0) + w2 (t - t0) - (w2 - w1) tau``, so the
  gap at ``t0`` between the two plateaus' fitted lines is ``(w2 - w1) * tau``.  ``t0`` is when
  the host wrote the command, so the lag includes the command path's latency -- which the
  speed loop sees as well.  Exact for a first-order response (the gap is the area above it),
  i.e. for steps small enough to stay below the amplifier's current limit.  Which lag depends
  on the motion: ``calibrate``'s lag run steps the *mean* wheel angle on a straight run (the
  body's mass on the wheels: the lag the PI is tuned on); its sweep turns in place (only the
  yaw inertia: a faster lag, reported, not tuned on);
* braking: from a steady straight run, the command goes to zero (code 512, amplifier on).
  The mean wheel speed (angle differences) falls along a line while the amplifier's current
  limit brakes; the line fitted between 85 % and 40 % of the steady speed gives the
  deceleration (its slope times the radius) and, where it meets the steady speed, the
  moment braking began: the reaction time is that moment minus the host's write of the zero
  command (command path + amplifier + current rise);
* geometry: radius = measured distance / mean wheel angle of a straight run; track width =
  radius * (right - left wheel angle) / measured heading change of an in-place turn.

Suggested PI gains (``control.pi``) by lambda (IMC) tuning of the first-order plant
``K / (tau s + 1)`` with ``K = full_scale_wheel_speed`` (rad/s per unit command): the PI zero
cancels the motor pole (``ki / kp = 1 / tau``) and the closed loop is a first-order lag of
``lam`` seconds: ``kp = tau / (K lam)``, ``ki = 1 / (K lam)``.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Sequence

import numpy as np

from m4k_rt.control.dac import DAC_SPAN  # codes from zero to full scale

__all__ = ['Braking', 'FitError', 'Plateau', 'SpeedLine', 'WheelModel', 'braking', 'fit_line',
           'fit_plateau',
           'new_trim', 'pi_gains', 'radius_from_run', 'speed_line', 'tau_from_plateaus',
           'track_from_turn', 'wheel_model']


class FitError(ValueError):
    """Raise when the data cannot give the quantity asked for; the message says why."""


def fit_line(t: Sequence[float], y: Sequence[float]) -> tuple[float, float]:
    """Return (slope, intercept) of the least-squares line y = slope * t + intercept."""
    if len(t) != len(y) or len(t) < 2:
        raise FitError(f'a line needs at least 2 points, got {len(t)}')
    ta, ya = np.asarray(t, dtype=float), np.asarray(y, dtype=float)
    tm = ta.mean()
    den = float(((ta - tm) ** 2).sum())
    if den == 0.0:
        raise FitError('a line needs points at different times')
    slope = float(((ta - tm) * (ya - ya.mean())).sum()) / den
    return slope, float(ya.mean()) - slope * float(tm)


@dataclass(frozen=True)
class Plateau:
    """One constant-command stretch of one wheel: its code offset and its steady angle line."""

    x: int                   # WHEEL_CMD code - 512 on this wheel
    t0: float                # s, when the command was written
    speed: float             # rad/s, slope of the fitted angle line
    angle_at_t0: float       # rad, the fitted line evaluated at t0

    def angle(self, t: float) -> float:
        """Return the fitted steady line at ``t``."""
        return self.angle_at_t0 + self.speed * (t - self.t0)


def fit_plateau(x: int, t0: float, t: Sequence[float], angle: Sequence[float]) -> Plateau:
    """Fit the steady part (samples ``t``, ``angle``) of a plateau commanded at ``t0``."""
    slope, icpt = fit_line([ti - t0 for ti in t], angle)
    return Plateau(x, t0, slope, icpt)


def tau_from_plateaus(plateaus: Sequence[Plateau], min_step: float) -> float:
    """Return the median lag (s) over consecutive plateaus whose speeds differ >= min_step."""
    taus = []
    for a, b in zip(plateaus[:-1], plateaus[1:], strict=True):
        dw = b.speed - a.speed
        if abs(dw) >= min_step:
            taus.append((a.angle(b.t0) - b.angle_at_t0) / dw)
    if not taus:
        raise FitError(f'no speed step of at least {min_step:.3g} rad/s to time the motor lag')
    return float(np.median(taus))


@dataclass(frozen=True)
class SpeedLine:
    """speed = k * (x - c) for one wheel and direction."""

    k: float                 # rad/s per code
    c: float                 # codes: where the line crosses zero speed
    points: int


def speed_line(points: Sequence[tuple[int, float]], direction: int,
               min_speed: float) -> SpeedLine:
    """Fit the steady (code offset, speed) points of one direction (+1/-1) beyond the dead band.

    Points with ``direction * x <= 0`` or a speed below ``min_speed`` (inside or at the edge of
    the dead band, where static friction is not linear) are left out.
    """
    use = [(x, w) for x, w in points if direction * x > 0 and direction * w >= min_speed]
    if len(use) < 2:
        raise FitError(f'{"forward" if direction > 0 else "backward"}: {len(use)} level(s) '
                       f'above {min_speed:.3g} rad/s, need 2 (raise the sweep speed)')
    k, icpt = fit_line([float(x) for x, _ in use], [w for _, w in use])
    if not k > 0:
        raise FitError(f'{"forward" if direction > 0 else "backward"}: speed does not grow '
                       f'with the command (slope {k:.4g} rad/s per code)')
    return SpeedLine(k, -icpt / k, len(use))


@dataclass(frozen=True)
class WheelModel:
    """One wheel's identified steady-state model (codes are WHEEL_CMD codes - 512)."""

    forward: SpeedLine
    backward: SpeedLine

    @property
    def zero_offset(self) -> float:
        """Return the command code offset (from 512) at which the amplifier sees zero."""
        return 0.5 * (self.forward.c + self.backward.c)

    @property
    def deadband_codes(self) -> float:
        """Return the half width of the dead band in codes."""
        return 0.5 * (self.forward.c - self.backward.c)

    @property
    def full_scale(self) -> float:
        """Return the speed line's slope times 511 (rad/s per unit of command)."""
        return 0.5 * (self.forward.k + self.backward.k) * DAC_SPAN


def wheel_model(points: Sequence[tuple[int, float]], min_speed: float) -> WheelModel:
    """Fit both directions of one wheel."""
    model = WheelModel(speed_line(points, 1, min_speed), speed_line(points, -1, min_speed))
    if model.deadband_codes < -1.0:
        raise FitError(f'the forward and backward speed lines cross zero in the wrong order '
                       f'({model.forward.c:.1f} < {model.backward.c:.1f} codes)')
    return model


def new_trim(zero_offset: float, sign: int, trim: int) -> float:
    """Return the DAC zero trim (codes, unrounded) that puts the amplifier's zero at 512.

    A WHEEL_CMD code ``512 + x`` is written as ``512 + trim + sign * x``; the amplifier's zero
    is at command offset ``zero_offset``, so at written offset ``trim + sign * zero_offset``.
    """
    return trim + sign * zero_offset


def radius_from_run(distance_m: float, left_rad: float, right_rad: float) -> float:
    """Return the wheel radius from a straight run's measured distance and wheel angles."""
    mean = 0.5 * (left_rad + right_rad)
    if not distance_m > 0 or not mean > 0:
        raise FitError(f'straight run: need a positive distance and forward wheel travel, '
                       f'got {distance_m!r} m over {mean:.4g} rad')
    return distance_m / mean


def track_from_turn(radius_m: float, left_rad: float, right_rad: float,
                    heading_rad: float) -> float:
    """Return the track width from an in-place turn (heading positive counter-clockwise)."""
    diff = right_rad - left_rad
    if heading_rad == 0.0 or diff * heading_rad <= 0:
        raise FitError(f'turn: wheel angle difference {diff:+.4g} rad and measured heading '
                       f'{math.degrees(heading_rad):+.1f} deg disagree in sign')
    return radius_m * diff / heading_rad


def pi_gains(full_scale: float, tau_s: float, lam_s: float) -> tuple[float, float]:
    """Return (kp, ki) placing the closed wheel-speed loop at a lag of ``lam_s``."""
    if not (full_scale > 0 and tau_s > 0 and lam_s > 0):
        raise FitError(f'PI tuning needs positive gain, lag and target, got '
                       f'{full_scale!r}, {tau_s!r}, {lam_s!r}')
    return tau_s / (full_scale * lam_s), 1.0 / (full_scale * lam_s)


@dataclass(frozen=True)
class Braking:
    """A braking run's result: deceleration, reaction time, the speed it braked from."""

    decel_mps2: float
    reaction_s: float
    speed_mps: float
    points: int


def braking(t_zero: float, before: Sequence[tuple[float, float]],
            after: Sequence[tuple[float, float]], radius_m: float,
            lo: float = 0.40, hi: float = 0.85) -> Braking:
    """Fit a braking run: (t, mean wheel angle) ``before`` and ``after`` the zero at ``t_zero``.

    ``before``: the steady run (its last half gives the steady speed); ``after``: from the zero
    command on. Speeds are angle differences over two samples, fitted as a line where they are
    between ``lo`` and ``hi`` of the steady speed.
    """
    half = list(before[len(before) // 2:])
    if len(half) < 2:
        raise FitError('braking: too few samples of the steady run before the stop')
    w1, _ = fit_line([t for t, _ in half], [a for _, a in half])
    if abs(w1) < 1e-3:
        raise FitError('braking: the wheels were not moving before the stop')
    sign = 1.0 if w1 > 0 else -1.0
    pts = list(before[-2:]) + list(after)
    ts, ws = [], []
    for (ta, aa), (tb, ab) in zip(pts[:-2], pts[2:], strict=True):
        if tb > ta:
            ts.append(0.5 * (ta + tb))
            ws.append(sign * (ab - aa) / (tb - ta))
    speed = abs(w1)
    use = [(t, w) for t, w in zip(ts, ws, strict=True)
           if t > t_zero and lo * speed <= w <= hi * speed]
    if len(use) < 3:
        raise FitError(f'braking: {len(use)} speed sample(s) between {lo:.0%} and {hi:.0%} of '
                       f'the steady speed, need 3 (brake from a higher speed)')
    slope, icpt = fit_line([t for t, _ in use], [w for _, w in use])
    if not slope < 0:
        raise FitError(f'braking: the speed does not fall after the stop (slope {slope:.4g})')
    t_brake = (speed - icpt) / slope
    return Braking(-slope * radius_m, t_brake - t_zero, speed * radius_m, len(use))
