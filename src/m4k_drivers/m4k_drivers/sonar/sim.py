"""Simulated US-100 at the GPIO boundary: a fake TRIG line and a fake ECHO line with edge times.

On the falling edge of a trigger pulse that was high >= 10 us, the sensor "fires": the range is
the nearest surface in a 15 deg cone (the US-100 beam) cast in the world from the sensor's
mount, plus Gaussian noise; the echo rises after the 8-cycle 40 kHz burst (0.2 ms) and falls
2 * range / c later.  Nothing within 4.5 m gives the long no-echo pulse (``no_echo_s``,
default 38 ms, the HC-SR04's figure: a real US-100's is measured).  The same
:class:`~m4k_drivers.sonar.real.EdgeSonar` code then turns those edges into a range.
"""

from __future__ import annotations

import math
import time
from typing import Callable, Sequence

from m4k_drivers.sonar import protocol as p
from m4k_drivers.sonar.real import EdgeSonar
from m4k_drivers.world import World

__all__ = ['FakeEchoLine', 'FakeTriggerLine', 'open_sim_sonar']

BURST_S = 8 / 40_000.0
NO_ECHO_PULSE_S = 0.038


class FakeEchoLine:
    """An input line that reports scheduled edges once the clock has reached them."""

    def __init__(self, clock: Callable[[], int], sleep: Callable[[float], None]) -> None:
        self.clock = clock
        self.sleep = sleep
        self.pending: list[p.Edge] = []
        self.closed = False

    def poll(self, timeout: float | None = None) -> bool:
        """Wait (at most ``timeout`` s) until the next scheduled edge has happened."""
        if not self.pending:
            if timeout:
                self.sleep(timeout)
            return False
        wait = (self.pending[0].timestamp - self.clock()) * 1e-9
        if timeout is not None and wait > timeout:
            self.sleep(timeout)
            return False
        if wait > 0:
            self.sleep(wait)
        return True

    def read_event(self) -> p.Edge:
        """Return the next edge."""
        return self.pending.pop(0)

    def close(self) -> None:
        """Mark closed."""
        self.closed = True


class FakeTriggerLine:
    """The TRIG output: a >= 10 us high pulse makes the simulated sensor fire."""

    def __init__(self, world: World, echo: FakeEchoLine, mount: Sequence[float],
                 fov_deg: float = 15.0, noise_sd: float = 0.003, temp_c: float = 20.0,
                 height: float = 0.0, no_echo_s: float = NO_ECHO_PULSE_S) -> None:
        self.world, self.echo, self.mount = world, echo, tuple(mount)
        self.no_echo_s = no_echo_s      # the part's width with nothing in range
        self.height = float(height)     # m above the floor of the transducers
        self.half_angle = math.radians(fov_deg) / 2.0
        self.noise_sd, self.temp_c = noise_sd, temp_c
        self.rng = world.rng('sonar')
        self.high_since: int | None = None
        self.fired = 0
        self.short_triggers = 0
        self.dead = False          # fault injection: the sensor never answers
        self.closed = False

    def write(self, value: bool) -> None:
        """Drive the line; a falling edge after >= 10 us high fires one measurement."""
        now = self.world.now()
        if value:
            self.high_since = now
            return
        if self.high_since is None:
            return
        width = (now - self.high_since) * 1e-9
        self.high_since = None
        if width < p.TRIGGER_S:
            self.short_triggers += 1
            return
        self.fired += 1
        if self.dead:
            return
        pose = self.world.sensor_pose(self.mount)
        dist = self.world.sonar_cast((pose.x, pose.y), pose.yaw, self.half_angle, p.MAX_RANGE_M,
                                     self.height)
        if math.isfinite(dist):
            dist = max(0.0, dist + float(self.rng.normal(0.0, self.noise_sd)))
            pulse = p.range_to_pulse(dist, self.temp_c)
        else:
            pulse = self.no_echo_s
        rise = now + round(BURST_S * 1e9)
        self.echo.pending += [p.Edge('rising', rise), p.Edge('falling', rise + round(pulse * 1e9))]

    def close(self) -> None:
        """Mark closed."""
        self.closed = True


def open_sim_sonar(world: World, mount: Sequence[float] = (0.225, 0.0, 0.0), *,
                   noise_sd: float = 0.003, fov_deg: float = 15.0,
                   sleep: Callable[[float], None] = time.sleep) -> EdgeSonar:
    """Return an EdgeSonar wired to simulated lines on ``world`` (``sleep`` on its clock)."""
    echo = FakeEchoLine(world.clock, sleep)
    trig = FakeTriggerLine(world, echo, mount, fov_deg, noise_sd)
    # The simulated echo line stamps edges with the world's (monotonic) clock: the model of a
    # line whose event clock was requested as CLOCK_MONOTONIC.
    return EdgeSonar(trig, echo, 'sim:sonar', hold=sleep, clock=world.clock,
                     line_clock='monotonic')
