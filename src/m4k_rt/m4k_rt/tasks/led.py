"""LED task body (20 ms): show the robot state on the LED strip unless the bridge overrides it.

Ports: ``led`` (driver host: LED out, DEVICE_STATUS in) and ``led_in`` (bridge: LED override
in, LED shown out). An LED datagram from the bridge with brightness 0 and source 0 releases
the override; any other sets it (kept until released). Each cycle the body sends the colour to
the handler (every cycle, so a restarted handler shows the right colour within 20 ms and the
fault blink has a clock) and echoes the shown colour to the bridge when it changes and at
least once a second.

State colours (from the shared state; fault wins, then obstacle, braking, driving, idle):

=========  ===================  ==========
state      colour (r, g, b)     brightness
=========  ===================  ==========
idle       green (0, 255, 0)    64
driving    blue (0, 0, 255)     160
braking    amber (255, 140, 0)  200
obstacle   red (255, 0, 0)      255
fault      red, blinking 2 Hz   255 / 0
=========  ===================  ==========

Fault means the actuator reports MODE_FAULT (motor stale) or MODE_E_STOP (e-stop latched), or
any device reported an error level (DEVICE_STATUS level >= LEVEL_ERROR).
"""

from __future__ import annotations

import time
from typing import Any, Callable, Mapping

from m4k_rt.config import TaskConfig
from m4k_rt.control.base import (
    MODE_BRAKING,
    MODE_DRIVING,
    MODE_E_STOP,
    MODE_FAULT,
    MODE_OBSTACLE,
)
from m4k_rt.protocol import Kind, LedSource, LEVEL_ERROR
from m4k_rt.tasks.interfaces import CycleContext, RtPort
from m4k_rt.tasks.portio import PortReader, PortWriter
from m4k_rt.tasks.state import robot_state, RobotState

__all__ = ['LedBody', 'make_led', 'STATE_COLOURS']

IDLE = (0, 255, 0, 64)
DRIVING = (0, 0, 255, 160)
BRAKING = (255, 140, 0, 200)
OBSTACLE = (255, 0, 0, 255)
FAULT_ON = (255, 0, 0, 255)
FAULT_OFF = (255, 0, 0, 0)
STATE_COLOURS = {'idle': IDLE, 'driving': DRIVING, 'braking': BRAKING, 'obstacle': OBSTACLE,
                 'fault': FAULT_ON}
SOURCE_STATE = int(LedSource.STATE)  # plain ints for the loop
SOURCE_OVERRIDE = int(LedSource.OVERRIDE)
BLINK_HALF_PERIOD_NS = 250_000_000
ECHO_EVERY_NS = 1_000_000_000

_LED = Kind.LED
_DEVICE_STATUS = Kind.DEVICE_STATUS
_HOST_DROPS = Kind.HOST_DROPS


class LedBody:
    """Per-cycle body of the LED task."""

    def __init__(self, dev_sock: RtPort, bridge_sock: RtPort, state: RobotState,
                 clock: Callable[[], int] = time.monotonic_ns) -> None:
        self.state = state
        self._dev_in = PortReader(dev_sock, 256)
        self._dev_out = PortWriter(dev_sock)
        self._bridge_in = PortReader(bridge_sock, 256)
        self._bridge_out = PortWriter(bridge_sock)
        self._clock = clock
        self.override: tuple[int, int, int, int] | None = None
        self.shown: tuple[int, int, int, int] = IDLE
        self.source = SOURCE_STATE
        self._echoed: tuple[int, int, int, int] | None = None   # colour last echoed
        self._echoed_source = SOURCE_STATE
        self._echo_ns = 0
        self.cycles = 0
        self.overrides = 0
        self.unexpected = 0

    @property
    def counters(self) -> Mapping[str, int]:
        """Return a snapshot of the body's counters (NRT use)."""
        return {'cycles': self.cycles, 'overrides': self.overrides,
                'unexpected': self.unexpected, 'sent': self._dev_out.sent,
                'echoed': self._bridge_out.sent}

    def state_colour(self, now_ns: int) -> tuple[int, int, int, int]:
        """Return the colour showing the robot state at ``now_ns``."""
        s = self.state
        mode = s.mode
        if mode in (MODE_FAULT, MODE_E_STOP) or s.worst_device_level() >= LEVEL_ERROR:
            return FAULT_ON if (now_ns // BLINK_HALF_PERIOD_NS) % 2 == 0 else FAULT_OFF
        if mode == MODE_OBSTACLE:
            return OBSTACLE
        if mode == MODE_BRAKING:
            return BRAKING
        if mode == MODE_DRIVING:
            return DRIVING
        return IDLE

    def __call__(self, ctx: CycleContext | None = None) -> None:
        """Run one LED cycle."""
        now = ctx.t_start if ctx is not None else self._clock()
        reader = self._bridge_in
        reader.start_cycle()
        while (got := reader.next()) is not None:
            hdr, msg = got
            if hdr.kind != _LED:
                self.unexpected += 1
            elif msg.brightness == 0 and msg.source == SOURCE_STATE:
                self.override = None
            else:
                self.override = (msg.r, msg.g, msg.b, msg.brightness)
                self.overrides += 1
        reader = self._dev_in
        reader.start_cycle()
        while (got := reader.next()) is not None:
            if got[0].kind == _DEVICE_STATUS:
                self.state.record_device_status('led', got[1], now)
            elif got[0].kind == _HOST_DROPS:
                self.state.record_host_drops('led', got[1], now)
            else:
                self.unexpected += 1
        override = self.override
        if override is not None:
            colour = override
            source = SOURCE_OVERRIDE
        else:
            colour = self.state_colour(now)
            source = SOURCE_STATE
        self.shown = colour
        self.source = source
        self.state.led_override = override is not None
        r, g, b, brightness = colour
        self._dev_out.send(_LED, now, r, g, b, brightness, source)
        if (self._echoed != colour or self._echoed_source != source
                or now - self._echo_ns >= ECHO_EVERY_NS):
            if self._bridge_out.send(_LED, now, r, g, b, brightness, source):
                self._echoed = colour      # an immutable tuple: kept, not copied
                self._echoed_source = source
                self._echo_ns = now
        self.cycles += 1


def make_led(task: TaskConfig, ports: Mapping[str, RtPort], shared: Any) -> LedBody:
    """Build the LED body from its ``led``/``led_in`` ports."""
    return LedBody(ports['led'], ports['led_in'], robot_state(shared))
