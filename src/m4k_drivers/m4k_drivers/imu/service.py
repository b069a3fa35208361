"""How the driver host serves the IMU: REQUEST -> IMU, or a stream at ``rate_hz``.

With ``stream: true`` the host sends a sample every ``1 / rate_hz`` s without waiting for
REQUESTs (and still answers any that come).
"""

from __future__ import annotations

import math
from typing import Any, Mapping

from m4k_drivers.handler import State, Status
from m4k_drivers.imu.handler import ImuHandler
from m4k_drivers.imu.protocol import ImuSample
from m4k_drivers.registry import Replier, ServiceSpec
from m4k_rt.protocol import Kind

__all__ = ['SERVICE']


def serve(handler: ImuHandler, msg: Any, tx: Replier) -> None:
    """Read one sample and send it as an IMU datagram (REQUEST or stream tick alike)."""
    if handler.state != State.ACTIVE:
        return
    r = handler.read()
    if r.status == Status.OK:
        s = r.value
        tx.send(Kind.IMU, *s.orientation, *s.angular_velocity, *s.linear_acceleration, s.status,
                stamp_ns=handler.sample_ns)       # the data-ready edge when known


def format_reading(value: ImuSample) -> str:
    """Return the ``--print`` line of one sample."""
    r, p, y = (math.degrees(a) for a in value.rpy)
    g, a = value.angular_velocity, value.linear_acceleration
    return (f'imu rpy=({r:+7.2f},{p:+7.2f},{y:+7.2f}) deg '
            f'gyro=({g[0]:+.4f},{g[1]:+.4f},{g[2]:+.4f}) rad/s '
            f'acc=({a[0]:+.3f},{a[1]:+.3f},{a[2]:+.3f}) m/s^2 '
            f'T={value.temperature:.1f}C status={value.status}')


def stream_period(section: Mapping[str, Any]) -> float | None:
    """Return the stream period (``stream: true``), else None: answer REQUESTs only."""
    if not section.get('stream'):
        return None
    return 1.0 / float(section.get('rate_hz', 100.0))


def _read_timeout(section: Mapping[str, Any]) -> float:
    period = stream_period(section)
    return 0.1 if period is None else period


SERVICE: ServiceSpec[ImuHandler] = ServiceSpec(
    accepts=frozenset({Kind.REQUEST}), serve=serve, format=format_reading,
    read_timeout=_read_timeout, stream_period=stream_period, path_key='bus', bus_arg=True)
