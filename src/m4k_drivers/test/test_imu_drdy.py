"""IMU data-ready (myAHRS+ J3-1) on a GPIO v2 edge: the sample stamped at the edge, polling else.

The real backend (smbus2 + python-periphery) runs through the kernel-ABI stand-in; the
DATA READY pin model emits edges at chosen CLOCK_MONOTONIC times, which the stand-in delivers
as ``gpio_v2_line_event`` records stamped with the clock the line request asks for.  The
ground truth of the stamp is the time the test gave the edge.
"""

from __future__ import annotations

import time

import pytest

from m4k_drivers import config as dconfig
from m4k_drivers import registry
from m4k_drivers.abi import uapi as u
from m4k_drivers.abi.devices import DataReadyPin, ImuState, MyAhrsPlus
from m4k_drivers.abi.kernel import GpioChip, I2cAdapter, KernelStandIn
from m4k_drivers.handler import Status
from m4k_drivers.imu.service import serve
from m4k_rt.protocol import Kind

CHIP = '/dev/gpiochip0'
LINE = 6


class _Tx:
    def __init__(self) -> None:
        self.sent: list[tuple[int, tuple, int | None]] = []

    def send(self, kind, *fields, stamp_ns=None):
        self.sent.append((kind, fields, stamp_ns))
        return True


@pytest.fixture
def rig():
    k = KernelStandIn().install()
    pin = DataReadyPin()
    k.i2c['/dev/i2c-1'] = I2cAdapter({0x20: MyAhrsPlus(ImuState)})
    k.gpio[CHIP] = GpioChip(lines={LINE: pin})
    made = []

    def build(**extra):
        section = dconfig.validate_device(
            'imu', {'backend': 'real', 'bus': 1, 'drdy_line': LINE} | extra, 'devices.imu')
        h = registry.create('imu', section, registry.BuildContext())
        h.configure()
        h.activate()
        made.append(h)
        return h
    yield k, pin, build
    for h in made:
        h.shutdown()
    leaked = k.open_fds()
    k.uninstall()
    assert leaked == []


@pytest.mark.parametrize('edge', ['rising', 'falling'])
def test_the_sample_is_stamped_at_its_data_ready_edge(rig, edge):
    k, pin, build = rig
    h = build(drdy_edge=edge)
    t0 = time.monotonic_ns() - 5_000_000               # an edge 5 ms ago, already due
    pin.pulse(t0, width_ns=100_000)
    tx = _Tx()
    serve(h, None, tx)
    (kind, _, stamp), = tx.sent
    assert kind == Kind.IMU
    assert stamp == (t0 if edge == 'rising' else t0 + 100_000)
    assert h.drdy_misses == 0


def test_the_newest_of_several_pending_edges_stamps_the_sample(rig):
    k, pin, build = rig
    h = build()
    now = time.monotonic_ns()
    for back_ms in (30, 20, 10):
        pin.pulse(now - back_ms * 1_000_000)
    assert h.read().status == Status.OK
    assert h.sample_ns == now - 10_000_000


def test_the_line_asks_for_one_edge_on_the_monotonic_clock(rig):
    k, pin, build = rig
    build(drdy_edge='falling')
    flags = [d['flags'][0] for p, c, d in k.log
             if c == 'line_config' and d['offsets'] == [LINE]][-1]
    assert flags & u.GPIO_V2_LINE_FLAG_EDGE_FALLING
    assert not flags & u.GPIO_V2_LINE_FLAG_EDGE_RISING
    assert not flags & u.GPIO_V2_LINE_FLAG_EVENT_CLOCK_REALTIME


def test_no_edge_falls_back_to_polling_and_counts_it(rig):
    k, pin, build = rig
    h = build(drdy_timeout_s=0.01)
    tx = _Tx()
    serve(h, None, tx)                                   # nothing pulses the pin
    (kind, _, stamp), = tx.sent
    assert kind == Kind.IMU and stamp is None            # timed on arrival by the host
    assert h.drdy_misses == 1


def test_without_a_data_ready_line_the_driver_polls(rig):
    k, pin, build = rig
    h = build(drdy_line=None)
    assert h.drdy is None and h.read().status == Status.OK and h.sample_ns is None
