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

__all__ = ['DAC_HOLD_MAX_S', 'JOG_MAX_DURATION_S', 'JOG_MAX_SPEED', 'JOG_MIN_TURN_RAD',
           'JogError', 'check_dac_hold', 'check_jog', 'run_dac_hold', 'run_jog', 'verdict']

JOG_MAX_SPEED = 0.25            # fraction of full scale (0.5 m/s rim speed on the M4K)
JOG_MAX_DURATION_S = 5.0
JOG_MIN_TURN_RAD = 0.05         # an encoder's angle change below this is "did not turn"
DAC_HOLD_MAX_S = 600.0          # long enough to probe both DAC outputs with a meter
SIDES = ('left', 'right')


class JogError(ValueError):
    """A jog request outside the caps, or refused at the prompt."""


def check_jog(side: str, speed: float, duration_s: float) -> None:
    """Raise JogError unless side, speed and duration are within the caps."""
    if side == 'dac':
        check_dac_hold(speed, duration_s)
        return
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
    """Jog one wheel (or hold a DAC code: ``side`` 'dac'); return the exit code."""
    check_jog(side, speed, duration_s)
    if side == 'dac':
        return run_dac_hold(handler, int(speed), duration_s, stop, out=out, stdin=stdin,
                            assume_yes=assume_yes)
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


# -- the DAC hold: a code on both DACs with the amplifier enable off ---------------------------
def check_dac_hold(code: float, duration_s: float) -> None:
    """Raise JogError unless ``code`` is a DAC code and the hold within its cap."""
    if not (math.isfinite(code) and code == int(code) and 0 <= code <= p.DAC_MAX):
        raise JogError(f'--dac CODE: must be an integer 0..{p.DAC_MAX}, got {code!r}')
    if not math.isfinite(duration_s) or not 0.0 < duration_s <= DAC_HOLD_MAX_S:
        raise JogError(f'--duration: must be in (0, {DAC_HOLD_MAX_S:.0f}] s for --dac, '
                       f'got {duration_s!r}')


def run_dac_hold(handler: MotorHandler, code: int, duration_s: float, stop: threading.Event,
                 *, out: TextIO, stdin: TextIO | None = None,
                 assume_yes: bool = False) -> int:
    """Write ``code`` to both DACs and hold it with the enable line inactive; 0 when done.

    The code goes out as it is (no dac_sign, no zero trim: the meter must see the chip's own
    output), /LDAC is pulsed when driven, and the heartbeat line is requested low and never
    toggled, so the enable monostable never fires: the amplifier stays disabled whatever the
    code.  A configuration without the heartbeat line (enable strapped on) is refused: there
    the amplifier would drive the motors at this code.
    """
    check_dac_hold(code, duration_s)
    amp = getattr(handler, 'amplifier', None) or {}
    vref = float(amp.get('vref', 3.3))
    volts = p.code_to_volts(code, vref)
    if not assume_yes:
        if stdin is None or not stdin.isatty():
            raise JogError('--dac needs confirmation: run it on a terminal, or pass --yes')
        print(f'driver_host: hold code {code} ({volts:.3f} V at vref {vref} V) on BOTH DACs '
              f'for {duration_s:.0f} s, amplifier enable OFF. Robot on blocks? [y/N] ',
              end='', file=out, flush=True)
        if stdin.readline().strip().lower() not in ('y', 'yes'):
            print('driver_host: DAC hold cancelled', file=out, flush=True)
            return 1
    try:
        handler.configure()
    except DriverError as exc:
        print(f'driver_host: motor: {exc}', file=out, flush=True)
        handler.shutdown()
        return 1
    bus = handler.bus
    rc = 0
    try:
        if bus is None or bus.enable is None:
            print('driver_host: --dac refused: no heartbeat line (heartbeat: false, the enable '
                  'strapped on) -- the motors would run at this code', file=out, flush=True)
            return 1
        frame = p.encode_dac(code)
        for port in bus.dacs:
            port.transfer(frame)
        bus.latch()
        print(f'dac hold: code {code} on both DACs: expect {volts:.3f} V at each MCP4911 VOUT '
              f'(vref {vref} V); enable line {bus.enable.where} held low, never toggled: the '
              f'amplifier stays disabled. Measure now; Ctrl-C ends.', file=out, flush=True)
        if amp:
            print(f"amplifier as configured: input {amp['amp_input_range_v']} V, zero "
                  f"{amp['amp_zero_v']} V, ENABLE {amp['amp_enable']}, current limit "
                  f"{amp['amp_current_limit_a']} A", file=out, flush=True)
        stop.wait(duration_s)
    except DriverError as exc:
        print(f'driver_host: dac hold: {exc}', file=out, flush=True)
        rc = 1
    finally:
        try:
            handler.make_safe()        # the zero code on both DACs (trims applied)
        except DriverError as exc:
            print(f'driver_host: dac hold: zeroing failed: {exc}', file=out, flush=True)
            rc = 1
        handler.shutdown()
    if rc == 0:
        print(f'dac hold: ended; both DACs back at zero (code {p.DAC_ZERO} + trim)', file=out,
              flush=True)
    return rc
