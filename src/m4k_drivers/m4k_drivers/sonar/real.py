"""US-100 transports: GPIO character device with kernel edge timestamps, or the IIO srf04 driver.

Backend A (``gpio``): TRIG is an output line, ECHO an input line requesting both edges; the
kernel timestamps each edge, so the pulse width does not depend on how fast this process wakes
up.  Which clock: GPIO cdev v2 stamps edges with CLOCK_MONOTONIC unless the request sets
``GPIO_V2_LINE_FLAG_EVENT_CLOCK_REALTIME`` -- and python-periphery 2.4 always sets it
(``gpio_cdev2.py``).  A wall-clock step (NTP on a board without RTC) between the two edges
would then stretch or shrink the pulse.  So :func:`open_gpio_sonar` reconfigures the echo line
with ``GPIO_V2_LINE_SET_CONFIG_IOCTL`` without that flag (monotonic edges).  Unless that
succeeded (``line_clock == 'monotonic'``), :class:`EdgeSonar` discards every reading across
which the realtime-minus-monotonic offset changed (status FAULT, counted in ``clock_steps``).
It does not trust a guess of the stamps' clock for that: on a board without RTC the wall clock
starts near the monotonic one, exactly when NTP is about to step it.

Backend B (``iio``): the kernel ``srf04`` driver does the timing; reading ``in_distance_raw``
triggers a measurement, times ``in_distance_scale`` gives metres.
"""

from __future__ import annotations

import errno
import os
import time
from typing import Any, Callable, Protocol

from m4k_drivers.handler import DeviceIOError, DriverError, wrap_os_error
from m4k_drivers.sonar import protocol as p

__all__ = ['EdgeSonar', 'GpioLike', 'IioSonar', 'OutputLike', 'open_gpio_sonar',
           'open_simbus_sonar']


class OutputLike(Protocol):
    """The python-periphery GPIO methods the trigger line needs."""

    def write(self, value: bool) -> None:
        """Drive an output line."""

    def close(self) -> None:
        """Release the line."""


class GpioLike(Protocol):
    """The python-periphery GPIO methods the echo (edge event) line needs."""

    def poll(self, timeout: float | None = None) -> bool:
        """Wait for an edge event."""

    def read_event(self) -> Any:
        """Return the next edge event (edge, timestamp)."""

    def close(self) -> None:
        """Release the line."""


def _busy_wait(seconds: float) -> None:
    # time.sleep(10e-6) may return early on some kernels' timer slack; spinning is certain.
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass


# Largest change of (CLOCK_REALTIME - CLOCK_MONOTONIC) across one ping that is still read
# jitter, not a clock step: 20 us = 3.4 mm of range.
CLOCK_STEP_TOLERANCE_NS = 20_000


class EdgeSonar:
    """Pulse-mode measurement over a trigger line and an edge-timestamping echo line."""

    def __init__(self, trigger: OutputLike, echo: GpioLike, where: str, *,
                 trigger_s: float = 2 * p.TRIGGER_S,
                 hold: Callable[[float], None] = _busy_wait,
                 clock: Callable[[], int] = time.monotonic_ns,
                 realtime: Callable[[], int] = time.time_ns,
                 line_clock: str = 'unknown') -> None:
        if trigger_s < p.TRIGGER_S:
            raise ValueError(f'trigger pulse must be >= 10 us, got {trigger_s!r} s')
        self.trigger, self.echo, self.where = trigger, echo, where
        self.trigger_s = trigger_s
        self._hold = hold
        self._clock = clock
        self._realtime = realtime
        self.clock_steps = 0          # pulses discarded because the wall clock stepped
        self.line_clock = line_clock  # 'monotonic' once the edge clock was requested as such
        self.edge_clock = 'unknown'   # diagnostics: the clock the last stamps looked like

    def _offset(self) -> int:
        """Return CLOCK_REALTIME - CLOCK_MONOTONIC (ns), read as tightly as Python can."""
        a = self._clock()
        r = self._realtime()
        b = self._clock()
        return r - (a + b) // 2

    def edges(self, timeout_s: float = p.ECHO_TIMEOUT_S) -> list[p.Edge]:
        """Trigger once and collect echo edges until a falling edge or the timeout."""
        try:
            while self.echo.poll(0.0):          # drop edges left from an earlier ping
                self.echo.read_event()
            self.trigger.write(True)
            self._hold(self.trigger_s)
            self.trigger.write(False)
            deadline = self._clock() + int(timeout_s * 1e9)
            out: list[p.Edge] = []
            while True:
                remaining = (deadline - self._clock()) * 1e-9
                # Past the deadline, still take the edges the kernel queued before it: this
                # process may wake late on a busy machine, the stamps say when they happened.
                if not self.echo.poll(max(remaining, 0.0)):
                    return self._until(out, deadline)
                ev = self.echo.read_event()
                out.append(p.Edge(ev.edge, ev.timestamp))
                if ev.edge == 'falling' and any(e.edge == 'rising' for e in out):
                    return self._until(out, deadline)
        except OSError as exc:
            raise wrap_os_error(exc, self.where, 'ping') from exc

    def _until(self, edges: list[p.Edge], deadline: int) -> list[p.Edge]:
        """Drop edges stamped after the deadline when the stamps are on our clock.

        Then whether an echo counts depends on when its edges happened, never on when this
        process got round to reading them (with realtime stamps the deadline cannot be
        compared, and the wait decides as before).
        """
        if self.line_clock != 'monotonic':
            return edges
        return [e for e in edges if e.timestamp <= deadline]

    def measure(self, temp_c: float = 20.0, timeout_s: float = p.ECHO_TIMEOUT_S,
                ) -> p.SonarReading:
        """Ping once and convert the echo pulse to a reading (FAULT if the clock stepped)."""
        off0 = self._offset()
        edges = self.edges(timeout_s)
        off1 = self._offset()
        if edges:
            # Which clock stamped the edges: the one whose "now" they are nearer to.
            now_mono = self._clock()
            now_real = now_mono + off1
            ts = edges[-1].timestamp
            self.edge_clock = ('monotonic' if abs(now_mono - ts) <= abs(now_real - ts)
                               else 'realtime')
            stepped = abs(off1 - off0) > CLOCK_STEP_TOLERANCE_NS
            if stepped and self.line_clock != 'monotonic':
                self.clock_steps += 1
                return p.SonarReading(0.0, p.STATUS_FAULT)
        return p.pulse_to_range(p.edges_to_width(edges), temp_c)

    def close(self) -> None:
        """Release both lines."""
        for line in (self.trigger, self.echo):
            try:
                line.close()
            except OSError:
                pass


def request_monotonic_edges(gpio: Any, *, rising: bool = True, falling: bool = True) -> bool:
    """Re-request the edge clock of a periphery cdev v2 input line as CLOCK_MONOTONIC.

    GPIO_V2_LINE_SET_CONFIG_IOCTL with INPUT | the chosen EDGE_RISING / EDGE_FALLING and no
    EVENT_CLOCK_REALTIME flag (Linux uapi ``gpio.h``: the default event clock is
    CLOCK_MONOTONIC).  Returns False when that is not possible (cdev v1, sysfs GPIO, an old
    kernel): :meth:`EdgeSonar.measure` then guards against clock steps instead.
    """
    import fcntl
    try:
        from periphery import gpio_cdev2 as c2
        cls = c2.Cdev2GPIO
        fd = gpio._line_fd
        config = c2._CGpioV2LineConfig()
        config.flags = (cls._GPIO_V2_LINE_FLAG_INPUT
                        | (cls._GPIO_V2_LINE_FLAG_EDGE_RISING if rising else 0)
                        | (cls._GPIO_V2_LINE_FLAG_EDGE_FALLING if falling else 0))
        config.num_attrs = 0
        fcntl.ioctl(fd, cls._GPIO_V2_LINE_SET_CONFIG_IOCTL, config)
    except (AttributeError, ImportError, OSError, TypeError):
        return False
    return True


def open_gpio_sonar(chip: str, trigger_line: int, echo_line: int) -> EdgeSonar:
    """Request TRIG (out, low) and ECHO (in, both edges, monotonic stamps) on a gpiochip."""
    from periphery import GPIO
    try:
        trigger = GPIO(chip, trigger_line, 'low')
    except OSError as exc:
        raise wrap_os_error(exc, f'{chip} line {trigger_line}') from exc
    try:
        echo = GPIO(chip, echo_line, 'in', edge='both')
    except OSError as exc:
        trigger.close()
        raise wrap_os_error(exc, f'{chip} line {echo_line}') from exc
    sonar = EdgeSonar(trigger, echo, f'{chip} lines {trigger_line}/{echo_line}')
    sonar.line_clock = 'monotonic' if request_monotonic_edges(echo) else 'unknown'
    return sonar


def open_simbus_sonar(runtime_dir: str, chip: str, trigger_line: int,
                      echo_line: int) -> EdgeSonar:
    """Request TRIG and ECHO of the simulated US-100 on ``sim_robot``'s sim-bus GPIO."""
    from m4k_drivers.simbus import GpioClient
    where = f'sim-bus:{chip}'
    try:
        trigger = GpioClient(runtime_dir, chip, trigger_line, 'low')
    except OSError as exc:
        raise wrap_os_error(exc, f'{where} line {trigger_line}') from exc
    try:
        echo = GpioClient(runtime_dir, chip, echo_line, 'in', edge='both')
    except OSError as exc:
        trigger.close()
        raise wrap_os_error(exc, f'{where} line {echo_line}') from exc
    # The sim-bus line was requested with a CLOCK_MONOTONIC edge clock (docs/sim-bus.md).
    return EdgeSonar(trigger, echo, f'{where} lines {trigger_line}/{echo_line}',
                     line_clock='monotonic')


class IioSonar:
    """The kernel srf04 IIO driver: ``in_distance_raw`` * ``in_distance_scale`` = metres."""

    def __init__(self, device_dir: str) -> None:
        self.raw_path = os.path.join(device_dir, 'in_distance_raw')
        scale_path = os.path.join(device_dir, 'in_distance_scale')
        try:
            with open(scale_path, encoding='ascii') as fh:
                self.scale = float(fh.read().strip())
            self.fd = os.open(self.raw_path, os.O_RDONLY)
        except OSError as exc:
            raise wrap_os_error(exc, exc.filename or device_dir) from exc
        except ValueError as exc:
            raise DeviceIOError(f'{scale_path}: not a number: {exc}') from exc

    def measure(self, temp_c: float = 20.0, timeout_s: float = p.ECHO_TIMEOUT_S,
                ) -> p.SonarReading:
        """Read one distance (the driver triggers and times it; temp is its business)."""
        try:
            text = os.pread(self.fd, 32, 0)
        except OSError as exc:
            if exc.errno in (errno.ETIMEDOUT, errno.EIO):
                return p.SonarReading(0.0, p.STATUS_TIMEOUT)
            raise wrap_os_error(exc, self.raw_path, 'read') from exc
        try:
            rng = int(text.strip()) * self.scale
        except ValueError as exc:
            raise DriverError(f'{self.raw_path}: not an integer: {text!r}') from exc
        if rng < p.MIN_RANGE_M:
            return p.SonarReading(rng, p.STATUS_FAULT)     # shorter than any echo: impossible
        if rng > p.MAX_RANGE_M:
            return p.SonarReading(rng, p.STATUS_NO_ECHO)   # the no-echo pulse, timed by the kernel
        return p.SonarReading(rng, p.STATUS_OK)

    def close(self) -> None:
        """Close the attribute file."""
        try:
            os.close(self.fd)
        except OSError:
            pass
