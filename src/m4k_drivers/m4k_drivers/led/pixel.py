"""WS2811/WS2812 pixel strips (the NS-LED-02 family) driven by bits on SPI MOSI.

A pixel strip takes one self-clocked line: per pixel 24 bits, colour order G, R, B for the
WS2812/WS2812B (the WS2811 IC is wired RGB on many strips: ``color_order``), MSB first; every
bit is a high time then a low time, and a low line for the reset time latches what was sent.
Timing (Worldsemi WS2812B datasheet; WS2811 high-speed mode is the same within tolerance)::

    T0H 0.40 us   T0L 0.85 us      a 0: short high, long low       each +/-150 ns
    T1H 0.80 us   T1L 0.45 us      a 1: long high, short low       each +/-150 ns
    TH + TL = 1.25 us +/- 600 ns   reset (latch): low >= 50 us (WS2812B V5 / WS2813: >= 280 us)

No root and no DMA from Python: SPI produces the waveform.  Each LED bit becomes ``n`` SPI
bits at ``n / 1.25 us`` (2.4 MHz for 3, 3.2 MHz for 4) with MOSI high for the first one or
two of them (:data:`PATTERNS`)::

    3 bits at 2.4 MHz (417 ns):  0 -> 100 (T0H 417, T0L 833)   1 -> 110 (T1H 833, T1L 417)
    4 bits at 3.2 MHz (312 ns):  0 -> 1000 (T0H 312, T0L 938)  1 -> 1110 (T1H 938, T1L 312)

then ``reset_us`` of zero bytes (MOSI low) latch the frame; one zero byte first makes sure the
line was low before the first rise.  The whole frame is one spidev message (at most spidev's
``bufsiz``, 4096 bytes by default: 450 pixels at 3 bits, 330 at 4).  On the M4K the strip
hangs on SPI1 MOSI (SPI0's carries the DAC words, which a strip would take for pixels):
the bcm2835 aux controller has a small FIFO refilled by interrupt, so a busy CPU can stretch a
low time between bytes -- WS2812-family parts latch a bit on the rising edge and only reset
after >= 50 us low, but a stretched T0L/T1L is outside the datasheet window: the bring-up step
in docs/real-robot.md checks the strip under load.
"""

from __future__ import annotations

from typing import Sequence

__all__ = ['ENCODINGS', 'PATTERNS', 'encode_frame', 'frame_bytes', 'pixel_bytes']

# SPI bits per LED bit -> (SPI clock Hz, pattern of a 0, pattern of a 1)
PATTERNS: dict[int, tuple[int, str, str]] = {
    3: (2_400_000, '100', '110'),
    4: (3_200_000, '1000', '1110'),
}
ENCODINGS = tuple(PATTERNS)
COLOR_ORDERS = ('GRB', 'RGB', 'BRG', 'RBG', 'GBR', 'BGR')
SPIDEV_BUFSIZ = 4096


def pixel_bytes(rgb: tuple[int, int, int], order: str) -> bytes:
    """Return one pixel's three bytes in the strip's colour order."""
    index = {'R': 0, 'G': 1, 'B': 2}
    return bytes(rgb[index[c]] for c in order)


def frame_bytes(pixels: int, reset_us: float, bits: int) -> int:
    """Return the SPI bytes of a frame of ``pixels`` (leading zero byte and reset included)."""
    hz = PATTERNS[bits][0]
    return 1 + (pixels * 24 * bits + 7) // 8 + reset_bytes(reset_us, hz)


def reset_bytes(reset_us: float, hz: int) -> int:
    """Return the zero bytes that hold MOSI low for at least ``reset_us``."""
    return -(-int(reset_us * 1e-6 * hz) // 8) + 1


def encode_frame(colors: Sequence[tuple[int, int, int]], *, bits: int = 3,
                 order: str = 'GRB', reset_us: float = 300.0) -> bytes:
    """Return the MOSI bytes that show ``colors`` (r, g, b 0..255 each) and latch them."""
    if bits not in PATTERNS:
        raise ValueError(f'bits per LED bit must be one of {ENCODINGS}, got {bits!r}')
    if order not in COLOR_ORDERS:
        raise ValueError(f'colour order must be one of {COLOR_ORDERS}, got {order!r}')
    hz, zero, one = PATTERNS[bits]
    stream = ''.join(one if byte >> (7 - i) & 1 else zero
                     for rgb in colors for byte in pixel_bytes(rgb, order) for i in range(8))
    stream += '0' * (-len(stream) % 8)
    body = int(stream, 2).to_bytes(len(stream) // 8, 'big') if stream else b''
    return b'\x00' + body + bytes(reset_bytes(reset_us, hz))
