"""The BCM2835 auxiliary SPI controller (SPI1/SPI2 on a Pi 0-4) as it drives its wires.

From the kernel driver ``drivers/spi/spi-bcm2835aux.c`` (raspberrypi/linux), read for what
reaches the pins, not copied:

* **Clock.** CNTL0's 12-bit SPEED field divides the core clock: SCLK = core / (2 (speed + 1)),
  the driver choosing ``speed = DIV_ROUND_UP(core, 2 f) - 1`` (0 when f >= core / 2, 0xFFF at
  most) -- the real clock is at most the requested one, often well below it.
* **Chunks.** ``bcm2835aux_wr_fifo()`` gathers at most 3 bytes per FIFO entry and sets the
  entry's bit length to 8 x count (variable-width mode); the driver's comment on its timing
  estimate says 2 idle clock cycles follow each chunk.  No data bit is shifted in them: MOSI
  holds the chunk's last level.  (The FIFO is refilled while fewer than 12 bytes are pending,
  so the entries follow each other without further gaps when the interrupt is on time; a late
  interrupt is not modelled.)
* **Modes.** ``mode_bits = SPI_CPOL | SPI_CS_HIGH | SPI_NO_CS``: no CPHA, so SPI modes 1 and 3
  are refused (spidev's SPI_IOC_WR_MODE returns EINVAL).

:class:`AuxSpiController` sits between a :class:`~m4k_drivers.abi.kernel.SpiNode` and the device
on a chip select: a device with a ``line(runs)`` method (the WS2812B strip) gets the MOSI
waveform as (level, ns) runs at the real clock; every other device gets its bytes at the real
clock.  Nothing here imports the driver code it serves.
"""

from __future__ import annotations

import math
import threading
import time
from typing import Any

__all__ = ['AuxSpiBus', 'AuxSpiController', 'aux_sclk_hz', 'bus_time_s', 'mosi_runs']

SPEED_MAX = 0xFFF
CHUNK_BYTES = 3
IDLE_CLOCKS = 2


def aux_sclk_hz(core_hz: float, requested_hz: float) -> float:
    """Return the SCLK the aux controller runs for ``requested_hz`` on a ``core_hz`` core clock."""
    if requested_hz <= 0:
        return core_hz / (2 * (SPEED_MAX + 1))      # speed 0 asks for the slowest clock
    speed = 0 if requested_hz >= core_hz / 2 else min(
        math.ceil(core_hz / (2 * requested_hz)) - 1, SPEED_MAX)
    return core_hz / (2 * (speed + 1))


def mosi_runs(tx: bytes, sclk_hz: float, *, chunk_bytes: int = CHUNK_BYTES,
              idle_clocks: int = IDLE_CLOCKS) -> list[tuple[int, float]]:
    """Return MOSI as (level, duration ns) runs: chunks of bytes, idle clocks after each."""
    bit_ns = 1e9 / sclk_hz
    runs: list[tuple[int, float]] = []

    def put(level: int, ns: float) -> None:
        if runs and runs[-1][0] == level:
            runs[-1] = (level, runs[-1][1] + ns)
        else:
            runs.append((level, ns))

    for start in range(0, len(tx), chunk_bytes):
        level = 0
        for byte in tx[start:start + chunk_bytes]:
            for i in range(8):
                level = byte >> (7 - i) & 1
                put(level, bit_ns)
        put(level, idle_clocks * bit_ns)          # MOSI holds the chunk's last bit
    return runs


def chunk_ends_high(tx: bytes, chunk_bytes: int = CHUNK_BYTES) -> int:
    """Return how many chunks of ``tx`` end with MOSI high (each then stretches a high time)."""
    return sum(tx[min(i + chunk_bytes, len(tx)) - 1] & 1
               for i in range(0, len(tx), chunk_bytes))


def bus_time_s(nbytes: int, sclk_hz: float) -> float:
    """Return how long ``nbytes`` hold the bus: 8 clocks per byte plus 2 idle per chunk."""
    chunks = math.ceil(nbytes / CHUNK_BYTES)
    return (8 * nbytes + IDLE_CLOCKS * chunks) / sclk_hz


class AuxSpiBus:
    """The one controller behind several chip selects: one message at a time.

    The SPI core queues the messages of all of a controller's devices and runs them one after
    the other (``spi_sync`` on one ``spi_controller``).  With ``pace`` a message also holds the
    bus for its modelled wire time (a real sleep), so a reader on another chip select waits as
    it would on the Pi; ``busy_s`` sums the wire time.
    """

    def __init__(self, core_hz: float, *, pace: bool = False) -> None:
        self.core_hz = core_hz
        self.pace = pace
        self.lock = threading.Lock()
        self.busy_s = 0.0


class AuxSpiController:
    """One aux SPI chip select: the real clock and the chunked MOSI waveform for its device."""

    MODE_BITS = 0x2 | 0x4 | 0x40          # SPI_CPOL | SPI_CS_HIGH | SPI_NO_CS (spi.h)

    def __init__(self, device: Any, core_hz: float, bus: AuxSpiBus | None = None) -> None:
        self.device = device
        self.core_hz = core_hz
        self.bus = bus if bus is not None else AuxSpiBus(core_hz)
        self.last_sclk_hz = 0.0
        self.chunks = 0
        self.chunks_ending_high = 0
        self.waits: list[float] = []          # s each transfer waited for the bus

    def transfer(self, tx: bytes, mode: int, speed_hz: int, bits_per_word: int) -> bytes:
        """Clock ``tx`` out at the real SCLK; return what the device put on MISO."""
        queued = time.monotonic()
        with self.bus.lock:
            t0 = time.monotonic()
            self.waits.append(t0 - queued)     # behind another chip select's message
            rx = self._clock(tx, mode, speed_hz, bits_per_word)
            wire = bus_time_s(len(tx), self.last_sclk_hz)
            self.bus.busy_s += wire
            if self.bus.pace:
                left = wire - (time.monotonic() - t0)
                if left > 0:
                    time.sleep(left)
        return rx

    def _clock(self, tx: bytes, mode: int, speed_hz: int, bits_per_word: int) -> bytes:
        sclk = aux_sclk_hz(self.core_hz, speed_hz)
        self.last_sclk_hz = sclk
        self.chunks += math.ceil(len(tx) / CHUNK_BYTES)
        self.chunks_ending_high += chunk_ends_high(tx)
        line = getattr(self.device, 'line', None)
        if line is not None:
            line(mosi_runs(tx, sclk))
            return bytes(len(tx))
        return bytes(self.device.transfer(tx, mode, int(sclk), bits_per_word))

    def release(self) -> None:
        """Pass a close of the node on to the device."""
        release = getattr(self.device, 'release', None)
        if release is not None:
            release()
