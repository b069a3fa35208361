"""Run the pieces the bench measures: rt_core + driver_host, the plain-ROS baseline.

Both drive the same simulated robot: a ``sim_robot`` process started first (as bringup does,
:func:`start_sim_robot`) and stopped last.

Children are started by module entry point (``python -c 'from MOD import main; ...'``), so the
bench works from the source tree and from the colcon install alike, each in its own session
with stderr logged to ``<results>/logs/``. They are stopped by their own pid (SIGTERM, then
SIGKILL after a grace period), never by name: each is a :class:`m4k_bringup.child.Child`,
the one process wrapper, started by :func:`start_child`.

:func:`start_stack` is the one place that starts the robot stack for a measurement.

While the RT stack runs, the bench records every TASK_STATS batch of the ``status`` port with
:class:`m4k_bench.recorder.Recorder`. Commands take the architecture's path end to end
(``e2e=True``, the default): the velocity profile (:func:`velocity_profile`, 20 Hz as the
paper's navigation stack) is published as Twist on ``cmd_vel`` over DDS, the bridge forwards it
over XDDP to the actuator -- the same DDS publisher the plain-ROS baseline gets
(:func:`ros_commander`), so both run the same control on the same commands over the same
middleware. The bridge's own ``status`` port is pointed at an unused label: the bench, not the
bridge, is that port's peer. ``e2e=False`` writes VELOCITY_CMD on ``cmd`` directly.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from typing import Any, Callable, Sequence

from m4k_bench import recorder
from m4k_bench.benchlib import liveclient, system
from m4k_bringup.child import Child, Output, Stopping
from m4k_rt import channel, protocol

__all__ = ['CMD_PERIOD_S', 'Child', 'M4kRun', 'entry_argv', 'module_available', 'run_m4k',
           'ros_commander', 'start_child', 'start_sim_robot', 'start_stack', 'velocity_profile']

CMD_PERIOD_S = 0.05   # 20 Hz, as the paper's navigation stack
_ENTRY = 'import sys; from {} import {} as _m; sys.exit(_m())'


def entry_argv(module: str, *args: str, func: str = 'main') -> list[str]:
    """Return argv running ``module.func()`` with ``args`` in this interpreter."""
    return [sys.executable, '-c', _ENTRY.format(module, func), *args]


def module_available(module: str) -> bool:
    """Tell whether ``module`` can be imported (without importing it)."""
    import importlib.util
    try:
        return importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:
        return False


def velocity_profile(t_s: float) -> tuple[float, float]:
    """Return (linear m/s, angular rad/s) at ``t_s``: 0.25 m/s forward 4 s, back 4 s, repeat.

    0.25 m/s is the paper's experiment speed; going back and forth keeps the simulated robot
    well inside the room (about 1 m of travel) for a run of any length.
    """
    phase = (t_s % 8.0) < 4.0
    return (0.25 if phase else -0.25), 0.0


def start_child(name: str, argv: Sequence[str], log_dir: str,
                env: dict[str, str] | None = None, *, log_name: str | None = None,
                stop_signal: int = signal.SIGTERM, group: bool = False) -> Child:
    """Start a bench child (:class:`m4k_bringup.child.Child`) in its own session, now.

    The bench's processes (the stacks of bench, soak and fuzz, and demo's bringup, planner and
    recorder) log to ``<log_dir>/<log_name>`` (default ``<name>.log``, appended to, headed by
    the command line). ``stop`` sends ``stop_signal`` (SIGTERM) to the process, or to its whole
    session with ``group=True`` (demo SIGINTs bringup's), then SIGKILL after the grace time
    (8 s unless given); a process that survives SIGKILL is an AssertionError.
    """
    os.makedirs(log_dir, exist_ok=True)
    return Child(name, argv, env,
                 output=Output(log_path=os.path.join(log_dir, log_name or name + '.log')),
                 stopping=Stopping(sig=stop_signal, group=group, timeout=8.0,
                                   must_end=True)).start()


def start_sim_robot(runtime_dir: str, log_dir: str, name: str,
                    env: dict[str, str] | None = None, timeout_s: float = 30.0) -> Child:
    """Start the simulated robot on ``runtime_dir`` the way bringup does; wait until it answers.

    Raise RuntimeError (with the log tail) when it exits or stays silent.
    """
    from m4k_bringup import bringup
    spec = bringup.sim_robot_spec(runtime_dir)
    child = start_child(name + '.sim_robot', entry_argv(spec.module, *spec.args), log_dir, env)
    deadline = time.monotonic() + timeout_s
    while not bringup.sim_ready(runtime_dir):
        if not child.alive() or time.monotonic() > deadline:
            child.stop()
            raise RuntimeError('sim_robot did not start: ' + ' | '.join(child.tail()))
        time.sleep(0.05)
    return child


class M4kRun:
    """What one rt_core (+ driver_host) run produced."""

    def __init__(self) -> None:
        """Start empty."""
        self.recorder = recorder.Recorder()
        self.cpu_percent: float | None = None
        self.cpu_s: float | None = None
        self.cpu_window_s = 0.0
        self.rt_exit: int | None = None
        self.host_exit: int | None = None
        self.commands_sent = 0
        self.odometry_received = 0
        self.live_view: dict[str, Any] | None = None   # the m4k_live viewer's counts
        self.errors: list[str] = []


UNUSED_STATUS_LABEL = 'bench_unused'


def start_stack(name: str, runtime_dir: str, log_dir: str, env: dict[str, str], *,
                tasks: str | None = None, driver_host: bool = True, bridge: bool = True,
                rt_config: str | None = None, live_port: int | None = None
                ) -> dict[str, Child]:
    """Start the robot stack for one measurement; return its children by role.

    sim_robot first (with the driver host; RuntimeError when it does not come up), rt_core
    (``--tasks`` / ``--config`` as given), then the driver host and the bridge. Every process
    the stack needs is started here and nowhere else.
    """
    rt_args = ['--tasks', tasks] if tasks else []
    if rt_config:
        rt_args += ['--config', rt_config]
    kids = {}
    if driver_host:     # the robot the driver host drives: first, and stopped last
        kids['sim_robot'] = start_sim_robot(runtime_dir, log_dir, name, env)
    kids['rt_core'] = start_child(name + '.rt_core', entry_argv('m4k_rt.rt_core', *rt_args),
                                  log_dir, env)
    if driver_host:
        kids['driver_host'] = start_child(name + '.driver_host',
                                          entry_argv('m4k_drivers.host'), log_dir, env)
    if bridge:
        kids['bridge'] = start_child(name + '.bridge', entry_argv(
            'm4k_bridge.node', '--ros-args', '-p',
            'ports.status:={}'.format(UNUSED_STATUS_LABEL)), log_dir, env)
    if bridge and live_port is not None:    # the live view (Foxglove WebSocket), on localhost
        kids['foxglove'] = start_child(name + '.foxglove', entry_argv(
            'm4k_bridge.foxglove.node', '--ros-args', '-p', 'port:={:d}'.format(live_port)),
            log_dir, env)
    return kids


def run_m4k(duration_s: float, runtime_dir: str, log_dir: str, name: str, *,
            tasks: str | None = None, driver_host: bool = True,
            progress: Callable[[str], None] | None = None,
            env: dict[str, str] | None = None, start_timeout_s: float = 30.0,
            rt_config: str | None = None, e2e: bool = True,
            on_started: Callable[[], None] | None = None, live: bool = False) -> M4kRun:
    """Run the stack for ``duration_s`` of task time, recording the status port.

    The CPU window starts when the first TASK_STATS batch arrives (tasks running, imports
    done; ``on_started`` is called then) and ends ``duration_s`` later, just before rt_core
    is stopped. ``live``: the live view runs too, with a viewer reading every channel
    (:mod:`m4k_bench.benchlib.liveclient`); its counts are ``live_view``.
    """
    out = M4kRun()
    env = dict(env or os.environ, M4K_RUNTIME_DIR=runtime_dir)
    channel.ensure_runtime_dir(runtime_dir)
    live_port = liveclient.free_port() if live and e2e else None
    try:
        kids = start_stack(name, runtime_dir, log_dir, env, tasks=tasks,
                           driver_host=driver_host, bridge=e2e, rt_config=rt_config,
                           live_port=live_port)
    except RuntimeError as exc:
        out.errors.append(str(exc))
        return out
    viewer = liveclient.LiveClient(live_port) if live_port is not None else None
    rt = kids['rt_core']
    status = channel.NrtLink('status', runtime_dir, retry_interval=0.05)
    cmd = None if e2e else channel.NrtLink('cmd', runtime_dir, retry_interval=0.05)
    stop_cmd = threading.Event()
    commander = ros_commander(stop_cmd) if e2e else None
    rec = out.recorder
    seq = 0
    try:
        t_begin = time.monotonic()
        t_first = None
        cpu0 = 0.0
        next_cmd = t_begin
        next_note = t_begin
        while True:
            now = time.monotonic()
            if t_first is None:
                if now - t_begin > start_timeout_s:
                    out.errors.append('no TASK_STATS within {:.0f} s of starting rt_core'
                                      .format(start_timeout_s))
                    break
                if not rt.alive():
                    out.errors.append('rt_core exited early: ' + ' | '.join(rt.tail()))
                    break
            elif now - t_first >= duration_s:
                break
            if now >= next_cmd:
                if cmd is not None:
                    v, w = velocity_profile(now - t_begin)
                    if cmd.write(protocol.encode(protocol.Kind.VELOCITY_CMD, seq,
                                                 time.monotonic_ns(), v, w)):
                        out.commands_sent += 1
                    seq += 1
                    while cmd.read(0.0) is not None:
                        out.odometry_received += 1
                next_cmd += CMD_PERIOD_S
            data = status.read(max(0.0, min(next_cmd - time.monotonic(), CMD_PERIOD_S)))
            if data:
                kind = rec.feed(data)
                if t_first is None and kind == protocol.Kind.TASK_STATS:
                    t_first = time.monotonic()
                    cpu0 = system.proc_cpu_seconds(rt.pid)
                    if on_started is not None:
                        on_started()
            if progress is not None and now >= next_note:
                next_note = now + 0.5
                progress('{} batches'.format(rec.datagrams))
        if t_first is not None and rt.alive():
            cpu1 = system.proc_cpu_seconds(rt.pid)
            out.cpu_window_s = time.monotonic() - t_first
            out.cpu_s = cpu1 - cpu0
            out.cpu_percent = 100.0 * (cpu1 - cpu0) / out.cpu_window_s
        if rt.alive():
            rt.send_signal(signal.SIGTERM)
        # rt_core ships the tail of every ring after its tasks stop: keep reading until it exits.
        end = time.monotonic() + 10.0
        while time.monotonic() < end:
            data = status.read(0.2)
            if data:
                rec.feed(data)
            elif not rt.alive():
                break
    finally:
        stop_cmd.set()
        if commander is not None:
            commander.join(5.0)
        if viewer is not None:
            out.live_view = viewer.stop()
            if out.live_view['error'] or not out.live_view['messages']:
                out.errors.append('live view: no messages ({})'.format(out.live_view['error']))
        status.close()
        if cmd is not None:
            cmd.close()
        out.rt_exit = rt.stop()
        for role, child in reversed(list(kids.items())):    # sim_robot last
            if role == 'rt_core':
                continue
            code = child.stop()
            if role == 'driver_host':
                out.host_exit = code
            if code not in (0, -signal.SIGTERM, None):
                out.errors.append('{} exited {}: {}'.format(role, code, ' | '.join(
                    child.tail())))
    if out.rt_exit not in (0, -signal.SIGTERM):
        out.errors.append('rt_core exited {}: {}'.format(out.rt_exit, ' | '.join(rt.tail())))
    return out


def ros_commander(stop: threading.Event, *, topic: str = 'cmd_vel',
                  t0: float | None = None,
                  moving: threading.Event | None = None) -> threading.Thread:
    """Start a thread publishing the velocity profile as Twist at 20 Hz until ``stop``.

    With ``moving``, the thread also takes ``odom`` and sets the event at the first odometry
    that reports motion: the whole loop (cmd_vel -> bridge -> RT -> drivers -> RT -> bridge ->
    odom) is flowing.
    """
    from geometry_msgs.msg import Twist
    import rclpy
    from rclpy.context import Context

    ctx = Context()
    # Not this process's command line (rclpy's default): launch arguments given to the tool
    # (a namespace, a node name) are not the stack's, and would move cmd_vel and odom away
    # from the stack the tool started.
    rclpy.init(context=ctx, args=[])
    node = rclpy.create_node('m4k_bench_commander', context=ctx)
    pub = node.create_publisher(Twist, topic, 10)
    start = time.monotonic() if t0 is None else t0
    executor = None
    if moving is not None:
        from nav_msgs.msg import Odometry
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import qos_profile_sensor_data

        def on_odom(msg: Odometry) -> None:
            if abs(msg.twist.twist.linear.x) > 1e-3 or abs(msg.twist.twist.angular.z) > 1e-3:
                moving.set()
        node.create_subscription(Odometry, 'odom', on_odom, qos_profile_sensor_data)
        executor = SingleThreadedExecutor(context=ctx)
        executor.add_node(node)

    def run() -> None:
        msg = Twist()
        nxt = time.monotonic()
        try:
            while not stop.is_set():
                v, w = velocity_profile(time.monotonic() - start)
                msg.linear.x, msg.angular.z = v, w
                pub.publish(msg)
                nxt += CMD_PERIOD_S
                while True:          # serve odom while waiting for the next command
                    left = nxt - time.monotonic()
                    if left <= 0 or stop.is_set():
                        break
                    if executor is None or moving is None or moving.is_set():
                        stop.wait(left)
                    else:
                        executor.spin_once(timeout_sec=left)
        finally:
            if executor is not None:
                executor.shutdown()
            node.destroy_node()
            ctx.try_shutdown()

    th = threading.Thread(target=run, name='bench-cmd_vel', daemon=True)
    th.start()
    return th


def run_baseline(duration_s: float, csv_path: str, log_dir: str, name: str, *,
                 env: dict[str, str] | None = None,
                 progress: Callable[[str], None] | None = None,
                 on_started: Callable[[], None] | None = None) -> dict[str, Any]:
    """Run the baseline node for ``duration_s`` with the profile on cmd_vel; return status."""
    import shutil
    import tempfile
    runtime_dir = tempfile.mkdtemp(prefix='m4k-base-')    # short: a Unix socket lives there
    env = dict(env or os.environ, M4K_RUNTIME_DIR=runtime_dir)
    try:
        sim = start_sim_robot(runtime_dir, log_dir, name, env)
    except RuntimeError as exc:
        shutil.rmtree(runtime_dir, ignore_errors=True)
        return {'exit': None, 'csv': None, 'log_tail': [str(exc)]}
    stop = threading.Event()
    commander = ros_commander(stop)
    child = start_child(name, entry_argv('m4k_bench.baseline', '--duration', str(duration_s),
                                         '--timing-csv', csv_path), log_dir, env)
    if on_started is not None:
        on_started()
    t0 = time.monotonic()
    try:
        while child.wait(0.5) is None:
            if progress is not None:
                progress('{:.0f} s'.format(time.monotonic() - t0))
            if time.monotonic() - t0 > duration_s + 60.0:
                break
    finally:
        code = child.stop()
        stop.set()
        commander.join(5.0)
        sim.stop()
        shutil.rmtree(runtime_dir, ignore_errors=True)
    return {'exit': code, 'csv': csv_path if os.path.exists(csv_path) else None,
            'log_tail': child.tail()}
