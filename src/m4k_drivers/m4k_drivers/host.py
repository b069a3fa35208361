"""driver_host: the NRT process serving every configured device to the RT process over XDDP.

One thread per device: it brings the handler up (configure + activate, retried with
exponential backoff while the device is missing), links its XDDP port with
:class:`m4k_rt.channel.NrtLink` and serves it (docs/internals.md, "Ports").  How a device is
served -- which datagram kinds it takes, the reply it sends, its stream rate, its watchdog and
link-loss behaviour, its ``--print`` line -- is the :class:`m4k_drivers.registry.ServiceSpec`
its own package registers next to its backends (e.g. :mod:`m4k_drivers.motors.service`); this
module is the plumbing around those specs and names no device.  It sends DEVICE_STATUS on every
state change and every second, each followed by HOST_DROPS (its drop counters, which the RT
monitor forwards to the bridge's /diagnostics).  When the RT side goes away the host keeps
running, relinks, and runs the device's link-loss hook (the motors go safe at once).
SIGINT/SIGTERM deactivate every device (motors at zero), clean up and exit 0.  A device
process (:mod:`m4k_drivers.hostproc`) or a service thread that ends on its own -- a crash, a
kill, a stop signal to it alone -- ends the whole host with exit 1, outputs safe, so that its
supervisor restarts all of it.

Bring-up without an RT process: ``driver_host --device imu --print`` prints decoded readings;
``--port``/``--bus`` select a real device path (and the ``real`` backend), e.g.
``driver_host --device lrf --port /dev/ttyACM0 --print``.  Wheel direction check on the real
robot (on blocks): ``driver_host --device motor --jog left 0.1 --duration 2``
(:mod:`m4k_drivers.motors.jog`; docs/real-robot.md).  A device kind from outside this package
is loaded with ``--device-module MOD`` (also ``$M4K_DEVICE_MODULES``, comma-separated).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
import threading
import time
from typing import Any, Sequence, TextIO

from m4k_drivers import config as dconfig
from m4k_drivers import hostproc, registry, safety
from m4k_drivers.handler import DeviceHandler, DriverError, RetryPolicy, State, Status
from m4k_rt import description, protocol, rosargs
from m4k_rt.channel import check_runtime_dir, NrtLink
from m4k_rt.sched import SchedError, set_thread_fifo
from m4k_rt.stopsignals import run_stoppable, StopSignals

__all__ = ['DEVICE_MODULES_ENV', 'DROP_REASONS', 'DeviceService', 'format_reading',
           'load_raw_config', 'main']

LOG = logging.getLogger('m4k_drivers.host')

# Bring-up retries for as long as the host runs: 0.5 s, 1 s, 2 s, ... then every 10 s.
BRINGUP_BACKOFF = RetryPolicy(attempts=0, base_s=0.5, factor=2.0, max_s=10.0)
DEVICE_MODULES_ENV = 'M4K_DEVICE_MODULES'
# Why a datagram from the RT side was not served, or a reply not delivered (DeviceService.drops):
# stale_host   older than the spec's max_age, and the previous pass was not busy with the
#              device: the host itself was not scheduled (a real robot sees these too);
# stale_device older than max_age right after a device transaction longer than max_age: the
#              device kept the loop (in simulation: sim_robot's scheduling over the sim bus);
# malformed    failed protocol.decode;  unexpected  a kind the device's spec does not take;
# inactive     a command for a device not ACTIVE (bring-up pending, error, deactivated);
# encode       a reply the wire cannot carry;  reply_lost  a reply the link did not take.
# Queue overflow and no-peer drops on the way in are counted by the RT side's PORT_STATS.
# The list itself is the HOST_DROPS datagram's (the wire carries every counter, in this order).
DROP_REASONS = protocol.HOST_DROP_REASONS


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
            return dconfig.fill_actuator_period(description.fill_sim_mounts(
                load_layered(overlay)))
    if overlay:
        raw = dconfig.merge(raw, dconfig.load_file(overlay))
    return description.fill_sim_mounts(raw)


class DeviceService:
    """Serve one device handler on its XDDP port from a thread of its own.

    ``kind``'s :class:`~m4k_drivers.registry.ServiceSpec` says how; this class is the loop:
    bring-up with backoff, (re)linking, decoding, DEVICE_STATUS, and the spec's hooks.  It is
    the spec's :class:`~m4k_drivers.registry.Replier` (:meth:`send`).
    """

    def __init__(self, kind: str, handler: DeviceHandler, section: dict[str, Any],
                 port: int | str, stop: threading.Event, runtime_dir: str | None = None,
                 status_period_s: float = 1.0, group: str | None = None) -> None:
        self.kind = kind
        self.spec = registry.service(kind)
        self.handler = handler
        self.section = section
        self.port = port
        self.stop = stop
        self.runtime_dir = runtime_dir
        self.group = group
        self.status_period_s = status_period_s
        self.link: Any = None
        self.seq = 0
        self.served = 0
        self.drops = dict.fromkeys(DROP_REASONS, 0)
        self._drops_logged = dict(self.drops)
        self._busy_ns = 0                # duration of the last device transaction (serve)
        self._status_state: tuple[int, int] | None = None
        self._status_due = 0.0
        self._retry_at = 0.0
        self._attempt = 0
        self._lost_seen = 0
        self._links_seen = 0
        # A no-peer episode (no RT process: start-up, rt_core restarting): when it began
        # (monotonic s; None = not in one) and the replies it lost.
        self._no_peer_since: float | None = None
        self._no_peer_lost = 0
        self.thread = threading.Thread(target=self.run, name=f'm4k-{kind}', daemon=True)

    # -- drop counters --------------------------------------------------------------------
    @property
    def stale(self) -> int:
        """Return the datagrams dropped as older than the spec's max_age (both causes)."""
        return self.drops['stale_host'] + self.drops['stale_device']

    @property
    def malformed(self) -> int:
        """Return the datagrams that failed to decode."""
        return self.drops['malformed']

    @property
    def unexpected(self) -> int:
        """Return the datagrams of a kind this device does not take."""
        return self.drops['unexpected']

    @property
    def encode_errors(self) -> int:
        """Return the replies the wire could not carry."""
        return self.drops['encode']

    def drop_line(self) -> str:
        """Return the counters as one log line (parsed by the bench: benchlib.hostdrops)."""
        return '{}: drops served={} {}'.format(self.handler.name, self.served, ' '.join(
            '{}={}'.format(k, v) for k, v in self.drops.items()))

    def _log_drops(self) -> None:
        # Once a second at most (the status period), only when a counter moved.
        if self.drops != self._drops_logged:
            self._drops_logged = dict(self.drops)
            LOG.warning('%s', self.drop_line())

    # -- plumbing -------------------------------------------------------------------------
    def start(self) -> None:
        """Start the service thread."""
        self.thread.start()

    def send(self, kind: int, *fields: Any, stamp_ns: int | None = None) -> bool:
        """Send one datagram, stamped with the sample time when known, else now."""
        self.seq = (self.seq + 1) & 0xFFFFFFFF
        stamp = time.monotonic_ns() if stamp_ns is None else stamp_ns
        if self.link.write(protocol.encode(kind, self.seq, stamp, *fields)):
            if self._no_peer_since is not None:
                self._end_no_peer('linked')
            return True
        self.drops['reply_lost'] += 1
        if not self.link.linked:
            self._lost_without_peer()
        return False

    def _lost_without_peer(self) -> None:
        # Expected while no RT process runs: one line when the episode starts and one when it
        # ends, not the drop line every status period.  Still counted in reply_lost.
        if self._no_peer_since is None:
            self._no_peer_since = time.monotonic()
            self._no_peer_lost = 0
            LOG.warning('%s: no RT peer: replies are not delivered (counted as reply_lost) '
                        'until it links', self.handler.name)
        self._no_peer_lost += 1
        self._drops_logged['reply_lost'] += 1      # told by the episode's lines instead

    def _end_no_peer(self, how: str) -> None:
        assert self._no_peer_since is not None
        LOG.warning('%s: RT peer %s after %.1f s without one: %d replies lost', self.handler.name,
                    how, time.monotonic() - self._no_peer_since, self._no_peer_lost)
        self._no_peer_since = None

    def _send_status(self, force: bool = False) -> None:
        h = self.handler
        now = time.monotonic()
        key = (int(h.state), h.status_level())
        if not force and key == self._status_state and now < self._status_due:
            return
        self._status_state = key
        self._status_due = now + self.status_period_s
        self._log_drops()
        self.send(protocol.Kind.DEVICE_STATUS, h.name[:16], int(h.state), h.status_level(),
                  h.faults & 0xFFFFFFFF, int(h.last_error))
        self.send(protocol.Kind.HOST_DROPS, h.name[:16], self.served, *self.drops.values())

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

    def _set_priority(self) -> None:
        # A device that feeds a heartbeat (the motors' amplifier enable) asks for SCHED_FIFO:
        # starved by other load for longer than the monostable's hold, it would drop the
        # motors of a live stack.
        prio = int(self.section.get('sched_priority') or 0)
        if prio <= 0:
            return
        try:
            set_thread_fifo(prio)
        except (SchedError, ValueError) as exc:
            LOG.warning('%s: stays SCHED_OTHER: %s', self.kind, exc)

    def run(self) -> bool:
        """Serve until the stop event is set, then deactivate and clean up.

        Return True when it ended on the stop event, False when the service crashed.
        """
        spec, h = self.spec, self.handler
        timeout = spec.read_timeout(self.section)
        stream = spec.stream_period(self.section)
        self._set_priority()
        self.link = NrtLink(self.port, self.runtime_dir, group=self.group)
        next_stream = time.monotonic()
        crashed = False
        try:
            while not self.stop.is_set():
                self._bring_up()
                data = self.link.read(timeout)
                if self.link.lost != self._lost_seen:        # RT side went away
                    self._lost_seen = self.link.lost
                    self._on_link_lost()
                if self.link.links != self._links_seen:      # (re)linked: say hello at once
                    self._links_seen = self.link.links
                    self._status_state = None
                    # Timestamped evidence for the fault tests (re-link time after a restart).
                    LOG.info('%s: linked to the RT side (link %d)', h.name, self.link.links)
                if data is not None:
                    self._dispatch(data)
                if spec.tick is not None and h.state == State.ACTIVE:
                    spec.tick(h)
                if stream is not None:
                    now = time.monotonic()
                    if now >= next_stream:
                        next_stream = now + stream
                        self._serve(None)
                self._send_status()
        except Exception:  # noqa: BLE001 - a bug must not leave the motors running
            LOG.exception('%s: service crashed; making outputs safe', h.name)
            crashed = True
        finally:
            h.shutdown()
            self.link.close()
            if self._no_peer_since is not None:
                self._end_no_peer('still absent at exit')
            LOG.info('%s at exit', self.drop_line())
        return not crashed

    def _on_link_lost(self) -> None:
        h = self.handler
        LOG.warning('%s: RT side gone, relinking', h.name)
        if self.spec.on_link_lost is not None and h.state == State.ACTIVE:
            try:
                self.spec.on_link_lost(h)
            except DriverError as exc:
                h.record_fault(exc)
        self._status_state = None

    # -- serving --------------------------------------------------------------------------
    def _dispatch(self, data: bytes) -> None:
        try:
            hdr, msg = protocol.decode(data)
        except protocol.ProtocolError:
            self.drops['malformed'] += 1
            return
        if hdr.kind not in self.spec.accepts:
            self.drops['unexpected'] += 1
            return
        max_age = self.spec.max_age(self.section)
        if max_age is not None and time.monotonic_ns() - hdr.stamp_ns > max_age * 1e9:
            # Queued while this host stalled: replaying it would drive (and re-enable the
            # amplifier) on a command the RT side has long replaced.  Attributed to the device
            # when the pass before was one device transaction longer than max_age.
            cause = 'stale_device' if self._busy_ns > max_age * 1e9 else 'stale_host'
            self.drops[cause] += 1
            if self.stale == 1 or self.stale % 100 == 0:
                LOG.warning('%s: dropped %d datagram(s) older than %.3f s (a stall?)',
                            self.handler.name, self.stale, max_age)
            return
        if self.handler.state != State.ACTIVE:
            self.drops['inactive'] += 1
        else:
            self.served += 1
        self._serve(msg)

    def _serve(self, msg: Any) -> None:
        t0 = time.monotonic_ns()
        try:
            self.spec.serve(self.handler, msg, self)
        except protocol.ProtocolError as exc:     # a reading the wire cannot carry: dropped
            self.drops['encode'] += 1
            LOG.error('%s: cannot encode the reply: %s', self.handler.name, exc)
        self._busy_ns = time.monotonic_ns() - t0


# -- console bring-up --------------------------------------------------------------------
def format_reading(kind: str, value: Any) -> str:
    """Return one console line for a decoded reading (the kind's ``--print`` format)."""
    fmt = registry.service(kind).format
    return fmt(value) if fmt is not None else f'{kind} {value!r}'


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
    ap.add_argument('--bus', help='bus number or path of the selected --device when its '
                    'service takes one, e.g. the I2C bus of --device imu (implies real)')
    ap.add_argument('--print', action='store_true', dest='print_mode',
                    help='print decoded readings to the console; no RT process needed')
    ap.add_argument('--count', type=int, default=0, help='--print: readings to print (0: all)')
    ap.add_argument('--rate', type=float, default=10.0, help='--print: readings per second')
    ap.add_argument('--jog', nargs=2, metavar=('WHEEL', 'SPEED'),
                    help='--device motor: turn WHEEL (left|right) at SPEED (fraction of full '
                    'scale, |SPEED| <= 0.25) for --duration s, then zero (bring-up)')
    ap.add_argument('--dac', type=int, metavar='CODE',
                    help='--device motor: hold CODE (0..1023) on both DACs with the amplifier '
                    'enable off, for --duration s (default 60, <= 600): the meter check '
                    'before first power (docs/real-robot.md)')
    ap.add_argument('--duration', type=float, default=None,
                    help='--jog: seconds (<= 5, default 1); --dac: seconds (default 60)')
    ap.add_argument('--yes', action='store_true', help='--jog: do not ask for confirmation')
    ap.add_argument('--runtime-dir', help='XDDP runtime directory')
    ap.add_argument('--device-module', action='append', default=[], metavar='MOD',
                    help='import MOD first: a device package registering its backends and '
                    'service (repeatable; also $' + DEVICE_MODULES_ENV + ')')
    ap.add_argument('-v', '--verbose', action='store_true')
    return ap


def _apply_overrides(devices: dict[str, Any], args: argparse.Namespace) -> dict[str, Any]:
    if not args.device:
        return devices
    out = {k: dict(devices.get(k) or {'backend': 'sim'}) for k in args.device}
    for kind, section in out.items():
        path: str | int | None = args.port
        # Only a device path asks the kind's service (which field it sets): a kind whose
        # package does not load is reported by the validation below, naming the field.
        spec = registry.service(kind) if args.port or args.bus is not None else None
        if spec is not None and spec.bus_arg and args.bus is not None:
            path = int(args.bus) if args.bus.isdigit() else args.bus
        if spec is not None and path is not None:
            section = {k: v for k, v in section.items()
                       if k in registry.COMMON_KEYS} | {spec.path_key: path}
            section['backend'] = 'real'
        if args.backend:
            section['backend'] = args.backend
        out[kind] = section
    return out


def _import_device_modules(argv: Sequence[str] | None) -> str | None:
    """Import the ``--device-module`` / ``$M4K_DEVICE_MODULES`` modules; return an error."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if '--ros-args' in argv:
        argv = argv[:argv.index('--ros-args')]
    pre = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    pre.add_argument('--device-module', action='append', default=[])
    mods = pre.parse_known_args(argv)[0].device_module
    mods += os.environ.get(DEVICE_MODULES_ENV, '').split(',')
    for mod in (m.strip() for m in mods):
        if not mod:
            continue
        try:
            importlib.import_module(mod)
        except Exception as exc:  # noqa: BLE001 -- report any plug-in failure as one line
            return f'cannot import device module {mod!r}: {exc}'
    return None


def _jog_kinds() -> list[str]:
    """Return the device kinds that offer ``--jog`` (for the usage message)."""
    out = []
    for kind in registry.kinds():
        try:
            if registry.service(kind).jog is not None:
                out.append(kind)
        except registry.RegistryError:      # an optional package not installed
            pass
    return out


def main(argv: list[str] | None = None) -> int:
    """Run the driver host (see the module docstring); return the exit code."""

    def body(signals: StopSignals) -> int:
        # Plug-in device kinds first: --device offers every registered kind.
        error = _import_device_modules(argv)
        if error:
            print(f'driver_host: {error}', file=sys.stderr)
            return 2
        return _main(rosargs.parse_args(_parser(), argv), signals)

    # Every handler built is shut down on the way out: outputs safe.
    return run_stoppable('driver_host', body, when_stopped='; outputs safe')


def _main(args: argparse.Namespace, signals: StopSignals) -> int:
    rosargs.configure_logging(args.ros_args, args.verbose)
    if args.dac is not None:
        if args.jog is not None:
            print('driver_host: --dac and --jog exclude each other', file=sys.stderr)
            return 2
        args.jog = ['dac', str(args.dac)]         # a jog target of the motor service
    if args.duration is None:
        args.duration = 60.0 if args.dac is not None else 1.0
    try:
        raw = load_raw_config(args.config, args.overlay)
        devices = _apply_overrides(raw.get('devices') or {}, args)
        cfg = dconfig.validate({'devices': devices, 'world': raw.get('world') or {}})
        enabled = [kind for kind, section in cfg.devices.items() if section['enabled']]
        for kind in enabled:
            registry.service(kind)          # a kind with backends but no service: refused
        # Serving the RT side drives the robot: refuse real motors without their protections
        # (one device's --print / --jog bring-up drives nothing on the RT's behalf).
        refusal = None if args.print_mode or args.jog is not None else safety.unsafe_mix(
            raw | {'devices': devices})
        if refusal:
            raise dconfig.ConfigError(refusal)
        standin = dconfig.kernel_standin(raw)
    except (dconfig.ConfigError, registry.RegistryError, ValueError) as exc:
        print(f'driver_host: {exc}', file=sys.stderr)
        return 2
    if args.print_mode and len(enabled) != 1:
        print('driver_host: --print needs exactly one enabled --device', file=sys.stderr)
        return 2
    jog: registry.Jog | None = None
    if args.jog is not None:
        try:
            if len(enabled) == 1 and not args.print_mode:
                jog = registry.service(enabled[0]).jog
            if jog is None:
                raise ValueError(f'--jog needs --device {"|".join(_jog_kinds())} alone '
                                 '(and no --print)')
            jog.check(args.jog[0], float(args.jog[1]), args.duration)
        except (ValueError, registry.RegistryError) as exc:
            print(f'driver_host: {exc}', file=sys.stderr)
            return 2
    runtime_dir = args.runtime_dir or (raw.get('runtime') or {}).get('runtime_dir')
    group = (raw.get('runtime') or {}).get('group')
    try:
        # As the RT side checks it: the ports and the sim bus are linked in there.
        check_runtime_dir(runtime_dir, group)
    except OSError as exc:
        print(f'driver_host: {exc}', file=sys.stderr)
        return 2
    children = hostproc.Children({})
    if not args.print_mode and jog is None:
        # Before any device is opened or thread started: an RT-facing device gets a process
        # of its own (m4k_drivers.hostproc), which goes on from here with its group alone.
        enabled, children = hostproc.fork_groups(hostproc.groups(enabled, cfg.devices))
    # sim backends reach sim_robot through the sim-bus socket in the runtime directory.
    ctx = registry.BuildContext(world_config=cfg.world_raw, runtime_dir=runtime_dir)
    if standin:
        # Real backends on simulated hardware: this process's open/ioctl/read of their device
        # nodes go to the kernel-ABI stand-in, wired to sim_robot (m4k_drivers.abi.wire).
        from m4k_drivers.abi.wire import standin_for
        kernel = standin_for(cfg.devices, ctx.sim_runtime_dir()).install()
        LOG.warning('kernel_standin: serving %s from the stand-in (no real device is opened)',
                    ', '.join(sorted([*kernel.spi, *kernel.i2c, *kernel.gpio])) or 'nothing')
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
        children.stop()
        return 2
    if signals.stopping:  # stopped during start-up: nothing was activated, shut down anyway
        for h in handlers.values():
            h.shutdown()
        return 0 if children.stop() else 1
    stop = signals.event
    if args.print_mode:
        (kind, handler), = handlers.items()
        return run_print(kind, handler, args.count, args.rate, stop)
    if jog is not None:
        (kind, handler), = handlers.items()
        try:
            return jog.run(handler, args.jog[0], float(args.jog[1]), args.duration, stop,
                           out=sys.stdout, stdin=sys.stdin, assume_yes=args.yes)
        except ValueError as exc:           # e.g. no terminal to confirm on and no --yes
            print(f'driver_host: {exc}', file=sys.stderr)
            handler.shutdown()
            return 2
    return _serve(handlers, cfg, devices, raw.get('ports') or {}, runtime_dir, stop, group,
                  children)


GROUP_STOP_GRACE_S = 2.0      # how long a device process's clean exit waits for our own stop


def _serve(handlers: dict[str, DeviceHandler], cfg: dconfig.DriverConfig,
           devices: dict[str, Any], ports: dict[str, Any], runtime_dir: str | None,
           stop: threading.Event, group: str | None = None,
           children: hostproc.Children | None = None) -> int:
    children = children if children is not None else hostproc.Children({})
    services = []
    for kind, handler in handlers.items():
        # An explicit xddp_port wins; else the RT side's ports table; else the default.
        explicit = 'xddp_port' in (devices.get(kind) or {})
        port = cfg.devices[kind]['xddp_port'] if explicit else ports.get(
            kind, cfg.devices[kind]['xddp_port'])
        services.append(DeviceService(kind, handler, cfg.devices[kind], port, stop, runtime_dir,
                                      group=group))
    LOG.info('serving %s (pid %d)', ', '.join(f'{s.kind}@{s.port}' for s in services),
             os.getpid())
    if len(services) == 1 and not children and hostproc.own_process(services[0].section):
        # An RT-facing device's own process: served from the main thread, the only one.  A
        # crash is not a stop: the parent must see a non-zero exit and end the host.
        return 0 if services[0].run() else 1
    for s in services:
        s.start()
    failed = False
    while not stop.wait(0.5):
        gone = children.poll()
        crashed = [s.kind for s in services if not s.thread.is_alive()]
        if not (gone or crashed) or stop.is_set():
            continue
        # A stop signal to the whole group reaches the device processes too, and one may act
        # on it first (it runs at SCHED_FIFO, this thread does not): a device process that
        # exited 0 (only a stop signal ends one so) waits a moment for this process's own.
        if gone and not crashed and children.exited_clean() and stop.wait(GROUP_STOP_GRACE_S):
            break
        # A device process or a service died on its own: end the host so its supervisor
        # restarts all of it (a host serving the sensors but never the wheels is worse).
        LOG.error('%s: stopping the driver host',
                  f'device process {gone}' if gone else f'service {", ".join(crashed)} crashed')
        failed = True
        stop.set()
    clean = children.stop()
    for s in services:
        s.thread.join(timeout=5.0)
    stuck = [s.kind for s in services if s.thread.is_alive()]
    if stuck:
        LOG.error('services did not stop: %s', ', '.join(stuck))
        return 1
    return 0 if clean and not failed else 1

if __name__ == '__main__':
    sys.exit(main())
