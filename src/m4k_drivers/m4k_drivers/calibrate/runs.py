"""The bounded motor runs of ``calibrate``: zero hold, sweep, lag, straight, turn, brake.

Every run goes through the motor handler's normal path (:class:`MotorRig`: one fresh
WHEEL_CMD with enable = 1 per actuator period, so the driver watchdog is fed and the
amplifier-enable heartbeat toggles: the amplifier is *on*, also during a zero hold), and reads
both encoders after each command.  Bounds: every command is within +/-``MAX_SPEED`` of full
scale (refused, not clamped), every run has a time limit, the straight run and the turns stop
at their planned wheel travel and abort when the wheels stop making progress under drive (a
stuck encoder would otherwise let them run on to the time limit).  :class:`MotorRig` is a
context manager: on leaving it -- normally, on an exception, on Ctrl-C (the ``stop`` event) --
both wheels get code 512 and the handler is shut down (outputs safe).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
import threading
import time
from types import TracebackType
from typing import Callable

from m4k_drivers.calibrate import fit
from m4k_drivers.handler import DriverError, Status
from m4k_drivers.motors import protocol as p
from m4k_drivers.motors.handler import MotorHandler, WheelCommand
from m4k_rt.protocol import EncoderStatus

__all__ = ['LAG_LEVELS', 'MAX_SPEED', 'Aborted', 'MotorRig', 'Sample', 'Sweep', 'brake', 'hold',
           'lag', 'straight', 'sweep', 'turn']

MAX_SPEED = 0.3               # fraction of full scale, any run (0.6 m/s rim speed on the M4K)
STOP_SPEED = 0.05             # rad/s: a wheel slower than this counts as stopped
BAD_RUN_MAX = 5               # encoder readings with frame/jump errors in a row: a fault
_BAD = EncoderStatus.INVALID           # frame or jump error on either wheel: angles untrusted
# The lag run's plateaus, fractions of its speed: two up-steps of a quarter of it each. Small
# enough that the amplifier stays below its current limit (on the default sim base a 0.0375
# full-scale step, 0.9 V, asks ~1.5 A over the ~0.5 A load, of 3 A): the linear region the
# wheel-speed PI works in, not the current-limited ramp of a step from rest.
LAG_LEVELS = (0.5, 0.75, 1.0)


class Aborted(RuntimeError):
    """A run ended early: stop requested, a device error, or a bound was reached."""


@dataclass(frozen=True)
class Sample:
    """One encoder reading: time (s, CLOCK_MONOTONIC) and both wheel angles (rad)."""

    t: float
    left: float
    right: float


class MotorRig:
    """Command both wheels once per period and read the encoders; zero on every way out."""

    def __init__(self, handler: MotorHandler, stop: threading.Event, *,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.handler = handler
        self.stop = stop
        self.clock = clock
        self.period = handler.period_s
        self.last: Sample | None = None
        self.bad_samples = 0             # encoder readings skipped (frame or jump error)
        self.bad_run = 0
        self._next = 0.0

    def __enter__(self) -> MotorRig:
        try:
            self.handler.configure()
            self.handler.activate()
        except DriverError:
            self.handler.shutdown()
            raise
        self._next = self.clock()
        self.command(p.DAC_ZERO, p.DAC_ZERO)
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        try:
            self.handler.write(WheelCommand(p.DAC_ZERO, p.DAC_ZERO, 0))
        finally:
            self.handler.shutdown()            # deactivate: code 512, outputs active

    def command(self, left: int, right: int) -> tuple[float, Sample]:
        """Write one WHEEL_CMD (enable on), read the encoders, wait for the next period.

        Return the time the command was written and the reading after it (the last good one
        when this one had a frame or jump error).
        """
        for code in (left, right):
            if abs(code - p.DAC_ZERO) > MAX_SPEED * fit.DAC_SPAN + 0.5:
                raise Aborted(f'command code {code} beyond the calibration cap '
                              f'(+/-{MAX_SPEED} of full scale)')
        if self.stop.is_set():
            raise Aborted('stopped')
        t_cmd = self.clock()
        if self.handler.write(WheelCommand(left, right, 1)) != Status.OK:
            raise Aborted(f'motor write failed: {self.handler.last_exception}')
        r = self.handler.read()
        if r.status != Status.OK:
            raise Aborted(f'encoder read failed: {self.handler.last_exception}')
        if r.value.status & _BAD:
            # One bad frame, or a reading whose host stamp came late (a busy machine makes an
            # honest step look like a jump), is skipped as the RT side skips it; a run of them
            # is a fault.
            self.bad_samples += 1
            self.bad_run += 1
            if self.bad_run >= BAD_RUN_MAX or self.last is None:
                raise Aborted(f'encoder frame/jump error (status 0x{r.value.status:02x}, '
                              f'{self.bad_run} in a row): {self.handler.last_exception}')
        else:
            self.bad_run = 0
            self.last = Sample(r.value.t_ns * 1e-9, r.value.left_angle, r.value.right_angle)
        self._next += self.period
        now = self.clock()
        if self._next < now:                 # late (busy machine): do not try to catch up
            self._next = now
        self.stop.wait(self._next - now)
        assert self.last is not None
        return t_cmd, self.last

    def run_for(self, left: int, right: int, seconds: float) -> tuple[float, list[Sample]]:
        """Hold one command for ``seconds``; return its write time and the readings."""
        t0, first = self.command(left, right)
        out = [first]
        while out[-1].t - t0 < seconds:
            s = self.command(left, right)[1]
            if s is not out[-1]:          # a skipped reading repeats the last good one
                out.append(s)
            elif self.clock() - t0 > seconds + 1.0:
                raise Aborted('no valid encoder reading')
        return t0, out

    def wait_stopped(self, limit_s: float = 3.0, still_s: float = 0.3) -> Sample:
        """Hold zero until both wheels are still for ``still_s``; Aborted after ``limit_s``."""
        t0, s = self.command(p.DAC_ZERO, p.DAC_ZERO)
        still_since = s
        while True:
            _, now = self.command(p.DAC_ZERO, p.DAC_ZERO)
            if (abs(now.left - still_since.left) > STOP_SPEED * (now.t - still_since.t) + 0.01
                    or abs(now.right - still_since.right)
                    > STOP_SPEED * (now.t - still_since.t) + 0.01):
                still_since = now
            elif now.t - still_since.t >= still_s:
                return now
            if now.t - t0 > limit_s:
                raise Aborted(f'the wheels did not come to rest within {limit_s} s at code 512 '
                              f'(a zero error beyond the dead band? run the sweep first)')


def _code(x: float) -> int:
    """Return the code for offset ``x``; corrections on top of a run never pass the cap."""
    cap = int(MAX_SPEED * fit.DAC_SPAN)
    return p.DAC_ZERO + max(-cap, min(cap, round(x)))


def hold(rig: MotorRig, seconds: float) -> tuple[float, float]:
    """Hold code 512 with the amplifier enabled; return each wheel's creep (rad/s)."""
    t0, samples = rig.run_for(p.DAC_ZERO, p.DAC_ZERO, seconds)
    half = [s for s in samples if s.t - t0 >= 0.3 * seconds]   # after any motion dies out
    return (fit.fit_line([s.t for s in half], [s.left for s in half])[0],
            fit.fit_line([s.t for s in half], [s.right for s in half])[0])


@dataclass
class Sweep:
    """The plateaus of a code sweep, per wheel (index 0 left, 1 right)."""

    plateaus: tuple[list[fit.Plateau], list[fit.Plateau]] = field(
        default_factory=lambda: ([], []))


def sweep(rig: MotorRig, max_speed: float, levels: int, settle_s: float,
          measure_s: float, log: Callable[[str], None]) -> Sweep:
    """Step both wheels through ``levels`` codes up to ``max_speed``, turning in place.

    One staircase per direction (left forward / right backward, then the mirror), each from a
    zero plateau: the steady speed of every plateau, and the angle lines for the lag.
    """
    if not 0 < max_speed <= MAX_SPEED:
        raise Aborted(f'sweep speed must be in (0, {MAX_SPEED}], got {max_speed!r}')
    out = Sweep()
    for direction in (1, -1):
        steps = [0.0] + [direction * max_speed * fit.DAC_SPAN * (i + 1) / levels
                         for i in range(levels)]
        for x in steps:
            xi = round(x)
            t0, samples = rig.run_for(_code(xi), _code(-xi), settle_s + measure_s)
            steady = [s for s in samples if s.t - t0 >= settle_s]
            pl = (fit.fit_plateau(xi, t0, [s.t for s in steady], [s.left for s in steady]),
                  fit.fit_plateau(-xi, t0, [s.t for s in steady], [s.right for s in steady]))
            out.plateaus[0].append(pl[0])
            out.plateaus[1].append(pl[1])
            log(f'sweep: code 512{xi:+d}/512{-xi:+d}: left {pl[0].speed:+.3f} rad/s, '
                f'right {pl[1].speed:+.3f} rad/s')
    return out


class _Progress:
    """Abort a run whose wheels stop making progress (a stuck encoder, a stalled drive)."""

    def __init__(self, what: str, t0: float, window_s: float = 1.0, min_rad: float = 0.05):
        self.what, self.window_s, self.min_rad = what, window_s, min_rad
        self.mark_t, self.mark = t0 + window_s, 0.0     # the first window includes the ramp

    def check(self, t: float, done: float) -> None:
        if t < self.mark_t:
            return
        if done - self.mark < self.min_rad:
            raise Aborted(f'{self.what}: the wheels moved {done - self.mark:.3f} rad in '
                          f'{self.window_s:.1f} s under drive: encoder or drive fault')
        self.mark_t, self.mark = t + self.window_s, done


def _ramp(t: float, remaining: float, full: float, ramp_s: float, slow_at: float) -> float:
    """Return the command fraction of ``full``: ramp up over ``ramp_s``, slow near the end."""
    return full * max(0.5, min(1.0, t / ramp_s, remaining / slow_at if slow_at > 0 else 1.0))


def straight(rig: MotorRig, distance_m: float, radius_m: float, speed: float,
             limit_s: float) -> tuple[float, float]:
    """Drive straight for about ``distance_m`` (by encoders, radius ``radius_m``).

    Both wheels get the same command plus a correction that keeps their angles equal (the
    robot keeps its heading whatever the amplifiers' mismatch).  Return the wheel angles
    travelled, measured after the robot stopped.
    """
    start = rig.wait_stopped()
    target = distance_m / radius_m                    # rad of wheel
    full = speed * fit.DAC_SPAN
    t0 = rig.clock()
    progress = _Progress('straight run', t0)
    s = start
    while True:
        dl, dr = s.left - start.left, s.right - start.right
        done = 0.5 * (dl + dr)
        if done >= target:
            break
        if rig.clock() - t0 > limit_s:
            raise Aborted(f'straight run: not there after {limit_s:.0f} s')
        progress.check(rig.clock(), done)
        x = _ramp(rig.clock() - t0, target - done, full, 0.5, 0.15 * target)
        corr = 40.0 * (dl - dr)                       # codes per rad of angle mismatch
        _, s = rig.command(_code(x - corr / 2), _code(x + corr / 2))
    end = rig.wait_stopped()
    return end.left - start.left, end.right - start.right


def turn(rig: MotorRig, heading_rad: float, radius_m: float, track_m: float, speed: float,
         limit_s: float) -> tuple[float, float]:
    """Turn in place by about ``heading_rad`` (CCW > 0) by encoders; return the wheel angles."""
    start = rig.wait_stopped()
    target = abs(heading_rad) * track_m / radius_m    # rad of (right - left) wheel angle
    sign = 1.0 if heading_rad > 0 else -1.0
    full = speed * fit.DAC_SPAN
    t0 = rig.clock()
    progress = _Progress('turn', t0)
    s = start
    while True:
        dl, dr = s.left - start.left, s.right - start.right
        done = sign * (dr - dl)
        if done >= target:
            break
        if rig.clock() - t0 > limit_s:
            raise Aborted(f'turn: not there after {limit_s:.0f} s')
        progress.check(rig.clock(), done)
        x = _ramp(rig.clock() - t0, target - done, full, 0.5, 0.15 * target)
        corr = 40.0 * 0.5 * (dl + dr)                 # keep the axle centre where it is
        _, s = rig.command(_code(-sign * x - corr), _code(sign * x - corr))
    end = rig.wait_stopped()
    if not math.isfinite(end.left + end.right):
        raise Aborted('turn: no encoder reading')
    return end.left - start.left, end.right - start.right


def lag(rig: MotorRig, speed: float, settle_s: float, measure_s: float,
        log: Callable[[str], None], deadband_codes: float = 0.0) -> list[fit.Plateau]:
    """Drive straight through plateaus at :data:`LAG_LEVELS` of ``speed`` (fraction of full scale).

    Both wheels get the same command (plus the straight run's heading correction, which is
    differential and so leaves the mean untouched).  Return each plateau's steady line of the
    *mean* wheel angle: the straight-line (common) mode, the body's mass on the wheels -- the
    plant the wheel-speed PI drives in, unlike the sweep's in-place turn, where the wheels move
    only the yaw inertia.  Consecutive plateaus time the lag (:func:`fit.tau_from_plateaus`).
    ``deadband_codes`` (the sweep's, when known) is added to every level, so that even the
    lowest plateau turns the wheels well clear of the dead band and its static friction.
    """
    if not 0 < speed <= MAX_SPEED:
        raise Aborted(f'lag run speed must be in (0, {MAX_SPEED}], got {speed!r}')
    start = rig.wait_stopped()
    s = start
    out = []
    for level in LAG_LEVELS:
        x = round(max(deadband_codes, 0.0) + level * speed * fit.DAC_SPAN)
        t0: float | None = None
        samples: list[Sample] = []
        while t0 is None or samples[-1].t - t0 < settle_s + measure_s:
            corr = 40.0 * ((s.left - start.left) - (s.right - start.right))
            t, s = rig.command(_code(x - corr / 2), _code(x + corr / 2))
            if t0 is None:
                t0 = t
            if not samples or s is not samples[-1]:
                samples.append(s)
            elif rig.clock() - t0 > settle_s + measure_s + 1.0:
                raise Aborted('lag run: no valid encoder reading')
        steady = [q for q in samples if q.t - t0 >= settle_s]
        pl = fit.fit_plateau(x, t0, [q.t for q in steady],
                             [0.5 * (q.left + q.right) for q in steady])
        out.append(pl)
        log(f'lag: code 512{x:+d} straight: mean wheel speed {pl.speed:+.3f} rad/s')
    rig.wait_stopped()
    return out


def brake(rig: MotorRig, speed: float, settle_s: float,
          stop_s: float = 1.5) -> tuple[float, list[Sample], list[Sample]]:
    """Drive straight at ``speed`` (fraction of full scale) for ``settle_s``, then command zero.

    The zero is code 512 with the amplifier enabled (what the guard's stop sends): the motors
    brake as hard as the amplifier and the tyres allow. Return the zero's write time and the
    readings before and after it (both wheels at rest at the end, else Aborted).
    """
    code = _code(speed * fit.DAC_SPAN)
    _, before = rig.run_for(code, code, settle_s)
    t_zero, after = rig.run_for(p.DAC_ZERO, p.DAC_ZERO, stop_s)
    rig.wait_stopped()
    return t_zero, before, after
