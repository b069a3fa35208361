"""Wheel jog for real-robot bring-up: one wheel, a small speed, a short time, then zero.

``driver_host --device motor --jog left|right SPEED --duration S [--yes]`` -- SPEED is a
fraction of the DAC's full scale (WHEEL_CMD code 512 + SPEED * 511, the owner of that mapping
is :mod:`m4k_rt.control.dac`), positive = the wheel should roll the robot forward.  It checks
a wheel's direction (and so ``dac_sign``/``enc_direction``) with the robot on blocks.

Safety: |SPEED| <= ``JOG_MAX_SPEED`` and S <= ``JOG_MAX_DURATION_S`` (larger values are
refused, not clamped); on a terminal it asks for confirmation unless ``--yes`` (without a
terminal, ``--yes`` is required).  Commands go through the motor handler's normal path
(:meth:`MotorHandler.write`, one fresh command per actuator period -- what feeds the driver
watchdog and the motor-enable heartbeat), the other wheel is held at zero, and both wheels are
commanded to zero at the end, on Ctrl-C (``stop``) and on any error.

The verdict reports both wheels from their encoders. A wheel "turned" only beyond
``JOG_MIN_TURN_RAD`` (0.05 rad: 33 counts of the 12-bit AS5045, 5 mm at the rim -- far above a
count of flicker or noise, far below what the smallest allowed jog turns on free wheels), so a
count of flicker never reads as "forward". The jogged wheel should turn the commanded way; the
held one should stay still -- if it moved, the channels are swapped or the other motor is
driven.
"""

from __future__ import annotations

import math
import threading
import time
from typing import Callable, TextIO

from m4k_drivers.handler import DriverError, Status
from m4k_drivers.motors import protocol as p
from m4k_drivers.motors.handler import MotorHandler, WheelCommand

__all__ = ['JOG_MAX_DURATION_S', 'JOG_MAX_SPEED', 'JOG_MIN_TURN_RAD', 'JogError', 'check_jog',
           'run_jog', 'verdict']

JOG_MAX_SPEED = 0.25            # fraction of full scale (0.5 m/s rim speed on the M4K)
JOG_MAX_DURATION_S = 5.0
JOG_MIN_TURN_RAD = 0.05         # an encoder's angle change below this is "did not turn"
SIDES = ('left', 'right')


class JogError(ValueError):
    """A jog request outside the caps, or refused at the prompt."""


def check_jog(side: str, speed: float, duration_s: float) -> None:
    """Raise JogError unless side, speed and duration are within the caps."""
    if side not in SIDES:
        raise JogError(f'--jog: wheel must be left or right, got {side!r}')
    if not math.isfinite(speed) or abs(speed) > JOG_MAX_SPEED or speed == 0.0:
        raise JogError(f'--jog SPEED: must be a non-zero fraction of full scale within '
                       f'+/-{JOG_MAX_SPEED}, got {speed!r}')
    if not math.isfinite(duration_s) or not 0.0 < duration_s <= JOG_MAX_DURATION_S:
        raise JogError(f'--duration: must be in (0, {JOG_MAX_DURATION_S}] s, got {duration_s!r}')


def verdict(side: str, speed: float, turned: tuple[float, float],
            threshold: float = JOG_MIN_TURN_RAD) -> tuple[bool, list[str]]:
    """Return (all as expected, one line per wheel) for the encoders' angle changes.

    ``turned`` is (left, right) in rad. The jogged wheel must turn the way ``speed`` says by
    more than ``threshold``; the held one must stay within it.
    """
    idx = SIDES.index(side)
    lines = []
    ok = True
    for i, name in enumerate(SIDES):
        d = turned[i]
        moved = abs(d) > threshold
        head = (f'jog {side}: {name} wheel angle changed {d:+.3f} rad '
                f'(threshold {threshold:.3f})')
        if i == idx:
            if moved and d * speed > 0:
                what = 'the encoder says it turned forward'
            elif moved:
                what = ('the encoder says it turned BACKWARD (check dac_sign / enc_direction)')
                ok = False
            else:
                what = ('the encoder says it did NOT turn measurably (check the amplifier '
                        'enable, the motor wiring, or swapped encoder channels)')
                ok = False
        elif moved:
            what = ('held at zero but the encoder says it MOVED (encoder channels swapped, or '
                    'this motor is driven: check the wiring)')
            ok = False
        else:
            what = 'held at zero and still, as it should be'
        lines.append(f'{head}: {what}')
    return ok, lines


def confirm(side: str, speed: float, duration_s: float, stdin: TextIO, out: TextIO) -> bool:
    """Ask on the terminal; True only for an explicit yes."""
    print(f'driver_host: jog the {side.upper()} wheel at {speed:+.2f} of full scale for '
          f'{duration_s:.1f} s. Robot on blocks, wheels free, e-stop in reach? [y/N] ',
          end='', file=out, flush=True)
    answer = stdin.readline().strip().lower()
    return answer in ('y', 'yes')


def run_jog(handler: MotorHandler, side: str, speed: float, duration_s: float,
            stop: threading.Event, *, out: TextIO, stdin: TextIO | None = None,
            assume_yes: bool = False, period_s: float | None = None,
            clock: Callable[[], float] | None = None) -> int:
    """Jog one wheel; return the exit code (0 done, 1 refused or failed)."""
    check_jog(side, speed, duration_s)
    if not assume_yes:
        if stdin is None or not stdin.isatty():
            raise JogError('--jog needs confirmation: run it on a terminal, or pass --yes')
        if not confirm(side, speed, duration_s, stdin, out):
            print('driver_host: jog cancelled', file=out, flush=True)
            return 1
    now = clock or time.monotonic
    period = period_s if period_s is not None else handler.period_s
    code = p.command_to_code(speed)
    cmd = WheelCommand(code, p.DAC_ZERO, 1) if side == 'left' else \
        WheelCommand(p.DAC_ZERO, code, 1)
    idx = SIDES.index(side)
    try:
        handler.configure()
        handler.activate()
    except DriverError as exc:
        print(f'driver_host: motor: {exc}', file=out, flush=True)
        handler.shutdown()
        return 1
    start: tuple[float, float] | None = None
    last: tuple[float, float] | None = None
    rc = 0
    try:
        end = now() + duration_s
        next_print = now()
        while not stop.is_set() and now() < end:
            if handler.write(cmd) != Status.OK:
                print(f'driver_host: jog: write failed: {handler.last_exception}', file=out)
                rc = 1
                break
            r = handler.read()
            if r.status == Status.OK:
                last = (r.value.left_angle, r.value.right_angle)
                if start is None:
                    start = last
                if now() >= next_print:
                    print(f'jog {side} code={code} angle={last[idx]:+.3f} rad '
                          f'status=0x{r.value.status:02x}', file=out, flush=True)
                    next_print += 0.1
            stop.wait(period)
    finally:
        zero = WheelCommand(p.DAC_ZERO, p.DAC_ZERO, 0)
        if handler.write(zero) != Status.OK:
            rc = 1
        handler.shutdown()             # deactivate: code 512 again, outputs active
    if start is not None and last is not None and all(map(math.isfinite, last)):
        _, lines = verdict(side, speed, (last[0] - start[0], last[1] - start[1]))
        for line in lines:
            print(line, file=out, flush=True)
    if stop.is_set():
        print('driver_host: jog stopped early; motors at zero', file=out, flush=True)
    return rc
