"""driver_host: the NRT process serving every configured device to the RT process over XDDP.

One thread per device (SCHED_OTHER): it brings the handler up (configure + activate, retried
with exponential backoff while the device is missing), links its XDDP port with
:class:`m4k_rt.xddp.NrtLink` and serves it (docs/internals.md, "Ports"):

* motor  WHEEL_CMD -> DACs, then encoders -> ENCODERS; watchdog -> outputs safe
* imu    REQUEST -> IMU (or a stream at ``rate_hz`` when ``stream: true``)
* sonar  REQUEST -> one ping -> SONAR
* led    LED -> strip
* lrf    REQUEST -> LASER_SCAN (handler from m4k_drivers.lrf, loaded lazily)

plus DEVICE_STATUS on every state change and every second.  When the RT side goes away the
host keeps running and relinks; the motors are made safe at once.  SIGINT/SIGTERM deactivate
every device (motors at zero), clean up and exit 0.

Bring-up without an RT process: ``driver_host --device imu --print`` prints decoded readings;
``--port``/``--bus`` select a real device path (and the ``real`` backend), e.g.
``driver_host --device lrf --port /dev/ttyACM0 --print``.  Wheel direction check on the real
robot (on blocks): ``driver_host --device motor --jog left 0.1 --duration 2``
(:mod:`m4k_drivers.motors.jog`; docs/real-robot.md).
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import threading
import time
from typing import Any, cast, TextIO, TYPE_CHECKING

from m4k_drivers import config as dconfig
from m4k_drivers import registry
from m4k_drivers.handler import DeviceHandler, DriverError, RetryPolicy, State, Status
from m4k_rt import description, rosargs
from m4k_rt.stopsignals import run_stoppable, StopSignals

if TYPE_CHECKING:  # pragma: no cover -- the host imports device packages on demand
    from m4k_drivers.motors.handler import MotorHandler

__all__ = ['DeviceService', 'format_reading', 'load_raw_config', 'main']

LOG = logging.getLogger('m4k_drivers.host')

# Which config field ``--port`` / ``--bus`` sets for each device kind.
PATH_KEYS = {'lrf': 'port', 'imu': 'bus', 'sonar': 'chip', 'led': 'name'}
# Bring-up retries for as long as the host runs: 0.5 s, 1 s, 2 s, ... then every 10 s.
BRINGUP_BACKOFF = RetryPolicy(attempts=0, base_s=0.5, factor=2.0, max_s=10.0)


def load_raw_config(path: str | None = None, overlay: str | None = None) -> dict[str, Any]:
    """Return the merged config document: ``path`` alone, or m4k_rt's layered files.

    Simulated sensors without a ``mount`` of their own take it from the robot section
    (``robot.sensors``, config/robot.yaml): the same pose the URDF and tf_static publish.
    """
    if path:
        raw = dconfig.load_file(path)
    else:
        try:
            from m4k_rt.config import load_layered
        except ImportError:
            raw = dconfig.load_file(dconfig.default_config_path())
        else:
            return description.fill_sim_mounts(load_layered(overlay))
    if overlay:
        raw = dconfig.merge(raw, dconfig.load_file(overlay))
    return description.fill_sim_mounts(raw)


class DeviceService:
    """Serve one device handler on its XDDP port from a thread of its own."""

    def __init__(self, kind: str, handler: DeviceHandler, section: dict[str, Any],
                 port: int | str, stop: threading.Event, runtime_dir: str | None = None,
                 status_period_s: float = 1.0) -> None:
        self.kind = kind
        self.handler = handler
        self.section = section
        self.port = port
        self.stop = stop
        self.runtime_dir = runtime_dir
        self.status_period_s = status_period_s
        self.link: Any = None
        self.seq = 0
        self.malformed = 0
        self.unexpected = 0
        self.served = 0
        self._status_state: tuple[int, int] | None = None
        self._status_due = 0.0
        self._retry_at = 0.0
        self._attempt = 0
        self._lost_seen = 0
        self._links_seen = 0
        self._scan_buf = bytearray(4096)
        self.thread = threading.Thread(target=self.run, name=f'm4k-{kind}', daemon=True)

    # -- plumbing -------------------------------------------------------------------------
    def start(self) -> None:
        """Start the service thread."""
        self.thread.start()

    def _send(self, kind: int, *fields: Any, stamp_ns: int | None = None) -> bool:
        """Send one datagram, stamped with the sample time when known, else now."""
        from m4k_rt import protocol
        self.seq = (self.seq + 1) & 0xFFFFFFFF
        stamp = time.monotonic_ns() if stamp_ns is None else stamp_ns
        return self.link.write(protocol.encode(kind, self.seq, stamp, *fields))

    def _send_status(self, force: bool = False) -> None:
        from m4k_rt import protocol
        h = self.handler
        now = time.monotonic()
        key = (int(h.state), h.status_level())
        if not force and key == self._status_state and now < self._status_due:
            return
        self._status_state = key
        self._status_due = now + self.status_period_s
        self._send(protocol.Kind.DEVICE_STATUS, h.name[:16], int(h.state), h.status_level(),
                   h.faults & 0xFFFFFFFF, int(h.last_error))

    def _bring_up(self) -> None:
        """Configure + activate when due; on failure schedule the next try with backoff."""
        h = self.handler
        if h.state == State.ACTIVE or time.monotonic() < self._retry_at:
            return
        try:
            if h.state in (State.UNCONFIGURED, State.ERROR):
                h.configure()
            h.activate()
            self._attempt = 0
            LOG.info('%s: active', h.name)
        except DriverError as exc:
            delay = BRINGUP_BACKOFF.delay(self._attempt)
            self._attempt += 1
            self._retry_at = time.monotonic() + delay
            LOG.error('%s: bring-up failed (retry in %.1f s): %s', h.name, delay, exc)

    def _timeout(self) -> float:
        if self.kind == 'motor':
            return float(self.section.get('period_s', 0.01))
        if self.kind == 'imu' and self.section.get('stream'):
            return 1.0 / float(self.section.get('rate_hz', 100.0))
        return 0.1

    def _set_priority(self) -> None:
        # The motor service feeds the amplifier-enable heartbeat: starved by other load for
        # longer than the monostable's hold, it would drop the motors of a live stack.
        prio = int(self.section.get('sched_priority') or 0)
        if prio <= 0:
            return
        from m4k_rt.sched import SchedError, set_thread_fifo
        try:
            set_thread_fifo(prio)
        except (SchedError, ValueError) as exc:
            LOG.warning('%s: stays SCHED_OTHER: %s', self.kind, exc)

    def run(self) -> None:
        """Serve until the stop event is set, then deactivate and clean up."""
        from m4k_rt.xddp import NrtLink
        self._set_priority()
        self.link = NrtLink(self.port, self.runtime_dir)
        next_stream = time.monotonic()
        try:
            while not self.stop.is_set():
                self._bring_up()
                data = self.link.read(self._timeout())
                if self.link.lost != self._lost_seen:        # RT side went away
                    self._lost_seen = self.link.lost
                    self._on_link_lost()
                if self.link.links != self._links_seen:      # (re)linked: say hello at once
                    self._links_seen = self.link.links
                    self._status_state = None
                    # Timestamped evidence for the fault tests (re-link time after a restart).
                    LOG.info('%s: linked to the RT side (link %d)', self.handler.name,
                             self.link.links)
                if data is not None:
                    self._dispatch(data)
                if self.kind == 'motor' and self.handler.state == State.ACTIVE:
                    self.handler.poll_watchdog()              # type: ignore[attr-defined]
                if self.kind == 'imu' and self.section.get('stream'):
                    now = time.monotonic()
                    if now >= next_stream:
                        next_stream = now + 1.0 / float(self.section.get('rate_hz', 100.0))
                        self._serve_imu(None)
                self._send_status()
        except Exception:  # noqa: BLE001 - a bug must not leave the motors running
            LOG.exception('%s: service crashed; making outputs safe', self.handler.name)
        finally:
            self.handler.shutdown()
            self.link.close()

    def _on_link_lost(self) -> None:
        LOG.warning('%s: RT side gone, relinking', self.handler.name)
        if self.kind == 'motor' and self.handler.state == State.ACTIVE:
            try:
                self.handler.make_safe()                      # type: ignore[attr-defined]
            except DriverError as exc:
                self.handler.record_fault(exc)
        self._status_state = None

    # -- serving --------------------------------------------------------------------------
    def _dispatch(self, data: bytes) -> None:
        from m4k_rt import protocol
        try:
            hdr, msg = protocol.decode(data)
        except protocol.ProtocolError:
            self.malformed += 1
            return
        expected = {'motor': protocol.Kind.WHEEL_CMD, 'led': protocol.Kind.LED}.get(
            self.kind, protocol.Kind.REQUEST)
        if hdr.kind != expected:
            self.unexpected += 1
            return
        self.served += 1
        getattr(self, f'_serve_{self.kind}')(msg)

    def _serve_motor(self, msg: Any) -> None:
        from m4k_drivers.motors import WheelCommand
        from m4k_rt import protocol
        if self.handler.state != State.ACTIVE:
            return
        self.handler.write(WheelCommand(msg.left_code, msg.right_code, msg.enable))
        r = self.handler.read()
        if r.status == Status.OK:
            v = r.value
            self._send(protocol.Kind.ENCODERS, v.left_raw, v.right_raw, v.left_angle,
                       v.right_angle, v.status, stamp_ns=v.t_ns)

    def _serve_imu(self, msg: Any) -> None:
        from m4k_rt import protocol
        if self.handler.state != State.ACTIVE:
            return
        r = self.handler.read()
        if r.status == Status.OK:
            s = r.value
            self._send(protocol.Kind.IMU, *s.orientation, *s.angular_velocity,
                       *s.linear_acceleration, s.status)

    def _serve_sonar(self, msg: Any) -> None:
        from m4k_rt import protocol
        r = self.handler.read() if self.handler.state == State.ACTIVE else None
        if r is None or r.status != Status.OK:
            self._send(protocol.Kind.SONAR, 0.0, protocol.SONAR_FAULT)
            return
        rng = r.value.range_m
        self._send(protocol.Kind.SONAR, rng if math.isfinite(rng) else 0.0, r.value.status)

    def _serve_led(self, msg: Any) -> None:
        if self.handler.state == State.ACTIVE:
            self.handler.write((msg.r, msg.g, msg.b, msg.brightness))

    def _serve_lrf(self, msg: Any) -> None:
        from m4k_rt import protocol
        if self.handler.state != State.ACTIVE:
            return
        r = self.handler.read()
        if r.status != Status.OK:
            return
        g = r.value.geometry
        self.seq = (self.seq + 1) & 0xFFFFFFFF
        try:
            n = protocol.encode_scan_into(
                # Stamped at acquisition (the sensor's clock mapped onto ours), not now.
                self._scan_buf, 0, self.seq, r.value.stamp_ns, g.angle_min,
                g.angle_increment, g.range_min, g.range_max, g.scan_time, g.time_increment,
                r.value.device_stamp, [int(x) for x in r.value.ranges_mm])
        except protocol.ProtocolError as exc:
            LOG.error('lrf: cannot encode scan: %s', exc)
            return
        self.link.write(memoryview(self._scan_buf)[:n])


# -- console bring-up --------------------------------------------------------------------
def format_reading(kind: str, value: Any) -> str:
    """Return one console line for a decoded reading."""
    if kind == 'imu':
        r, p, y = (math.degrees(a) for a in value.rpy)
        g, a = value.angular_velocity, value.linear_acceleration
        return (f'imu rpy=({r:+7.2f},{p:+7.2f},{y:+7.2f}) deg '
                f'gyro=({g[0]:+.4f},{g[1]:+.4f},{g[2]:+.4f}) rad/s '
                f'acc=({a[0]:+.3f},{a[1]:+.3f},{a[2]:+.3f}) m/s^2 '
                f'T={value.temperature:.1f}C status={value.status}')
    if kind == 'sonar':
        names = {0: 'ok', 1: 'no echo', 2: 'timeout', 3: 'invalid'}
        return f'sonar range={value.range_m:.3f} m status={value.status} ' \
               f'({names.get(value.status, "?")})'
    if kind == 'motor':
        return (f'motor raw=({value.left_raw},{value.right_raw}) '
                f'angle=({value.left_angle:+.4f},{value.right_angle:+.4f}) rad '
                f'status=0x{value.status:02x}')
    if kind == 'led':
        from m4k_drivers.led.protocol import to_hex
        return f'led shown={to_hex(value)}'
    if kind == 'lrf':
        ranges = [int(x) for x in value.ranges_mm]
        valid = [x for x in ranges if x >= 20]
        front = ranges[len(ranges) // 2] if ranges else 0
        return (f'lrf seq={value.seq} n={len(ranges)} valid={len(valid)} '
                f'min={min(valid, default=0) / 1000:.3f} m front={front / 1000:.3f} m '
                f'stamp={value.device_stamp}')
    return f'{kind} {value!r}'


def run_print(kind: str, handler: DeviceHandler, count: int, rate_hz: float,
              stop: threading.Event, out: TextIO | None = None) -> int:
    """Bring one device up and print ``count`` readings (0 = until stopped) to ``out``."""
    out = out if out is not None else sys.stdout      # looked up now, not at import
    try:
        handler.configure()
        handler.activate()
    except DriverError as exc:
        print(f'driver_host: {kind}: {exc}', file=sys.stderr)
        handler.shutdown()
        return 1
    n = 0
    try:
        while not stop.is_set() and (count <= 0 or n < count):
            r = handler.read()
            if r.status == Status.OK:
                print(format_reading(kind, r.value), file=out, flush=True)
            else:
                print(f'{kind} error: {r.error}', file=out, flush=True)
            n += 1
            stop.wait(1.0 / rate_hz)
    finally:
        handler.shutdown()
    return 0


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='driver_host', description=__doc__.split('\n\n')[0])
    ap.add_argument('--config', help='devices YAML file (default: the layered m4k config)')
    ap.add_argument('--overlay', help='YAML file merged over the configuration')
    ap.add_argument('--device', action='append', choices=registry.kinds(),
                    help='serve only this device (repeatable)')
    ap.add_argument('--backend', help='override the backend of the selected --device')
    ap.add_argument('--port', help='device path of the selected --device (implies real)')
    ap.add_argument('--bus', help='I2C bus number or path for --device imu (implies real)')
    ap.add_argument('--print', action='store_true', dest='print_mode',
                    help='print decoded readings to the console; no RT process needed')
    ap.add_argument('--count', type=int, default=0, help='--print: readings to print (0: all)')
    ap.add_argument('--rate', type=float, default=10.0, help='--print: readings per second')
    ap.add_argument('--jog', nargs=2, metavar=('WHEEL', 'SPEED'),
                    help='--device motor: turn WHEEL (left|right) at SPEED (fraction of full '
                    'scale, |SPEED| <= 0.25) for --duration s, then zero (bring-up)')
    ap.add_argument('--duration', type=float, default=1.0, help='--jog: seconds (<= 5)')
    ap.add_argument('--yes', action='store_true', help='--jog: do not ask for confirmation')
    ap.add_argument('--runtime-dir', help='XDDP runtime directory')
    ap.add_argument('-v', '--verbose', action='store_true')
    return ap


def _apply_overrides(devices: dict[str, Any], args: argparse.Namespace) -> dict[str, Any]:
    if not args.device:
        return devices
    out = {k: dict(devices.get(k) or {'backend': 'sim'}) for k in args.device}
    for kind, section in out.items():
        path: str | int | None = args.port
        if kind == 'imu' and args.bus is not None:
            path = int(args.bus) if args.bus.isdigit() else args.bus
        if path is not None:
            section = {k: v for k, v in section.items()
                       if k in registry.COMMON_KEYS} | {PATH_KEYS.get(kind, 'port'): path}
            section['backend'] = 'real'
        if args.backend:
            section['backend'] = args.backend
        out[kind] = section
    return out


def main(argv: list[str] | None = None) -> int:
    """Run the driver host (see the module docstring); return the exit code."""
    # Every handler built is shut down on the way out: outputs safe.
    return run_stoppable('driver_host',
                         lambda signals: _main(rosargs.parse_args(_parser(), argv), signals),
                         when_stopped='; outputs safe')


def _main(args: argparse.Namespace, signals: StopSignals) -> int:
    rosargs.configure_logging(args.ros_args, args.verbose)
    try:
        raw = load_raw_config(args.config, args.overlay)
        devices = _apply_overrides(raw.get('devices') or {}, args)
        cfg = dconfig.validate({'devices': devices, 'world': raw.get('world') or {}})
    except (dconfig.ConfigError, registry.RegistryError, ValueError) as exc:
        print(f'driver_host: {exc}', file=sys.stderr)
        return 2
    enabled = [kind for kind, section in cfg.devices.items() if section['enabled']]
    if args.print_mode and len(enabled) != 1:
        print('driver_host: --print needs exactly one enabled --device', file=sys.stderr)
        return 2
    if args.jog is not None:
        from m4k_drivers.motors.jog import check_jog, JogError
        try:
            if enabled != ['motor'] or args.print_mode:
                raise JogError('--jog needs --device motor alone (and no --print)')
            check_jog(args.jog[0], float(args.jog[1]), args.duration)
        except (JogError, ValueError) as exc:
            print(f'driver_host: {exc}', file=sys.stderr)
            return 2
    runtime_dir = args.runtime_dir or (raw.get('runtime') or {}).get('runtime_dir')
    # sim backends reach sim_robot through the sim-bus socket in the runtime directory.
    ctx = registry.BuildContext(world_config=cfg.world_raw, runtime_dir=runtime_dir)
    handlers: dict[str, DeviceHandler] = {}
    try:
        for kind in enabled:
            if signals.stopping:
                break
            handlers[kind] = registry.create(kind, cfg.devices[kind], ctx)
    except (DriverError, ValueError) as exc:
        print(f'driver_host: {exc}', file=sys.stderr)
        for h in handlers.values():
            h.shutdown()
        return 2
    if signals.stopping:  # stopped during start-up: nothing was activated, shut down anyway
        for h in handlers.values():
            h.shutdown()
        return 0
    stop = signals.event
    if args.print_mode:
        (kind, handler), = handlers.items()
        return run_print(kind, handler, args.count, args.rate, stop)
    if args.jog is not None:
        from m4k_drivers.motors.jog import JogError, run_jog
        try:
            # Every backend of the motor kind builds a MotorHandler (m4k_drivers.motors).
            motor = cast('MotorHandler', handlers['motor'])
            return run_jog(motor, args.jog[0], float(args.jog[1]),
                           args.duration, stop, out=sys.stdout, stdin=sys.stdin,
                           assume_yes=args.yes)
        except JogError as exc:
            print(f'driver_host: {exc}', file=sys.stderr)
            handlers['motor'].shutdown()
            return 2
    return _serve(handlers, cfg, devices, raw.get('ports') or {}, runtime_dir, stop)


def _serve(handlers: dict[str, DeviceHandler], cfg: dconfig.DriverConfig,
           devices: dict[str, Any], ports: dict[str, Any], runtime_dir: str | None,
           stop: threading.Event) -> int:
    services = []
    for kind, handler in handlers.items():
        # An explicit xddp_port wins; else the RT side's ports table; else the default.
        explicit = 'xddp_port' in (devices.get(kind) or {})
        port = cfg.devices[kind]['xddp_port'] if explicit else ports.get(
            kind, cfg.devices[kind]['xddp_port'])
        services.append(DeviceService(kind, handler, cfg.devices[kind], port, stop, runtime_dir))
    for s in services:
        s.start()
    LOG.info('serving %s', ', '.join(f'{s.kind}@{s.port}' for s in services))
    while not stop.wait(0.5):
        pass
    for s in services:
        s.thread.join(timeout=5.0)
    stuck = [s.kind for s in services if s.thread.is_alive()]
    if stuck:
        LOG.error('services did not stop: %s', ', '.join(stuck))
        return 1
    return 0

if __name__ == '__main__':
    sys.exit(main())
