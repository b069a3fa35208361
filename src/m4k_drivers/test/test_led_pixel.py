"""The pixel-strip LED backend: WS2812 bit timing on SPI MOSI, decoded by the datasheet.

The strip model (:class:`m4k_drivers.abi.devices.Ws2812Strip`) rebuilds the waveform from
the MOSI bytes at the SPI clock and classifies every high/low pair by the WS2812B timing
windows; it is the ground truth of what a strip would show.
"""

from __future__ import annotations

import pytest

from m4k_drivers import config as dconfig
from m4k_drivers import registry
from m4k_drivers.abi.devices import Ws2812Strip
from m4k_drivers.abi.kernel import KernelStandIn, SpiNode
from m4k_drivers.led import pixel as px
from m4k_drivers.led.protocol import LedColor

COLORS = [(255, 0, 0), (0, 255, 0), (0, 0, 255), (18, 52, 86), (255, 255, 255)]


@pytest.mark.parametrize('bits', [3, 4])
def test_frame_decodes_to_the_colours_at_the_encodings_clock(bits):
    strip = Ws2812Strip(len(COLORS))
    frame = px.encode_frame(COLORS, bits=bits, order='GRB', reset_us=300)
    strip.transfer(frame, 0, px.PATTERNS[bits][0], 8)
    assert strip.bad_bits == 0 and strip.frames == 1
    assert strip.shown == COLORS


@pytest.mark.parametrize('hz', [1_200_000, 4_800_000, 6_400_000])
def test_a_wrong_spi_clock_puts_the_bits_out_of_tolerance(hz):
    strip = Ws2812Strip(2)
    strip.transfer(px.encode_frame(COLORS[:2], bits=3), 0, hz, 8)
    assert strip.bad_bits > 0 and strip.rejected_frames == 1
    assert strip.shown == [(0, 0, 0), (0, 0, 0)]


def test_rgb_order_strip_fed_grb_swaps_red_and_green():
    strip = Ws2812Strip(1)
    strip.transfer(px.encode_frame([(200, 10, 0)], order='RGB'), 0, 2_400_000, 8)
    assert strip.shown == [(10, 200, 0)]     # the model is a GRB part: the order matters


def test_pixel_backend_through_spidev_shows_the_colour_and_switches_off(tmp_path):
    strip = Ws2812Strip(8)
    section = dconfig.validate_device('led', {'backend': 'pixel_spi', 'pixels': 8},
                                      'devices.led')
    with KernelStandIn() as kernel:
        kernel.spi['/dev/spidev1.2'] = SpiNode(strip)
        h = registry.create('led', section, registry.BuildContext())
        h.configure()
        h.activate()
        h.write(LedColor(255, 128, 0, 255))
        assert strip.shown == [(255, 128, 0)] * 8 and strip.bad_bits == 0
        h.write(LedColor(255, 255, 255, 51))          # brightness 20 %
        assert strip.shown == [(51, 51, 51)] * 8
        xfer = [d for p, c, d in kernel.log if c == 'spi_xfer'][-1]
        assert (xfer['mode'], xfer['speed_hz'], xfer['bits']) == (0, 2_400_000, 8)
        h.shutdown()
        assert strip.shown == [(0, 0, 0)] * 8
        assert kernel.open_fds() == []


def test_a_strip_longer_than_spidev_bufsiz_is_refused_with_the_reason():
    from m4k_drivers.led.real import PixelSpiOutput
    with pytest.raises(ValueError, match='bufsiz'):
        PixelSpiOutput('/dev/spidev0.0', 1000)


def test_pixel_settings_are_validated():
    with pytest.raises(dconfig.ConfigError, match='devices.led.bits_per_led_bit'):
        dconfig.validate_device('led', {'backend': 'pixel_spi', 'bits_per_led_bit': 5},
                                'devices.led')
    with pytest.raises(dconfig.ConfigError, match='devices.led.color_order'):
        dconfig.validate_device('led', {'backend': 'pixel_spi', 'color_order': 'RGBW'},
                                'devices.led')
