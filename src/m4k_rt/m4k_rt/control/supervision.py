"""Wheel supervision at every setpoint, from zero to top speed: latched motor fault (pure).

Nothing else compares what a wheel does with what it was told: a wrong-sign, swapped or
frozen encoder with valid frames turns the speed PI into positive feedback, and the guard only
caps the commanded speed. A check that trusts the encoder under test cannot see that encoder
lie, so each symptom below is judged against something the encoder does not produce: the
setpoint, the drive effort (the PI output the DAC word carries), the other wheel, and the
IMU's gyro. Every actuator cycle, per wheel, the supervisor accumulates the time each symptom
has held without a break:

* **wrong way** (``|setpoint| > speed_threshold``): the measured speed is beyond
  ``min_speed`` and of the other sign (``wrong_way_time``);
* **frozen**: the encoder angle has not moved ``FROZEN_COUNTS`` counts (3: the simulated
  AS5045's +/-0.5 LSB noise never does) while the wheel is told to turn fast enough to move
  4 counts in ``frozen_time`` (0.04 rad/s at 0.15 s) and it should be turning: it was seen
  following this setpoint (a wheel that turned does not stop by itself: a magnet slipping
  mid-drive, a wheel blocked), or its effort ``|u| >= moving_effort`` (enough to break any
  plausible wheel away from rest: the PI winding up on a reading that never moved reaches it)
  or the other wheel follows the same way and the gyro shows less than half the turn the
  encoders describe (the still-reading wheel turns unseen: frozen from the start, below that
  effort) (``frozen_time``). A dead encoder, or a wheel that does not turn at all (blocked:
  its honest encoder only shows noise, and the body turns as the encoders say);
* **stall** (effort against speed): the PI output is saturated and the wheel turns at less
  than ``stall_ratio`` of its setpoint, or the effort's free-running speed ``|u| / kff``
  exceeds the measured speed in the effort's direction by ``effort_margin``: the amplifier
  is driving the wheel at its current limit and the encoder sees no result (``stall_time``);
* **swapped** (both wheels, while their setpoints differ by more than the threshold): each
  wheel's speed is closer to the other wheel's setpoint than to its own (``swap_time``);
* **still** (setpoint zero: outputs at the zero word, the drive brakes): the wheel turns
  faster than ``still_speed`` above a bound that starts at its speed when the setpoint went to
  zero and falls at ``still_deceleration`` (far below what back-EMF braking and friction
  give): a wheel driven while commanded still, or an encoder that reports motion the braking
  does not end (``still_time``);
* **yaw** (both wheels, whenever a fresh IMU sample is given): the wheels' yaw rate
  ``r (w_r - w_l) / track`` differs from the gyro's by more than ``yaw_tolerance`` plus
  ``yaw_ratio`` of the larger of the two (``yaw_time``). This one needs no setpoint at all:
  a frozen, flipped or swapped encoder makes the wheels describe a turn the body does not make
  (or miss one it makes), at any speed. The tolerance covers the myAHRS+ gyro's noise (sd
  0.0024 rad/s) and bias (sd 0.002 rad/s after its calibration), and the skew between the
  IMU and encoder samples (up to 20 ms at the 1.85 rad/s^2 angular limit: 0.04 rad/s); the
  ratio covers tyre slip and track-width error (a slipping wheel under a 25 % difference
  does not trip it).

A symptom that holds for its time latches the fault; a cycle without it resets its time.
Every symptom time is *encoder* time: it advances only over cycles that brought a new
ENCODERS sample, and a cycle without one neither adds nor resets it (under load the driver
host's datagrams arrive late and bunched; counting their repeats as time turned one reading
into a 0.1 s "wrong way" on healthy wheels). All times are at most 0.3 s (the schema bounds
them), so a fault latches within 0.3 s of sim time from the first cycle it is visible. The
latch holds until :meth:`reset` (an explicit request from the bridge); the controller
meanwhile brakes with the zero word, then drops the enable (a category-1 stop, control.base).

Cycles in which the wheels cannot be expected to follow (the amplifier disabled, the driver
holding the DACs safe, the e-stop contact open) are skipped by the caller, and the symptom
times restart.
"""

from __future__ import annotations

import math

from m4k_rt.control.params import SupervisionParams
from m4k_rt.protocol import FaultCause

__all__ = ['cause_text', 'COUNT', 'ENCODER_TRUST', 'FROZEN_COUNTS', 'WheelSupervisor']

COUNT = 2.0 * math.pi / 4096     # one count of the 12-bit AS5045, rad
FROZEN_COUNTS = 3                # less motion than this is "not moving" (noise: +/-1 count)

_LEFT_WRONG = int(FaultCause.LEFT_WRONG_WAY)
_RIGHT_WRONG = int(FaultCause.RIGHT_WRONG_WAY)
_LEFT_FROZEN = int(FaultCause.LEFT_FROZEN)
_RIGHT_FROZEN = int(FaultCause.RIGHT_FROZEN)
_LEFT_STALL = int(FaultCause.LEFT_STALL)
_RIGHT_STALL = int(FaultCause.RIGHT_STALL)
_SWAPPED = int(FaultCause.SWAPPED)
_LEFT_STILL = int(FaultCause.LEFT_STILL)
_RIGHT_STILL = int(FaultCause.RIGHT_STILL)
_YAW = int(FaultCause.YAW)
# Causes after which the encoders' "at rest" cannot be believed (control.base then brakes for
# the whole time bound before it drops the enable).
ENCODER_TRUST = (_LEFT_WRONG | _RIGHT_WRONG | _LEFT_FROZEN | _RIGHT_FROZEN | _SWAPPED
                 | _LEFT_STILL | _RIGHT_STILL | _YAW)

# symptom slots in WheelSupervisor._t, and the cause each latches
_WRONG, _FROZEN, _STALL, _STILL = 0, 2, 4, 6     # + 0 left, + 1 right
_SWAP, _YAWS = 8, 9
_N = 10
_CAUSES = ((_LEFT_WRONG, _RIGHT_WRONG), (_LEFT_FROZEN, _RIGHT_FROZEN),
           (_LEFT_STALL, _RIGHT_STALL), (_LEFT_STILL, _RIGHT_STILL))


class WheelSupervisor:
    """Symptom timers per wheel and the latched fault (cause bits).

    ``params`` is the one declaration of the settings (:class:`SupervisionParams`);
    ``wheel_radius``/``track_width`` turn wheel speeds into a yaw rate, ``feed_forward`` (1 /
    full-scale wheel speed) turns the PI output into the speed it would drive a free wheel at.
    """

    __slots__ = ('p', 'enabled', 'cause', 'faults', 'last_cause', '_r_over_track', '_kff',
                 '_times', '_t', '_angle', '_ref', '_fresh', '_bound', '_following', '_sp',
                 '_frozen_min')

    def __init__(self, params: SupervisionParams, wheel_radius: float, track_width: float,
                 feed_forward: float) -> None:
        self.p = params
        self.enabled = bool(params.enabled)
        self._r_over_track = float(wheel_radius) / float(track_width)
        self._kff = float(feed_forward)
        eps = 1e-9          # a time reached within float error counts
        self._times = [params.wrong_way_time - eps] * 2 + [params.frozen_time - eps] * 2 + \
            [params.stall_time - eps] * 2 + [params.still_time - eps] * 2 + \
            [params.swap_time - eps, params.yaw_time - eps]
        self.cause = 0            # FaultCause bits of the latched fault; 0: none latched
        self.last_cause = 0       # the cause of the last fault (kept after a reset)
        self.faults = 0
        self._t = [0.0] * _N      # symptom times [s]
        self._angle = [0.0, 0.0]       # the newest sample's angles
        self._ref = [math.nan, math.nan]   # frozen: the angle the wheel last moved away from
        self._fresh = False        # a sample arrived since the last step
        self._bound = [-1.0, -1.0]     # still: the falling speed bound; < 0: not commanded still
        self._following = [False, False]   # the wheel was seen following its setpoint
        self._sp = [0.0, 0.0]          # the last setpoints (a sign change restarts following)
        # the least setpoint that moves a healthy wheel 4 counts within frozen_time
        self._frozen_min = 4.0 * COUNT / params.frozen_time

    @property
    def latched(self) -> bool:
        """Return True while a motor fault is latched."""
        return self.cause != 0

    def encoders(self, left_angle: float, right_angle: float) -> None:
        """Note one valid ENCODERS sample (did either angle change since the last?)."""
        self._fresh = True
        self._angle[0] = left_angle
        self._angle[1] = right_angle

    def idle(self) -> None:
        """Restart every symptom time (a cycle in which the wheels are not expected to follow)."""
        t = self._t
        for i in range(_N):
            t[i] = 0.0
        self._fresh = False
        for k in (0, 1):
            self._ref[k] = math.nan
            self._bound[k] = -1.0
            self._following[k] = False
            self._sp[k] = 0.0

    def step(self, dt: float, sp_left: float, sp_right: float, meas_left: float,
             meas_right: float, u_left: float, u_right: float, saturated_left: bool,
             saturated_right: bool, yaw_rate: float = math.nan) -> bool:
        """Advance one cycle; return True when a fault latched in this cycle.

        ``sp_*`` are the wheel setpoints the outputs were computed for (rad/s), ``meas_*`` the
        measured wheel speeds, ``u_*`` the PI outputs (normalized -1..1, 0 at a zero setpoint),
        ``saturated_*`` whether that output was at its limit, ``yaw_rate`` the body's yaw rate
        from a fresh gyro sample (rad/s, about base_link z), NaN when there is none.
        """
        if not self.enabled or self.cause:
            self._fresh = False
            return False
        if not self._fresh:
            # no new sample: nothing measured this cycle; every symptom time stands still
            return False
        p = self.p
        t = self._t
        th = p.speed_threshold
        ms = p.min_speed
        kff = self._kff
        # The gyro against the turn the encoders describe: a wheel that reads still while the
        # other turns the same way describes a turn; if the body does not make half of it,
        # the still wheel turns unseen (frozen from the start, below moving_effort).
        w_enc = self._r_over_track * (meas_right - meas_left)
        unseen_turn = (p.use_imu and yaw_rate == yaw_rate and sp_left * sp_right > 0.0
                       and yaw_rate * w_enc < 0.5 * w_enc * w_enc)
        for k in (0, 1):
            sp = sp_left if k == 0 else sp_right
            m = meas_left if k == 0 else meas_right
            u = u_left if k == 0 else u_right
            sat = saturated_left if k == 0 else saturated_right
            asp = abs(sp)
            if asp > th and ((m > ms and sp < 0.0) or (m < -ms and sp > 0.0)):
                t[_WRONG + k] += dt
            else:
                t[_WRONG + k] = 0.0
            if sp * self._sp[k] <= 0.0:
                self._following[k] = False      # a new setpoint direction (or zero)
            self._sp[k] = sp
            a = self._angle[k]
            ref = self._ref[k]
            if not abs(a - ref) < FROZEN_COUNTS * COUNT:     # moved (or no reference yet)
                if (a - ref) * sp > 0.0:
                    self._following[k] = True   # seen turning the way it is told
                self._ref[k] = a
                t[_FROZEN + k] = 0.0
            elif asp >= self._frozen_min and (self._following[k]
                                             or abs(u) >= p.moving_effort
                                             or (unseen_turn and self._following[1 - k])):
                t[_FROZEN + k] += dt
            else:
                t[_FROZEN + k] = 0.0
            # the speed the effort would drive a free wheel at, against the speed measured in
            # the effort's direction
            excess = abs(u) / kff - (m if u >= 0.0 else -m)
            if ((sat and asp > th and abs(m) < p.stall_ratio * asp)
                    or (u != 0.0 and excess > p.effort_margin)):
                t[_STALL + k] += dt
            else:
                t[_STALL + k] = 0.0
            if sp == 0.0:
                b = self._bound[k]
                b = abs(m) if b < 0.0 else max(b - p.still_deceleration * dt, 0.0)
                self._bound[k] = b
                if abs(m) > b + p.still_speed:
                    t[_STILL + k] += dt
                else:
                    t[_STILL + k] = 0.0
            else:
                self._bound[k] = -1.0
                t[_STILL + k] = 0.0
        self._fresh = False
        diff = sp_left - sp_right
        if (diff > th or diff < -th) and (abs(sp_left) > th or abs(sp_right) > th):
            own = abs(meas_left - sp_left) + abs(meas_right - sp_right)
            other = abs(meas_left - sp_right) + abs(meas_right - sp_left)
            t[_SWAP] = t[_SWAP] + dt if own - other > th else 0.0
        else:
            t[_SWAP] = 0.0
        if p.use_imu and yaw_rate == yaw_rate:          # not NaN: a fresh gyro sample
            w_wheels = self._r_over_track * (meas_right - meas_left)
            bound = p.yaw_tolerance + p.yaw_ratio * max(abs(w_wheels), abs(yaw_rate))
            t[_YAWS] = t[_YAWS] + dt if abs(w_wheels - yaw_rate) > bound else 0.0
        cause = 0
        times = self._times
        for i in range(8):
            if t[i] >= times[i]:
                cause |= _CAUSES[i >> 1][i & 1]
        if t[_SWAP] >= times[_SWAP]:
            cause |= _SWAPPED
        if t[_YAWS] >= times[_YAWS]:
            cause |= _YAW
        if cause:
            self.cause = cause
            self.last_cause = cause
            self.faults += 1
            return True
        return False

    def reset(self) -> bool:
        """Clear the latched fault (an explicit request); return whether one was latched."""
        was = self.cause != 0
        self.cause = 0
        self.idle()
        return was


def cause_text(cause: int) -> str:
    """Return the cause bits as words (NRT use: diagnostics), e.g. 'left wrong way'."""
    names = []
    for bit, text in ((_LEFT_WRONG, 'left wheel turns against its setpoint'),
                      (_RIGHT_WRONG, 'right wheel turns against its setpoint'),
                      (_LEFT_FROZEN, 'left encoder frozen or wheel not turning'),
                      (_RIGHT_FROZEN, 'right encoder frozen or wheel not turning'),
                      (_LEFT_STALL, 'left wheel does not follow its drive effort (stalled)'),
                      (_RIGHT_STALL, 'right wheel does not follow its drive effort (stalled)'),
                      (_SWAPPED, 'wheels answer each other (swapped channels)'),
                      (_LEFT_STILL, 'left wheel turns while commanded still'),
                      (_RIGHT_STILL, 'right wheel turns while commanded still'),
                      (_YAW, "the wheels' turn rate disagrees with the IMU gyro")):
        if cause & bit:
            names.append(text)
    return '; '.join(names) if names else 'none'
