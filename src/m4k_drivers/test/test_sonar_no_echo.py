"""The US-100's no-echo width is a setting: open space stays "nothing in range" at each width.

The real gpio backend runs through the kernel stand-in against the US-100 model, whose
no-echo width is what the part would do; the timeout rule makes every width a fresh NO_ECHO
reading (the guard lets the robot drive), and the old fixed 60 ms wait shows the freeze.
"""

from __future__ import annotations

import io

import pytest

from m4k_drivers import config as dconfig
from m4k_drivers import registry
from m4k_drivers.abi.devices import Us100
from m4k_drivers.abi.kernel import GpioChip, KernelStandIn
from m4k_drivers.sonar import protocol as sp
from m4k_drivers.sonar.echowidth import measure_widths, report
from m4k_drivers.sonar.real import open_gpio_sonar

WIDTHS = [0.038, 0.07, 0.12]


def _section(**kw):
    return dconfig.validate_device('sonar', {'backend': 'gpio', 'chip': '/dev/gpiochip0',
                                             'trigger_line': 23, 'echo_line': 24} | kw,
                                   'devices.sonar')


@pytest.mark.parametrize('width', WIDTHS)
def test_open_space_reads_no_echo_at_each_width_with_the_timeout_rule(width):
    with KernelStandIn() as kernel:
        part = Us100(lambda: None, no_echo_s=width)
        kernel.gpio['/dev/gpiochip0'] = GpioChip(lines={23: part.trigger, 24: part.echo})
        h = registry.create('sonar', _section(no_echo_s=width, timeout_s=width + 0.01),
                            registry.BuildContext())
        h.configure()
        statuses = [h.read().value.status for _ in range(3)]
        h.shutdown()
        assert statuses == [sp.STATUS_NO_ECHO] * 3
        assert part.pings == 3


def test_a_long_no_echo_pulse_with_the_old_fixed_wait_is_a_timeout():
    with KernelStandIn() as kernel:
        part = Us100(lambda: None, no_echo_s=0.07)
        kernel.gpio['/dev/gpiochip0'] = GpioChip(lines={23: part.trigger, 24: part.echo})
        sonar = open_gpio_sonar('/dev/gpiochip0', 23, 24)
        try:
            assert sonar.measure(20.0, 0.06).status == sp.STATUS_TIMEOUT   # the freeze
        finally:
            sonar.close()


def test_a_timeout_shorter_than_the_no_echo_width_is_refused():
    with pytest.raises(ValueError, match='devices.sonar.timeout_s'):
        registry.create('sonar', _section(no_echo_s=0.07), registry.BuildContext())


@pytest.mark.parametrize('width', [0.038, 0.07])
def test_sonar_echo_width_measures_the_part_and_prints_the_settings(width):
    with KernelStandIn() as kernel:
        part = Us100(lambda: None, no_echo_s=width)
        kernel.gpio['/dev/gpiochip0'] = GpioChip(lines={23: part.trigger, 24: part.echo})
        sonar = open_gpio_sonar('/dev/gpiochip0', 23, 24)
        try:
            widths = measure_widths(sonar, 3, 0.3)
        finally:
            sonar.close()
    assert widths == [pytest.approx(width, abs=1e-6)] * 3     # edge stamps: exact
    out = io.StringIO()
    assert report(widths, out) == 0
    assert f'no_echo_s: {width:.3f}' in out.getvalue()


def test_sonar_echo_width_refuses_a_target_in_the_cone():
    out = io.StringIO()
    assert report([0.006, 0.006], out) == 1
    assert 'open space' in out.getvalue()
