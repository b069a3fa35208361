"""Emergency stop latch of the base controller (pure: no I/O, no clock).

The latch lives in the RT actuator, not in the bridge, so it holds when the bridge (or the
laptop that published ``e_stop``) dies after latching. Its rules:

* ``engage()`` latches the stop: the controller ramps both axes to zero at the e-stop
  decelerations (``control.e_stop``) from the cycle that saw the datagram, whatever commands
  arrive meanwhile.
* ``release()`` unlatches it, but the robot stays stopped (*hold*) until a velocity command
  arrives **after** the release, in the order the actuator receives datagrams on its ``cmd``
  port. The bridge forwards ``cmd_vel`` and ``e_stop`` on that one ordered port, so a command
  sent before the release (including the last one received during the latch) never restarts
  the robot on its own.

Ordering rather than time stamps decides "after": two datagrams drained in the same cycle
carry the same receive time, and their order is exactly the order the bridge sent them.
"""

from __future__ import annotations

import math

__all__ = ['EStopLatch', 'ramp_to_zero']


def ramp_to_zero(value: float, deceleration: float, dt: float) -> float:
    """Return ``value`` moved toward zero by at most ``deceleration * dt`` (never past it)."""
    step = deceleration * dt
    if value > step:
        return value - step
    if value < -step:
        return value + step
    return 0.0


class EStopLatch:
    """The latched stop and the "fresh command after release" rule."""

    __slots__ = ('linear_deceleration', 'angular_deceleration', 'engaged', 'holding',
                 'engagements', 'releases')

    def __init__(self, linear_deceleration: float, angular_deceleration: float) -> None:
        for name, value in (('linear_deceleration', linear_deceleration),
                            ('angular_deceleration', angular_deceleration)):
            if (isinstance(value, bool) or not isinstance(value, (int, float))
                    or not math.isfinite(value) or value <= 0.0):
                raise ValueError(f'e-stop {name} must be a finite number > 0, got {value!r}')
        self.linear_deceleration = float(linear_deceleration)
        self.angular_deceleration = float(angular_deceleration)
        self.engaged = False
        self.holding = False     # released (or engaged): no motion until a newer command
        self.engagements = 0
        self.releases = 0

    @property
    def blocking(self) -> bool:
        """Return True while the latch keeps the robot's target at zero."""
        return self.engaged or self.holding

    def engage(self) -> None:
        """Latch the stop (idempotent: a repeated engage changes nothing)."""
        if not self.engaged:
            self.engagements += 1
        self.engaged = True
        self.holding = True

    def release(self) -> None:
        """Unlatch; keep holding until the next command. A release when not engaged is a no-op.

        The no-op matters: a repeated release (a transient-local publisher re-delivering its
        last value) must not re-arm the hold after a fresh command has restarted the robot.
        """
        if self.engaged:
            self.engaged = False
            self.holding = True
            self.releases += 1

    def command(self) -> bool:
        """Note that a velocity command arrived (in port order); return whether it may drive."""
        if self.engaged:
            return False
        self.holding = False
        return True

    def set(self, engage: bool) -> None:
        """Apply one E_STOP datagram's ``engage`` field."""
        if engage:
            self.engage()
        else:
            self.release()
