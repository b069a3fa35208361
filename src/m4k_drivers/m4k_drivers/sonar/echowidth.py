"""``sonar_echo_width``: measure the US-100's echo width with nothing in range (bring-up).

Point the sensor at open space (nothing within 5 m in its 15 deg cone: up a stairwell, out
of an open door, at the sky) and run::

    sonar_echo_width --overlay my_robot.yaml [--pings 20]

It opens the configured ``gpio`` sonar (the real backend: TRIG and ECHO on the gpiochip),
pings with a generous wait (``--wait``, 0.5 s), and reports each echo width and their
spread.  The no-echo width is a property of the part (the HC-SR04's is documented as 38 ms;
no US-100 document found gives the US-100's, hence this measurement): put the printed
``no_echo_s`` and ``timeout_s`` into ``devices.sonar`` (docs/real-robot.md, section 7).
Exit 0 when every ping gave a whole pulse, 1 otherwise.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from typing import Sequence, TextIO

from m4k_drivers.sonar import protocol as p

__all__ = ['main', 'measure_widths', 'report']


def measure_widths(sonar: object, pings: int, wait_s: float) -> list[float | None]:
    """Ping ``pings`` times; return each echo width in s (None: no whole pulse)."""
    out: list[float | None] = []
    for _ in range(pings):
        edges = sonar.edges(wait_s)            # type: ignore[attr-defined]
        out.append(p.edges_to_width(edges))
    return out


def report(widths: Sequence[float | None], out: TextIO, margin_s: float = 0.01) -> int:
    """Print the widths and the settings they call for; return the exit code."""
    whole = [w for w in widths if w is not None]
    for i, w in enumerate(widths):
        print(f'ping {i + 1}: ' + ('no whole pulse' if w is None else f'{w * 1000:.2f} ms'),
              file=out)
    if not whole:
        print('no echo pulse at all: TRIG/ECHO wiring, the mode jumper (off = pulse mode), or a '
              'longer --wait', file=out)
        return 1
    hi = max(whole)
    print(f'{len(whole)}/{len(widths)} pulses: median {statistics.median(whole) * 1000:.2f} ms, '
          f'min {min(whole) * 1000:.2f} ms, max {hi * 1000:.2f} ms', file=out)
    if hi < p.range_to_pulse(p.MAX_RANGE_M):
        print(f'the longest pulse is an echo within {p.MAX_RANGE_M} m: something is in the '
              'cone -- point the sensor at open space', file=out)
        return 1
    print(f'devices.sonar: no_echo_s: {hi:.3f}   timeout_s: {hi + margin_s:.3f}', file=out)
    return 0 if len(whole) == len(widths) else 1


def main(argv: list[str] | None = None) -> int:
    """Run the measurement on the configured sonar."""
    from m4k_drivers import config as dconfig
    from m4k_drivers.handler import DriverError
    from m4k_drivers.host import load_raw_config
    from m4k_drivers.sonar.real import open_gpio_sonar
    from m4k_rt import rosargs
    ap = argparse.ArgumentParser(prog='sonar_echo_width', description=__doc__.split('\n')[0])
    ap.add_argument('--config', help='one config file instead of the layered configuration')
    ap.add_argument('--overlay', help='overlay YAML (your robot)')
    ap.add_argument('--pings', type=int, default=20)
    ap.add_argument('--wait', type=float, default=0.5, help='wait per ping for the edges, s')
    args = rosargs.parse_args(ap, argv)
    try:
        raw = load_raw_config(args.config, args.overlay)
        section = (raw.get('devices') or {}).get('sonar') or {}
        s = dconfig.validate_device('sonar', section, 'devices.sonar')
        if s['backend'] not in ('gpio', 'real'):
            raise ValueError(f"devices.sonar.backend: {s['backend']!r}; the measurement needs "
                             "the gpio backend (the iio driver hides the pulse)")
        if not 1 <= args.pings <= 1000 or not 0.05 <= args.wait <= 2.0:
            raise ValueError('--pings 1..1000, --wait 0.05..2 s')
    except (dconfig.ConfigError, ValueError) as exc:
        print(f'sonar_echo_width: {exc}', file=sys.stderr)
        return 2
    try:
        sonar = open_gpio_sonar(s['chip'], s['trigger_line'], s['echo_line'])
    except DriverError as exc:
        print(f'sonar_echo_width: {exc}', file=sys.stderr)
        return 1
    try:
        return report(measure_widths(sonar, args.pings, args.wait), sys.stdout)
    except DriverError as exc:
        print(f'sonar_echo_width: {exc}', file=sys.stderr)
        return 1
    finally:
        sonar.close()


if __name__ == '__main__':
    raise SystemExit(main())
