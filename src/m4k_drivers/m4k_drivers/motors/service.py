"""How the driver host serves the motors: WHEEL_CMD -> DACs, then encoders -> ENCODERS.

The service also owns the motors' two safety duties in the host: the watchdog (polled every
loop pass: no WHEEL_CMD for ``watchdog_periods`` -> outputs safe until a fresh command) and
outputs safe at once when the RT side goes away.  WHEEL_CMDs older than two periods (stamped
by the RT side) are dropped, not replayed: a stalled host resumes on the newest command.
The service thread's loop runs at the actuator period (``period_s``) so the watchdog fires on time.
"""

from __future__ import annotations

from typing import Any, Mapping

from m4k_drivers.handler import State, Status
from m4k_drivers.motors import jog
from m4k_drivers.motors.handler import EncoderReading, MotorHandler, WheelCommand
from m4k_drivers.registry import Jog, Replier, ServiceSpec
from m4k_rt.protocol import Kind, WheelCmd

__all__ = ['SERVICE']


def serve(handler: MotorHandler, msg: WheelCmd, tx: Replier) -> None:
    """Write the command to the DACs, then answer with the encoders read right after."""
    if handler.state != State.ACTIVE:
        return
    handler.write(WheelCommand(msg.left_code, msg.right_code, msg.enable))
    r = handler.read()
    if r.status == Status.OK:
        v = r.value
        tx.send(Kind.ENCODERS, v.left_raw, v.right_raw, v.left_angle, v.right_angle, v.status,
                stamp_ns=v.t_ns)


def format_reading(value: EncoderReading) -> str:
    """Return the ``--print`` line of one encoder reading."""
    return (f'motor raw=({value.left_raw},{value.right_raw}) '
            f'angle=({value.left_angle:+.4f},{value.right_angle:+.4f}) rad '
            f'status=0x{value.status:02x}')


def _period(section: Mapping[str, Any]) -> float:
    # the validated section always has it (a Derived default: the actuator task's period)
    return float(section['period_s'])


def _max_age(section: Mapping[str, Any]) -> float:
    # A WHEEL_CMD older than two actuator periods has been replaced by a newer one (or the RT
    # side stopped sending): after a stall the queue is dropped, not replayed, so a dead
    # command never toggles the heartbeat back on.  Same host, same CLOCK_MONOTONIC.
    return 2.0 * _period(section)


SERVICE: ServiceSpec[MotorHandler] = ServiceSpec(
    accepts=frozenset({Kind.WHEEL_CMD}), serve=serve, format=format_reading,
    # The RT side gone: nobody commands the motors any more, so zero both DACs at once.
    read_timeout=_period, max_age=_max_age, tick=MotorHandler.poll_watchdog,
    on_link_lost=MotorHandler.make_safe,
    jog=Jog(jog.check_jog, jog.run_jog))
