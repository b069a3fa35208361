"""Benchmark: how long an AS5045 read on SPI1 waits behind the pixel strip on the same bus.

The encoders (CS0, CS1) and the strip (CS2) share the aux SPI controller, which runs one message
at a time.  An encoder read queued behind a strip frame waits for the rest of that frame, and
its latch stamp (taken before the transfer) is early by that wait.  Two figures:

* **model** -- the frame's wire time at the real clock (:func:`~m4k_drivers.abi.auxspi.bus_time_s`)
  and, for reads landing at random times, the mean and worst wait for a strip that re-sends
  every 20 ms (the former LED task) and one that sends on change;
* **stand-in** -- the real backends (python-periphery spidev for the encoder reads, the
  ``pixel_spi`` LED handler in its own thread) through the kernel-ABI stand-in, whose aux bus
  holds each message for its modelled wire time: with the strip off, re-sent every 20 ms, and
  on change (one colour change per second), the encoder transfer's duration (this machine's
  Python and scheduling included) and its wait for the bus alone (the part the strip causes).

A report figure, not a test: it depends on this machine's scheduling.  Run with
``python -m m4k_drivers.abi.spi1_share [--seconds S]``.
"""

from __future__ import annotations

import argparse
import statistics
import threading
import time
from typing import Any

from m4k_drivers.abi.auxspi import aux_sclk_hz, AuxSpiBus, AuxSpiController, bus_time_s
from m4k_drivers.abi.devices import As5045, Ws2812Strip
from m4k_drivers.abi.kernel import KernelStandIn, SpiNode

CORE_HZ = 250e6
PIXELS = 8
ENC_HZ = 500_000
LED_PERIOD_S = 0.02            # the RT side's LED datagram period
READ_PERIOD_S = 0.005


def model() -> dict[str, float]:
    """Return the modelled frame wire time and the encoder waits it causes, s."""
    from m4k_drivers.led import pixel as px
    sclk = px.aux_clock_hz(CORE_HZ, 7_000_000)
    frame = px.frame_bytes(PIXELS, 300.0, px.plan(1e9 / sclk))
    wire = bus_time_s(frame, sclk)
    enc = bus_time_s(3, aux_sclk_hz(CORE_HZ, ENC_HZ))
    duty = wire / LED_PERIOD_S
    return {'frame_bytes': frame, 'frame_wire_s': wire, 'encoder_wire_s': enc,
            'every_20ms_mean_wait_s': duty * wire / 2, 'every_20ms_worst_wait_s': wire,
            'every_20ms_share_of_reads_delayed': duty, 'on_change_worst_wait_s': wire}


def _measure(seconds: float, led_mode: str) -> tuple[list[float], list[float]]:
    from periphery import SPI

    from m4k_drivers import config as dconfig
    from m4k_drivers import registry
    from m4k_drivers.led.protocol import LedColor
    bus = AuxSpiBus(CORE_HZ, pace=True)
    kernel = KernelStandIn()
    encoder = AuxSpiController(As5045(lambda: 1234), CORE_HZ, bus)
    kernel.spi['/dev/spidev1.0'] = SpiNode(encoder)
    kernel.spi['/dev/spidev1.2'] = SpiNode(AuxSpiController(Ws2812Strip(PIXELS), CORE_HZ, bus))
    waits: list[float] = []
    stop = threading.Event()
    with kernel:
        handler: Any = None
        if led_mode != 'off':
            section = dconfig.validate_device('led', {'backend': 'pixel_spi', 'pixels': PIXELS},
                                              'devices.led')
            handler = registry.create('led', section, registry.BuildContext())
            handler.configure()
            handler.activate()
            colors = [LedColor(255, 0, 0), LedColor(0, 0, 255)]

            def led() -> None:
                n = 0
                while not stop.wait(LED_PERIOD_S):
                    n += 1
                    if led_mode == 'every':
                        handler.write(colors[n % 2])      # a new colour each time: sent
                    else:
                        handler.write(colors[n // 50 % 2])  # changes once a second
            t = threading.Thread(target=led, daemon=True)
            t.start()
        enc = SPI('/dev/spidev1.0', 2, ENC_HZ)
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            t0 = time.perf_counter()
            enc.transfer(b'\0\0\0')
            waits.append(time.perf_counter() - t0)
            time.sleep(READ_PERIOD_S)
        stop.set()
        enc.close()
        if handler is not None:
            t.join(1.0)
            handler.shutdown()
    return waits, encoder.waits


def main(argv: list[str] | None = None) -> int:
    """Print the model figures and the stand-in measurement."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n', 1)[0])
    ap.add_argument('--seconds', type=float, default=5.0, help='per strip mode (default 5)')
    args = ap.parse_args(argv)
    for k, v in model().items():
        print(f'model {k}: {v * 1e3:.3f} ms' if k.endswith('_s') else f'model {k}: {v:.4g}')
    for mode in ('off', 'every', 'change'):
        calls, queued = _measure(args.seconds, mode)
        for what, w in (('transfer', sorted(calls)), ('bus wait', sorted(queued))):
            p99 = w[int(0.99 * (len(w) - 1))]
            late = sum(1 for x in w if x > 1e-4)
            print(f'stand-in strip {mode:6s} {what:8s}: {len(w)} encoder reads, median '
                  f'{statistics.median(w) * 1e3:.3f} ms, p99 {p99 * 1e3:.3f} ms, max '
                  f'{w[-1] * 1e3:.3f} ms, {late} over 0.1 ms')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
