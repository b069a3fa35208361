"""LED class and sysfs-PWM backends against temporary sysfs trees that follow the kernel's rules.

The PWM tree is written through :class:`FakePwmKernel`, which plays drivers/pwm/sysfs.c: a write
is parsed whole, applied to the channel's state and refused like the kernel refuses it
(duty_cycle > period: EINVAL, on a duty_cycle write and on a period write; polarity change while
enabled: EBUSY; any apply while the period is 0 -- enable 0 or 1, a duty cycle, a polarity --
EINVAL, as pwm_apply_state() of the strict kernels; export creates the channel directory).
"""

import errno
import os

import pytest

from m4k_drivers import config as dconfig
from m4k_drivers.handler import DeviceIdentityError, DeviceIOError, DeviceNotFoundError
from m4k_drivers.led import protocol as p
from m4k_drivers.led.handler import LedHandler
from m4k_drivers.led.real import LedClassOutput, LedClassRgbOutput, PwmOutput


class FakePwmKernel:
    """The sysfs PWM attribute semantics over real files in ``root``."""

    def __init__(self, root, chip=0, npwm=3):
        self.root = root
        self.chip_dir = root / f'pwmchip{chip}'
        self.chip_dir.mkdir(parents=True)
        (self.chip_dir / 'npwm').write_text(f'{npwm}\n')
        (self.chip_dir / 'export').write_text('')
        self.npwm = npwm
        self.writes = []
        self.refused = []

    def export(self, channel, period=0, duty=0, enable=0, polarity='normal'):
        d = self.chip_dir / f'pwm{channel}'
        d.mkdir()
        for attr, value in (('period', period), ('duty_cycle', duty), ('enable', enable),
                            ('polarity', polarity)):
            (d / attr).write_text(f'{value}\n')

    def state(self, channel):
        d = self.chip_dir / f'pwm{channel}'
        return {a: (d / a).read_text().strip() for a in ('period', 'duty_cycle', 'enable',
                                                          'polarity')}

    def _refuse(self, path, err):
        self.refused.append((os.path.basename(path), err))
        raise OSError(err, os.strerror(err), path)

    def write(self, path, text):
        self.writes.append((os.path.relpath(path, self.root), text.strip()))
        value = text.strip()
        d, attr = os.path.split(path)
        if attr == 'export':
            ch = int(value)
            if not 0 <= ch < self.npwm:
                self._refuse(path, errno.EINVAL)
            if os.path.isdir(os.path.join(d, f'pwm{ch}')):
                self._refuse(path, errno.EBUSY)
            self.export(ch)
            return
        st = {a: open(os.path.join(d, a)).read().strip()
              for a in ('period', 'duty_cycle', 'enable', 'polarity')}
        period, duty, enabled = int(st['period']), int(st['duty_cycle']), st['enable'] == '1'
        if attr in ('period', 'duty_cycle'):
            try:
                n = int(value)
            except ValueError:
                self._refuse(path, errno.EINVAL)
            if n < 0:
                self._refuse(path, errno.EINVAL)
            if attr == 'period':
                period = n
            else:
                duty = n
            if duty > period or period == 0:           # pwm_apply_state(): duty <= period
                self._refuse(path, errno.EINVAL)
        elif attr == 'enable':
            if value not in ('0', '1'):
                self._refuse(path, errno.EINVAL)
            if period == 0:                            # pwm_apply_state(): !period
                self._refuse(path, errno.EINVAL)
        elif attr == 'polarity':
            if value not in ('normal', 'inversed'):
                self._refuse(path, errno.EINVAL)
            if period == 0:
                self._refuse(path, errno.EINVAL)
            if enabled and value != st['polarity']:
                self._refuse(path, errno.EBUSY)
        else:
            self._refuse(path, errno.EACCES)
        with open(path, 'w') as fh:
            fh.write(value + '\n')


@pytest.fixture
def kernel(tmp_path):
    return FakePwmKernel(tmp_path)


def _pwm(kernel, **kw):
    return PwmOutput(0, [0, 1, 2], root=str(kernel.root), write=kernel.write, **kw)


def test_fake_kernel_enforces_the_rules(kernel):
    kernel.export(0, period=1000, duty=500, enable=1)
    path = str(kernel.chip_dir / 'pwm0')
    with pytest.raises(OSError) as info:
        kernel.write(path + '/duty_cycle', '2000\n')
    assert info.value.errno == errno.EINVAL
    with pytest.raises(OSError):
        kernel.write(path + '/period', '400\n')            # below the present duty
    with pytest.raises(OSError) as info:
        kernel.write(path + '/polarity', 'inversed\n')
    assert info.value.errno == errno.EBUSY


def test_pwm_exports_configures_and_shows_colours(kernel):
    out = _pwm(kernel, period_ns=1_000_000)
    for ch in range(3):
        assert kernel.state(ch) == {'period': '1000000', 'duty_cycle': '0', 'enable': '1',
                                    'polarity': 'normal'}
    out.show(p.LedColor(255, 128, 0, 255))
    assert [kernel.state(ch)['duty_cycle'] for ch in range(3)] == ['1000000', '501961', '0']
    out.close()
    assert all(kernel.state(ch)['enable'] == '0' and kernel.state(ch)['duty_cycle'] == '0'
               for ch in range(3))
    assert kernel.refused == []


def test_pwm_shorter_period_after_a_long_duty_is_accepted(kernel):
    # A previous user left a 10 ms period at 8 ms duty, enabled: setting a 1 ms period first
    # (the old order) is EINVAL; duty 0 first makes every step valid.
    for ch in range(3):
        kernel.export(ch, period=10_000_000, duty=8_000_000, enable=1)
    out = _pwm(kernel, period_ns=1_000_000)
    assert kernel.refused == []
    assert kernel.state(0)['period'] == '1000000'
    first = [w for w in kernel.writes if w[0].startswith('pwmchip0/pwm0/')]
    assert [a.rsplit('/', 1)[1] for a, _ in first][:3] == ['enable', 'duty_cycle', 'period']
    out.close()


def test_pwm_polarity_inversed_written_while_disabled(kernel):
    for ch in range(3):
        kernel.export(ch, period=1000, duty=0, enable=1)
    out = _pwm(kernel, period_ns=2000, polarity='inversed')
    assert all(kernel.state(ch)['polarity'] == 'inversed' for ch in range(3))
    assert kernel.refused == []
    out.close()


def test_pwm_bad_polarity_and_period_are_clear_errors(kernel):
    with pytest.raises(ValueError, match="polarity must be one of .*'upside'"):
        _pwm(kernel, polarity='upside')
    with pytest.raises(ValueError, match='period_ns must be a positive int, got 0'):
        _pwm(kernel, period_ns=0)


def test_pwm_missing_chip_names_path(tmp_path):
    with pytest.raises(DeviceNotFoundError, match=r'pwmchip4: No such file or directory'):
        PwmOutput(4, [0, 1, 2], root=str(tmp_path))


def test_pwm_refused_write_names_attribute_and_errno(kernel):
    kernel.npwm = 2                                        # channel 2 does not exist
    with pytest.raises(DeviceIOError, match=r'pwmchip0/export: .*errno 22'):
        _pwm(kernel)
    assert kernel.state(0)['enable'] == '0'                # what was set up is turned off


def test_pwm_config_validation_names_field():
    base = {'backend': 'pwm', 'chip': 0}
    for extra, match in (({'polarity': 'up'}, r"devices\.led\.polarity: must be 'normal' or "
                                             r"'inversed', got 'up'"),
                         ({'period_ns': 0}, r'devices\.led\.period_ns: must be > 0, got 0'),
                         ({'channels': [0, 0, 1]}, r'devices\.led\.channels: expected three '
                                                   r'distinct')):
        with pytest.raises(dconfig.ConfigError, match=match):
            dconfig.validate({'devices': {'led': base | extra}})
    cfg = dconfig.validate({'devices': {'led': base}})
    assert cfg.devices['led']['polarity'] == 'normal'


# -- LED class -------------------------------------------------------------------------------
def _led(root, name, max_brightness=255, index=None):
    d = root / name
    d.mkdir()
    (d / 'max_brightness').write_text(f'{max_brightness}\n')
    (d / 'brightness').write_text('0\n')
    if index is not None:
        (d / 'multi_index').write_text(index + '\n')
        (d / 'multi_intensity').write_text(' '.join('0' for _ in index.split()) + '\n')
    return d


@pytest.mark.parametrize('index, expected', [
    ('red green blue', '255 0 51'),
    ('green red blue', '0 255 51'),
    ('blue green red', '51 0 255'),
    ('red green blue white', '255 0 51 0'),
])
def test_multicolor_order_follows_multi_index(tmp_path, index, expected):
    d = _led(tmp_path, 'rgb:status', index=index)
    out = LedClassOutput('rgb:status', root=str(tmp_path))
    out.show(p.LedColor(255, 0, 51, 128))
    assert (d / 'multi_intensity').read_text() == expected + '\n'
    assert (d / 'brightness').read_text() == '128\n'
    out.close()


def test_multicolor_without_rgb_channels_is_identity_error(tmp_path):
    _led(tmp_path, 'uv:status', index='violet ir')
    with pytest.raises(DeviceIdentityError, match='multi_index .* no red, green or blue'):
        LedClassOutput('uv:status', root=str(tmp_path))


def test_three_single_colour_leds_as_one_strip(tmp_path):
    dirs = [_led(tmp_path, n, max_brightness=100) for n in ('red:s', 'green:s', 'blue:s')]
    out = LedClassRgbOutput(['red:s', 'green:s', 'blue:s'], root=str(tmp_path))
    h = LedHandler(lambda: out)
    h.configure()
    h.activate()
    h.write((255, 51, 0, 255))
    assert [(d / 'brightness').read_text() for d in dirs] == ['100\n', '20\n', '0\n']
    h.shutdown()
    assert [(d / 'brightness').read_text() for d in dirs] == ['0\n', '0\n', '0\n']


def test_rgb_strip_refuses_a_multicolor_member_and_missing_led(tmp_path):
    _led(tmp_path, 'red:s')
    _led(tmp_path, 'rgb:s', index='red green blue')
    with pytest.raises(DeviceIdentityError, match='multicolor'):
        LedClassRgbOutput(['red:s', 'rgb:s', 'red:s'], root=str(tmp_path))
    with pytest.raises(DeviceNotFoundError, match='green:s'):
        LedClassRgbOutput(['red:s', 'green:s', 'blue:s'], root=str(tmp_path))
    with pytest.raises(dconfig.ConfigError, match=r'devices\.led\.names: expected \[red'):
        dconfig.validate({'devices': {'led': {'backend': 'led_class_rgb', 'names': ['a']}}})
