"""The pixel stream as the Pi's aux SPI controller sends it, judged by the WS2812B windows.

The controller model (:mod:`m4k_drivers.abi.auxspi`, from spi-bcm2835aux.c: 3-byte FIFO
chunks, 2 idle clocks after each, SCLK = core / (2 ceil(core / 2f))) turns the frame into the
waveform on DIN; the strip model (:class:`~m4k_drivers.abi.devices.Ws2812Strip`) decodes that
waveform by the datasheet's windows.  Neither imports the encoder.
"""

from __future__ import annotations

import random

import pytest

from m4k_drivers.abi.auxspi import aux_sclk_hz, AuxSpiController, chunk_ends_high, mosi_runs
from m4k_drivers.abi.devices import Ws2812Strip
from m4k_drivers.led import pixel as px

# The documented settings (docs/real-robot.md): Pi 3 core_freq=250, Pi 4 core_freq_min=500.
CORES = [250_000_000, 500_000_000]


def _worst_patterns() -> list[list[tuple[int, int, int]]]:
    rnd = random.Random(43)
    return [
        [(0, 0, 0)] * 8,                    # every bit a 0: the long lows, the short highs
        [(255, 255, 255)] * 8,              # every bit a 1: the long highs
        [(0xAA, 0x55, 0xAA)] * 8,           # 1010...: a value change at every bit
        [(0x55, 0xAA, 0x55)] * 8,
        [(0x01, 0x80, 0xFE)] * 8,           # a lone 1 / a lone 0 at each chunk position
        [tuple(rnd.randrange(256) for _ in range(3)) for _ in range(8)],
    ]


def _old_frame(colors, hz=2_400_000, reset_us=300.0):
    """The encoding this replaced: one zero byte, then 3 SPI bits (100 / 110) per LED bit."""
    stream = ''.join('110' if byte >> (7 - i) & 1 else '100'
                     for rgb in colors for byte in (rgb[1], rgb[0], rgb[2]) for i in range(8))
    stream += '0' * (-len(stream) % 8)
    body = int(stream, 2).to_bytes(len(stream) // 8, 'big')
    return b'\x00' + body + bytes(-(-int(reset_us * 1e-6 * hz) // 8) + 1)


@pytest.mark.parametrize(('core', 'asked', 'real'), [
    (250e6, 2_400_000, 250e6 / 106), (250e6, 3_200_000, 3_125_000.0),
    (250e6, 3_300_000, 250e6 / 76), (500e6, 7_000_000, 500e6 / 72),
    (250e6, 200e6, 125e6), (250e6, 1, 250e6 / (2 * 4096))])
def test_aux_clock_is_the_core_over_an_even_divider(core, asked, real):
    assert aux_sclk_hz(core, asked) == pytest.approx(real)


def test_the_old_encoding_ends_chunks_high_and_the_strip_rejects_it():
    rnd = random.Random(7)
    colors = [tuple(rnd.randrange(256) for _ in range(3)) for _ in range(8)]
    frame = _old_frame(colors)
    assert len(frame) == 164                        # the frame: 164 bytes, 55 chunks
    strip = Ws2812Strip(8)
    ctl = AuxSpiController(strip, 250e6)
    ctl.transfer(frame, 0, 2_400_000, 8)
    # The figure: 24 of 55 chunks end inside a high phase (whatever the colours: the
    # zero byte puts a chunk boundary after the first, always high, bit of every 8th LED bit).
    assert (ctl.chunks, ctl.chunks_ending_high) == (55, 24)
    bit_ns = 1e9 / aux_sclk_hz(250e6, 2_400_000)
    highs = {round(d / bit_ns) for level, d in mosi_runs(frame, aux_sclk_hz(250e6, 2_400_000))
             if level == 1}
    assert 3 in highs                               # a 0's high stretched to 3 bits = 1.27 us
    assert strip.bad_bits > 0 and strip.rejected_frames == 1
    assert strip.shown == [(0, 0, 0)] * 8           # nothing latched


def test_the_old_encoding_decodes_on_an_ideal_controller_so_only_the_chunks_break_it():
    strip = Ws2812Strip(8)
    colors = [(18, 52, 86)] * 8
    strip.transfer(_old_frame(colors), 0, 2_400_000, 8)
    assert strip.shown == colors and strip.bad_bits == 0


@pytest.mark.parametrize('core', CORES)
@pytest.mark.parametrize('pattern', range(len(_worst_patterns())))
def test_worst_patterns_decode_through_the_aux_controller(core, pattern):
    colors = _worst_patterns()[pattern]
    sclk = px.aux_clock_hz(core, 7_000_000)
    plan = px.plan(1e9 / sclk)
    frame = px.encode_frame(colors, plan)
    assert chunk_ends_high(frame) == 0
    strip = Ws2812Strip(8, reset_us=280.0)
    ctl = AuxSpiController(strip, core)
    ctl.transfer(frame, 0, 7_000_000, 8)
    assert ctl.last_sclk_hz == pytest.approx(sclk)
    assert strip.bad_bits == 0 and strip.frames == 1
    assert strip.shown == colors


def _plannable(core: float) -> list[int]:
    """Requested speeds (one per real clock) from 2 to 12 MHz that the encoder accepts."""
    out = []
    for n in range(int(core / 24e6), int(core / 4e6) + 1):
        asked = int(core / (2 * n)) + 1 if core / (2 * n) != int(core / (2 * n)) else int(
            core / (2 * n))
        try:
            px.plan(1e9 / px.aux_clock_hz(core, asked))
        except ValueError:
            continue
        out.append(asked)
    return out


@pytest.mark.parametrize('core', CORES)
def test_every_clock_the_encoder_accepts_decodes_the_worst_patterns(core):
    speeds = _plannable(core)
    assert speeds                                   # at least one clock fits
    for asked in speeds:
        plan = px.plan(1e9 / px.aux_clock_hz(core, asked))
        for colors in _worst_patterns():
            frame = px.encode_frame(colors, plan)
            assert chunk_ends_high(frame) == 0, asked
            strip = Ws2812Strip(8, reset_us=280.0)
            AuxSpiController(strip, core).transfer(frame, 0, asked, 8)
            assert (strip.bad_bits, strip.shown) == (0, colors), asked


@pytest.mark.parametrize('asked', [2_400_000, 3_200_000])
def test_a_clock_without_a_fitting_layout_is_refused_with_the_reason(asked):
    with pytest.raises(ValueError, match='no pixel encoding fits the WS2812B windows'):
        px.plan(1e9 / px.aux_clock_hz(250e6, asked))


@pytest.mark.parametrize('core', [200e6, 300e6, 400e6, 450e6, 550e6, 600e6])
def test_the_7_mhz_plan_survives_any_core_clock_from_200_to_600_mhz(core):
    # At 7 MHz the divider is fine-grained: the real clock stays within 6.67..7.0 MHz, so a
    # core that is not pinned still shows the colours (a change *during* a frame is not
    # modelled).
    plan = px.plan(1e9 / px.aux_clock_hz(250e6, 7_000_000))
    strip = Ws2812Strip(8)
    AuxSpiController(strip, core).transfer(px.encode_frame([(255, 0, 0)] * 8, plan), 0,
                                           7_000_000, 8)
    assert strip.bad_bits == 0 and strip.shown == [(255, 0, 0)] * 8


def test_a_frame_sent_at_another_clock_than_planned_garbles_the_strip():
    plan = px.plan(1e9 / px.aux_clock_hz(250e6, 7_000_000))
    strip = Ws2812Strip(8)
    AuxSpiController(strip, 250e6).transfer(px.encode_frame([(255, 0, 0)] * 8, plan), 0,
                                            5_000_000, 8)
    assert strip.bad_bits > 0 and strip.shown == [(0, 0, 0)] * 8
