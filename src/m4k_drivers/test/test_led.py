import pytest

from m4k_drivers.handler import DeviceNotFoundError
from m4k_drivers.led import protocol as p
from m4k_drivers.led.real import LedClassOutput


def test_channel_levels_and_duty():
    c = p.LedColor(255, 128, 0, 128)
    lv = p.channel_levels(c)
    assert lv == pytest.approx((128 / 255, 128 / 255 * 128 / 255, 0.0))
    assert p.duty_ns(lv[0], 1_000_000) == 501_961
    assert p.duty_ns(1.5, 1000) == 1000 and p.duty_ns(-1, 1000) == 0


def test_multicolor_values_scale_to_max_brightness():
    assert p.multicolor_values(p.LedColor(255, 0, 51, 255), 255) == ('255 0 51', 255)
    assert p.multicolor_values(p.LedColor(255, 0, 51, 128), 100) == ('100 0 20', 50)
    assert p.to_hex(p.LedColor(255, 0, 51, 128)) == '#ff0033@128'


@pytest.mark.parametrize('bad', [(256, 0, 0, 0), (0, -1, 0, 0), (0, 0, 1.5, 0), (0, 0, 0, True)])
def test_color_validation_names_component(bad):
    with pytest.raises(ValueError, match='must be an int 0..255'):
        p.LedColor(*bad).validated()


def test_led_class_multicolor_writes_files(tmp_path):
    d = tmp_path / 'rgb:status'
    d.mkdir()
    (d / 'max_brightness').write_text('255\n')
    (d / 'brightness').write_text('0\n')
    (d / 'multi_intensity').write_text('0 0 0\n')
    (d / 'multi_index').write_text('red green blue\n')
    out = LedClassOutput('rgb:status', root=str(tmp_path))
    out.show(p.LedColor(255, 0, 51, 128))
    assert (d / 'multi_intensity').read_text() == '255 0 51\n'
    assert (d / 'brightness').read_text() == '128\n'
    out.close()


def test_led_class_mono_shows_brightest_channel(tmp_path):
    d = tmp_path / 'led0'
    d.mkdir()
    (d / 'max_brightness').write_text('1\n')
    (d / 'brightness').write_text('0\n')
    out = LedClassOutput('led0', root=str(tmp_path))
    out.show(p.LedColor(0, 255, 0, 255))
    assert (d / 'brightness').read_text() == '1\n'
    out.close()


def test_missing_led_names_path(tmp_path):
    with pytest.raises(DeviceNotFoundError, match=r'/nope: No such file or directory'):
        LedClassOutput('nope', root=str(tmp_path))
