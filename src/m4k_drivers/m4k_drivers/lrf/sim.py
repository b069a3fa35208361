"""A simulated URG-04LX speaking SCIP 2.0 on a pseudo terminal.

The device answers on the master side of an ``os.openpty()`` pair whose slave is put in raw
mode; the driver opens the slave path through pyserial exactly as it opens ``/dev/ttyACM0``, so
the real serial and protocol code runs in simulation. With ``link_path`` the sim keeps a stable
symlink (e.g. ``<tmp>/ttyACM0 -> /dev/pts/N``) that :meth:`UrgSim.replug` re-points to a fresh pty,
so a driver configured with that path reconnects to the same name, as after a USB replug.

Commands: SCIP2.0, VV, PP, II, BM, QT, RS, TM, GD/GS, MD/MS (anything else: status 0E; in
time-adjust mode everything but TM). Ranges come
from ray casting a world (:class:`ScanWorld`: the shared :class:`m4k_drivers.world.World`, or
:class:`RectRoom` for standalone tests). Timestamps come from a 24-bit ms counter that can start
near its wrap.

Timing, as the real sensor: the mirror turns continuously (``scan_period`` per turn, ``ARES``
steps); a scan's timestamp is the device counter when the mirror passes step 0 (the start of
the sweep, :data:`STAMP_STEP`); step ``i`` is measured ``i`` step periods later, each with the
robot pose of that instant (interpolated between the poses sampled at the start and the end of
the sweep); the response is formatted once the mirror has passed the last requested step and
its bytes are released after the transfer time (``transfer_bps`` bits per second, 10 bits a
byte).  So a scan arrives (end + 1) / ARES x scan_period + transfer after its stamp -- about
71 ms + 21 ms for AMAX 725 -- like the real URG, and a driver that takes the arrival as the
stamp is that late.  Fault hooks: corrupt the sums of the next N scans, inject stray bytes,
unplug and replug. Simplification: SCIP 1.1 is not emulated; the sim only remembers whether the
SCIP2.0 switch was sent (first switch answers ``0``, later ones ``0E`` as a device already in
SCIP 2.0).

All pty fds are opened and closed by the sim's own thread (or before it starts / after it
stops), so unplugging never closes an fd under a running ``select``.
"""

from __future__ import annotations

from collections import Counter
import errno
import math
import os
import select
import threading
import time
import tty
from typing import Any, Callable, Protocol, Sequence

import numpy as np

from m4k_drivers.lrf import scip

URG04LX_PP: dict[str, str] = {
    'MODL': 'URG-04LX(Hokuyo Automatic Co.,Ltd.)', 'DMIN': '20', 'DMAX': '5600', 'ARES': '1024',
    'AMIN': '44', 'AMAX': '725', 'AFRT': '384', 'SCAN': '600',
}
URG04LX_VV: dict[str, str] = {
    'VEND': 'Hokuyo Automatic Co.,Ltd.', 'PROD': 'SOKUIKI Sensor URG-04LX',
    'FIRM': '3.4.03(m4k sim)', 'PROT': 'SCIP 2.0', 'SERI': 'H0000000',
}
MAX_STEP = 768            # highest step a request may name (spec table: URG-04LX step E)
FAR_CODE = 0              # no surface within DMAX: "possibly at 22 m"
NEAR_CODE = 1             # closer than DMIN: too little usable reflected light
LOW_LIGHT_CODE = 2        # a black surface: "reflected light has low intensity" (Table 3)
DEAD_ZONE_CODE = 19       # steps outside AMIN..AMAX: non-measurable
OUT_LIMIT = 1 << 20       # bytes queued for a reader that does not read; beyond: dropped
STAMP_STEP = 0            # the step a scan's timestamp refers to (the start of the sweep)
TRANSFER_BPS = 1_000_000  # effective link rate: USB full speed CDC-ACM, ~1 Mbit/s of data
ORIGIN_CHUNK = 32         # steps sharing one interpolated sensor origin (yaw is per step)


class ScanWorld(Protocol):
    """What the sim needs from a world (met by m4k_drivers.world.World and RectRoom)."""

    def pose(self) -> Sequence[float]:
        """Return the robot pose (x, y, yaw) in the world frame."""

    def raycast_many(self, origin: Sequence[float], angles: Any, max_range: float) -> np.ndarray:
        """Return the distance along each world angle to the nearest surface (inf: none)."""


class RectRoom:
    """An axis-aligned rectangular room with a settable pose: a standalone test world."""

    def __init__(self, xmin: float, ymin: float, xmax: float, ymax: float,
                 pose: Sequence[float] = (0.0, 0.0, 0.0)) -> None:
        if not (xmin < xmax and ymin < ymax):
            raise ValueError(f'bad room bounds {(xmin, ymin, xmax, ymax)!r}')
        self.bounds = (xmin, ymin, xmax, ymax)
        self._pose = tuple(float(v) for v in pose)

    def set_pose(self, x: float, y: float, yaw: float) -> None:
        """Move the robot."""
        self._pose = (float(x), float(y), float(yaw))

    def pose(self) -> tuple[float, float, float]:
        """Return the robot pose (x, y, yaw)."""
        return self._pose  # type: ignore[return-value]

    def raycast_many(self, origin: Sequence[float], angles: Any, max_range: float) -> np.ndarray:
        """Return the distance from ``origin`` to the walls along each angle (inf beyond max)."""
        xmin, ymin, xmax, ymax = self.bounds
        ang = np.atleast_1d(np.asarray(angles, dtype=float))
        c, s = np.cos(ang), np.sin(ang)
        with np.errstate(divide='ignore', invalid='ignore'):
            tx = np.where(c > 1e-12, (xmax - origin[0]) / c,
                          np.where(c < -1e-12, (xmin - origin[0]) / c, np.inf))
            ty = np.where(s > 1e-12, (ymax - origin[1]) / s,
                          np.where(s < -1e-12, (ymin - origin[1]) / s, np.inf))
        t = np.minimum(tx, ty)
        return np.where(t <= max_range, t, np.inf)


class UrgSim:
    """A SCIP 2.0 URG-04LX on a pseudo terminal, served by its own thread."""

    def __init__(self, world: ScanWorld, *, link_path: str | None = None,
                 mount: Sequence[float] = (0.0, 0.0, 0.0), noise_mm: float = 0.0, seed: int = 0,
                 scan_period: float | None = None, timestamp_start: int = 0,
                 transfer_bps: float = TRANSFER_BPS,
                 clock: Callable[[], float] = time.monotonic, height: float = 0.0) -> None:
        if not 0 <= timestamp_start < scip.TIMESTAMP_MODULO:
            raise ValueError(f'timestamp_start {timestamp_start!r} is not a 24-bit value')
        if noise_mm < 0 or not math.isfinite(noise_mm):
            raise ValueError(f'noise_mm must be finite and >= 0, got {noise_mm!r}')
        if not transfer_bps > 0:
            raise ValueError(f'transfer_bps must be > 0, got {transfer_bps!r}')
        self.transfer_bps = float(transfer_bps)
        self.world = world
        self.link_path = link_path
        self.mount = tuple(float(v) for v in mount)
        self.height = float(height)     # m above the floor of the scan plane
        self.noise_mm = noise_mm
        self.spec = scip.SensorSpec.from_params(URG04LX_PP)
        self.scan_period = 60.0 / self.spec.scan_rpm if scan_period is None else scan_period
        if self.scan_period <= 0:
            raise ValueError(f'scan_period must be > 0, got {scan_period!r}')
        self._rng = np.random.default_rng(seed)
        self._clock = clock
        self._ts_start = timestamp_start
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._stop = False
        self._requests: list[str] = []
        self._done = threading.Condition(self._lock)
        self._wake_r = self._wake_w = -1
        self._master = self._slave = -1
        self._slave_path = ''
        self._corrupt = 0
        self._stray = bytearray()
        # counters
        self.commands = 0
        self.command_codes: Counter[str] = Counter()     # e.g. {'SCIP2.0': 2, 'GD': 10}
        self.scans_sent = 0
        self.corrupted = 0
        self.stray_sent = 0
        self.dropped_bytes = 0
        self.plugs = 0
        self._reset_device()

    # -- public API -----------------------------------------------------------------------
    @property
    def slave_path(self) -> str:
        """Return the current pty slave path (changes on replug)."""
        return self._slave_path

    @property
    def path(self) -> str:
        """Return the path a driver should open: the stable link if any, else the slave."""
        return self.link_path or self._slave_path

    @property
    def plugged(self) -> bool:
        """Return True while a pty is attached."""
        return self._master >= 0

    @property
    def started(self) -> bool:
        """Return True once started (until stopped), plugged in or not."""
        return self._thread is not None

    def start(self) -> UrgSim:
        """Create the pty (and link) and start serving."""
        if self._thread is not None:
            raise RuntimeError('UrgSim already started')
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        self._plug()
        self._thread = threading.Thread(target=self._run, name='urg-sim', daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the thread and release the pty, the link and the wake pipe."""
        if self._thread is not None:
            with self._lock:
                self._stop = True
            self._wake()
            # its select wakes within 0.5 s: 2 s keeps sim_robot's whole close (sim-bus 2 s,
            # this, LEDs 2 s) inside bringup's 8 s stop budget even if the thread hangs
            self._thread.join(timeout=2.0)
            self._thread = None
        self._unplug()
        for fd in (self._wake_r, self._wake_w):
            if fd >= 0:
                os.close(fd)
        self._wake_r = self._wake_w = -1

    def __enter__(self) -> UrgSim:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def corrupt_next_checksums(self, n: int = 1) -> None:
        """Give the next ``n`` scan responses one data line with a wrong sum each."""
        with self._lock:
            self._corrupt += n

    def inject_stray(self, data: bytes) -> None:
        """Send ``data`` before the next response (line noise, a half-written frame)."""
        with self._lock:
            self._stray += data
        self._wake()

    def unplug(self) -> None:
        """Close the pty as a USB unplug does: the reader sees EIO, the path disappears."""
        self._request('unplug')

    def replug(self) -> None:
        """Attach a fresh pty (a power-cycled device) and re-point the link to it."""
        self._request('replug')

    def device_timestamp(self, at: float | None = None) -> int:
        """Return the device's 24-bit ms counter now (or at clock time ``at``)."""
        elapsed_ms = math.floor(((self._clock() if at is None else at) - self._t0) * 1000.0)
        return (self._ts_start + elapsed_ms) % scip.TIMESTAMP_MODULO

    @property
    def step_period(self) -> float:
        """Return the time the mirror takes per step, s."""
        return self.scan_period / self.spec.ares

    def transfer_time(self, nbytes: int) -> float:
        """Return the time ``nbytes`` take on the link, s (10 bits a byte)."""
        return nbytes * 10.0 / self.transfer_bps

    def render_scan(self, command: str, start: int, end: int, cluster: int, *,
                    interval: int = 0, remaining: int = 0, tag: bytes = b'') -> bytes:
        """Measure the world now and return the bytes of one scan response."""
        ranges = self.measure(start, end, cluster)
        return scip.format_scan(command, start, end, cluster, self.device_timestamp(), ranges,
                                interval=interval, remaining=remaining, tag=tag)

    def _sample_pose(self) -> tuple[float, tuple[float, float, float]]:
        """Return (clock time, robot pose) now, the shared world advanced to this instant."""
        now = getattr(self.world, 'now', None)
        if callable(now):
            now()                       # advance the shared world's dynamics to this instant
        x, y, yaw = self.world.pose()
        return self._clock(), (float(x), float(y), float(yaw))

    def measure(self, start: int, end: int, cluster: int = 1,
                sweep: tuple[float, Sequence[float], float, Sequence[float]] | None = None
                ) -> np.ndarray:
        """Ray cast steps ``start..end`` (merged by ``cluster``) into ranges in mm/codes.

        ``sweep`` = (t0, pose0, t1, pose1): the sweep passed :data:`STAMP_STEP` at ``t0`` and
        the robot pose is linear between the two samples, so step ``i`` sees the world from
        the pose at ``t0 + (i - STAMP_STEP) * step_period``.  Without it: the pose now.
        """
        steps = np.arange(start, end + 1)
        if sweep is None:
            t, pose = self._sample_pose()
            sweep = (t, pose, t, pose)
        t0, p0, t1, p1 = sweep
        ts = t0 + (steps - STAMP_STEP) * self.step_period
        f = np.clip((ts - t0) / (t1 - t0), 0.0, None) if t1 > t0 else np.zeros(steps.shape)
        x = p0[0] + f * (p1[0] - p0[0])
        y = p0[1] + f * (p1[1] - p0[1])
        dyaw = math.remainder(p1[2] - p0[2], 2.0 * math.pi)
        yaw = p0[2] + f * dyaw
        mx, my, myaw = self.mount
        c, s = np.cos(yaw), np.sin(yaw)
        ox, oy = x + c * mx - s * my, y + s * mx + c * my
        angles = yaw + myaw + (steps - self.spec.afrt) * 2.0 * math.pi / self.spec.ares
        dist = np.empty(steps.shape)
        black = np.zeros(steps.shape, dtype=bool)
        cast = getattr(self.world, 'laser_cast', None)
        for i in range(0, steps.size, ORIGIN_CHUNK):
            j = min(i + ORIGIN_CHUNK, steps.size)
            mid = (i + j - 1) // 2
            origin = (float(ox[mid]), float(oy[mid]))
            if callable(cast):   # surfaces: glass passes the beam, black returns too little light
                dist[i:j], black[i:j] = cast(origin, angles[i:j], self.spec.dmax / 1000.0,
                                             self.height)
            else:
                dist[i:j] = np.asarray(self.world.raycast_many(origin, angles[i:j],
                                                               self.spec.dmax / 1000.0))
        mm = dist * 1000.0
        if self.noise_mm:
            mm = mm + self._rng.normal(0.0, self.noise_mm, mm.shape)
        out = np.full(steps.shape, FAR_CODE, dtype=np.int64)
        finite = np.isfinite(mm)
        out[finite] = np.rint(mm[finite]).astype(np.int64)
        out[finite & (out > self.spec.dmax)] = FAR_CODE
        out[finite & (out < self.spec.dmin)] = NEAR_CODE
        out[black] = LOW_LIGHT_CODE
        out[(steps < self.spec.amin) | (steps > self.spec.amax)] = DEAD_ZONE_CODE
        group = max(cluster, 1)
        if group > 1:
            pad = (-out.size) % group
            grid = np.concatenate([out, np.full(pad, -1)]).reshape(-1, group)
            valid = np.where(grid >= scip.RANGE_ERROR_LIMIT, grid, np.iinfo(np.int64).max)
            best = valid.min(axis=1)
            out = np.where(best == np.iinfo(np.int64).max, grid[:, 0], best)
        return out

    # -- plumbing ------------------------------------------------------------------------
    def _reset_device(self) -> None:
        self._scip2 = False
        self._laser = False
        self.time_adjust = False               # TM0 .. TM2 (SCIP 2.0 spec 8.6)
        self._stream: dict[str, Any] | None = None
        self._sweeps: list[dict[str, Any]] = []   # sweeps measured or in transfer, in order
        self._inbuf = bytearray()
        self._out = bytearray()
        self._t0 = self._clock()

    def _wake(self) -> None:
        if self._wake_w >= 0:
            try:
                os.write(self._wake_w, b'x')
            except BlockingIOError:
                pass

    def _request(self, what: str) -> None:
        if self._thread is None:
            (self._unplug if what == 'unplug' else self._plug)()
            return
        with self._lock:
            self._requests.append(what)
        self._wake()
        with self._lock:
            # Return only once done: a caller told "unplugged" must not see the old pty serve
            # on (a loaded machine can starve this thread for seconds, hence the long bound).
            if not self._done.wait_for(lambda: what not in self._requests, timeout=60.0):
                raise TimeoutError(f'UrgSim: {what} not done by the sim thread within 60 s')

    def _plug(self) -> None:
        if self._master >= 0:
            return
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self._slave_path = os.ttyname(slave)
        if self.link_path:
            tmp = f'{self.link_path}.tmp{os.getpid()}'
            try:
                os.unlink(tmp)
            except FileNotFoundError:
                pass
            os.symlink(self._slave_path, tmp)
            os.replace(tmp, self.link_path)        # atomic re-point
        self._reset_device()
        self.plugs += 1

    def _unplug(self) -> None:
        if self.link_path:
            try:
                os.unlink(self.link_path)
            except FileNotFoundError:
                pass
        for fd in (self._master, self._slave):
            if fd >= 0:
                os.close(fd)
        self._master = self._slave = -1

    def _run(self) -> None:
        while True:
            with self._lock:
                if self._stop:
                    return
                requests, stray = list(self._requests), bytes(self._stray)
                self._stray.clear()
            for what in requests:
                (self._unplug if what == 'unplug' else self._plug)()
            if requests:
                with self._lock:
                    del self._requests[:len(requests)]
                    self._done.notify_all()
            if stray and self._master >= 0:
                self._queue(stray)
                self.stray_sent += len(stray)
            self._serve_once()

    def _serve_once(self) -> None:
        timeout = 0.5
        if self._master >= 0:
            events = [sw['at'] for sw in self._sweeps]
            if self._stream is not None:
                events.append(self._stream['due'])
            if events:
                timeout = max(0.0, min(timeout, min(events) - self._clock()))
        rlist = [self._wake_r] + ([self._master] if self._master >= 0 else [])
        wlist = [self._master] if self._master >= 0 and self._out else []
        readable, writable, _ = select.select(rlist, wlist, [], timeout)
        if self._wake_r in readable:
            try:
                os.read(self._wake_r, 4096)
            except BlockingIOError:
                pass
        if self._master < 0:
            return
        if self._master in readable:
            try:
                self._inbuf += os.read(self._master, 4096)
            except (BlockingIOError, InterruptedError):
                pass
            except OSError as exc:
                if exc.errno != errno.EIO:   # EIO: no slave open right now; not an error
                    raise
            self._handle_input()
        if self._stream is not None and self._clock() >= self._stream['due']:
            self._emit_stream_scan()
        self._advance_sweeps()
        if self._out:
            try:
                n = os.write(self._master, self._out)
                del self._out[:n]
            except (BlockingIOError, InterruptedError):
                pass
            except OSError as exc:
                if exc.errno != errno.EIO:
                    raise

    def _queue(self, data: bytes) -> None:
        if len(self._out) + len(data) > OUT_LIMIT:
            self.dropped_bytes += len(data)     # nobody reads: drop like a full USB FIFO
            return
        self._out += data

    def _send(self, data: bytes, scan: bool = False) -> None:
        with self._lock:
            stray = bytes(self._stray)
            self._stray.clear()
            corrupt = scan and self._corrupt > 0
            if corrupt:
                self._corrupt -= 1
        if stray:
            self._queue(stray)
            self.stray_sent += len(stray)
        if corrupt:
            data = self._corrupt_sum(data)
            self.corrupted += 1
        self._queue(data)

    @staticmethod
    def _corrupt_sum(data: bytes) -> bytes:
        lines = data.split(b'\n')
        line = bytearray(lines[3])                # first data line (after echo, status, stamp)
        line[-1] = (line[-1] - 0x30 + 1) % 64 + 0x30
        lines[3] = bytes(line)
        return b'\n'.join(lines)

    def _handle_input(self) -> None:
        while True:
            idx = self._inbuf.find(b'\n')
            if idx < 0:
                if len(self._inbuf) > 4096:
                    self._inbuf.clear()          # garbage without LF: a real FIFO overflows
                return
            line = bytes(self._inbuf[:idx]).rstrip(b'\r')
            del self._inbuf[:idx + 1]
            if line:
                self.commands += 1
                self.command_codes[line.decode('ascii', 'replace')[:7 if line.startswith(
                    b'SCIP') else 2]] += 1
                self._command(line)

    def _reply(self, echo: bytes, status: str, lines: Sequence[bytes] = (),
               param_lines: bool = False) -> None:
        self._send(scip.format_response(echo, status, lines, param_lines=param_lines))

    def _command(self, echo: bytes) -> None:
        if echo == b'SCIP2.0':
            self._reply(echo, '0E' if self._scip2 else '0')
            self._scip2 = True
            return
        body, _, tag = echo.partition(b';')
        code, args = body[:2].decode('ascii', 'replace'), body[2:].decode('ascii', 'replace')
        if code == 'TM':
            self._tm(echo, args)
        elif self.time_adjust:
            self._reply(echo, '0E')        # spec 8.6: nothing but TM in time-adjust mode
        elif code in ('VV', 'PP', 'II') and not args:
            self._reply(echo, '00', self._params(code), param_lines=True)
        elif code == 'BM' and not args:
            self._reply(echo, '02' if self._laser else '00')
            self._laser = True
        elif code in ('QT', 'RS') and not args:
            self._laser = False
            self._stream = None
            self._sweeps = [sw for sw in self._sweeps if sw['data'] is not None]   # sent on
            if code == 'RS':
                self._t0, self._ts_start = self._clock(), 0
            self._reply(echo, '00')
        elif code in ('GD', 'GS'):
            self._gd(echo, code, args, tag)
        elif code in ('MD', 'MS'):
            self._md(echo, code, args, tag)
        else:
            self._reply(echo, '0E')

    def _tm(self, echo: bytes, args: str) -> None:
        # SCIP 2.0 spec 8.6: TM0 adjust mode on (laser off), TM1 time, TM2 adjust mode off.
        if args == '0':
            self._reply(echo, '02' if self.time_adjust else '00')
            self.time_adjust, self._laser, self._stream = True, False, None
        elif args == '1':
            if not self.time_adjust:
                self._reply(echo, '04')
            else:
                self._reply(echo, '00', [scip.encode(self.device_timestamp(), 4)])
        elif args == '2':
            self._reply(echo, '00' if self.time_adjust else '03')
            self.time_adjust = False
        else:
            self._reply(echo, '01')

    def _params(self, code: str) -> list[bytes]:
        if code == 'VV':
            table = URG04LX_VV
        elif code == 'PP':
            table = URG04LX_PP
        else:
            table = {
                'MODL': 'URG-04LX(Hokuyo Automatic Co.,Ltd.)',
                'LASR': 'ON' if self._laser else 'OFF',
                'SCSP': f'Initial({self.spec.scan_rpm}[rpm])',
                'MESM': 'Measuring by Normal Mode',
                'SBPS': 'USB only',
                'TIME': scip.encode(self.device_timestamp(), 4).decode(),
                'STAT': 'Stable 000 no error.',
            }
        return [f'{k}:{v}'.encode() for k, v in table.items()]

    def _check_steps(self, args: str) -> str | None:
        for i, status in ((0, '01'), (4, '02'), (8, '03')):
            if not args[i:i + (2 if i == 8 else 4)].isdigit():
                return status
        start, end = int(args[0:4]), int(args[4:8])
        if end > MAX_STEP:
            return '04'
        if end < start:
            return '05'
        return None

    def _gd(self, echo: bytes, code: str, args: str, tag: bytes) -> None:
        if len(args) != 10:
            self._reply(echo, '0C')
            return
        status = self._check_steps(args) or (None if self._laser else '10')
        if status:
            self._reply(echo, status)
            return
        start, end, cluster = int(args[0:4]), int(args[4:8]), int(args[8:10])
        # The answer is the next sweep: measured from step 0 on, sent after its last step.
        self._begin_sweep(code, start, end, cluster, tag=tag)

    def _md(self, echo: bytes, code: str, args: str, tag: bytes) -> None:
        if len(args) != 13:
            self._reply(echo, '0C')
            return
        status = self._check_steps(args)
        if status is None and not args[10].isdigit():
            status = '06'
        if status is None and not args[11:13].isdigit():
            status = '07'
        if status:
            self._reply(echo, status)
            return
        self._reply(echo, '00')
        self._laser = True
        self._stream = {
            'code': code, 'start': int(args[0:4]), 'end': int(args[4:8]),
            'cluster': int(args[8:10]), 'interval': int(args[10]), 'count': int(args[11:13]),
            'sent': 0, 'skipped': 0, 'tag': tag, 'due': self._clock() + self.scan_period,
        }

    def _emit_stream_scan(self) -> None:
        st = self._stream
        assert st is not None
        st['due'] += self.scan_period
        if self._clock() > st['due']:
            st['due'] = self._clock() + self.scan_period   # fell behind: do not burst
        if st['skipped'] < st['interval']:
            st['skipped'] += 1
            return
        st['skipped'] = 0
        remaining = max(st['count'] - st['sent'] - 1, 0) if st['count'] else 0
        self._begin_sweep(st['code'], st['start'], st['end'], st['cluster'],
                          interval=st['interval'], remaining=remaining, tag=st['tag'])
        st['sent'] += 1
        if st['count'] and st['sent'] >= st['count']:
            self._stream = None
            self._laser = False                # the device switches the laser off when done

    def _begin_sweep(self, code: str, start: int, end: int, cluster: int, *,
                     interval: int = 0, remaining: int = 0, tag: bytes = b'') -> None:
        """Start measuring a scan now: stamp at step 0, complete after step ``end``."""
        t0, pose0 = self._sample_pose()
        self._sweeps.append({
            'code': code, 'start': start, 'end': end, 'cluster': cluster,
            'interval': interval, 'remaining': remaining, 'tag': tag,
            'stamp': self.device_timestamp(t0), 't0': t0, 'pose0': pose0,
            'at': t0 + (end + 1 - STAMP_STEP) * self.step_period, 'data': None,
        })

    def _advance_sweeps(self) -> None:
        """Format the sweeps past their last step; release the ones whose transfer is done."""
        now = self._clock()
        while self._sweeps and self._sweeps[0]['at'] <= now:
            sw = self._sweeps[0]
            if sw['data'] is None:
                t1, pose1 = self._sample_pose()
                ranges = self.measure(sw['start'], sw['end'], sw['cluster'],
                                      (sw['t0'], sw['pose0'], t1, pose1))
                data = scip.format_scan(sw['code'], sw['start'], sw['end'], sw['cluster'],
                                        sw['stamp'], ranges, interval=sw['interval'],
                                        remaining=sw['remaining'], tag=sw['tag'])
                sw['data'] = data
                sw['at'] = max(sw['at'], now) + self.transfer_time(len(data))
                continue
            self._sweeps.pop(0)
            self._send(sw['data'], scan=True)
            self.scans_sent += 1
