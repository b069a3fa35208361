"""sim_robot: the simulated M4K as a process of its own -- world, dynamics, motor lag, sensors.

It plays the hardware the driver host talks to, and nothing else reaches the world:

* SPI (sim-bus): ``left_dac``/``right_dac`` MCP4911 + amplifier, ``left_enc``/``right_enc``
  AS5045 on the wheel shafts (:mod:`m4k_drivers.motors.sim`); the DACs latch their last word;
* GPIO (sim-bus): the amplifier-enable heartbeat monostable (``devices.motor.heartbeat_*``),
  the e-stop read-back input after the contact (``devices.motor.estop_readback_*``),
  the US-100 TRIG and ECHO lines with edge timestamps (``devices.sonar.chip`` / ``*_line``);
* I2C (sim-bus): the myAHRS+ registers on bus ``devices.imu.bus`` (:mod:`m4k_drivers.imu.sim`);
* a pseudo terminal: the URG-04LX speaking SCIP 2.0, linked at ``<runtime_dir>/sim-urg``;
* LED class and sysfs PWM: files in ``<runtime_dir>/sim-sysfs`` it polls (``led.simfs``).

Every device whose ``devices.<kind>.backend`` is ``sim`` is simulated, configured by the same
section the driver host reads (one configuration); the robot itself is ``world.robot``, the
robot *as built*, whose unset fields take the ``control:`` values (wheel radius, track, full
scale), so a scenario can build a robot unlike its configuration (what ``calibrate`` finds).
Because the world lives here, killing or restarting the driver host leaves the robot as the
real one would be left -- DACs latched -- and never resets the pose.  Ground truth:
``sim_truth`` asks over the socket and prints JSON;
``--world-report FILE`` (default ``$M4K_WORLD_REPORT``, else ``<runtime_dir>/world.json``)
is rewritten 10 times a second and at exit.  SIGINT/SIGTERM stop it (exit 0); exit 2 is a
configuration error or another sim_robot on the runtime directory.
"""

from __future__ import annotations

import argparse
import errno
import faulthandler
import json
import logging
import math
import os
import sys
import threading
import time
from typing import Any, Callable

from m4k_drivers import config as dconfig
from m4k_drivers import safety
from m4k_drivers.simbus import read_truth, SimBusServer, socket_path
from m4k_drivers.world import World
from m4k_rt import rosargs

__all__ = ['SYSFS_DIR', 'SimRobot', 'URG_LINK', 'main', 'truth_main', 'wait_ready']

LOG = logging.getLogger('m4k_drivers.sim_robot')
URG_LINK = 'sim-urg'          # <runtime_dir>/sim-urg -> /dev/pts/N of the simulated URG
SYSFS_DIR = 'sim-sysfs'       # <runtime_dir>/sim-sysfs: the LED class and PWM files
REPORT_PERIOD_S = 0.1
EVENT_PERIOD_S = 0.02         # world events (unplug a sensor) take effect within this
CLOSE_DUMP_S = 4.0           # s: a close taking longer dumps every thread's stack (see _main)


class _EchoLine:
    """The US-100 ECHO line as a sim-bus GPIO model (edges scheduled by the trigger)."""

    def __init__(self, echo: Any) -> None:
        self.echo = echo

    def write(self, value: bool, t_ns: int | None = None) -> None:
        raise OSError(errno.EPERM, 'ECHO was requested as an input')

    def read(self) -> bool:
        return False

    def wait_event(self, timeout_s: float) -> tuple[str, int] | None:
        if not self.echo.poll(timeout_s):
            return None
        ev = self.echo.read_event()
        return ev.edge, ev.timestamp


class _OutputLine:
    """A GPIO output model that only records its level (sonar TRIG wraps the fake line)."""

    def __init__(self, line: Any) -> None:
        self.line = line
        self.level = False

    def write(self, value: bool, t_ns: int | None = None) -> None:
        self.level = bool(value)
        self.line.write(value)

    def read(self) -> bool:
        return self.level

    def wait_event(self, timeout_s: float) -> None:
        raise OSError(errno.EINVAL, 'output line: no edge events')


class _I2cBus:
    """One simulated I2C bus: the devices on it by address."""

    def __init__(self) -> None:
        self.devices: dict[int, Any] = {}

    def _dev(self, addr: int) -> Any:
        dev = self.devices.get(addr)
        if dev is None:
            # Nobody acknowledges the address: the kernel reports EREMOTEIO.
            raise OSError(errno.EREMOTEIO, f'no device at 0x{addr:02x}')
        return dev

    def read_burst(self, addr: int, reg: int, n: int) -> bytes:
        return self._dev(addr).read_burst(addr, reg, n)

    def write_byte_data(self, addr: int, reg: int, value: int) -> None:
        self._dev(addr).write_byte_data(addr, reg, value)


class SimRobot:
    """The simulated robot: a world, the device models on it, the sim-bus server."""

    def __init__(self, cfg: dconfig.DriverConfig, runtime_dir: str,
                 report_path: str | None = None, *,
                 clock: Callable[[], int] = time.monotonic_ns,
                 sleep: Callable[[float], None] = time.sleep,
                 heights: dict[str, float] | None = None, standin: bool = False) -> None:
        self.cfg = cfg
        # Height above the floor of each sensor (robot.sensors.<laser|sonar>.pose z): an
        # obstacle lower than a sensor is under its beam. None: every obstacle is seen.
        self.heights = dict(heights or {})
        self.runtime_dir = runtime_dir
        self.report_path = report_path
        self.report_error: str | None = None   # the failure last logged (logged once)
        self.sleep = sleep       # waits on ``clock`` (sonar echoes); tests pass a fake pair
        self.world = World(cfg.world, clock=clock)
        self.spi: dict[str, Any] = {}
        self.gpio: dict[tuple[str, int], Any] = {}
        self.i2c: dict[str, _I2cBus] = {}
        self.enable: Any = None
        self.urg: Any = None
        self.sonar_trigger: Any = None
        self.imu: Any = None             # the FakeMyAhrsBus; fault injection (tests): ``garble``
        self.leds: Any = None
        self.events: list[dict[str, Any]] = []    # the world events applied: what, when
        self.sims = [k for k, s in cfg.devices.items() if s['enabled'] and s['backend'] == 'sim']
        sections = {k: cfg.devices[k] for k in self.sims}
        if standin:
            # The driver host runs these kinds' real backends on the kernel-ABI stand-in,
            # which forwards the wires here (m4k_drivers.abi.wire): simulate them too.
            for kind, sec in standin_sections(cfg.devices).items():
                self.sims.append(kind)
                sections[kind] = sec
        for kind in self.sims:
            build = getattr(self, f'_build_{kind}', None)
            if build is not None:
                build(sections[kind])
        self.server = SimBusServer(socket_path(runtime_dir), self._open, self.truth)

    # -- device models -------------------------------------------------------------------
    def _build_motor(self, s: dict[str, Any]) -> None:
        from m4k_drivers.motors.sim import EnableMonostable, SimDac, SimEncoder
        for side, name in enumerate(('left', 'right')):
            self.spi[f'{name}_dac'] = SimDac(self.world, side, s['vref'])
            self.spi[f'{name}_enc'] = SimEncoder(self.world, side, s['noise_lsb'],
                                                 s['lead_bits'])
        if s['heartbeat']:
            self.enable = EnableMonostable(self.world, s['heartbeat_hold_s'])
            self.gpio[(s['heartbeat_chip'], s['heartbeat_line'])] = self.enable
        if s['estop_readback_line'] is not None:
            from m4k_drivers.motors.sim import EstopReadback
            self.gpio[(s['estop_readback_chip'], s['estop_readback_line'])] = \
                EstopReadback(self.world, s['estop_readback_active'] == 'low')

    def _build_imu(self, s: dict[str, Any]) -> None:
        from m4k_drivers.imu.sim import FakeMyAhrsBus
        bus = self.i2c.setdefault(str(s['bus']), _I2cBus())
        self.imu = FakeMyAhrsBus(self.world, s['address'], gyro_bias_sd=s['gyro_bias_sd'])
        bus.devices[s['address']] = self.imu

    def _build_sonar(self, s: dict[str, Any]) -> None:
        from m4k_drivers.sonar.sim import FakeEchoLine, FakeTriggerLine
        echo = FakeEchoLine(self.world.clock, self.sleep)
        trig = FakeTriggerLine(self.world, echo, s['mount'], s['fov_deg'], s['noise_sd'],
                               s['temperature_c'], self.heights.get('sonar', 0.0),
                               no_echo_s=s['no_echo_s'])
        self.sonar_trigger = trig        # fault injection (tests): ``dead``
        self.gpio[(s['chip'], s['trigger_line'])] = _OutputLine(trig)
        self.gpio[(s['chip'], s['echo_line'])] = _EchoLine(echo)

    def _build_lrf(self, s: dict[str, Any]) -> None:
        from m4k_drivers.lrf.sim import UrgSim
        link = s.get('link_path') or os.path.join(self.runtime_dir, URG_LINK)
        args = {k: s[k] for k in ('mount', 'noise_mm', 'seed', 'scan_period', 'timestamp_start',
                                     'transfer_bps')
                if s.get(k) is not None}
        self.urg = UrgSim(self.world, link_path=link, height=self.heights.get('laser', 0.0),
                          **args)

    def _build_led(self, s: dict[str, Any]) -> None:
        from m4k_drivers.led.simfs import SysfsLeds
        self.leds = SysfsLeds(os.path.join(self.runtime_dir, SYSFS_DIR), s, self.world.clock)

    def apply_events(self) -> None:
        """Apply the world events whose moment came (``world.events``: unplug a sensor).

        Unplugged is what the hardware does: the US-100 never answers a trigger (no edge), the
        URG's tty goes away (EIO, the link dangles), the myAHRS+ no longer acknowledges its
        I2C address (EREMOTEIO).
        """
        self.world.now()
        for ev in self.world.take_events():
            done = False
            if ev.unplug == 'sonar' and self.sonar_trigger is not None:
                self.sonar_trigger.dead = done = True
            elif ev.unplug == 'lrf' and self.urg is not None:
                self.urg.unplug()
                done = True
            elif ev.unplug == 'imu':
                for bus in self.i2c.values():
                    done = bool(bus.devices) or done
                    bus.devices.clear()
            self.events.append({'unplug': ev.unplug, 't_ns': self.world.t_ns,
                                'applied': done})
            LOG.info('world event: %s unplugged%s', ev.unplug,
                     '' if done else ' (not simulated here: nothing to unplug)')

    def _open(self, spec: dict[str, Any]) -> tuple[str, Any]:
        bus = spec.get('bus')
        if bus == 'spi':
            name = str(spec.get('name'))
            if name not in self.spi:
                raise OSError(errno.ENOENT, f'no simulated spidev {name!r}; have '
                              f'{sorted(self.spi)}')
            return name, self.spi[name]
        if bus == 'i2c':
            name = str(spec.get('i2c_bus'))
            if name not in self.i2c:
                raise OSError(errno.ENOENT, f'no simulated I2C bus {name!r}')
            return f'i2c-{name}', self.i2c[name]
        if bus == 'gpio':
            key = (str(spec.get('chip')), int(spec.get('line', -1)))
            if key not in self.gpio:
                raise OSError(errno.ENOENT, f'no simulated line {key[1]} on {key[0]!r}')
            return f'{key[0]}:{key[1]}', self.gpio[key]
        if bus == 'sysfs':
            if self.leds is None:
                raise OSError(errno.ENOENT, 'no simulated sysfs (the LED is not simulated)')
            return 'sysfs', self.leds
        raise OSError(errno.EINVAL, f'unknown sim-bus bus {bus!r}')

    # -- truth -------------------------------------------------------------------------
    def truth(self) -> dict[str, Any]:
        """Return the ground truth now (JSON-able)."""
        self.world.now()
        st = self.world.state()
        x, y, th = st.pose
        return {
            't': st.t_ns * 1e-9, 't_ns': st.t_ns, 'x': x, 'y': y, 'theta': th,
            'pose': [x, y, th], 'v': st.v, 'w': st.w,
            'wheel_speed_left': st.wheel_speed[0], 'wheel_speed_right': st.wheel_speed[1],
            # Drive physics (m4k_drivers.drive, docs/sim-physics.md): the body's longitudinal
            # acceleration over the last 1 ms step, each tyre's slip (rim speed - ground speed
            # of its contact, m/s), the wheel angles the encoders see (rad), and the peaks since
            # start (contact steps excluded): the judge's deceleration is measured here.
            'accel': st.accel, 'slip_left': st.slip[0], 'slip_right': st.slip[1],
            'wheel_angle_left': st.wheel_angle[0], 'wheel_angle_right': st.wheel_angle[1],
            'peak_decel': self.world.peak_decel, 'peak_accel': self.world.peak_accel,
            'peak_speed': self.world.peak_speed, 'peak_slip': self.world.peak_slip,
            'traction_decel': self.world.robot.traction_decel_mps2,
            'motor_enabled': self.world.drive_enabled(),
            'heartbeat_enabled': self.world.heartbeat_enabled(),
            'estop_open': self.world.estop_open,
            'faults': self.world.active_faults(),     # [{kind, wheel}] on now (world.faults)
            'heartbeat': self.enable is not None,
            'heartbeat_edges': self.enable.edges if self.enable else 0,
            'heartbeat_drops': self.enable.drops if self.enable else 0,
            'heartbeat_last_edge_ns': self.enable.last_edge_ns if self.enable else None,
            'motor_volts': [self.world.motor_voltage(0), self.world.motor_voltage(1)],
            'collisions': st.collisions, 'contacts': st.collisions,
            'in_contact': st.in_contact, 'led': self.leds.shown() if self.leds else None,
            # clearances in m; null when nothing is there at all (JSON has no infinity)
            'rest_since_ns': self.world.rest_since_ns,
            'travelled': self.world.travelled, 'min_clearance': _finite(self.world.min_clearance),
            'clearance': _finite(self.world.clearance(st.pose)),
            'front_clearance': _finite(self.world.front_clearance(st.pose)),
            'obstacle_offsets': self.world.obstacle_offsets(), 'events': list(self.events),
        }

    def write_report(self) -> None:
        """Rewrite the world report file atomically (nothing without a path)."""
        if not self.report_path:
            return
        tmp = self.report_path + '.tmp'
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o600)
            with open(fd, 'w', encoding='utf-8') as f:
                json.dump(self.truth(), f)
            os.replace(tmp, self.report_path)
        except OSError as exc:
            # Rewritten every 100 ms: log a failure once, not ten times a second.
            if str(exc) != self.report_error:
                LOG.warning('world report %s: %s (not logged again until it changes)',
                            self.report_path, exc)
                self.report_error = str(exc)
            return
        if self.report_error is not None:
            LOG.info('world report %s: written again', self.report_path)
            self.report_error = None

    # -- running -------------------------------------------------------------------------
    def start(self) -> SimRobot:
        """Start the pty device and the sim-bus server."""
        if self.urg is not None:
            self.urg.start()
        if self.leds is not None:
            self.leds.start()
        self.server.start()
        LOG.info('simulating %s on %s', ', '.join(self.sims) or 'nothing',
                 self.server.path)
        return self

    def run(self, stop: threading.Event) -> None:
        """Keep the world and the report current until ``stop`` is set."""
        n = 0
        while not stop.wait(EVENT_PERIOD_S):
            if self.world.config.events:
                self.apply_events()
            n += 1
            if n * EVENT_PERIOD_S >= REPORT_PERIOD_S - 1e-9:
                n = 0
                self.write_report()

    def close(self) -> None:
        """Stop serving; write a last report."""
        self.server.close()
        if self.urg is not None:
            self.urg.stop()
        if self.leds is not None:
            self.leds.close()
        self.write_report()


def standin_sections(devices: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Return the sim sections of the real devices the kernel stand-in serves.

    Each is the real section's shared fields validated as a ``sim`` section (the sim-only
    ones, e.g. the DAC's ``vref``, at their defaults).
    """
    from m4k_drivers import registry
    out = {}
    for kind in dconfig.STANDIN_KINDS:
        s = devices.get(kind)
        if not s or not s['enabled'] or s['backend'] not in ('real', 'gpio'):
            continue
        params = registry.get(kind, 'sim').params
        raw = {k: v for k, v in s.items() if k in params}
        if kind == 'imu':
            raw['bus'] = str(s['bus']).removeprefix('/dev/i2c-')
        out[kind] = dconfig.validate_device(kind, {'backend': 'sim', **raw},
                                            f'devices.{kind}')
    return out


def _finite(v: float) -> float | None:
    return v if math.isfinite(v) else None


def _sensor_heights(raw: dict[str, Any]) -> dict[str, float]:
    """Return the laser's and the sonar's height above the floor from the robot section.

    The pose z is in base_link, on the wheel axle: the axle is one wheel radius above the
    floor (``control.wheel_radius``).
    """
    out: dict[str, float] = {}
    try:
        axle = float((raw.get('control') or {}).get('wheel_radius', 0.0) or 0.0)
        sensors = raw['robot']['sensors']
        for name in ('laser', 'sonar'):
            out[name] = axle + float(sensors[name]['pose'][2])
    except (KeyError, TypeError, IndexError, ValueError):
        pass     # no robot section (a bare devices file): every obstacle is seen
    return out


def wait_ready(runtime_dir: str, timeout_s: float = 10.0) -> bool:
    """Wait until a sim_robot answers on ``runtime_dir``'s sim-bus; True when it does."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            read_truth(runtime_dir, timeout_s=1.0)
            return True
        except (OSError, ValueError):
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.05)


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='sim_robot', description=__doc__.split('\n\n')[0])
    ap.add_argument('--config', help='devices YAML file (default: the layered m4k config)')
    ap.add_argument('--overlay', help='YAML file merged over the configuration')
    ap.add_argument('--runtime-dir', help='runtime directory (sim-bus socket, pty link)')
    ap.add_argument('--world-report', default=os.environ.get('M4K_WORLD_REPORT'),
                    metavar='FILE', help='JSON ground truth file (default: $M4K_WORLD_REPORT, '
                    'else <runtime_dir>/world.json)')
    ap.add_argument('--priority', type=int, default=45, metavar='P',
                    help='SCHED_FIFO priority of the simulator (0: SCHED_OTHER; default 45, '
                    'below the RT tasks and the motor service): hardware does not slow down '
                    'when the machine is busy, so neither may the simulator')
    ap.add_argument('-v', '--verbose', action='store_true')
    return ap


def main(argv: list[str] | None = None) -> int:
    """Run the simulator until SIGINT/SIGTERM; return the exit code."""
    from m4k_rt.stopsignals import run_stoppable
    return run_stoppable('sim_robot',
                         lambda signals: _main(rosargs.parse_args(_parser(), argv), signals))


def _main(args: argparse.Namespace, signals: Any) -> int:
    rosargs.configure_logging(args.ros_args, args.verbose)
    from m4k_drivers.host import load_raw_config
    from m4k_rt import channel
    from m4k_rt.rt_core import InstanceLock, LockError
    try:
        raw = load_raw_config(args.config, args.overlay)
        refusal = safety.unsafe_mix(raw)     # a simulated sensor beside real motors
        if refusal:
            raise dconfig.ConfigError(refusal)
        cfg = dconfig.validate({'devices': raw.get('devices') or {},
                                'world': raw.get('world') or {}},
                               control=raw.get('control') or {},
                               body=(raw.get('robot') or {}).get('body'),
                               wheel_width=(raw.get('robot') or {}).get('wheel_width'))
        standin = dconfig.kernel_standin(raw)
        runtime_dir = channel.ensure_runtime_dir(
            args.runtime_dir or (raw.get('runtime') or {}).get('runtime_dir'))
    except (dconfig.ConfigError, ValueError) as exc:
        print(f'sim_robot: {exc}', file=sys.stderr)
        return 2
    try:
        lock = InstanceLock(runtime_dir, 'sim_robot')
    except LockError as exc:
        print(f'sim_robot: {exc}', file=sys.stderr)
        return 2
    if args.priority > 0:
        from m4k_rt.sched import SchedError, set_thread_fifo
        try:
            set_thread_fifo(args.priority)    # inherited by every thread started below
        except (SchedError, ValueError) as exc:
            LOG.warning('stays SCHED_OTHER: %s', exc)
    stop = signals.event
    try:
        if signals.stopping:  # stopped during start-up: nothing built yet
            return 0
        report = args.world_report or os.path.join(runtime_dir, 'world.json')
        try:
            robot = SimRobot(cfg, runtime_dir, report, heights=_sensor_heights(raw),
                             standin=standin).start()
        except (ValueError, OSError) as exc:
            print(f'sim_robot: {exc}', file=sys.stderr)
            return 2
        try:
            robot.run(stop)
        finally:
            # Closing joins three threads (at most 2 + 5 + 2 s). Once, in a fresh clone's
            # `make test`, a sim_robot stopped right after start-up outlived bringup's 8 s and
            # was killed, and it could not be reproduced. If closing ever takes this long
            # again, every thread's stack goes to stderr (the bringup log) to show where.
            faulthandler.dump_traceback_later(CLOSE_DUMP_S)
            try:
                robot.close()
            finally:
                faulthandler.cancel_dump_traceback_later()
        return 0
    finally:
        lock.release()


def truth_main(argv: list[str] | None = None) -> int:
    """``sim_truth``: print the running simulator's ground truth as one JSON object."""
    ap = argparse.ArgumentParser(prog='sim_truth', description='Print the ground truth of the '
                                 'running sim_robot (one JSON object) and exit.')
    ap.add_argument('--runtime-dir', help='runtime directory of the stack')
    args = rosargs.parse_args(ap, argv)
    from m4k_rt import channel
    runtime_dir = args.runtime_dir or channel.default_runtime_dir()
    try:
        doc = read_truth(runtime_dir)
    except (OSError, ValueError) as exc:
        print(f'sim_truth: no sim_robot answering on {socket_path(runtime_dir)}: {exc}',
              file=sys.stderr)
        return 1
    keys = ('t', 'x', 'y', 'theta', 'v', 'w', 'wheel_speed_left', 'wheel_speed_right',
            'motor_enabled', 'contacts')
    print(json.dumps({k: doc[k] for k in keys} | {
        k: v for k, v in doc.items() if k not in keys and not (
            isinstance(v, float) and not math.isfinite(v))}))
    return 0


if __name__ == '__main__':
    sys.exit(main())
