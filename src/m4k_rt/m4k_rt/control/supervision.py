"""Wheel supervision: measured wheel speed against the setpoint, latched motor fault (pure).

Nothing else compares what a wheel does with what it was told: a wrong-sign, swapped or
frozen encoder with valid frames turns the speed PI into positive feedback, and the guard only
caps the commanded speed. So every actuator cycle, per wheel, while ``|setpoint|`` is above
``speed_threshold`` (below it encoder quantization and static friction make the comparison
meaningless), the supervisor accumulates the time each symptom has held without a break:

* **wrong way**: the measured speed is beyond ``min_speed`` and of the other sign
  (``wrong_way_time``);
* **frozen**: the encoder angle has not changed by a single count (``frozen_time``, counted
  over cycles that brought a new sample only: a late driver host is not a frozen encoder): a
  frozen frame, a dead encoder, or a wheel that does not turn at all (a stalled wheel whose
  encoder is healthy reads the same);
* **stall**: the PI output is saturated and the wheel turns at less than ``stall_ratio`` of
  its setpoint (``stall_time``);
* **swapped** (both wheels, while their setpoints differ by more than the threshold): each
  wheel's speed is closer to the other wheel's setpoint than to its own, by more than the
  threshold (``swap_time``). Driving straight, swapped channels are harmless and invisible.

A symptom that holds for its time latches the fault; a cycle without it resets its time.
Every symptom time is *encoder* time: it advances only over cycles that brought a new
ENCODERS sample, and a cycle without one neither adds nor resets it. The measured speeds of
a cycle without a sample are the previous sample's, not news: under load the driver host's
datagrams arrive late and bunched, and counting those repeats as time turned one reading
(e.g. the few-mm rebound of a hard guard stop, taken just before a gap of ~90 ms) into a
0.1 s "wrong way" and a latched fault on healthy wheels.
All times are at most 0.3 s (the schema bounds them), so a fault latches within 0.3 s of
sim time from the first cycle it is visible. The latch holds until :meth:`reset` (an explicit
request from the bridge); the controller meanwhile zeroes the outputs and drops the enable.

Cycles in which the wheels cannot be expected to follow (the amplifier disabled, the driver
holding the DACs safe, the e-stop contact open) are skipped by the caller, and the symptom
times restart.
"""

from __future__ import annotations

from m4k_rt.control.params import SupervisionParams
from m4k_rt.protocol import FaultCause

__all__ = ['WheelSupervisor']

_LEFT_WRONG = int(FaultCause.LEFT_WRONG_WAY)
_RIGHT_WRONG = int(FaultCause.RIGHT_WRONG_WAY)
_LEFT_FROZEN = int(FaultCause.LEFT_FROZEN)
_RIGHT_FROZEN = int(FaultCause.RIGHT_FROZEN)
_LEFT_STALL = int(FaultCause.LEFT_STALL)
_RIGHT_STALL = int(FaultCause.RIGHT_STALL)
_SWAPPED = int(FaultCause.SWAPPED)


class WheelSupervisor:
    """Symptom timers per wheel and the latched fault (cause bits)."""

    __slots__ = ('enabled', 'threshold', 'min_speed', 'wrong_way_time', 'frozen_time',
                 'stall_time', 'stall_ratio', 'swap_time', 'cause', 'faults', 'last_cause',
                 '_t', '_left_angle', '_right_angle', '_left_moved', '_right_moved', '_fresh')

    def __init__(self, params: SupervisionParams | None = None) -> None:
        # The settings and their defaults are declared once, on SupervisionParams.
        p = SupervisionParams() if params is None else params
        self.enabled = bool(p.enabled)
        self.threshold = float(p.speed_threshold)
        self.min_speed = float(p.min_speed)
        self.wrong_way_time = float(p.wrong_way_time)
        self.frozen_time = float(p.frozen_time)
        self.stall_time = float(p.stall_time)
        self.stall_ratio = float(p.stall_ratio)
        self.swap_time = float(p.swap_time)
        self.cause = 0            # FaultCause bits of the latched fault; 0: none latched
        self.last_cause = 0       # the cause of the last fault (kept after a reset)
        self.faults = 0
        # symptom times [s]: wrong L, wrong R, frozen L, frozen R, stall L, stall R, swap
        self._t = [0.0] * 7
        self._left_angle = 0.0
        self._right_angle = 0.0
        self._left_moved = False   # the angle changed since the last step
        self._right_moved = False
        self._fresh = False        # a sample arrived since the last step

    @property
    def latched(self) -> bool:
        """Return True while a motor fault is latched."""
        return self.cause != 0

    def encoders(self, left_angle: float, right_angle: float) -> None:
        """Note one valid ENCODERS sample (did either angle change since the last?)."""
        self._fresh = True
        if left_angle != self._left_angle:
            self._left_moved = True
            self._left_angle = left_angle
        if right_angle != self._right_angle:
            self._right_moved = True
            self._right_angle = right_angle

    def idle(self) -> None:
        """Restart every symptom time (a cycle in which the wheels are not expected to follow)."""
        t = self._t
        for i in range(7):
            t[i] = 0.0
        self._left_moved = self._right_moved = self._fresh = False

    def step(self, dt: float, sp_left: float, sp_right: float, meas_left: float,
             meas_right: float, saturated_left: bool, saturated_right: bool) -> bool:
        """Advance one cycle; return True when a fault latched in this cycle.

        ``sp_*`` are the wheel setpoints the last outputs were computed for (rad/s), ``meas_*``
        the measured wheel speeds, ``saturated_*`` whether that PI output was at its limit.
        """
        if not self.enabled or self.cause:
            self._left_moved = self._right_moved = self._fresh = False
            return False
        t = self._t
        # A cycle without a new sample (the driver host late) says nothing about the wheels:
        # the symptom times count only over cycles that brought a sample.
        fresh = self._fresh
        th = self.threshold
        ms = self.min_speed
        cause = 0
        # per wheel: index offset 0 = left, 1 = right
        if not fresh:
            # no new sample: nothing measured this cycle; every symptom time stands still
            self._left_moved = self._right_moved = False
            return False
        for k in (0, 1):
            sp = sp_left if k == 0 else sp_right
            m = meas_left if k == 0 else meas_right
            moved = self._left_moved if k == 0 else self._right_moved
            sat = saturated_left if k == 0 else saturated_right
            if sp > th or sp < -th:
                if (m > ms and sp < 0.0) or (m < -ms and sp > 0.0):
                    t[k] += dt
                else:
                    t[k] = 0.0
                if moved:
                    t[2 + k] = 0.0
                else:
                    t[2 + k] += dt
                if sat and abs(m) < self.stall_ratio * abs(sp):
                    t[4 + k] += dt
                else:
                    t[4 + k] = 0.0
            else:
                t[k] = t[2 + k] = t[4 + k] = 0.0
        self._left_moved = self._right_moved = self._fresh = False
        diff = sp_left - sp_right
        if (diff > th or diff < -th) and (sp_left > th or sp_left < -th
                                          or sp_right > th or sp_right < -th):
            own = abs(meas_left - sp_left) + abs(meas_right - sp_right)
            other = abs(meas_left - sp_right) + abs(meas_right - sp_left)
            if own - other > th:
                t[6] += dt
            else:
                t[6] = 0.0
        else:
            t[6] = 0.0
        eps = 1e-9
        if t[6] >= self.swap_time - eps:
            cause |= _SWAPPED
        if t[0] >= self.wrong_way_time - eps:
            cause |= _LEFT_WRONG
        if t[1] >= self.wrong_way_time - eps:
            cause |= _RIGHT_WRONG
        if t[2] >= self.frozen_time - eps:
            cause |= _LEFT_FROZEN
        if t[3] >= self.frozen_time - eps:
            cause |= _RIGHT_FROZEN
        if t[4] >= self.stall_time - eps:
            cause |= _LEFT_STALL
        if t[5] >= self.stall_time - eps:
            cause |= _RIGHT_STALL
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
                      (_LEFT_STALL, 'left wheel stalled at full output'),
                      (_RIGHT_STALL, 'right wheel stalled at full output'),
                      (_SWAPPED, 'wheels answer each other (swapped channels)')):
        if cause & bit:
            names.append(text)
    return '; '.join(names) if names else 'none'
