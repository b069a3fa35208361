"""The e-stop read-back as docs/real-robot.md wires it, through the GPIO v2 ABI model.

The read-back is the monostable's output 1Q after a dedicated safety-relay contact, at 3.3 V,
either straight (active high, pull-down) or through an inverting stage (active low, the line
requested with GPIO_V2_LINE_FLAG_ACTIVE_LOW).  The real backend (python-periphery) reads it
through :class:`~m4k_drivers.abi.kernel.KernelStandIn`; the ground truth is the wiring model
(:class:`~m4k_drivers.abi.devices.RelayReadback`: relay state, monostable, a stuck fault).

The monostable model holds for 60 s of real time after an edge, so its output never depends on
this machine's speed; the handler's own notion of "heartbeat silent" runs on a fake clock.
"""

from __future__ import annotations

from fakeclock import FakeClock
import pytest

from m4k_drivers.abi import uapi as u
from m4k_drivers.abi.devices import As5045, Mcp4911, Monostable, RelayReadback
from m4k_drivers.abi.kernel import GpioChip, KernelStandIn, SpiNode
from m4k_drivers.motors.handler import MotorHandler, READBACK_FAULT_SAMPLES, WheelCommand
from m4k_drivers.motors.real import open_real_bus, open_real_enable, open_real_readback
from m4k_rt.config import shipped_period_s
from m4k_rt.protocol import EncoderStatus

PERIOD_S = shipped_period_s('actuator')   # the actuator task's, as shipped

CHIP = '/dev/gpiochip0'
MS = 1_000_000
OPEN, FAULT = EncoderStatus.ESTOP_OPEN, EncoderStatus.READBACK_FAULT


class _Rig:
    def __init__(self, kernel: KernelStandIn, wired_low: bool, configured_low: bool) -> None:
        self.encs = [As5045(lambda: 100), As5045(lambda: 200)]
        for path, dev in zip(('/dev/spidev0.0', '/dev/spidev0.1', '/dev/spidev1.0',
                              '/dev/spidev1.1'), [Mcp4911(), Mcp4911()] + self.encs,
                             strict=True):
            kernel.spi[path] = SpiNode(dev)
        self.mono = Monostable(60.0)
        self.back = RelayReadback(self.mono, active_low=wired_low)
        kernel.gpio[CHIP] = GpioChip(lines={25: self.mono, 26: self.back})
        self.kernel = kernel
        self.clock = FakeClock()

        def opener():
            return open_real_bus('/dev/spidev0.0', '/dev/spidev0.1', '/dev/spidev1.0',
                                 '/dev/spidev1.1', enable=lambda: open_real_enable(CHIP, 25),
                                 readback=lambda: open_real_readback(CHIP, 26,
                                                                     active_low=configured_low))
        self.h = MotorHandler(opener, name='motor', clock=self.clock, enable_hold_s=0.05,
                              period_s=PERIOD_S)
        self.h.configure()
        self.h.activate()

    def command(self, n: int = 1) -> list[int]:
        out = []
        for _ in range(n):
            self.clock.t += 10 * MS
            self.h.write(WheelCommand(512, 512, 1))
            out.append(self.h.read().value.status)
        return out

    def silent(self, n: int, step_ms: int = 10) -> list[int]:
        out = []
        for _ in range(n):
            self.clock.t += step_ms * MS
            out.append(self.h.read().value.status)
        return out


@pytest.fixture
def rig():
    made = []

    def build(wired_low: bool, configured_low: bool | None = None):
        k = KernelStandIn().install()
        r = _Rig(k, wired_low, wired_low if configured_low is None else configured_low)
        made.append(r)
        return r
    yield build
    for r in made:
        r.h.shutdown()
        leaked = r.kernel.open_fds()
        r.kernel.uninstall()
        assert leaked == []


@pytest.mark.parametrize('low', [False, True])
def test_closed_relay_reads_no_estop_and_open_relay_reads_estop_open(rig, low):
    r = rig(low)
    assert all(not s & (OPEN | FAULT) for s in r.command(3))
    r.back.relay_closed = False                  # e-stop pressed: the relay drops
    assert all(s & OPEN and not s & FAULT for s in r.command(3))
    r.back.relay_closed = True                   # released and reset
    assert all(not s & (OPEN | FAULT) for s in r.command(3))


@pytest.mark.parametrize('low', [False, True])
def test_the_line_is_requested_with_the_configured_polarity(rig, low):
    r = rig(low)
    cfg = [d for p, c, d in r.kernel.log if c == 'line_config' and d['offsets'] == [26]]
    assert cfg and bool(cfg[0]['flags'][0] & u.GPIO_V2_LINE_FLAG_ACTIVE_LOW) == low
    assert cfg[0]['flags'][0] & u.GPIO_V2_LINE_FLAG_INPUT


@pytest.mark.parametrize('low', [False, True])
def test_no_heartbeat_and_nothing_asserted_is_neither_estop_nor_fault(rig, low):
    r = rig(low)
    r.mono.last_rise_ns = None                   # the monostable never fired
    assert all(not s & (OPEN | FAULT) for s in r.silent(READBACK_FAULT_SAMPLES + 2))


@pytest.mark.parametrize('low', [False, True])
def test_enable_held_with_the_heartbeat_silent_latches_a_readback_fault(rig, low):
    r = rig(low)
    r.command(2)
    r.back.stuck = True                          # 1Q stuck high through a bridged contact
    before = r.silent(READBACK_FAULT_SAMPLES, step_ms=100)[:READBACK_FAULT_SAMPLES - 1]
    assert all(not s & FAULT for s in before)    # not before N readings in a row
    assert all(s & FAULT and s & OPEN for s in r.silent(3))
    assert 'heartbeat silent' in str(r.h.last_exception)
    r.back.stuck = None                          # the fault goes away: the latch holds
    assert all(s & FAULT and s & OPEN for s in r.command(3))
    r.h.cleanup()                                # reconfigure clears it
    r.h.configure()
    r.h.activate()
    assert all(not s & (OPEN | FAULT) for s in r.command(3))


def test_a_read_back_configured_with_the_wrong_polarity_is_a_latched_fault(rig):
    r = rig(wired_low=True, configured_low=False)
    # Wired inverting, requested active high: the idle line reads asserted before any command.
    assert r.silent(READBACK_FAULT_SAMPLES)[-1] & FAULT


def test_within_two_holds_after_the_last_command_nothing_latches(rig):
    r = rig(False)
    r.command(2)
    # The monostable model still holds (60 s), the handler stopped commanding 60 ms ago: the
    # real hold may outlast the configured one, so no contradiction before two holds.
    assert all(not s & FAULT for s in r.silent(READBACK_FAULT_SAMPLES + 2, step_ms=12))
