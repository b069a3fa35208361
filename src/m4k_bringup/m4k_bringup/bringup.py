"""bringup: start, watch and stop the whole m4k stack (``make run``).

Starts the children -- ``sim_robot`` (the simulated robot, when any device's backend is
``sim``; started first and stopped last, so a driver-host restart never resets the world),
``rt_core``, ``driver_host`` (every device simulated unless the configuration says otherwise)
and the ROS ``bridge`` -- each with the user overlay (``--config FILE``): rt_core and
sim_robot ``--config``/``--overlay``, driver_host ``--overlay``, and for the bridge the
overlay's ``m4k_bridge: ros__parameters:`` section plus the parameters derived from the
layered configuration (:func:`bridge_overlay`), in a temporary parameter file passed after
``config/bridge.yaml``. Executables come from the ament index
(``<prefix>/lib/<pkg>/<exe>``), else ``python -m <module>``.

Supervision: a child that dies is restarted after an exponential backoff (0.5 s doubling to
10 s; reset after 30 s of stable running) and the restart is reported; exit code 2 of a child
means a configuration error (or another stack owning the runtime directory) and stops the
stack instead, since restarting cannot fix it. Children get SIGTERM if bringup itself dies
(``setpriv --pdeathsig``, when available).

Status: one live line on a TTY (tasks OK, rates, worst jitter, collision guard, restarts),
plain lines every ``--status-interval`` seconds otherwise. It is read from the bridge's
``rt_status`` and ``diagnostics`` topics rather than an XDDP port, so ``rt_stat`` can still
open the ``stat`` port next to a running stack.

Ctrl-C / SIGTERM: bridge first (it sends a zero velocity), then driver host (motors safe),
then rt_core, then sim_robot; each gets a bounded wait, then SIGKILL. Exit codes: 0 clean
stop, 1 a child kept failing, 2 configuration error or another stack already running.
"""

from __future__ import annotations

import argparse
import dataclasses
import fcntl
import math
import os
import shutil
import signal
import socket
import sys
import tempfile
import threading
import time
from typing import Any, Callable, Mapping, Sequence, TextIO

import yaml

from m4k_bridge import params as bridge_params
from m4k_bringup import robots
from m4k_bringup.child import Child, Launch, Output, Stopping
from m4k_drivers import simbus
from m4k_rt import config, estop_request, rosargs
from m4k_rt.control.params import control_params
from m4k_rt.rt_core import InstanceLock
from m4k_rt.stopsignals import run_stoppable, StopSignals

__all__ = ['Child', 'ChildSpec', 'Supervisor', 'bridge_overlay', 'bringup_argv', 'child_specs',
           'format_status',
           'foxglove_spec', 'lock_owner', 'main', 'resolve_command', 'restart_delay', 'sim_ready',
           'sim_robot_spec', 'supervised_child', 'uses_sim']

STABLE_S = 30.0           # a child running this long has its backoff reset
STOP_TIMEOUT_S = 8.0      # per child, then SIGKILL
CONFIG_ERROR = 2


@dataclasses.dataclass(frozen=True)
class ChildSpec:
    """How to run one child of the stack."""

    name: str
    package: str
    executable: str
    module: str
    args: tuple[str, ...] = ()
    ready: Callable[[], bool] | None = None   # start the next child once this is true


READY_TIMEOUT_S = 10.0


def restart_delay(failures: int, base: float = 0.5, cap: float = 10.0) -> float:
    """Return the backoff before restart number ``failures`` (1-based): base * 2^(n-1), capped."""
    if failures < 1:
        return 0.0
    return min(cap, base * 2.0 ** (failures - 1))


def resolve_command(spec: ChildSpec, force_module: bool = False) -> list[str]:
    """Return the argv of a child: the installed executable, else ``python -m module``."""
    if not force_module:
        try:
            from ament_index_python.packages import get_package_prefix, PackageNotFoundError
            try:
                exe = os.path.join(get_package_prefix(spec.package), 'lib', spec.package,
                                   spec.executable)
            except PackageNotFoundError:
                exe = ''
            if exe and os.access(exe, os.X_OK):
                return [exe, *spec.args]
        except ImportError:
            pass
    return [sys.executable, '-m', spec.module, *spec.args]


def _coerce(name: str, value: Any) -> Any:
    # Hand-written YAML says 1 for 1.0; rclpy would refuse an integer for a double parameter.
    try:
        default = bridge_params.spec(name).default
    except KeyError:
        return value
    if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(default, list) and isinstance(value, list):
        return [float(v) if isinstance(v, int) and not isinstance(v, bool) else v
                for v in value]
    return value


def bridge_overlay(doc: Mapping[str, Any] | None, runtime_dir: str) -> dict[str, Any]:
    """Return the bridge parameter document for a (validated) layered config and runtime dir.

    The overlay's ``m4k_bridge:`` section, plus every parameter derived from the
    configuration (:data:`m4k_bridge.params.DERIVED`: command timeout, velocity limits,
    sensor frames, port labels, robot description) -- which that section may not set: each
    value has one source. The ``ros2 launch`` file calls this too, so both start the bridge
    alike. Raise :class:`m4k_bridge.params.ParamError` naming a bad parameter.
    """
    section: dict[str, Any] = {}
    if doc and bridge_params.NODE_NAME in doc:
        sub = {bridge_params.NODE_NAME: doc[bridge_params.NODE_NAME]}
        flat = bridge_params.flatten_section(sub)
        section = {k: _coerce(k, v) for k, v in flat.items()}
        bridge_params.check_section({bridge_params.NODE_NAME: {
            'ros__parameters': bridge_params.nest(section)}})
        bridge_params.check_not_derived(section)
    base = section.get('base_frame', bridge_params.spec('base_frame').default)
    footprint = section.get('footprint_frame', bridge_params.spec('footprint_frame').default)
    section.update(bridge_params.derived_values(doc or {}, base, footprint))
    section['runtime_dir'] = runtime_dir
    return {bridge_params.NODE_NAME: {'ros__parameters': bridge_params.nest(section)}}


def lock_owner(runtime_dir: str, name: str = 'rt_core.lock') -> str | None:
    """Return the pid text of whoever holds ``<runtime_dir>/<name>``, or None when free."""
    path = os.path.join(runtime_dir, name)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    except FileNotFoundError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return os.pread(fd, 32, 0).decode(errors='replace').strip() or '?'
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


class Console:
    """Serialize child output lines and the status line on one terminal."""

    def __init__(self, out: TextIO, err: TextIO, live: bool) -> None:
        self.out, self.err, self.live = out, err, live
        self._lock = threading.Lock()
        self._status = ''

    def line(self, text: str) -> None:
        """Print one log line (above the live status line)."""
        with self._lock:
            if self.live and self._status:
                self.out.write('\r\x1b[K')
                self.out.flush()
            self.err.write(text.rstrip('\n') + '\n')
            self.err.flush()
            if self.live and self._status:
                self.out.write(self._status)
                self.out.flush()

    def status(self, text: str) -> None:
        """Show the status: redraw the live line, or print a plain line."""
        with self._lock:
            if self.live:
                width = shutil.get_terminal_size((120, 24)).columns - 1
                self._status = text[:width]
                self.out.write('\r\x1b[K' + self._status)
            else:
                self.out.write(text + '\n')
            self.out.flush()

    def close(self) -> None:
        """End the live line."""
        with self._lock:
            if self.live and self._status:
                self.out.write('\n')
                self.out.flush()
                self._status = ''


def supervised_child(spec: ChildSpec, argv: list[str], env: Mapping[str, str],
                     console: Console) -> Child:
    """Return bringup's child for ``spec``: output to the console with a ``[name]`` prefix.

    Stopped by SIGTERM to the process only (it stops its own children in order; a group signal
    would not), SIGKILL after ``STOP_TIMEOUT_S``.
    """
    name = spec.name
    return Child(name, argv, env,
                 output=Output(on_line=lambda line: console.line('[{}] {}'.format(name, line))),
                 stopping=Stopping(sig=signal.SIGTERM, group=False, timeout=STOP_TIMEOUT_S,
                                   on_escalate=lambda t: console.line(
                                       'bringup: {} did not stop within {:.0f} s: SIGKILL'
                                       .format(name, t))),
                 launch=Launch(supervised=True, ready=spec.ready))


class Supervisor:
    """Start children in order, restart them with backoff, stop them in reverse order."""

    def __init__(self, children: Sequence[Child], console: Console, max_restarts: int = 10,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.children = list(children)
        self.console = console
        self.max_restarts = max_restarts
        self.clock = clock
        self.fatal: tuple[int, str] | None = None   # (exit code, why) -> stop the stack

    @property
    def restarts(self) -> int:
        """Return the total number of restarts."""
        return sum(c.restarts for c in self.children)

    def start_all(self, stopping: Callable[[], bool] = lambda: False) -> None:
        """Start every child in order (waiting, bounded, for a child's ``ready`` check).

        Start no more once ``stopping()`` says so (a stop signal during start-up).
        """
        for c in self.children:
            if stopping():
                return
            c.start()
            if c.launch.ready is not None:
                deadline = self.clock() + READY_TIMEOUT_S
                while (not c.launch.ready() and c.alive() and not stopping()
                       and self.clock() < deadline):
                    time.sleep(0.05)

    def step(self) -> None:
        """Reap children that ended; schedule and perform restarts."""
        now = self.clock()
        for c in self.children:
            if c.proc is not None:
                rc = c.reap()
                if rc is None:
                    if c.failures and now - c.started_at > STABLE_S:
                        c.failures = 0
                    continue
                ran = now - c.started_at
                if rc == CONFIG_ERROR:
                    self.fatal = (CONFIG_ERROR, '{} exited with code 2 (configuration error or '
                                  'another stack running; see its message above)'.format(
                                      c.name))
                    return
                c.failures = 1 if ran > STABLE_S else c.failures + 1
                if c.failures > self.max_restarts:
                    self.fatal = (1, '{} failed {} times in a row; giving up'.format(
                        c.name, c.failures))
                    return
                delay = restart_delay(c.failures)
                c.next_start = now + delay
                self.console.line('bringup: {} exited with code {} after {:.1f} s; restart {} '
                                  'in {:.1f} s'.format(c.name, rc, ran, c.restarts + 1,
                                                       delay))
            elif c.next_start and now >= c.next_start:
                c.restarts += 1
                c.start()
                self.console.line('bringup: {} restarted (restart {})'.format(
                    c.name, c.restarts))

    def stop_all(self) -> None:
        """Stop children in reverse start order (bridge, driver host, rt_core, sim_robot)."""
        for c in reversed(self.children):
            rc = c.stop()
            if rc is not None:
                self.console.line('bringup: {} stopped (exit code {})'.format(c.name, rc))


def sim_robot_spec(runtime_dir: str, overlay: str | None = None) -> ChildSpec:
    """Return how to run the simulated robot on ``runtime_dir`` (bringup, bench, demo).

    The one place that knows how the simulator is started; ``ready`` is true once it accepts
    connections on its sim-bus socket (docs/sim-bus.md).
    """
    args: tuple[str, ...] = ('--runtime-dir', runtime_dir)
    if overlay:
        args += ('--overlay', overlay)
    return ChildSpec('sim_robot', 'm4k_drivers', 'sim_robot', 'm4k_drivers.sim_robot', args,
                     ready=lambda: sim_ready(runtime_dir))


def sim_ready(runtime_dir: str) -> bool:
    """Return True when a simulator accepts connections on ``runtime_dir``'s sim-bus socket."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        sock.connect(os.path.join(runtime_dir, simbus.SOCKET_NAME))
        return True
    except OSError:
        return False
    finally:
        sock.close()


def uses_sim(doc: Mapping[str, Any] | None) -> bool:
    """Return True when the layered configuration has an enabled ``sim`` device or stand-in."""
    devices = (doc or {}).get('devices') or {}
    standin = (doc or {}).get('kernel_standin')
    if isinstance(standin, Mapping) and standin.get('enabled') is True:
        return True     # the real backends' wires end in sim_robot (m4k_drivers.abi.wire)
    return any(isinstance(s, Mapping) and s.get('backend') == 'sim' and s.get('enabled', True)
               for s in devices.values())


def foxglove_spec(address: str = '127.0.0.1', port: int = 8765,
                  params_file: str | None = None) -> ChildSpec:
    """Return how to run the Foxglove WebSocket server (the live view) on ``address:port``.

    ``params_file``: a ROS parameter file with an ``m4k_foxglove:`` section (token_file,
    allowed_origins, nav_goals, ...); address and port given here win over it.
    """
    extra = ('--params-file', params_file) if params_file else ()
    return ChildSpec('foxglove', 'm4k_bridge', 'foxglove', 'm4k_bridge.foxglove.node',
                     ('--ros-args', *extra, '-p', 'address:=' + address,
                      '-p', 'port:={:d}'.format(port)))


def child_specs(overlay: str | None, bridge_params_file: str, bridge_yaml: str,
                runtime_dir: str, sim: bool = True, foxglove: str | None = None,
                foxglove_port: int = 8765, namespace: str = '',
                extra_params: Sequence[str] = (),
                foxglove_params: str | None = None) -> list[ChildSpec]:
    """Return the children with their arguments, in start order (sim_robot first if ``sim``).

    ``foxglove``: the address to serve the live view on (None: no live view), on
    ``foxglove_port``; it starts last and so stops first. ``namespace``: ROS namespace of the
    bridge and the live view (their topics; /tf, /tf_static and /diagnostics stay absolute
    unless the bridge's tf_namespaced). ``extra_params``: more parameter files for the bridge,
    after the configuration's (later files win: e.g. two recipes' m4k_bridge sections).
    """
    ns_args: tuple[str, ...] = ('-r', '__ns:=/' + namespace.strip('/')) if namespace else ()
    rt_args: tuple[str, ...] = ('--config', overlay) if overlay else ()
    host_args: tuple[str, ...] = ('--runtime-dir', runtime_dir)
    if overlay:
        host_args += ('--overlay', overlay)
    live = []
    if foxglove:
        spec = foxglove_spec(foxglove, foxglove_port, foxglove_params)
        live = [dataclasses.replace(spec, args=spec.args + ns_args)]
    return [sim_robot_spec(runtime_dir, overlay)] * sim + [
        ChildSpec('rt_core', 'm4k_rt', 'rt_core', 'm4k_rt.rt_core', rt_args),
        ChildSpec('driver_host', 'm4k_drivers', 'driver_host', 'm4k_drivers.host', host_args),
        ChildSpec('bridge', 'm4k_bridge', 'bridge', 'm4k_bridge.node',
                  ('--ros-args', *ns_args, '--params-file', bridge_yaml, '--params-file',
                   bridge_params_file,
                   *(a for f in extra_params for a in ('--params-file', f)))),
    ] + live


# --- status line ------------------------------------------------------------------------------

_SHORT = {'actuator': 'act', 'monitor': 'mon', 'sonar': 'son'}


def format_status(rt: Any, task_levels: Mapping[str, int], restarts: int, uptime_s: float,
                  down: Sequence[str] = ()) -> str:
    """Format the one-line status from an RtStatus message (or None) and task levels (pure)."""
    parts = ['m4k {:d}:{:02d}'.format(int(uptime_s) // 60, int(uptime_s) % 60)]
    if rt is None or not rt.tasks:
        parts.append('waiting for rt_status')
    else:
        ok = sum(1 for t in rt.tasks if task_levels.get(t.name) == 0)
        parts.append('tasks {}/{} OK'.format(ok, len(rt.tasks)))
        rates = []
        worst = (0.0, '')
        for t in rt.tasks:
            avg = t.period_measured.avg
            rates.append('{} {}'.format(_SHORT.get(t.name, t.name),
                                        '{:.1f}'.format(1.0 / avg) if avg > 0 else '-'))
            if t.jitter.samples and t.jitter.max > worst[0]:
                worst = (t.jitter.max, t.name)
        parts.append(' '.join(rates) + ' Hz')
        if worst[1]:
            parts.append('worst jitter {:.2f} ms ({})'.format(worst[0] * 1e3, worst[1]))
        parts.append('guard {}'.format('ACTIVE' if rt.collision_guard_active else 'off'))
        if not math.isfinite(rt.rt_link_age) or rt.rt_link_age > 2.0:
            parts.append('RT silent {:.0f} s'.format(rt.rt_link_age)
                         if math.isfinite(rt.rt_link_age) else 'RT not linked')
    parts.append('restarts {}'.format(restarts))
    if down:
        parts.append('down: ' + ', '.join(down))
    return ' | '.join(parts)


class StatusSource:
    """Subscribe rt_status and diagnostics (rclpy) for the status line."""

    def __init__(self, namespace: str = '') -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        from m4k_msgs.msg import RtStatus
        self._rclpy = rclpy
        self.context = rclpy.context.Context()
        rclpy.init(args=[], context=self.context,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node('m4k_bringup', context=self.context,
                                      namespace='/' + namespace.strip('/'))
        self.rt: Any = None
        self.levels: dict[str, int] = {}
        self.node.create_subscription(RtStatus, 'rt_status', self._on_rt, 10)
        self.node.create_subscription(DiagnosticArray, bridge_params.spec(
            'topics.diagnostics').default, self._on_diag, 10)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def _on_rt(self, msg: Any) -> None:
        self.rt = msg

    def _on_diag(self, msg: Any) -> None:
        for s in msg.status:
            if s.name.startswith('m4k_rt: task '):
                self.levels[s.name[len('m4k_rt: task '):]] = s.level[0]

    def spin(self, timeout: float) -> None:
        """Process callbacks for up to ``timeout`` seconds."""
        self.executor.spin_once(timeout_sec=timeout)

    def close(self) -> None:
        """Destroy the node and shut its context down."""
        self.executor.shutdown()
        self.node.destroy_node()
        self._rclpy.try_shutdown(context=self.context)


# --- main ------------------------------------------------------------------------------------

def _parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog='bringup', description='Start and supervise the m4k '
                                 'stack: sim_robot (when devices are simulated), rt_core, '
                                 'driver_host (simulated devices by default) '
                                 'and the ROS 2 bridge. Ctrl-C stops it.')
    ap.add_argument('--config', metavar='FILE', help='user overlay YAML for every component '
                    '(its m4k_bridge: section holds bridge parameters)')
    ap.add_argument('--status-interval', type=float, default=10.0, metavar='S',
                    help='seconds between status lines when stdout is not a TTY')
    ap.add_argument('--max-restarts', type=int, default=10, metavar='N',
                    help='consecutive failures of one child before giving up')
    ap.add_argument('--python-m', action='store_true', help='run children with python -m '
                    '(source tree) instead of the installed executables')
    ap.add_argument('--no-status', action='store_true', help='do not subscribe rt_status')
    ap.add_argument('--namespace', default='', metavar='NS', help='ROS namespace of the '
                    'bridge (as ros2 launch ... namespace:=NS); /tf, /tf_static and '
                    '/diagnostics stay absolute')
    ap.add_argument('--robot', default='', metavar='NAME', help='one robot of several: '
                    'namespace /NAME, tf on /NAME/tf (tf_namespaced), frames unprefixed '
                    '(generate matching recipes with `recipes --robot NAME`)')
    ap.add_argument('--bridge-params', action='append', default=[], metavar='FILE',
                    help='another ROS parameter file for the bridge, after the configuration '
                    "(repeat it; later files win), e.g. two recipes' m4k_bridge sections")
    ap.add_argument('--foxglove', action='store_true', help='serve the live view to Foxglove '
                    '(WebSocket protocol, port 8765, localhost only: use an SSH tunnel)')
    ap.add_argument('--foxglove-address', metavar='ADDR', default='127.0.0.1',
                    help='address the live view listens on; 0.0.0.0 serves the LAN: give it '
                    'a token_file (--foxglove-params) and firewall it, or anyone who reaches '
                    'it can drive the robot')
    ap.add_argument('--foxglove-port', metavar='PORT', type=int, default=8765,
                    help='port of the live view (0: any free port, logged)')
    ap.add_argument('--foxglove-params', metavar='FILE',
                    help='ROS parameter file of the live view (m4k_foxglove: ros__parameters: '
                    'token_file, allowed_origins, nav_goals, max_clients, ...; '
                    'docs/live-view.md)')
    return rosargs.parse_args(ap, argv)


def _err(msg: str) -> None:
    sys.stderr.write('bringup: {}\n'.format(msg))
    sys.stderr.flush()


def bringup_argv(config: str | None = None, *, python_m: bool = True) -> list[str]:
    """Return the command that starts the stack, for tools that start it as a child.

    ``python_m``: no installed console script is needed, neither for bringup (``python -m``)
    nor for the children it starts (``--python-m``); else the installed ``bringup`` when
    there is one. ``config``: an overlay (``--config``).
    """
    exe = None if python_m else shutil.which('bringup')
    argv = [exe] if exe else [sys.executable, '-m', 'm4k_bringup.bringup']
    if python_m:
        argv.append('--python-m')
    return argv + (['--config', config] if config else [])


def main(argv: Sequence[str] | None = None) -> int:
    """Run the stack until Ctrl-C / SIGTERM; return the exit code."""
    return run_stoppable('bringup', lambda stop: _main(_parse_args(argv), stop))


def _main(args: argparse.Namespace, stop: StopSignals) -> int:
    from m4k_rt import channel
    overlay = os.path.abspath(args.config) if args.config else None
    try:
        cfg = config.load(overlay)
        doc = config.load_layered(overlay)
        control_params(doc.get('control'))   # the RT actuator's check, before any child runs
    except config.ConfigError as exc:   # ControlConfigError included
        _err('config error: {}'.format(exc))
        return CONFIG_ERROR
    try:
        runtime_dir = channel.ensure_runtime_dir(cfg.runtime.runtime_dir, cfg.runtime.group)
    except OSError as exc:
        _err('cannot create the runtime directory: {}'.format(exc))
        return 1
    try:
        bridge_doc = bridge_overlay(doc, runtime_dir)
        args.bridge_params = robots.param_files(args.bridge_params)
        if args.robot:
            namespace, values = robots.robot_settings(args.robot)
            if args.namespace and args.namespace.strip('/') != namespace.strip('/'):
                raise ValueError('--robot {} puts the bridge in {}, --namespace says {}: give '
                                 'one'.format(args.robot, namespace, args.namespace))
            args.namespace = namespace.strip('/')
            bridge_doc[bridge_params.NODE_NAME]['ros__parameters'].update(values)
    except bridge_params.ParamError as exc:
        _err('config error: m4k_bridge: {}'.format(exc))
        return CONFIG_ERROR
    except ValueError as exc:
        _err('usage: {}'.format(exc))
        return CONFIG_ERROR
    try:
        # Through the one loader now, before any child: under --namespace these files are
        # rewritten later, and a duplicate key must not be resolved silently on the way.
        for path in args.bridge_params:
            robots.load_param_file(path)
    except ValueError as exc:
        _err('config error: m4k_bridge: {}'.format(exc))
        return CONFIG_ERROR
    if args.foxglove_params:        # before any child: the live view would only exit 2
        from m4k_bridge.foxglove import params as foxglove_params
        from m4k_rt import yamlload
        try:
            with open(args.foxglove_params, encoding='utf-8') as f:
                foxglove_params.check_param_file(yamlload.load(f), args.foxglove_params)
        except (OSError, ValueError, yaml.YAMLError) as exc:
            _err('config error: m4k_foxglove: {}'.format(exc))
            return CONFIG_ERROR
    owner = lock_owner(runtime_dir)
    if owner is not None:
        _err('another m4k stack owns {} (rt_core pid {}); stop it first'.format(
            runtime_dir, owner))
        return CONFIG_ERROR
    try:
        lock = InstanceLock(runtime_dir, 'bringup')
    except RuntimeError as exc:
        _err('{}; stop it first'.format(exc))
        return CONFIG_ERROR
    tmpdir = tempfile.mkdtemp(prefix='m4k-bringup-')
    try:
        return _run(args, overlay, runtime_dir, bridge_doc, tmpdir, stop, uses_sim(doc))
    finally:
        shutil.rmtree(tmpdir, ignore_errors=True)
        lock.release()


def _run(args: argparse.Namespace, overlay: str | None, runtime_dir: str,
         bridge_doc: dict[str, Any], tmpdir: str, stop: StopSignals, sim: bool = True) -> int:
    params_file = os.path.join(tmpdir, 'bridge_overlay.yaml')
    with open(params_file, 'w', encoding='utf-8') as f:
        # keyed by the node's fully qualified name under a namespace (rcl would not apply a
        # bare m4k_bridge section to /r1/m4k_bridge)
        yaml.safe_dump(robots.for_namespace(bridge_doc, args.namespace), f)
    extra = robots.namespaced_files(args.bridge_params, args.namespace, tmpdir)
    bridge_yaml = os.path.join(config.find_config_dir(), 'bridge.yaml')
    # the e-stop request's state directory, from this environment before the children get
    # M4K_RUNTIME_DIR (m4k_rt.estop_request: persistent unless the runtime dir is private)
    env = dict(os.environ, M4K_RUNTIME_DIR=runtime_dir, PYTHONUNBUFFERED='1',
               M4K_STATE_DIR=estop_request.state_dir())
    console = Console(sys.stdout, sys.stderr, sys.stdout.isatty())
    children = [supervised_child(s, resolve_command(s, args.python_m), env, console)
                for s in child_specs(overlay, params_file, bridge_yaml, runtime_dir, sim,
                                     args.foxglove_address if args.foxglove else None,
                                     args.foxglove_port, args.namespace, extra,
                                     os.path.abspath(args.foxglove_params)
                                     if args.foxglove_params else None)]
    sup = Supervisor(children, console, args.max_restarts)
    status = None
    try:
        if not args.no_status and not stop.stopping:
            try:
                status = StatusSource(args.namespace)
            except Exception as exc:  # noqa: BLE001 -- the stack runs without a status line
                console.line('bringup: no status line ({}: {})'.format(type(exc).__name__, exc))
        console.line('bringup: runtime dir {}; starting {}'.format(
            runtime_dir, ', '.join(' '.join(c.argv) for c in children)))
        sup.start_all(lambda: stop.stopping)
        t0 = time.monotonic()
        next_status = t0 + (1.0 if console.live else min(args.status_interval, 3.0))
        while not stop.stopping and sup.fatal is None:
            if status is not None:
                status.spin(0.1)
            else:
                stop.event.wait(0.1)
            sup.step()
            now = time.monotonic()
            if now >= next_status:
                down = [c.name for c in children if not c.alive()]
                console.status(format_status(status.rt if status else None,
                                             status.levels if status else {}, sup.restarts,
                                             now - t0, down))
                next_status = now + (1.0 if console.live else args.status_interval)
        console.close()
        if sup.fatal is not None:
            console.line('bringup: {}; stopping the stack'.format(sup.fatal[1]))
        else:
            console.line('bringup: stopping (bridge, driver_host, rt_core{})'.format(
                ', sim_robot' if sim else ''))
        return sup.fatal[0] if sup.fatal is not None else 0
    finally:
        # Signals during the stop sequence must not interrupt the bounded waits.
        stop.ignore()
        sup.stop_all()
        if status is not None:
            status.close()


if __name__ == '__main__':
    sys.exit(main())
