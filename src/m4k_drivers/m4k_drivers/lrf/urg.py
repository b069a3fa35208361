"""Serial driver of the Hokuyo URG-04LX-UG01 (SCIP 2.0 over USB CDC-ACM) through pyserial.

Connect sequence: ``SCIP2.0`` (answer ``0`` = switched, ``0E``/``0D`` = already in SCIP 2.0),
``QT`` (stops a stream a previous client left running; its leftovers are skipped; a sensor
left in time-adjust mode refuses it with ``0E`` and is taken out of it with ``TM2`` first), ``VV``,
``PP`` (the scan geometry comes from these parameters, never from constants), ``II``, the
clock calibration (``TM0``, ``TM1`` x 8: the sensor's ms counter against the midpoint of each
request/reply, the quickest reply kept; ``TM2``: :mod:`m4k_drivers.lrf.stamp`; a sensor that
refuses TM is stamped from the scan geometry alone, with a warning), ``BM`` (laser on; ``02``
= already on).  Stamps refer to step 0 (the sensor's reference point); a scan's ``stamp_ns``
is when its first value (step ``start``) was measured.

Two ways to read: :meth:`UrgDriver.get_scan` polls one GD scan; :meth:`UrgDriver.start_stream`
sends an endless MD request and a reader thread keeps the latest scan (``latest``/``wait_scan``).
Like urg_node2, errors (timeouts, bad sums, refused commands) are counted; ``error_limit``
consecutive errors, or the port failing (unplug: EIO), trigger a reconnect: close, reopen the same
configured path (a udev or sim symlink survives a replug), redo the connect sequence.

Errors (all :class:`m4k_drivers.handler.DriverError`, so the lifecycle can classify them)::

    UrgError
      UrgPortError        the port path does not exist (names the path)     DeviceNotFoundError
      UrgPermissionError  the port exists but may not be opened              DevicePermissionError
      UrgIOError          the port failed (unplug, EIO)                      DeviceIOError
      UrgTimeoutError     no (complete) answer in time                       DeviceIOError
      UrgProtocolError    bad sum, malformed reply, refused command          DeviceProtocolError
"""

from __future__ import annotations

from dataclasses import dataclass, fields
import errno as errno_mod
import logging
import threading
import time
from typing import Any, Callable

import numpy as np
import serial

from m4k_drivers.handler import (
    DeviceIOError,
    DeviceNotFoundError,
    DevicePermissionError,
    DeviceProtocolError,
    DriverError,
)
from m4k_drivers.lrf import scip
from m4k_drivers.lrf.stamp import ScanStamper

_ALREADY_SCIP2 = ('0', '00', '0D', '0E')
TM_SAMPLES = 8          # TM1 exchanges at connect; the one with the shortest round trip wins


class UrgError(DriverError):
    """Base of the URG driver errors."""


class UrgPortError(UrgError, DeviceNotFoundError):
    """The configured serial port does not exist; ``path`` names it."""

    def __init__(self, path: str, detail: str = '') -> None:
        super().__init__(f'URG port {path!r} does not exist'
                         + (f' ({detail})' if detail else ''))
        self.path = path
        self.errno = errno_mod.ENOENT


class UrgPermissionError(UrgError, DevicePermissionError):
    """The port exists but may not be opened."""


class UrgIOError(UrgError, DeviceIOError):
    """The port failed while open (device unplugged, EIO)."""


class UrgTimeoutError(UrgError, DeviceIOError):
    """The device did not answer in time."""


class UrgProtocolError(UrgError, DeviceProtocolError):
    """A reply failed its sum, was malformed, or reported a non-success status."""


@dataclass
class UrgStats:
    """Counters of the driver (snapshots are copies)."""

    scans: int = 0
    checksum_errors: int = 0
    format_errors: int = 0
    status_errors: int = 0
    stray_bytes: int = 0
    timeouts: int = 0
    io_errors: int = 0
    reconnects: int = 0
    reconnect_failures: int = 0
    consecutive_errors: int = 0


@dataclass(frozen=True)
class UrgScan:
    """One scan as handed out by the driver."""

    seq: int                    # driver scan counter (1, 2, ...)
    ranges_mm: np.ndarray       # uint32 mm; values < 20 are URG error codes
    geometry: scip.ScanGeometry
    device_stamp: int           # raw 24-bit device ms counter
    stamp_ms: int               # device ms unwrapped since the first scan of this connection
    host_stamp_ns: int          # CLOCK_MONOTONIC when the scan's last bytes were read
    stamp_ns: int = 0           # CLOCK_MONOTONIC when its first value was measured (estimated)


SerialFactory = Callable[..., Any]


class UrgDriver:
    """SCIP 2.0 client of one URG on one serial port."""

    def __init__(self, port: str, baudrate: int = 115200, *, timeout: float = 1.0,
                 error_limit: int = 4, start_step: int | None = None,
                 end_step: int | None = None, cluster: int = 1, reconnect_delay: float = 0.2,
                 serial_factory: SerialFactory = serial.serial_for_url,
                 logger: logging.Logger | None = None) -> None:
        if not isinstance(port, str) or not port:
            raise ValueError(f'URG port must be a non-empty path or URL, got {port!r}')
        if timeout <= 0 or error_limit < 1 or reconnect_delay < 0:
            raise ValueError(f'bad URG timing: timeout={timeout!r} error_limit={error_limit!r} '
                             f'reconnect_delay={reconnect_delay!r}')
        self.port = port
        self.baudrate = baudrate
        self.timeout = timeout
        self.error_limit = error_limit
        self.reconnect_delay = reconnect_delay
        self._steps = (start_step, end_step, cluster)
        self._factory = serial_factory
        self.log = logger or logging.getLogger('m4k_drivers.lrf.urg')
        self._serial: Any = None
        self._parser = scip.ScipParser()
        self._stats = UrgStats()
        self._unwrap = scip.TimestampUnwrapper()
        self._stamper = ScanStamper()
        self._rx_ns = 0
        self._io_lock = threading.RLock()
        self._cond = threading.Condition()
        self._latest: UrgScan | None = None
        self._reader: threading.Thread | None = None
        self._stop = threading.Event()
        self.spec: scip.SensorSpec | None = None
        self.geometry: scip.ScanGeometry | None = None
        self.version: dict[str, str] = {}
        self.status: dict[str, str] = {}

    # -- connection -----------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        """Return True while the port is open and the connect sequence succeeded."""
        return self._serial is not None

    def open(self) -> None:
        """Open the port and run the connect sequence (raises UrgError on failure)."""
        with self._io_lock:
            self._open_port()
            try:
                self._handshake()
            except BaseException:
                self._close_port()
                raise

    def close(self) -> None:
        """Stop streaming (QT), close the port; never raises."""
        self.stop_stream()
        with self._io_lock:
            if self._serial is not None:
                try:
                    self._serial.write(scip.build_command('QT'))
                except (serial.SerialException, OSError):
                    pass
            self._close_port()

    def __enter__(self) -> UrgDriver:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def stats(self) -> UrgStats:
        """Return a snapshot of the counters."""
        snap = UrgStats(**{f.name: getattr(self._stats, f.name) for f in fields(UrgStats)})
        snap.stray_bytes = self._parser.stray_bytes
        snap.checksum_errors = self._parser.checksum_errors
        snap.format_errors = self._parser.format_errors
        return snap

    def _open_port(self) -> None:
        self._close_port()
        try:
            self._serial = self._factory(self.port, baudrate=self.baudrate, timeout=0.05,
                                         write_timeout=self.timeout)
        except (serial.SerialException, OSError) as exc:
            err = getattr(exc, 'errno', None)
            if err in (errno_mod.ENOENT, errno_mod.ENODEV, errno_mod.ENXIO):
                raise UrgPortError(self.port, str(exc)) from exc
            if err in (errno_mod.EACCES, errno_mod.EPERM):
                raise UrgPermissionError(f'URG port {self.port!r}: permission denied '
                                         f'(errno {err})') from exc
            raise UrgIOError(f'URG port {self.port!r}: cannot open: {exc}') from exc
        self._parser.reset()

    def _close_port(self) -> None:
        if self._serial is not None:
            try:
                self._serial.close()
            except (serial.SerialException, OSError):
                pass
            self._serial = None

    def _handshake(self) -> None:
        try:
            self._serial.reset_input_buffer()
        except (serial.SerialException, OSError) as exc:
            raise UrgIOError(f'URG port {self.port!r}: {exc}') from exc
        self._command(scip.build_command('SCIP2.0'), 'SCIP2.0', _ALREADY_SCIP2)
        qt = self._command(scip.build_command('QT'), 'QT', ('00', '0E'))
        if qt.status == '0E':
            # A previous client left the sensor in time-adjust mode (TM0), where it refuses
            # every other command (spec 8.6); leave it with TM2 as urg_c does, then go on.
            self.log.warning('URG on %s is in time-adjust mode; sending TM2', self.port)
            self._command(scip.build_command('TM2'), 'TM', ('00', '03'))
            self._command(scip.build_command('QT'), 'QT')
        self.version = scip.parse_params(self._command(scip.build_command('VV'), 'VV'))
        params = scip.parse_params(self._command(scip.build_command('PP'), 'PP'))
        try:
            self.spec = scip.SensorSpec.from_params(params)
            self.geometry = self.spec.geometry(*self._steps)
        except (scip.ScipError, ValueError) as exc:
            raise UrgProtocolError(f'URG on {self.port!r}: {exc}') from exc
        self.status = scip.parse_params(self._command(scip.build_command('II'), 'II'))
        self._unwrap.reset()
        self._stamper.reset()
        g = self.geometry
        # Without a calibration, at least the sweep from step 0 past the last step is known.
        self._stamper.known_latency_ns = round((g.end + 1) * g.time_increment / g.cluster * 1e9)
        self._calibrate_clock()
        self._command(scip.build_command('BM'), 'BM', ('00', '02'))
        self._stats.consecutive_errors = 0

    def _calibrate_clock(self) -> None:
        """Measure host - sensor clock offset in time-adjust mode (TM0, TM1 x N, TM2)."""
        try:
            self._command(scip.build_command('TM0'), 'TM', ('00', '02'))
        except UrgProtocolError as exc:
            self.log.warning('URG on %s refuses time adjust (%s): scan stamps carry the '
                             'transfer delay', self.port, exc)
            return
        best: tuple[int, int] | None = None      # (round trip ns, offset ns)
        try:
            for _ in range(TM_SAMPLES):
                t0 = time.monotonic_ns()
                resp = self._command(scip.build_command('TM1'), 'TM')
                t1 = time.monotonic_ns()
                if not resp.lines:
                    raise UrgProtocolError(f'URG on {self.port!r}: TM1 reply without a time')
                try:
                    raw = scip.decode(resp.lines[0])
                    sensor_ms = self._unwrap.update(raw)
                except ValueError as exc:
                    raise UrgProtocolError(f'URG on {self.port!r}: TM1: {exc}') from exc
                # Both the TM1 time and scan stamps are the same floored ms counter: the
                # floor's half-ms bias cancels between them.
                sample = (t1 - t0, (t0 + t1) // 2 - sensor_ms * 1_000_000)
                if best is None or sample[0] < best[0]:
                    best = sample
        finally:
            self._command(scip.build_command('TM2'), 'TM', ('00', '03'))
        if best is not None:
            self._stamper.calibrate(best[1])
            self.log.debug('URG on %s: clock offset %d ns (round trip %d ns)', self.port,
                           best[1], best[0])

    # -- request / response -----------------------------------------------------------------
    def _write(self, data: bytes) -> None:
        try:
            self._serial.write(data)
        except (serial.SerialException, OSError) as exc:
            self._stats.io_errors += 1
            self._close_port()
            raise UrgIOError(f'URG port {self.port!r}: write failed: {exc}') from exc

    def _read_some(self) -> bytes:
        try:
            data = self._serial.read(max(1, self._serial.in_waiting))
            self._rx_ns = time.monotonic_ns()    # receive time of the bytes just read
            return data
        except (serial.SerialException, OSError) as exc:
            self._stats.io_errors += 1
            self._close_port()
            raise UrgIOError(f'URG port {self.port!r}: read failed: {exc}') from exc

    def _command(self, line: bytes, expect: str,
                 ok: tuple[str, ...] = ('00',)) -> scip.Response:
        """Send one command and wait for its reply; other replies are skipped."""
        if self._serial is None:
            raise UrgIOError(f'URG port {self.port!r} is not open')
        self._write(line)
        deadline = time.monotonic() + self.timeout
        while time.monotonic() < deadline:
            for item in self._parser.feed(self._read_some()):
                if isinstance(item, scip.ScipError):
                    if item.echo is not None and item.echo.startswith(expect.encode()):
                        raise UrgProtocolError(f'URG reply to {expect}: {item}') from item
                    continue          # a leftover of an earlier stream: counted by the parser
                if item.command != expect or (expect == 'MD' and item.status == '99'):
                    continue          # not ours, or scan data of a stream (not its ack)
                if item.status not in ok:
                    self._stats.status_errors += 1
                    err = scip.ScipStatusError(item.command, item.status)
                    raise UrgProtocolError(f'URG on {self.port!r}: {err}') from err
                return item
        self._stats.timeouts += 1
        raise UrgTimeoutError(f'URG on {self.port!r}: no reply to {expect} within '
                              f'{self.timeout} s')

    def _make_scan(self, data: scip.ScanData) -> UrgScan:
        assert self.geometry is not None
        if data.count != self.geometry.count:
            raise UrgProtocolError(f'URG scan has {data.count} values, expected '
                                   f'{self.geometry.count}')
        self._stats.scans += 1
        g = self.geometry
        stamp_ms = self._unwrap.update(data.timestamp)
        # The device stamps step 0; the first value is measured ``start`` steps later.
        step0_ns = self._stamper.update(stamp_ms, self._rx_ns)
        first_ns = step0_ns + round(g.start * g.time_increment / g.cluster * 1e9)
        return UrgScan(self._stats.scans, data.ranges, g, data.timestamp, stamp_ms,
                       self._rx_ns, min(first_ns, self._rx_ns))

    def _count_error(self) -> bool:
        """Count one consecutive error; return True when the limit asks for a reconnect."""
        self._stats.consecutive_errors += 1
        return self._stats.consecutive_errors >= self.error_limit

    def reconnect(self) -> bool:
        """Close, reopen the configured path and redo the connect sequence; True on success."""
        with self._io_lock:
            self._close_port()
            try:
                self.open()
            except UrgError as exc:
                self._stats.reconnect_failures += 1
                self.log.warning('URG reconnect to %s failed: %s', self.port, exc)
                return False
            self._stats.reconnects += 1
            self.log.info('URG reconnected on %s', self.port)
            return True

    # -- polling (GD) ------------------------------------------------------------------------
    def get_scan(self) -> UrgScan:
        """Request and return one GD scan; on failure count, maybe reconnect, and raise."""
        if self._reader is not None:
            raise RuntimeError('get_scan() while streaming; use latest()/wait_scan()')
        with self._io_lock:
            if self._serial is None and not self.reconnect():
                raise UrgIOError(f'URG on {self.port!r} is disconnected (reconnect failed)')
            g = self.geometry
            assert g is not None
            try:
                resp = self._command(scip.gd_command(g.start, g.end, g.cluster), 'GD')
                scan = self._make_scan(scip.parse_scan(resp))
            except UrgIOError:
                raise                        # port closed: the next call reconnects
            except (UrgError, scip.ScipError) as exc:
                if self._count_error():
                    self.reconnect()
                if isinstance(exc, scip.ScipError):
                    raise UrgProtocolError(f'URG GD reply: {exc}') from exc
                raise
            self._stats.consecutive_errors = 0
            return scan

    # -- streaming (MD) ------------------------------------------------------------------------
    def start_stream(self) -> None:
        """Send an endless MD request and start the reader thread."""
        if self._reader is not None:
            return
        with self._io_lock:
            if self._serial is None:
                self.open()
            self._send_md()
        self._stop.clear()
        self._reader = threading.Thread(target=self._read_loop, name='urg-reader', daemon=True)
        self._reader.start()

    def stop_stream(self) -> None:
        """Stop the reader thread and the device stream (QT)."""
        reader, self._reader = self._reader, None
        if reader is None:
            return
        self._stop.set()
        reader.join(timeout=5.0)
        with self._io_lock:
            if self._serial is not None:
                try:
                    self._command(scip.build_command('QT'), 'QT')
                except UrgError as exc:
                    self.log.warning('URG QT after stream failed: %s', exc)

    def latest(self) -> UrgScan | None:
        """Return the newest streamed scan (None before the first)."""
        with self._cond:
            return self._latest

    def wait_scan(self, after_seq: int = 0, timeout: float = 1.0) -> UrgScan | None:
        """Wait for a streamed scan newer than ``after_seq``; None on timeout."""
        with self._cond:
            self._cond.wait_for(lambda: self._latest is not None
                                and self._latest.seq > after_seq, timeout=timeout)
            latest = self._latest
        return latest if latest is not None and latest.seq > after_seq else None

    def _send_md(self) -> None:
        g = self.geometry
        assert g is not None
        self._command(scip.md_command(g.start, g.end, g.cluster, 0, 0), 'MD')

    def _read_loop(self) -> None:
        last_rx = time.monotonic()
        while not self._stop.is_set():
            with self._io_lock:
                if self._serial is None:
                    if not (self.reconnect() and self._restart_stream()):
                        self._stop.wait(self.reconnect_delay)
                    last_rx = time.monotonic()
                    continue
                try:
                    data = self._read_some()
                except UrgIOError as exc:
                    self.log.warning('%s', exc)
                    continue
                now = time.monotonic()
                if data:
                    last_rx = now
                    need_reconnect = self._on_stream_bytes(data)
                elif now - last_rx > self.timeout:
                    self._stats.timeouts += 1
                    last_rx = now
                    need_reconnect = self._count_error()
                else:
                    need_reconnect = False
                if need_reconnect:
                    self.reconnect()
                    self._restart_stream()
                    last_rx = time.monotonic()

    def _restart_stream(self) -> bool:
        if self._serial is None:
            return False
        try:
            self._send_md()
        except UrgError as exc:
            self.log.warning('URG MD restart failed: %s', exc)
            return False
        return True

    def _on_stream_bytes(self, data: bytes) -> bool:
        need_reconnect = False
        for item in self._parser.feed(data):
            if isinstance(item, scip.ScipError):
                need_reconnect |= self._count_error()
                continue
            if item.command != 'MD' or item.status == '00':
                continue                                  # ack or an unrelated reply
            try:
                scan = self._make_scan(scip.parse_scan(item))
            except (scip.ScipError, UrgError) as exc:
                if isinstance(exc, scip.ScipStatusError):
                    self._stats.status_errors += 1
                self.log.debug('URG stream: %s', exc)
                need_reconnect |= self._count_error()
                continue
            self._stats.consecutive_errors = 0
            with self._cond:
                self._latest = scan
                self._cond.notify_all()
        return need_reconnect
