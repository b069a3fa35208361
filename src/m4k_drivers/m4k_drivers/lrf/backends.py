"""The laser's backends and driver-host service, registered for device kind ``lrf``.

``real`` opens ``port`` (e.g. ``/dev/ttyACM0``) with pyserial; ``sim`` opens the pty of the
:class:`m4k_drivers.lrf.sim.UrgSim` that ``sim_robot`` runs (``link_path``, default
``<runtime_dir>/sim-urg``), so the same pyserial path runs in simulation; the other sim fields
configure that simulated URG inside sim_robot.  Both build an :class:`LrfHandler` around an
opener of the port, like every other device.  This module (not the package) is what the
registry imports, so importing :mod:`m4k_drivers.lrf` or its pure ``scip`` loads no pyserial.
"""

from __future__ import annotations

import logging
import os
from typing import Any, Callable

from m4k_drivers.lrf.handler import LrfHandler
from m4k_drivers.lrf.service import SERVICE
from m4k_drivers.lrf.urg import UrgDriver
from m4k_drivers.registry import BuildContext, Param, register, register_service

__all__ = ['urg_opener']

_COMMON = {
    'baudrate': Param(int, 115200, 'serial bit rate (ignored by USB CDC-ACM)'),
    'mode': Param(str, 'stream', "'stream' (MD + reader thread) or 'poll' (one GD per read)"),
    'timeout': Param(float, 1.0, 's to wait for a reply; a stream silent this long is an error'),
    'error_limit': Param(int, 4, 'consecutive errors that trigger a reconnect'),
    'start_step': Param((int, type(None)), None, 'first step (default: AMIN from PP)'),
    'end_step': Param((int, type(None)), None, 'last step (default: AMAX from PP)'),
    'cluster': Param(int, 1, 'adjacent steps merged per value (0..99)'),
}
_SIM = {
    'link_path': Param((str, type(None)), None, 'stable symlink to the pty (survives replug)'),
    'noise_mm': Param(float, 10.0, 'Gaussian range noise sigma, mm'),
    'seed': Param(int, 0, 'noise seed'),
    'scan_period': Param((float, type(None)), None, 's per scan (default: 60/SCAN rpm)'),
    'mount': Param(list, [0.0, 0.0, 0.0], 'sensor pose in base_link: x m, y m, yaw rad'),
    'timestamp_start': Param(int, 0, 'initial 24-bit device ms counter (test wrap-around)'),
    'transfer_bps': Param(float, 1_000_000.0, 'link data rate of the simulated URG, bit/s (10 '
                          'bits a byte): a scan leaves this long after its sweep'),
}
_DRIVER_KEYS = ('baudrate', 'timeout', 'error_limit', 'start_step', 'end_step', 'cluster')


def urg_opener(port: str, params: dict[str, Any], name: str = 'lrf') -> Callable[[], UrgDriver]:
    """Return an opener of the URG on ``port`` with the driver fields of a device section."""
    if not isinstance(port, str) or not port:
        raise ValueError(f'devices.{name}.port: expected a device path, got {port!r}')
    kw = {k: params[k] for k in _DRIVER_KEYS if k in params}
    log = logging.getLogger(f'm4k_drivers.{name}')
    return lambda: UrgDriver(port, logger=log, **kw)


def _handler(name: str, port: str, params: dict[str, Any]) -> LrfHandler:
    return LrfHandler(urg_opener(port, params, name), name=name,
                      mode=params.get('mode', 'stream'))


@register('lrf', 'real', params={'port': Param(str, '/dev/ttyACM0', 'serial device path'),
                                 **_COMMON})
def _build_real(name: str, params: dict[str, Any], ctx: BuildContext) -> LrfHandler:
    return _handler(name, params['port'], params)


@register('lrf', 'sim', params={**_COMMON, **_SIM})
def _build_sim(name: str, params: dict[str, Any], ctx: BuildContext) -> LrfHandler:
    # The simulated URG runs in sim_robot; the driver opens its pty like /dev/ttyACM0.
    port = params.get('link_path') or os.path.join(ctx.sim_runtime_dir(), 'sim-urg')
    return _handler(name, port, params)


# How the driver host answers the RT side for this kind (m4k_drivers.lrf.service).
register_service('lrf', SERVICE)
