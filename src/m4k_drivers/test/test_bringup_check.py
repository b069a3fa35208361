"""bringup_check end to end against the kernel-ABI models, and one planted fault per bus.

The real backends run unchanged through :class:`~m4k_drivers.abi.kernel.KernelStandIn`
(spidev, i2c-dev, GPIO v2) and a pty URG simulator; the verdicts come from the models' wires
(a MOSI->MISO jumper, the myAHRS+ registers, the monostable and relay contact, the US-100's
edges, the SCIP 2.0 stand-in).  The GPIO and amplifier steps use a 0.5 s monostable hold so a
slow machine cannot make a level late.
"""

from __future__ import annotations

import json

import pytest
import yaml

from m4k_drivers import config as dconfig
from m4k_drivers.abi.auxspi import AuxSpiController
from m4k_drivers.abi.devices import (
    ImuState,
    Line,
    Monostable,
    MyAhrsPlus,
    RelayReadback,
    SpiLoopback,
    Us100,
)
from m4k_drivers.abi.kernel import GpioChip, I2cAdapter, KernelStandIn, SpiNode
from m4k_drivers.bringup import cli
from m4k_drivers.lrf.sim import RectRoom, UrgSim

CHIP = '/dev/gpiochip0'
HOLD_S = 0.5
NO_ECHO_S = 0.0412          # the model part's width (a US-100's is to be measured, not 38 ms)


class _Bench:
    def __init__(self, kernel: KernelStandIn, urg_path: str) -> None:
        self.loops = {p: SpiLoopback() for p in ('/dev/spidev0.0', '/dev/spidev0.1',
                                                  '/dev/spidev1.0', '/dev/spidev1.1')}
        for path, loop in self.loops.items():
            dev = AuxSpiController(loop, 250e6) if path.startswith('/dev/spidev1') else loop
            kernel.spi[path] = SpiNode(dev)
        self.imu = MyAhrsPlus(ImuState)
        self.i2c = I2cAdapter({0x20: self.imu})
        kernel.i2c['/dev/i2c-1'] = self.i2c
        self.mono = Monostable(HOLD_S)
        self.back = RelayReadback(self.mono)
        self.us100 = Us100(lambda: None, no_echo_s=NO_ECHO_S)
        self.chip = GpioChip(lines={25: self.mono, 26: self.back, 23: self.us100.trigger,
                                    24: self.us100.echo})
        kernel.gpio[CHIP] = self.chip
        self.urg_path = urg_path

    def devices(self) -> dict:
        raw = {
            'motor': {'backend': 'real', 'left_dac': '/dev/spidev0.0',
                      'right_dac': '/dev/spidev0.1', 'left_enc': '/dev/spidev1.0',
                      'right_enc': '/dev/spidev1.1', 'heartbeat_hold_s': HOLD_S,
                      'estop_readback_line': 26},
            'imu': {'backend': 'real', 'bus': 1},
            'sonar': {'backend': 'gpio', 'chip': CHIP, 'trigger_line': 23, 'echo_line': 24,
                      'no_echo_s': NO_ECHO_S, 'timeout_s': NO_ECHO_S + 0.02},
            'lrf': {'backend': 'real', 'port': self.urg_path},
        }
        return raw


@pytest.fixture
def bench(tmp_path):
    urg = UrgSim(RectRoom(-2.0, -1.5, 2.0, 1.5), link_path=str(tmp_path / 'ttyACM0'),
                 scan_period=0.02)
    urg.start()
    k = KernelStandIn().install()
    try:
        yield _Bench(k, urg.path)
    finally:
        leaked = k.open_fds()
        k.uninstall()
        urg.stop()
    assert leaked == [], f'descriptors left open: {leaked}'


def _validated(raw: dict) -> dict:
    return {k: dconfig.validate_device(k, v, f'devices.{k}') for k, v in raw.items()}


def test_every_step_passes_end_to_end_and_the_report_says_so(bench, tmp_path, capsys):
    cfg = tmp_path / 'robot.yaml'
    cfg.write_text(yaml.safe_dump({'devices': bench.devices()}))
    report = tmp_path / 'bringup-check.json'
    assert cli.main(['--config', str(cfg), '--report', str(report)]) == 0
    doc = json.loads(report.read_text())
    assert doc['passed'] and doc['skipped'] == []
    names = [s['step'].split()[0] for s in doc['steps']]
    assert names == ['spi', 'spi', 'i2c', 'gpio', 'sonar', 'amplifier', 'urg']
    assert all(s['passed'] is True and s['expect'] and s['failure_means'] for s in doc['steps'])
    urg = doc['steps'][-1]['detail']
    assert 'PROT SCIP 2.0' in urg and 'URG-04LX' in urg
    assert f'no_echo_s: {NO_ECHO_S:.4f}' in doc['steps'][4]['detail']
    assert 'PASS' in capsys.readouterr().out


def _plant(bench: _Bench, bus: str) -> None:
    if bus == 'spi':
        bench.loops['/dev/spidev1.0'].open = True          # jumper missing on SPI1
    elif bus == 'i2c':
        bench.i2c.devices.clear()                            # nobody acknowledges 0x20
    elif bus == 'gpio':
        bench.back.relay_closed = False                      # e-stop pressed
    elif bus == 'sonar':
        bench.chip.lines[24] = Line()                        # ECHO not connected
    elif bus == 'amp':
        bench.back.stuck = True                              # enable held without heartbeat
    elif bus == 'urg':
        bench.urg_path += '-unplugged'


@pytest.mark.parametrize(('bus', 'step', 'message'), [
    ('spi', 'spi loopback /dev/spidev1.0', 'MISO reads constant 0x00: no jumper'),
    ('i2c', 'i2c 1 0x20 WHO_AM_I', 'no answer'),
    ('gpio', 'gpio heartbeat', 'asserted while toggling: False'),
    ('sonar', 'sonar no-echo width', 'gave no whole ECHO pulse'),
    ('amp', 'amplifier hold', 'read-back asserted in'),
    ('urg', 'urg', 'unplugged'),
])
def test_a_planted_fault_fails_its_own_step_with_a_clear_message(bench, bus, step, message):
    _plant(bench, bus)
    results = cli.run(_validated(bench.devices()), (bus,))
    assert results, f'no {bus} step ran'
    bad = [r for r in results if r.passed is False]
    assert [r.step.startswith(step) for r in bad] == [True]
    assert message in bad[0].detail and bad[0].failure_means


def test_a_sonar_width_other_than_the_configured_one_fails_and_names_the_setting(bench):
    raw = bench.devices()
    raw['sonar']['no_echo_s'] = 0.038                        # the HC-SR04's figure
    raw['sonar']['timeout_s'] = 0.06
    (r,) = cli.run(_validated(raw), ('sonar',))
    assert r.passed is False and f'no_echo_s: {NO_ECHO_S:.4f}' in r.detail


def test_unknown_step_is_refused_with_exit_2(capsys):
    assert cli.main(['--steps', 'spi,cam']) == 2
    assert "unknown ['cam']" in capsys.readouterr().err
