"""Wheel supervision at every setpoint, from zero to top speed: latched motor fault (pure).

Nothing else compares what a wheel does with what it was told: a wrong-sign, swapped or
frozen encoder with valid frames turns the speed PI into positive feedback, and the guard only
caps the commanded speed. A check that trusts the encoder under test cannot see that encoder
lie, so each symptom below is judged against something the encoder does not produce: the
setpoint, the drive effort (the PI output the DAC word carries), the other wheel, and the
IMU's gyro. Every actuator cycle, per wheel, the supervisor accumulates the time each symptom
has held without a break:

* **wrong way** (``|setpoint| > speed_threshold``): the measured speed is beyond
  ``min_speed`` and of the other sign (``wrong_way_time``), and, when the setpoint has just
  left zero or changed sign against the last nonzero setpoint while the wheel still rolled
  that old way (a reversal: a guard released mid-brake with a turn held hands the inner wheel
  a backward setpoint while it still rolls forward), beyond a
  bound that starts at the wheel's speed then and falls at ``still_deceleration`` -- the wheel
  braking toward the new direction is no fault, one that does not slow is;
* **frozen**: the encoder angle has not moved ``FROZEN_COUNTS`` counts (3: the simulated
  AS5045's +/-0.5 LSB noise never does) while the wheel is told to turn fast enough to move
  4 counts in ``frozen_time`` (0.04 rad/s at 0.15 s) and it should be turning: it was seen
  following this setpoint (a wheel that turned does not stop by itself: a magnet slipping
  mid-drive, a wheel blocked; motion within what a wheel already rolling that way when the
  setpoint took its direction rolls by itself, ``ROLL_PER_SPEED2``, is not following: it
  then stops where its effort is below the friction), or its effort ``|u| >= moving_effort``
  (enough to break any plausible wheel away from rest: the PI's break-away boost gets a
  wheel that has not moved there within ~0.1 s) (``frozen_time``); or it turns *unseen*:
  since it last moved (or its setpoint left zero), the other wheel's counts less the gyro's
  integrated turn, less its own counts over the same aligned window, put its own motion
  ``UNSEEN_COUNTS`` (6) counts its setpoint's way (frozen from the start: the body
  does not make the pivot the encoders describe; integrated, so quantization cannot reset
  it, and only over a start, so the gyro's bias cannot build up: a third of ``frozen_time``
  confirms it, and the controller then gives that wheel no more effort than the other's).
  A dead encoder, or a wheel that does not turn at all (blocked: its honest encoder only
  shows noise, and the body turns as the encoders say);
* **stall** (effort against speed): the PI output is saturated and the wheel turns at less
  than ``stall_ratio`` of its setpoint, or the effort's free-running speed ``|u| / kff``
  exceeds the measured speed in the effort's direction by ``effort_margin``: the amplifier
  is driving the wheel at its current limit and the encoder sees no result (``stall_time``);
  not while the wheel rolls beyond ``min_speed`` against the effort (it is being braked);
* **swapped** (both wheels, while their setpoints differ by more than the threshold): each
  wheel's speed is closer to the other wheel's setpoint than to its own (``swap_time``);
* **still** (setpoint zero: outputs at the zero word, the drive brakes): the wheel turns
  faster than ``still_speed`` above a bound that starts at its speed when the setpoint went to
  zero and falls at ``still_deceleration`` (far below what back-EMF braking and friction
  give): a wheel driven while commanded still, or an encoder that reports motion the braking
  does not end (``still_time``); a wheel the standstill hold holds (``control.hold``) is
  judged by where it is instead: turned more than ``standstill_window`` counts from where it
  first read still in its hold latches at once (a safe operating stop's position window),
  and so does, on a floor the IMU's orientation reads level along the track, a hold whose
  integral passes ``level_hold_effort`` (nothing on the level leans on a wheel standing
  still: the amplifier drives it);
* **yaw** (both wheels, whenever a fresh IMU sample is given): the wheels' yaw rate
  ``r (w_r - w_l) / track`` differs from the gyro's by more than ``yaw_tolerance`` plus
  ``yaw_ratio`` of the larger of the two (``yaw_time``). This one needs no setpoint at all:
  a frozen, flipped or swapped encoder makes the wheels describe a turn the body does not make
  (or miss one it makes), at any speed. The tolerance covers the myAHRS+ gyro's noise (sd
  0.0024 rad/s) and bias (sd 0.002 rad/s after its calibration), and the skew between the
  IMU and encoder samples (up to 20 ms at the 1.85 rad/s^2 angular limit: 0.04 rad/s); the
  ratio covers tyre slip and track-width error (a slipping wheel under a 25 % difference
  does not trip it).
  The same comparison integrated (``_yaw_window``): the heading the wheels describe over the
  last YAW_WINDOW (0.15 s) against the gyro's heading over the same span, both read at
  aligned instants (no skew), beyond YAW_COUNTS (8) counts of wheel angle as heading plus
  ``yaw_ratio`` of the turn, counts three times as fast (integrated evidence). Crossed
  channels in a creep turn differ from the gyro by twice the turn rate, about the per-cycle
  tolerance: that test alone took up to 0.37 s forward and 0.92 s backward on an
  uncalibrated base; the window takes 0.20-0.25 s.

**Aligned in time.** The unseen and counts-against tests compare the other wheel's counts with
the gyro's integrated turn, so both must be taken at one instant: the gyro reaches the RT side
one hop (an IMU task period, the driver host's I2C read) after the encoders, and under load
tens of ms later. Held and integrated per actuator cycle, a turn starting up (an arc from
rest: the inner wheel still below break-away while the outer one drives the body round at
1.85 rad/s^2) ran ahead in the encoders of a gyro 20 ms late by 13 counts of the still
wheel's "own" motion, and latched a healthy wheel frozen (arc_leg_outside_0_5 under load).
So the gyro is integrated over its samples' own acquisition stamps (:meth:`gyro`), the
encoders kept with theirs (:meth:`encoders`), and both tests read the two at the newest instant
both cover (``RING`` samples of each, linearly interpolated). A gap in the gyro longer than
``GYRO_GAP_S`` restarts the integration and every window on it.

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

from collections.abc import Sequence
import math

from m4k_rt.control.params import SupervisionParams
from m4k_rt.control.trace import SupervisionTrace
from m4k_rt.protocol import FaultCause, TraceFlag

__all__ = ['cause_text', 'COUNT', 'ENCODER_TRUST', 'FROZEN_COUNTS', 'RING', 'WheelSupervisor']

COUNT = 2.0 * math.pi / 4096     # one count of the 12-bit AS5045, rad
FROZEN_COUNTS = 3                # less motion than this is "not moving" (noise: +/-1 count)
# A still-reading wheel that the other wheel and the gyro show turning this many counts its
# setpoint's way turns unseen (gyro bias 0.005 rad/s over a 0.2 s start: 2.6 counts)
UNSEEN_COUNTS = 6
START_WINDOW = 0.3               # s after a setpoint leaves zero: the counts-against test
RING = 32                        # encoder and gyro samples kept to align the two (0.32 s)
# The integrated yaw test: the heading the wheels describe against the gyro's over this window,
# at aligned instants; tolerance YAW_COUNTS counts of wheel angle as heading (quantization at
# both ends, the gyro's bias over the window) plus yaw_ratio of the turn
YAW_WINDOW = 0.15
YAW_COUNTS = 8
_YAW_WINDOW_NS = int(YAW_WINDOW * 1e9)
GYRO_GAP_NS = 100_000_000        # a longer gap between gyro samples restarts the integration
# A wheel rolling at m rad/s with no drive stops within m^2 / (2 a) rad, a the deceleration of
# friction alone (3.6 rad/s^2 on the simulated base; 3.0 leaves margin)
ROLL_PER_SPEED2 = 1.0 / (2.0 * 3.0)

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
_SAT_L, _SAT_R = int(TraceFlag.SATURATED_LEFT), int(TraceFlag.SATURATED_RIGHT)
_HELD_L, _HELD_R = int(TraceFlag.HELD_LEFT), int(TraceFlag.HELD_RIGHT)
_T_GYRO, _T_LEVEL, _T_ENC = int(TraceFlag.GYRO), int(TraceFlag.LEVEL), int(TraceFlag.ENCODERS)
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
                 '_times', '_t', '_angle', '_ref', '_fresh', '_bound', '_rev', '_dir',
                 '_following', '_roll', '_roll_a', '_sp',
                 'frozen_min', 'unseen', '_et', '_el', '_er', '_en', '_gt', '_gp', '_gn',
                 '_g_rate', '_epoch', '_at', '_u_ref', '_s_ref', '_s_age', '_origin',
                 '_window', 'trace', '_yt', '_yl', '_yr', '_yh', '_y_epoch', '_yn', '_yaw_hit')

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
        # held (the standstill hold): the angle where the wheel first read still in its hold
        # (NaN: not held), and how far from it the wheel may turn (rad)
        self._origin = [math.nan, math.nan]
        self._window = params.standstill_window * COUNT
        self._rev = [0.0, 0.0]         # wrong way: a reversal's falling speed bound (0: none)
        self._dir = [0.0, 0.0]         # the sign of the last nonzero setpoint (0: none yet)
        self._following = [False, False]   # the wheel was seen following its setpoint
        # what is left of an earlier motion: when a setpoint takes its direction with the
        # wheel already rolling that way, the angle then and how far the wheel may still roll
        # by itself (rad; braked by friction alone): motion within it is no evidence that the
        # wheel follows the drive
        self._roll = [0.0, 0.0]
        self._roll_a = [0.0, 0.0]
        self._sp = [0.0, 0.0]          # the last setpoints (a sign change restarts following)
        # the least setpoint that moves a healthy wheel 4 counts within frozen_time
        self.frozen_min = 4.0 * COUNT / params.frozen_time
        # Unseen motion: the gyro's heading integrated over the gyro's own stamps, the
        # encoder angles kept with theirs (rings of RING samples), and the two read at one
        # instant ``_at`` (this wheel's angle, the other's, the heading; per wheel order
        # [left angle, right angle, heading]); ``_epoch`` counts restarts of the heading.
        self.unseen = [False, False]     # the wheel turns its setpoint's way, encoder still
        self._et = [0] * RING             # encoder stamps (ns)
        self._el = [0.0] * RING
        self._er = [0.0] * RING
        self._en = 0                      # encoder samples taken (ring index: _en % RING)
        self._gt = [0] * RING             # gyro stamps (ns), this epoch
        self._gp = [0.0] * RING           # the heading integrated up to that stamp (rad)
        self._gn = 0                      # gyro samples taken in this epoch
        self._g_rate = 0.0
        self._epoch = 0
        self._at: list[float] | None = None   # [left, right, heading] at the aligned instant
        # per wheel, the unseen window's start [epoch, other wheel's angle, heading, this
        # wheel's angle] and the start window's [epoch, this angle, other angle, heading]
        # (epoch -1: not taken yet)
        self._u_ref = [[-1.0, 0.0, 0.0, 0.0], [-1.0, 0.0, 0.0, 0.0]]
        self._s_ref = [[-1.0, 0.0, 0.0, 0.0], [-1.0, 0.0, 0.0, 0.0]]
        self._s_age = [0.0, 0.0]
        # every supervised cycle's inputs, frozen at a latch (m4k_rt.control.trace)
        self.trace = SupervisionTrace()
        # the aligned instants of the last RING cycles for the integrated yaw test: time (ns),
        # left and right angle, heading; ``_yn`` entries taken since a restart, all of them on
        # the gyro's heading epoch ``_y_epoch``
        self._yt = [0.0] * RING
        self._yl = [0.0] * RING
        self._yr = [0.0] * RING
        self._yh = [0.0] * RING
        self._y_epoch = -1.0
        self._yn = 0
        self._yaw_hit = False

    @property
    def latched(self) -> bool:
        """Return True while a motor fault is latched."""
        return self.cause != 0

    def encoders(self, left_angle: float, right_angle: float, stamp_ns: int) -> None:
        """Note one valid ENCODERS sample taken at ``stamp_ns`` (the driver's stamp)."""
        self._fresh = True
        self._angle[0] = left_angle
        self._angle[1] = right_angle
        if self._en and stamp_ns <= self._et[(self._en - 1) % RING]:
            return          # not newer (a repeat): the ring keeps time order
        i = self._en % RING
        self._et[i] = stamp_ns
        self._el[i] = left_angle
        self._er[i] = right_angle
        self._en += 1

    def gyro(self, yaw_rate: float, stamp_ns: int) -> None:
        """Note one gyro sample (rad/s about base_link z) taken at ``stamp_ns``.

        The heading is integrated sample to sample (trapezoid) on the samples' own stamps; a
        sample that is no newer than the last is the same one again and is ignored, a NaN or a
        gap over GYRO_GAP_NS restarts the integration (a new epoch: every window on the old
        heading restarts).
        """
        n = self._gn
        if n:
            last = self._gt[(n - 1) % RING]
            if stamp_ns <= last:
                return
            if yaw_rate != yaw_rate or stamp_ns - last > GYRO_GAP_NS:
                self._gn = n = 0
                self._epoch += 1
        if yaw_rate != yaw_rate:
            return
        i = n % RING
        if n:
            j = (n - 1) % RING
            self._gp[i] = self._gp[j] + 0.5 * (yaw_rate + self._g_rate) * \
                (stamp_ns - self._gt[j]) * 1e-9
        else:
            self._gp[i] = 0.0
        self._gt[i] = stamp_ns
        self._g_rate = yaw_rate
        self._gn = n + 1

    def _aligned(self) -> list[float] | None:
        """Return [left angle, right angle, heading, t_ns] at the newest instant both rings cover.

        That instant is the older of the newest encoder and gyro stamps; the other ring is
        interpolated there. None when the rings do not overlap (no gyro, or one too old).
        """
        en, gn = self._en, self._gn
        if not en or not gn:
            return None
        t_e, t_g = self._et[(en - 1) % RING], self._gt[(gn - 1) % RING]
        if t_g <= t_e:
            w = self._weights(self._et, en, t_g)
            if w is None:
                return None
            i, j, f = w
            el, er = self._el, self._er
            return [el[i] + f * (el[j] - el[i]), er[i] + f * (er[j] - er[i]),
                    self._gp[(gn - 1) % RING], float(t_g)]
        w = self._weights(self._gt, gn, t_e)
        if w is None:
            return None
        i, j, f = w
        e = (en - 1) % RING
        return [self._el[e], self._er[e], self._gp[i] + f * (self._gp[j] - self._gp[i]),
                float(t_e)]

    @staticmethod
    def _weights(ts: Sequence[float], n: int, t: float) -> tuple[int, int, float] | None:
        """Return ring slots i, j and the fraction f with t = ts[i] + f (ts[j] - ts[i]).

        i holds the newest sample at or before ``t`` (t at the newest itself: f 0); None when
        ``t`` is older than the ring.
        """
        k = n - 1
        oldest = max(0, n - RING)
        while k >= oldest and ts[k % RING] > t:
            k -= 1
        if k < oldest:
            return None
        i = k % RING
        if k == n - 1:
            return i, i, 0.0
        j = (k + 1) % RING
        return i, j, (t - ts[i]) / (ts[j] - ts[i])

    def idle(self) -> None:
        """Restart every symptom time (a cycle in which the wheels are not expected to follow)."""
        t = self._t
        for i in range(_N):
            t[i] = 0.0
        self._fresh = False
        for k in (0, 1):
            self._ref[k] = math.nan
            self._bound[k] = -1.0
            self._origin[k] = math.nan
            self._rev[k] = 0.0
            self._dir[k] = 0.0
            self._following[k] = False
            self._roll[k] = 0.0
            self._sp[k] = 0.0
            self.unseen[k] = False
            self._u_ref[k][0] = -1.0
            self._s_ref[k][0] = -1.0
        self._yn = 0
        self._yaw_hit = False

    def step(self, dt: float, sp_left: float, sp_right: float, meas_left: float,
             meas_right: float, u_left: float, u_right: float, saturated_left: bool,
             saturated_right: bool, yaw_rate: float = math.nan,
             held: Sequence[bool] = (False, False),
             level_hold: Sequence[float] | None = None, now_ns: int = 0) -> bool:
        """Advance one cycle; return True when a fault latched in this cycle.

        ``sp_*`` are the wheel setpoints the outputs were computed for (rad/s), ``meas_*`` the
        measured wheel speeds, ``u_*`` the outputs (normalized -1..1: the PI's, or at a zero
        setpoint the standstill hold's, which the effort tests leave alone: a held wheel
        standing against its load is what the hold is for),
        ``saturated_*`` whether that output was at its limit, ``yaw_rate`` the body's yaw rate
        from a fresh gyro sample (rad/s, about base_link z), NaN when there is none.
        ``held``: per wheel, the standstill hold holds it (zero setpoints) and it has read
        still since the hold began: judged by the standstill window from where it first read
        still, not by the still test's speed. A wheel the hold found pulled and brakes from
        speed is not held yet: a guard stop's first cycles (the speed estimate lagging the
        zero word) read as pulled, and a window from there latched a false fault at 2 m/s.
        ``level_hold``: per wheel, the standstill hold's integral (the load it holds), given
        while the hold holds and a fresh IMU sample says the floor is level along the track
        (``level_grade``), else None: a held wheel whose hold holds more than
        ``level_hold_effort`` latches the still fault at once. Not the hold's output: its
        proportional part brakes a wheel found pulled, which a guard stop on the level may
        be for a few cycles (up to 0.1 of full scale in a 2 m/s arc).
        ``now_ns``: the cycle's time, for the fault trace (:attr:`trace`) only.
        """
        if not self.enabled or self.cause:
            self._fresh = False
            return False
        if not self._fresh:
            # no new sample: nothing measured this cycle; every symptom time stands still
            self._record(now_ns, 0, sp_left, sp_right, meas_left, meas_right, u_left, u_right,
                         saturated_left, saturated_right, yaw_rate, held, level_hold)
            return False
        p = self.p
        t = self._t
        th = p.speed_threshold
        ms = p.min_speed
        kff = self._kff
        # The gyro against the turn the encoders describe: a wheel that reads still while the
        # other turns the same way describes a turn; if the body does not make it, the still
        # wheel turns unseen (frozen from the start, below moving_effort). Both read at one
        # instant (``_aligned``); without a gyro there is no evidence either way.
        ang = self._angle
        at = self._at = self._aligned() if p.use_imu else None
        epoch = float(self._epoch)
        for k in (0, 1):
            sp = sp_left if k == 0 else sp_right
            m = meas_left if k == 0 else meas_right
            u = u_left if k == 0 else u_right
            sat = saturated_left if k == 0 else saturated_right
            asp = abs(sp)
            sref = self._s_ref[k]
            if sp * self._sp[k] <= 0.0:
                sref[0] = -1.0                       # a new start window, taken below
                self._s_age[k] = 0.0
            else:
                self._s_age[k] += dt
            if at is not None and sref[0] != epoch:
                sref[0], sref[1], sref[2], sref[3] = epoch, at[k], at[1 - k], at[2]
            # a reversal: the wheel still rolls the old way as the setpoint leaves zero or
            # changes sign; its speed then, falling at still_deceleration, bounds "wrong way"
            rev = self._rev[k]
            if sp * self._sp[k] <= 0.0:
                # the wheel still rolls the way its last setpoint asked, against this one
                d = self._dir[k]
                rev = abs(m) if d * sp < 0.0 and m * d > ms else 0.0
            elif rev > 0.0:
                rev = max(rev - p.still_deceleration * dt, 0.0)
            self._rev[k] = rev
            if sp != 0.0:
                self._dir[k] = 1.0 if sp > 0.0 else -1.0
            against = m > ms if sp < 0.0 else m < -ms
            if asp > th and against and abs(m) > rev:
                t[_WRONG + k] += dt
            elif self._counts_against(k, sp):
                t[_WRONG + k] += 3.0 * dt            # integrated evidence, as unseen below
            else:
                t[_WRONG + k] = 0.0
            a = ang[k]
            if sp * self._sp[k] <= 0.0:
                self._following[k] = False      # a new setpoint direction (or zero)
                self._u_ref[k][0] = -1.0        # and a new unseen-motion window
                self.unseen[k] = False
                # a wheel still rolling this way (a guard released to a creep mid-brake)
                # may roll this far by itself, then stop where its effort is below the
                # break-away
                along = m if sp > 0.0 else -m
                self._roll[k] = along * along * ROLL_PER_SPEED2 if along > 0.0 else 0.0
                self._roll_a[k] = a
            self._sp[k] = sp
            ref = self._ref[k]
            if not abs(a - ref) < FROZEN_COUNTS * COUNT:     # moved (or no reference yet)
                if (a - ref) * sp > 0.0 and (a - self._roll_a[k]) * sp >= asp * (
                        self._roll[k] + FROZEN_COUNTS * COUNT):
                    # seen turning the way it is told, beyond what it rolls by itself
                    self._following[k] = True
                self._ref[k] = a
                self._u_ref[k][0] = -1.0
                self.unseen[k] = False
                t[_FROZEN + k] = 0.0
            else:
                uref = self._u_ref[k]
                if at is not None:
                    if uref[0] != epoch:
                        uref[0], uref[1], uref[2], uref[3] = epoch, at[1 - k], at[2], at[k]
                    # this wheel's motion as the other wheel's encoder and the gyro tell it,
                    # less what its own encoder showed over the same (aligned) window: the
                    # window starts at the aligned instant, older than the newest sample
                    # that found the wheel still, and a wheel stopping then still moved
                    turn = (at[2] - uref[2]) / self._r_over_track
                    own = ((at[1] - uref[1] - turn) if k == 0 else (at[0] - uref[1] + turn)) \
                        - (at[k] - uref[3])
                    if sp != 0.0 and own * sp >= UNSEEN_COUNTS * COUNT * asp:
                        self.unseen[k] = True
                if asp >= self.frozen_min and self.unseen[k]:
                    # integrated evidence (6 counts beyond the gyro's drift), no per-cycle
                    # noise to ride out: a third of frozen_time confirms it, before the
                    # wheel the PI cannot see speeds up far
                    t[_FROZEN + k] += 3.0 * dt
                elif asp >= self.frozen_min and (self._following[k]
                                                 or abs(u) >= p.moving_effort):
                    t[_FROZEN + k] += dt
                else:
                    t[_FROZEN + k] = 0.0
            # the speed the effort would drive a free wheel at, against the speed measured in
            # the effort's direction
            # (an effort against the motion brakes the wheel: no stall, whatever it costs --
            # a reversal, or a guard release mid-brake with a turn held, saturates the PI
            # backwards while the wheel still rolls forward; a wheel reading against its
            # effort for another reason is the wrong-way test's)
            excess = abs(u) / kff - (m if u >= 0.0 else -m)
            braking = m < -ms if u > 0.0 else m > ms if u < 0.0 else False
            if not braking and ((sat and asp > th and abs(m) < p.stall_ratio * asp)
                                or (u != 0.0 and sp != 0.0 and excess > p.effort_margin)):
                t[_STALL + k] += dt
            else:
                t[_STALL + k] = 0.0
            if sp == 0.0 and held[k]:
                # A safe operating stop: where the wheel is, not how fast it turns. A hold
                # still taking a ramp's load lets the wheel roll slowly for longer than
                # still_time (a false still fault on a 4.8 deg ramp at 0.51 s); a wheel
                # driven beyond what the hold can hold leaves the window, and that latches.
                o = self._origin[k]
                if o != o:
                    o = self._origin[k] = a
                t[_STILL + k] = self._times[_STILL + k] if abs(a - o) > self._window else 0.0
                self._bound[k] = 0.0
            elif sp == 0.0:
                self._origin[k] = math.nan
                # The bound follows the wheel down (a wheel that has been slow cannot be
                # braking from a higher speed any more) and falls at still_deceleration: a
                # wheel braked from speed that settles on a driven creep trips it as soon as
                # one that was slow from the start (a guard stop from 1 m/s: 1.7 s before).
                b = self._bound[k]
                b = abs(m) if b < 0.0 else max(min(b, abs(m) + 0.5 * p.still_speed)
                                               - p.still_deceleration * dt, 0.0)
                self._bound[k] = b
                if abs(m) > b + p.still_speed:
                    t[_STILL + k] += dt
                else:
                    t[_STILL + k] = 0.0
            else:
                self._bound[k] = -1.0
                self._origin[k] = math.nan
                t[_STILL + k] = 0.0
            if sp == 0.0 and held[k] and level_hold is not None and (
                    abs(level_hold[k]) > p.level_hold_effort):
                # On the level nothing leans on a wheel standing still: a hold holding more
                # than a dead band and an uncalibrated zero take is holding the amplifier
                # driving it (the hold's integral grows at the break-away rate while the wheel
                # rolls: a 2 V offset passes 0.1 of full scale 0.10 s from rest). Held wheels
                # only (read still in this hold): one the hold found pulled still brakes from
                # speed, and a late encoder sample can make a braking wheel read pulled.
                t[_STILL + k] = self._times[_STILL + k]
        self._fresh = False
        diff = sp_left - sp_right
        if saturated_left or saturated_right:
            # a wheel at its output limit cannot follow its setpoint, so being nearer the
            # other's is no evidence (an uncalibrated base at top speed in a turn); the time
            # stands (a true swap saturates a PI soon, after it has counted)
            pass
        elif (diff > th or diff < -th) and (abs(sp_left) > th or abs(sp_right) > th):
            own = abs(meas_left - sp_left) + abs(meas_right - sp_right)
            other = abs(meas_left - sp_right) + abs(meas_right - sp_left)
            t[_SWAP] = t[_SWAP] + dt if own - other > th else 0.0
        else:
            t[_SWAP] = 0.0
        # The integrated yaw test (integrated evidence, as unseen motion: a third of yaw_time
        # confirms it): crossed channels in a creep turn differ from the gyro by twice the turn
        # rate, about the per-cycle test's tolerance, which alone took up to 0.92 s.
        if at is not None and self._yaw_window(at, epoch):
            t[_YAWS] += 3.0 * dt
        elif p.use_imu and yaw_rate == yaw_rate:        # not NaN: a fresh gyro sample
            w_wheels = self._r_over_track * (meas_right - meas_left)
            bound = p.yaw_tolerance + p.yaw_ratio * max(abs(w_wheels), abs(yaw_rate))
            t[_YAWS] = t[_YAWS] + dt if abs(w_wheels - yaw_rate) > bound else 0.0
        self._record(now_ns, _T_ENC, sp_left, sp_right, meas_left, meas_right, u_left, u_right,
                     saturated_left, saturated_right, yaw_rate, held, level_hold)
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
            self.trace.freeze(self.faults, cause)
            return True
        return False

    def _yaw_window(self, at: list[float], epoch: float) -> bool:
        """Return True when the wheels' heading over YAW_WINDOW disagrees with the gyro's.

        ``at`` is this cycle's aligned instant; one entry per new instant is kept. Windows
        never span a restart of the gyro's heading (``epoch``); before a whole window has been
        seen there is no evidence either way.
        """
        n = self._yn
        t_now = at[3]
        if n:
            last = self._yt[(n - 1) % RING]
            if self._y_epoch != epoch or t_now < last:
                n = 0
            elif t_now == last:
                return self._yaw_hit              # no newer instant: the same verdict
        self._y_epoch = epoch
        i = n % RING
        self._yt[i] = t_now
        self._yl[i] = at[0]
        self._yr[i] = at[1]
        self._yh[i] = at[2]
        self._yn = n = n + 1
        # the newest instant a whole window back (this one is newer than that, so never it)
        w = self._weights(self._yt, n, t_now - _YAW_WINDOW_NS)
        if w is None:
            self._yaw_hit = False
            return False
        j = w[0]
        rt = self._r_over_track
        wheels = rt * ((at[1] - self._yr[j]) - (at[0] - self._yl[j]))
        gyro = at[2] - self._yh[j]
        bound = YAW_COUNTS * COUNT * rt + self.p.yaw_ratio * max(abs(wheels), abs(gyro))
        self._yaw_hit = abs(wheels - gyro) > bound
        return self._yaw_hit

    def _record(self, now_ns: int, flags: int, sp_l: float, sp_r: float, m_l: float,
                m_r: float, u_l: float, u_r: float, sat_l: bool, sat_r: bool, yaw: float,
                held: Sequence[bool], level_hold: Sequence[float] | None) -> None:
        if sat_l:
            flags |= _SAT_L
        if sat_r:
            flags |= _SAT_R
        if held[0]:
            flags |= _HELD_L
        if held[1]:
            flags |= _HELD_R
        if yaw == yaw:
            flags |= _T_GYRO
        else:
            yaw = 0.0
        h_l = h_r = 0.0
        if level_hold is not None:
            flags |= _T_LEVEL
            h_l, h_r = level_hold[0], level_hold[1]
        self.trace.record(now_ns, flags, (sp_l, sp_r, m_l, m_r, u_l, u_r, self._angle[0],
                                           self._angle[1], yaw, h_l, h_r, self._bound[0],
                                           self._bound[1]), self._t)

    def _counts_against(self, k: int, sp: float) -> bool:
        """Return True if wheel ``k``'s encoder counts against its setpoint over a start.

        Within START_WINDOW s of its setpoint leaving zero (or changing sign): it reads
        FROZEN_COUNTS against the setpoint while the other wheel's counts less the gyro's
        turn put its own motion UNSEEN_COUNTS the setpoint's way -- a sign flip or crossed
        channels at a creep, below speed_threshold, where a reversal cannot be told from a
        fault by the speed alone. Short, so the gyro's bias cannot build up; a wheel still
        turning the old way (a reversal) reads against, but is inferred against too.
        """
        sref = self._s_ref[k]
        at = self._at
        if (sp == 0.0 or at is None or sref[0] != float(self._epoch)
                or self._s_age[k] > START_WINDOW):
            return False
        turn = (at[2] - sref[3]) / self._r_over_track
        own = (at[1] - sref[2] - turn) if k == 0 else (at[0] - sref[2] + turn)
        if sp < 0.0:
            return (at[k] - sref[1] >= FROZEN_COUNTS * COUNT
                    and own <= -UNSEEN_COUNTS * COUNT)
        return at[k] - sref[1] <= -FROZEN_COUNTS * COUNT and own >= UNSEEN_COUNTS * COUNT

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
