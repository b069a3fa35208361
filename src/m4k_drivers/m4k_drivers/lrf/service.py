"""How the driver host serves the laser: REQUEST -> the next scan -> LASER_SCAN.

The datagram is stamped at acquisition (the first value, the sensor's clock mapped onto ours:
:mod:`m4k_drivers.lrf.stamp`), not at send time.  No new scan (laser unplugged, stream
silent): no reply, so nothing stale goes out under a new stamp.
"""

from __future__ import annotations

from typing import Any

from m4k_drivers.handler import State, Status
from m4k_drivers.lrf.handler import LrfHandler, LrfReading
from m4k_drivers.registry import Replier, ServiceSpec
from m4k_rt.protocol import Kind, SCAN_ERROR_CODE_MAX

__all__ = ['SERVICE']


def serve(handler: LrfHandler, msg: Any, tx: Replier) -> None:
    """Read the next scan and send it as one LASER_SCAN datagram."""
    if handler.state != State.ACTIVE:
        return
    r = handler.read()
    if r.status != Status.OK:
        return
    v = r.value
    g = v.geometry
    # tolist(): Python ints in one C loop (a third of the cost of a per-value int()).
    tx.send(Kind.LASER_SCAN, g.angle_min, g.angle_increment, g.range_min, g.range_max,
            g.scan_time, g.time_increment, v.device_stamp, v.ranges_mm.tolist(),
            stamp_ns=v.stamp_ns)


def format_reading(value: LrfReading) -> str:
    """Return the ``--print`` line of one scan: size, valid values, nearest and front range."""
    ranges = [int(x) for x in value.ranges_mm]
    valid = [x for x in ranges if x > SCAN_ERROR_CODE_MAX]
    front = ranges[len(ranges) // 2] if ranges else 0
    return (f'lrf seq={value.seq} n={len(ranges)} valid={len(valid)} '
            f'min={min(valid, default=0) / 1000:.3f} m front={front / 1000:.3f} m '
            f'stamp={value.device_stamp}')


SERVICE: ServiceSpec[LrfHandler] = ServiceSpec(
    accepts=frozenset({Kind.REQUEST}), serve=serve, format=format_reading)
