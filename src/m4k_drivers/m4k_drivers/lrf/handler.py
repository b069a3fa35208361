"""Lifecycle adapter of the URG laser for the driver host, and its backend factories.

``LrfHandler`` (a :class:`m4k_drivers.handler.DeviceHandler`): configure() opens the port and runs
the SCIP connect sequence, activate() starts the MD stream (``mode: stream``, default) or does
nothing (``mode: poll``: each read() sends one GD), read() returns :class:`LrfReading`
(stream mode: the next scan not returned before, waiting up to 1.5 scan times, else a
counted UrgTimeoutError -- never the same scan twice; ``fresh`` marks a new scan),
deactivate() stops the stream, cleanup() closes the port.

Backends (registered for kind ``lrf``): ``real`` opens ``port`` (e.g. ``/dev/ttyACM0``);
``sim`` opens the pty of the :class:`m4k_drivers.lrf.sim.UrgSim` that ``sim_robot`` runs
(``link_path``, default ``<runtime_dir>/sim-urg``), so the pyserial path runs in simulation;
the other sim fields configure that simulated URG.  :func:`make_lrf` with ``backend: sim`` and a
world still builds an in-process pty device (unit tests).
"""

from __future__ import annotations

import logging
from typing import Any, NamedTuple

import numpy as np

from m4k_drivers.handler import DeviceHandler
from m4k_drivers.lrf import scip
from m4k_drivers.lrf.sim import ScanWorld, UrgSim
from m4k_drivers.lrf.urg import UrgDriver, UrgScan, UrgTimeoutError
from m4k_drivers.registry import BuildContext, Param, register

MODES = ('stream', 'poll')


class LrfReading(NamedTuple):
    """One laser reading handed to the host: ranges in mm (values < 20: URG error codes)."""

    ranges_mm: np.ndarray
    geometry: scip.ScanGeometry
    device_stamp: int          # raw 24-bit device ms counter
    stamp_ms: int              # unwrapped device ms
    host_stamp_ns: int         # CLOCK_MONOTONIC when received
    seq: int
    fresh: bool                # False: the same scan as the previous read()
    stamp_ns: int = 0          # CLOCK_MONOTONIC of the first value (m4k_drivers.lrf.stamp)


class LrfHandler(DeviceHandler):
    """URG-04LX handler: a :class:`UrgDriver` (and optionally the pty sim it talks to)."""

    kind = 'lrf'

    def __init__(self, name: str = 'lrf', *, port: str = '', baudrate: int = 115200,
                 mode: str = 'stream', timeout: float = 1.0, error_limit: int = 4,
                 start_step: int | None = None, end_step: int | None = None, cluster: int = 1,
                 sim: UrgSim | None = None, logger: logging.Logger | None = None,
                 **kwargs: Any) -> None:
        super().__init__(name, logger=logger, **kwargs)
        if mode not in MODES:
            raise ValueError(f'lrf mode must be one of {MODES!r}, got {mode!r}')
        if sim is None and not port:
            raise ValueError('lrf: a serial port path is required for the real backend')
        self.port = port
        self.mode = mode
        self.sim = sim
        self._driver_args: dict[str, Any] = {
            'baudrate': baudrate, 'timeout': timeout, 'error_limit': error_limit,
            'start_step': start_step, 'end_step': end_step, 'cluster': cluster,
            'logger': self.log}
        self.driver: UrgDriver | None = None
        self._last_seq = 0

    def on_configure(self) -> None:
        """Start the sim if any, open the port and run the SCIP connect sequence."""
        port = self.port
        if self.sim is not None:
            # Start it once; an unplugged device stays unplugged (the open below fails and the
            # host retries) -- a driver cannot plug a device back in. Restarting a started sim
            # raised RuntimeError, which ended the lrf service for good (issue 10 flake).
            if not self.sim.started:
                self.sim.start()
            port = self.sim.path
        self.driver = UrgDriver(port, **self._driver_args)
        self.driver.open()

    def on_activate(self) -> None:
        """Start the MD stream (stream mode)."""
        assert self.driver is not None
        if self.mode == 'stream':
            self.driver.start_stream()

    def on_read(self) -> LrfReading:
        """Return the latest scan (stream) or poll one (GD)."""
        assert self.driver is not None
        scan: UrgScan | None
        if self.mode == 'poll':
            scan = self.driver.get_scan()
        else:
            # Only a scan not returned before: handing out the last one again would let the
            # host send stale ranges under a new stamp (e.g. while the laser is unplugged).
            # A live URG delivers one every scan_time, so waiting 1.5 of them is enough.
            g = self.driver.geometry
            first = self._last_seq == 0
            wait = self.driver.timeout if first or g is None else 1.5 * g.scan_time
            scan = self.driver.wait_scan(self._last_seq, wait)
            if scan is None:
                raise UrgTimeoutError(f'lrf: no new scan from {self.driver.port!r} within '
                                      f'{wait:.2f} s')
        return self._reading(scan)

    def _reading(self, scan: UrgScan) -> LrfReading:
        fresh = scan.seq != self._last_seq
        self._last_seq = scan.seq
        return LrfReading(scan.ranges_mm, scan.geometry, scan.device_stamp, scan.stamp_ms,
                          scan.host_stamp_ns, scan.seq, fresh, scan.stamp_ns)

    def on_deactivate(self) -> None:
        """Stop the stream (the laser goes off with QT)."""
        if self.driver is not None:
            self.driver.stop_stream()

    def on_cleanup(self) -> None:
        """Close the port and stop the sim; never raises."""
        if self.driver is not None:
            self.driver.close()
            self.driver = None
        if self.sim is not None:
            self.sim.stop()


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
}
_SIM_KEYS = tuple(_SIM)
_DRIVER_KEYS = tuple(_COMMON)


def make_lrf(cfg: dict[str, Any], world: ScanWorld | None = None,
             name: str = 'lrf') -> LrfHandler:
    """Build an LrfHandler from a config section: backend 'real' (port) or 'sim' (world)."""
    backend = cfg.get('backend', 'real')
    driver_args = {k: cfg[k] for k in _DRIVER_KEYS if k in cfg}
    if backend == 'real':
        port = cfg.get('port')
        if not isinstance(port, str) or not port:
            raise ValueError(f'lrf.port: expected a device path, got {port!r}')
        return LrfHandler(name, port=port, **driver_args)
    if backend == 'sim':
        if world is None:
            raise ValueError("lrf backend 'sim' needs a world to ray cast")
        sim_args = {k: cfg[k] for k in _SIM_KEYS if k in cfg and cfg[k] is not None}
        sim = UrgSim(world, **sim_args)
        return LrfHandler(name, sim=sim, **driver_args)
    raise ValueError(f"lrf.backend: expected 'real' or 'sim', got {backend!r}")


@register('lrf', 'real', params={'port': Param(str, '/dev/ttyACM0', 'serial device path'),
                                 **_COMMON})
def _build_real(name: str, params: dict[str, Any], ctx: BuildContext) -> LrfHandler:
    return make_lrf({'backend': 'real', **params}, name=name)


@register('lrf', 'sim', params={**_COMMON, **_SIM})
def _build_sim(name: str, params: dict[str, Any], ctx: BuildContext) -> LrfHandler:
    # The simulated URG runs in sim_robot; the driver opens its pty like /dev/ttyACM0.
    import os
    port = params.get('link_path') or os.path.join(ctx.sim_runtime_dir(), 'sim-urg')
    return make_lrf({'backend': 'real', 'port': port,
                     **{k: v for k, v in params.items() if k in _DRIVER_KEYS}}, name=name)
