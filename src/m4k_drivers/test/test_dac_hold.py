"""Before first power: the DAC hold (``--dac CODE``) and the amplifier settings' fit check.

The hold runs the real motor backend through the kernel stand-in; ground truth is the MCP4911
models' output registers and the enable monostable's input (no rising edge = enable off).
"""

from __future__ import annotations

import io
import threading

import pytest

from m4k_drivers import config as dconfig
from m4k_drivers import registry
from m4k_drivers.abi.devices import As5045, Mcp4911, Monostable
from m4k_drivers.abi.kernel import GpioChip, KernelStandIn, SpiNode
from m4k_drivers.motors.amplifier import check_amplifier
from m4k_drivers.motors.jog import check_jog, JogError, run_dac_hold

SECTION = {'backend': 'real', 'left_dac': '/dev/spidev0.0', 'right_dac': '/dev/spidev0.1',
           'left_enc': '/dev/spidev1.0', 'right_enc': '/dev/spidev1.1'}


class _Probe(threading.Event):
    """The hold's wait: look at the hardware while the code is held, then end the hold."""

    def __init__(self, look):
        super().__init__()
        self.look = look
        self.seen = None

    def wait(self, timeout=None):
        self.seen = self.look()
        return True


def _rig(kernel, heartbeat=True):
    dacs = [Mcp4911(), Mcp4911()]
    enable = Monostable(0.05)
    for path, dev in zip(('/dev/spidev0.0', '/dev/spidev0.1', '/dev/spidev1.0',
                          '/dev/spidev1.1'), dacs + [As5045(lambda: 100), As5045(lambda: 200)],
                         strict=True):
        kernel.spi[path] = SpiNode(dev)
    kernel.gpio['/dev/gpiochip0'] = GpioChip(lines={25: enable})
    section = dconfig.validate_device('motor', SECTION | {'heartbeat': heartbeat},
                                      'devices.motor')
    return dacs, enable, registry.create('motor', section, registry.BuildContext())


@pytest.mark.parametrize('code', [0, 512, 1023])
def test_dac_hold_puts_the_code_on_both_dacs_with_the_enable_never_raised(code):
    with KernelStandIn() as kernel:
        dacs, enable, handler = _rig(kernel)
        probe = _Probe(lambda: ([d.code for d in dacs], [round(d.volts, 4) for d in dacs],
                                enable.rising_edges))
        out = io.StringIO()
        rc = run_dac_hold(handler, code, 30.0, probe, out=out, assume_yes=True)
        assert rc == 0, out.getvalue()
        codes, volts, edges = probe.seen
        assert codes == [code, code] and edges == 0
        assert volts == [round(3.3 * code / 1024, 4)] * 2
        assert f'expect {3.3 * code / 1024:.3f} V' in out.getvalue()
        assert [d.code for d in dacs] == [512, 512]      # back at zero afterwards
        assert enable.rising_edges == 0 and kernel.open_fds() == []


def test_dac_hold_is_refused_with_the_enable_strapped_on():
    with KernelStandIn() as kernel:
        dacs, _, handler = _rig(kernel, heartbeat=False)
        out = io.StringIO()
        assert run_dac_hold(handler, 800, 1.0, _Probe(lambda: None), out=out,
                            assume_yes=True) == 1
        assert 'refused' in out.getvalue()
        assert [d.code for d in dacs] == [512, 512]


def test_dac_hold_checks_its_arguments_before_opening_anything():
    with pytest.raises(JogError, match='integer 0..1023'):
        check_jog('dac', 1024.0, 10.0)
    with pytest.raises(JogError, match='integer 0..1023'):
        check_jog('dac', 511.5, 10.0)
    with pytest.raises(JogError, match='600'):
        check_jog('dac', 512.0, 601.0)


def _amp(**kw):
    return dconfig.validate_device('motor', SECTION | kw, 'devices.motor')


def test_amplifier_that_fits_the_dac_is_accepted():
    check_amplifier(_amp())
    check_amplifier(_amp(amp_input_range_v=[0.0, 5.0], amp_zero_v=1.70))   # 15 codes of trim


@pytest.mark.parametrize('kw, field', [
    ({'amp_input_range_v': [-10.0, 10.0], 'amp_zero_v': 0.0}, 'amp_zero_v'),
    ({'amp_input_range_v': [0.0, 5.0], 'amp_zero_v': 2.5}, 'amp_zero_v'),
    ({'amp_input_range_v': [0.0, 2.5], 'amp_zero_v': 1.25}, 'amp_input_range_v'),
    ({'amp_input_range_v': [0.5, 3.3]}, 'amp_input_range_v'),
])
def test_amplifier_that_does_not_fit_the_dac_is_refused_naming_the_field(kw, field):
    with pytest.raises(ValueError, match=f'devices.motor.{field}'):
        check_amplifier(_amp(**kw))
    with pytest.raises(ValueError, match=f'devices.motor.{field}'):
        registry.create('motor', _amp(**kw), registry.BuildContext())


def test_amplifier_settings_are_validated_field_by_field():
    with pytest.raises(dconfig.ConfigError, match='amp_enable'):
        _amp(amp_enable='low')
    with pytest.raises(dconfig.ConfigError, match='amp_current_limit_a'):
        _amp(amp_current_limit_a=0.0)
