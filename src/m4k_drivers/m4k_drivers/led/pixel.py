"""WS2811/WS2812 pixel strips (the NS-LED-02 family) driven by bits on the Pi's aux SPI MOSI.

A pixel strip takes one self-clocked line: per pixel 24 bits, colour order G, R, B for the
WS2812/WS2812B (the WS2811 IC is wired RGB on many strips: ``color_order``), MSB first; every
bit is a high time then a low time, and a low line for the reset time latches what was sent.
Timing (Worldsemi WS2812B datasheet)::

    T0H 0.40 us   T0L 0.85 us      a 0: short high, long low       each +/-150 ns
    T1H 0.80 us   T1L 0.45 us      a 1: long high, short low       each +/-150 ns
    TH + TL = 1.25 us +/- 600 ns   reset (latch): low >= 50 us (WS2812B V5 / WS2813: >= 280 us)

**The controller the bits really leave.**  The strip hangs on SPI1 MOSI, and SPI1 is the
BCM2835 *auxiliary* SPI (``drivers/spi/spi-bcm2835aux.c``), which is not a continuous shift
register: the driver writes at most 3 bytes per FIFO entry (variable-width mode), and its own
comment says 2 idle clock cycles follow each such chunk.  MOSI does not toggle in them, so the
level at a chunk's end lasts 2 bit times longer.  Its clock is the core clock over an even
divider, ``f = core / (2 * ceil(core / (2 * f_requested)))`` (the driver's ``speed`` field,
``DIV_ROUND_UP(clk_hz, 2 * spi_hz) - 1``): 7 MHz asked of a 250 MHz core gives 6.944 MHz.

So the encoding is planned per *chunk*, at the clock the controller really runs
(:func:`plan`): each 24-bit chunk carries a few LED bits, each LED bit a fixed number of SPI
bits with MOSI high for the first ones; the last LED bit of a chunk always ends low inside the
chunk, so the idle clocks lengthen a low time only -- and that lengthened low is still inside
its window, because the plan counts the idle clocks into that slot.  Of all layouts the one
with the widest margin to every window (both values, every slot) wins.  No chunk ever ends in
a high phase, whatever the colours: that is what a leading zero *byte* broke (it moved the
3-byte chunks off the LED-bit boundaries, and a 0's high time stretched to about 1.27 us).

The frame starts with one whole zero chunk (the line is low before the first rise and the
chunks stay aligned), then the pixels, then zero bytes for ``reset_us`` (counted at 8 bit
times per byte, the idle clocks only lengthen it).  One spidev message carries it all (at
most ``bufsiz``, 4096 bytes by default).  A gap the controller adds beyond the idle clocks (its
FIFO refilled late by the interrupt handler, 12 bytes deep in the driver) lengthens a low
time further: outside the window, and a gap over 50 us latches half a frame.
"""

from __future__ import annotations

from dataclasses import dataclass
import functools
import itertools
import math
from typing import Sequence

__all__ = ['AUX_CHUNK_BYTES', 'AUX_IDLE_BITS', 'COLOR_ORDERS', 'Plan', 'Slot', 'aux_clock_hz',
           'encode_frame', 'plan', 'pixel_bytes']

COLOR_ORDERS = ('GRB', 'RGB', 'BRG', 'RBG', 'GBR', 'BGR')
SPIDEV_BUFSIZ = 4096
AUX_CHUNK_BYTES = 3         # spi-bcm2835aux: bcm2835aux_wr_fifo() gathers up to 3 bytes
AUX_IDLE_BITS = 2           # "2 idle clocks after each chunk" (the driver's comment)
AUX_SPEED_MAX = 0xFFF       # CNTL0 SPEED field, 12 bits

# Worldsemi WS2812B: (nominal ns, tolerance ns) of each phase; the bit period window.
WINDOWS = {'T0H': (400, 150), 'T0L': (850, 150), 'T1H': (800, 150), 'T1L': (450, 150)}
PERIOD_NS, PERIOD_TOL_NS = 1250, 600
MIN_MARGIN_NS = 20.0        # a plan closer than this to a window edge is refused


def aux_clock_hz(core_hz: float, requested_hz: float) -> float:
    """Return the SCLK the aux controller really runs for a requested speed (driver formula)."""
    if requested_hz >= core_hz / 2:
        speed = 0
    else:
        speed = min(math.ceil(core_hz / (2 * requested_hz)) - 1, AUX_SPEED_MAX)
    return core_hz / (2 * (speed + 1))


@dataclass(frozen=True)
class Slot:
    """One LED bit of a chunk: ``length`` SPI bits, high for the first ``high0``/``high1``."""

    length: int
    high0: int
    high1: int


@dataclass(frozen=True)
class Plan:
    """The LED-bit slots of one chunk at one bit time, and their worst window margin."""

    bit_ns: float
    slots: tuple[Slot, ...]
    margin_ns: float
    chunk_bits: int
    idle_bits: int

    @property
    def bits_per_chunk(self) -> int:
        """LED bits one chunk carries."""
        return len(self.slots)


def _margin(high_ns: float, low_ns: float, one: bool) -> float:
    """Return how far (ns) a high/low pair is inside the windows of its value (< 0: outside)."""
    h, tol_h = WINDOWS['T1H' if one else 'T0H']
    lo, tol_l = WINDOWS['T1L' if one else 'T0L']
    return min(tol_h - abs(high_ns - h), tol_l - abs(low_ns - lo),
               PERIOD_TOL_NS - abs(high_ns + low_ns - PERIOD_NS))


def _best_slots(bit_ns: float, extra_low: int) -> dict[int, tuple[float, Slot]]:
    """Return, per slot length, the widest-margin slot whose low gains ``extra_low`` bits."""
    best: dict[int, tuple[float, Slot]] = {}
    for length in range(2, 16):
        for high0, high1 in itertools.product(range(1, length), repeat=2):
            low0 = (length - high0 + extra_low) * bit_ns
            low1 = (length - high1 + extra_low) * bit_ns
            m = min(_margin(high0 * bit_ns, low0, False), _margin(high1 * bit_ns, low1, True))
            if m >= 0 and (length not in best or m > best[length][0]):
                best[length] = (m, Slot(length, high0, high1))
    return best


@functools.lru_cache(maxsize=32)
def plan(bit_ns: float, *, chunk_bits: int = 8 * AUX_CHUNK_BYTES,
         idle_bits: int = AUX_IDLE_BITS) -> Plan:
    """Return the chunk layout with the widest window margin; ValueError when none fits.

    The last slot of a chunk gets ``idle_bits`` more low time; ties go to more LED bits per
    chunk (a shorter frame).
    """
    inner = _best_slots(bit_ns, 0)
    last = _best_slots(bit_ns, idle_bits)
    found: tuple[float, int, tuple[Slot, ...]] | None = None
    for tail_len, (tail_m, tail) in last.items():
        rest = chunk_bits - tail_len
        for k in range(rest // 2 + 1):
            for lengths in itertools.combinations_with_replacement(sorted(inner), k):
                if sum(lengths) != rest:
                    continue
                m = min([tail_m] + [inner[n][0] for n in lengths])
                key = (m, k + 1)
                if found is None or key > found[:2]:
                    found = (m, k + 1, tuple(inner[n][1] for n in lengths) + (tail,))
    if found is None or found[0] < MIN_MARGIN_NS:
        best = 'none' if found is None else f'{found[0]:.0f} ns'
        raise ValueError(f'no pixel encoding fits the WS2812B windows at {1e3 / bit_ns:.3f} MHz '
                         f'with {idle_bits} idle clocks per {chunk_bits}-bit chunk (best margin '
                         f'{best}, need {MIN_MARGIN_NS:.0f}): choose another spi_hz')
    return Plan(bit_ns, found[2], found[0], chunk_bits, idle_bits)


def pixel_bytes(rgb: tuple[int, int, int], order: str) -> bytes:
    """Return one pixel's three bytes in the strip's colour order."""
    index = {'R': 0, 'G': 1, 'B': 2}
    return bytes(rgb[index[c]] for c in order)


def reset_bytes(reset_us: float, bit_ns: float) -> int:
    """Return the zero bytes that hold MOSI low for at least ``reset_us``."""
    return math.ceil(reset_us * 1e3 / bit_ns / 8) + 1


def frame_bytes(pixels: int, reset_us: float, p: Plan) -> int:
    """Return the SPI bytes of a frame of ``pixels`` (lead chunk and reset included)."""
    chunk = p.chunk_bits // 8
    chunks = math.ceil(pixels * 24 / p.bits_per_chunk)
    return chunk + chunks * chunk + reset_bytes(reset_us, p.bit_ns)


def encode_frame(colors: Sequence[tuple[int, int, int]], p: Plan, *, order: str = 'GRB',
                 reset_us: float = 300.0) -> bytes:
    """Return the MOSI bytes that show ``colors`` (r, g, b 0..255 each) and latch them."""
    if order not in COLOR_ORDERS:
        raise ValueError(f'colour order must be one of {COLOR_ORDERS}, got {order!r}')
    bits = [byte >> (7 - i) & 1 for rgb in colors for byte in pixel_bytes(rgb, order)
            for i in range(8)]
    out: list[str] = ['0' * p.chunk_bits]
    for start in range(0, len(bits), p.bits_per_chunk):
        chunk = ''
        for slot, b in zip(p.slots, bits[start:start + p.bits_per_chunk], strict=False):
            high = slot.high1 if b else slot.high0
            chunk += '1' * high + '0' * (slot.length - high)
        out.append(chunk.ljust(p.chunk_bits, '0'))   # a short last chunk ends low
    stream = ''.join(out)
    body = int(stream, 2).to_bytes(len(stream) // 8, 'big')
    return body + bytes(reset_bytes(reset_us, p.bit_ns))
