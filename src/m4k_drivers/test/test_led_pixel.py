"""The pixel-strip LED backend: WS2812 bit timing on SPI MOSI, decoded by the datasheet.

The strip model (:class:`m4k_drivers.abi.devices.Ws2812Strip`) classifies every high/low pair
of the waveform the aux controller model (:mod:`m4k_drivers.abi.auxspi`) drives -- 3-byte
chunks, idle clocks, the real clock -- by the WS2812B timing windows; it is the ground truth of
what a strip would show.
"""

from __future__ import annotations

import pytest

from m4k_drivers import config as dconfig
from m4k_drivers import registry
from m4k_drivers.abi.auxspi import AuxSpiController
from m4k_drivers.abi.devices import Ws2812Strip
from m4k_drivers.abi.kernel import KernelStandIn, SpiNode
from m4k_drivers.led import pixel as px
from m4k_drivers.led.protocol import LedColor

COLORS = [(255, 0, 0), (0, 255, 0), (0, 0, 255), (18, 52, 86), (255, 255, 255)]
PLAN = px.plan(1e9 / px.aux_clock_hz(250e6, 7_000_000))


def test_frame_decodes_to_the_colours_through_the_aux_controller():
    strip = Ws2812Strip(len(COLORS))
    frame = px.encode_frame(COLORS, PLAN, order='GRB', reset_us=300)
    AuxSpiController(strip, 250e6).transfer(frame, 0, 7_000_000, 8)
    assert strip.bad_bits == 0 and strip.frames == 1
    assert strip.shown == COLORS


@pytest.mark.parametrize('hz', [1_200_000, 4_800_000, 12_000_000])
def test_a_wrong_spi_clock_puts_the_bits_out_of_tolerance(hz):
    strip = Ws2812Strip(2)
    AuxSpiController(strip, 250e6).transfer(px.encode_frame(COLORS[:2], PLAN), 0, hz, 8)
    assert strip.bad_bits > 0 and strip.rejected_frames == 1
    assert strip.shown == [(0, 0, 0), (0, 0, 0)]


def test_rgb_order_strip_fed_grb_swaps_red_and_green():
    strip = Ws2812Strip(1)
    AuxSpiController(strip, 250e6).transfer(px.encode_frame([(200, 10, 0)], PLAN, order='RGB'),
                                            0, 7_000_000, 8)
    assert strip.shown == [(10, 200, 0)]     # the model is a GRB part: the order matters


def test_pixel_backend_through_spidev_shows_the_colour_and_switches_off(tmp_path):
    strip = Ws2812Strip(8)
    section = dconfig.validate_device('led', {'backend': 'pixel_spi', 'pixels': 8},
                                      'devices.led')
    with KernelStandIn() as kernel:
        ctl = AuxSpiController(strip, 250e6)
        kernel.spi['/dev/spidev1.2'] = SpiNode(ctl)
        h = registry.create('led', section, registry.BuildContext())
        h.configure()
        h.activate()
        h.write(LedColor(255, 128, 0, 255))
        assert strip.shown == [(255, 128, 0)] * 8 and strip.bad_bits == 0
        h.write(LedColor(255, 255, 255, 51))          # brightness 20 %
        assert strip.shown == [(51, 51, 51)] * 8
        xfer = [d for p, c, d in kernel.log if c == 'spi_xfer'][-1]
        assert (xfer['mode'], xfer['speed_hz'], xfer['bits']) == (0, 7_000_000, 8)
        assert ctl.chunks_ending_high == 0
        sent = strip.frames
        h.write(LedColor(255, 255, 255, 51))          # the same colour again: not re-sent
        assert strip.frames == sent
        h.shutdown()
        assert strip.shown == [(0, 0, 0)] * 8
        assert kernel.open_fds() == []


def test_a_strip_longer_than_spidev_bufsiz_is_refused_with_the_reason():
    from m4k_drivers.led.real import PixelSpiOutput
    with pytest.raises(ValueError, match='bufsiz'):
        PixelSpiOutput('/dev/spidev0.0', 1000, spi_hz=7_000_000, core_clock_hz=250_000_000)


def test_a_clock_with_no_fitting_encoding_fails_configure_with_the_reason():
    from m4k_drivers.led.real import PixelSpiOutput
    with pytest.raises(ValueError, match='choose another spi_hz'):
        PixelSpiOutput('/dev/spidev1.2', 8, spi_hz=2_400_000, core_clock_hz=250_000_000)


def test_pixel_settings_are_validated():
    with pytest.raises(dconfig.ConfigError, match='devices.led.spi_hz'):
        dconfig.validate_device('led', {'backend': 'pixel_spi', 'spi_hz': 10},
                                'devices.led')
    with pytest.raises(dconfig.ConfigError, match='devices.led.color_order'):
        dconfig.validate_device('led', {'backend': 'pixel_spi', 'color_order': 'RGBW'},
                                'devices.led')
