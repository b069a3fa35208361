"""The RT process: load config, harden, bind ports, build bodies, run the tasks until a signal.

Start-up order matters: everything that allocates, imports, opens files or prints happens
here, before the first task starts -- config, instance lock, hardening report (stderr), port
binding, body factories, GC freeze, forbidden-call audit hook and console guard. Inside the
loops the only way information leaves the process is the ``monitor`` task, which ships
timing samples and counters as datagrams on the ``status`` port (the bridge) and the ``stat``
port (``rt_stat``, opened on demand). No file I/O happens in the RT process after start-up.

Exit codes: 0 clean stop, 1 runtime failure (hardening required but degraded, a port could
not be bound, a body failed to build, a task did not stop), 2 configuration error or another
stack owning the runtime directory.
"""

import argparse
import dataclasses
import fcntl
import importlib
import json
import os
import sys
import threading
from typing import Any, Sequence

from m4k_rt import config, cycleprof, modeswitch, rosargs, sched, tasks, timing
from m4k_rt.stopsignals import run_stoppable, StopSignals
from m4k_rt.task import RtTask
from m4k_rt.tasks import register_body
from m4k_rt.tasks.monitor import make_monitor, StatsShipper
from m4k_rt.timerfd import monotonic_ns

__all__ = ['InstanceLock', 'LockError', 'SharedState', 'StatsShipper', 'main', 'register_body']

BODY_MODULES_ENV = 'M4K_BODY_MODULES'


class LockError(RuntimeError):
    """Another RT core owns the runtime directory."""


class InstanceLock:
    """An flock on ``<runtime_dir>/<owner>.lock`` holding the owner's pid.

    rt_core takes ``rt_core.lock``; bringup takes ``bringup.lock`` first, which closes the race
    between two stacks starting at once.
    """

    def __init__(self, runtime_dir: str, owner: str = 'rt_core') -> None:
        """Take the lock or raise :class:`LockError` naming the owner's pid."""
        self.path = os.path.join(runtime_dir, owner + '.lock')
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            try:
                pid = os.pread(fd, 32, 0).decode().strip() or '?'
            finally:
                os.close(fd)
            raise LockError('another m4k stack owns {} ({}pid {})'.format(
                runtime_dir, '' if owner == 'rt_core' else owner + ' ', pid)) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, '{}\n'.format(os.getpid()).encode(), 0)
        self._fd = fd

    def release(self) -> None:
        """Drop the lock (idempotent)."""
        if self._fd >= 0:
            fd, self._fd = self._fd, -1
            os.close(fd)


@dataclasses.dataclass
class SharedState:
    """What body factories get besides their own config and ports."""

    config: config.RtConfig
    hardening: sched.Hardening
    tasks: list[RtTask] = dataclasses.field(default_factory=list)
    # The threads to start and stop: every task's own, or the frame executive's runner in
    # place of its members (m4k_rt.frame); empty = ``tasks``.
    runners: list[RtTask] = dataclasses.field(default_factory=list)
    stop_event: threading.Event = dataclasses.field(default_factory=threading.Event)
    audit_installed: bool = False    # the forbidden-call audit hook (RT_STATUS flags bit)
    robot: Any = None                # tasks.state.RobotState, set by the first robot body
    ports: dict[str, Any] = dataclasses.field(default_factory=dict)  # label -> RtXddpSocket
    runtime_dir: str = ''            # the sockets' directory (the e-stop request file's too)


register_body('monitor', make_monitor)


def _err(msg: str) -> None:
    sys.stderr.write('rt_core: {}\n'.format(msg))
    sys.stderr.flush()


def _parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog='rt_core', description='m4k real-time core process.')
    ap.add_argument('--config', metavar='FILE', help='user overlay YAML (merged last)')
    ap.add_argument('--config-dir', metavar='DIR', help='config directory (default: found)')
    ap.add_argument('--require-rt', action='store_true',
                    help='exit 1 when SCHED_FIFO, mlockall or other hardening is not granted')
    ap.add_argument('--tasks', metavar='A,B', help='run only these tasks (monitor always runs)')
    ap.add_argument('--echo', action='store_true', help='use echo bodies for all but monitor')
    ap.add_argument('--duration', type=float, metavar='S', help='stop after S seconds')
    ap.add_argument('--body-module', action='append', default=[], metavar='MOD',
                    help='import MOD first (it may call register_body); also $' +
                    BODY_MODULES_ENV)
    ap.add_argument('--cycle-profile', metavar='FILE', default=cycleprof.env_path(),
                    help='time the parts of every task cycle (m4k_rt.cycleprof) and write '
                    'the breakdown as JSON to FILE at exit; also $' + cycleprof.ENV)
    return rosargs.parse_args(ap, argv)


def _select(cfg: config.RtConfig, names: str | None,
            echo: bool) -> list[config.TaskConfig]:
    chosen = list(cfg.tasks)
    if names:
        wanted = [n.strip() for n in names.split(',') if n.strip()]
        known = {t.name for t in cfg.tasks}
        for n in wanted:
            if n not in known:
                raise config.ConfigError('--tasks', 'unknown task {!r} (configured: {})'.format(
                    n, ', '.join(sorted(known))), n)
        chosen = [t for t in cfg.tasks if t.name in wanted or t.body == 'monitor']
    if echo:
        chosen = [t if t.body == 'monitor' else dataclasses.replace(t, body='echo')
                  for t in chosen]
    return chosen


def main(argv: Sequence[str] | None = None) -> int:
    """Run the RT process; return the exit code."""
    return run_stoppable('rt_core', lambda stop: _main(_parse_args(argv), stop))


def _main(args: argparse.Namespace, stop: StopSignals) -> int:
    mods = list(args.body_module) + [m for m in os.environ.get(BODY_MODULES_ENV, '').split(',')
                                     if m.strip()]
    for mod in mods:
        try:
            importlib.import_module(mod.strip())
        except Exception as exc:  # noqa: BLE001 -- report any plug-in failure as one line
            _err('cannot import body module {!r}: {}'.format(mod, exc))
            return 2
    try:
        cfg = config.load(args.config, args.config_dir, body_exists=tasks.body_exists)
        chosen = _select(cfg, args.tasks, args.echo)
    except config.ConfigError as exc:
        _err('config error: {}'.format(exc))
        return 2
    rt = cfg.runtime
    cycleprof.enable(bool(args.cycle_profile))  # before any task, reader or writer is built
    from m4k_rt import channel  # bound here so a config error exits before any socket work
    try:
        runtime_dir = channel.ensure_runtime_dir(rt.runtime_dir, rt.group)
    except OSError as exc:
        _err('cannot create runtime dir: {}'.format(exc))
        return 1
    try:
        lock = InstanceLock(runtime_dir)
    except LockError as exc:
        _err(str(exc))
        return 2
    socks: list[Any] = []
    try:
        return _run(args, cfg, chosen, runtime_dir, socks, stop)
    finally:
        for s in socks:
            s.close()
        lock.release()


def _run(args: argparse.Namespace, cfg: config.RtConfig, chosen: list[config.TaskConfig],
         runtime_dir: str, socks: list[Any], stop: StopSignals) -> int:
    from m4k_rt import channel
    rt = cfg.runtime
    if stop.stopping:
        return 0
    hard = sched.harden(priority=max(t.priority for t in chosen), mlockall=rt.mlockall,
                        cpu_dma_latency=rt.cpu_dma_latency,
                        switch_interval_s=rt.switch_interval_s)
    try:
        for line in hard.lines():
            _err(line)
        if (args.require_rt or rt.require_rt) and hard.degraded:
            _err('--require-rt: refusing to run degraded')
            return 1
        shared = SharedState(cfg, hard, stop_event=stop.event, runtime_dir=runtime_dir)
        built: list[tuple[config.TaskConfig, Any]] = []
        for t in chosen:
            ports = {}
            for label in t.ports:
                try:
                    s = channel.rt_xddp_bind(cfg.ports[label], label, poolsz=rt.poolsz,
                                          max_datagram=rt.max_datagram, runtime_dir=runtime_dir,
                                          max_ports=rt.max_ports, group=rt.group,
                                          transport=rt.transport)
                except OSError as exc:
                    _err('cannot bind port {} ({!r}) for task {}: {}'.format(
                        cfg.ports[label], label, t.name, exc))
                    return 1
                socks.append(s)
                ports[label] = s
                shared.ports[label] = s
            try:
                body = tasks.get_factory(t.body)(t, ports, shared)
            except Exception as exc:  # noqa: BLE001 -- one line naming the task, then exit
                _err('task {}: body {!r} failed to build: {}: {}'.format(
                    t.name, t.body, type(exc).__name__, exc))
                return 1
            built.append((t, body))
            if stop.stopping:  # nothing runs yet: outputs were never driven
                return 0
        start = timing.first_release(monotonic_ns(), 1_000_000,
                                     lead_ns=int(rt.start_delay_ms * 1e6))
        for i, (t, body) in enumerate(built):
            shared.tasks.append(RtTask(t.name, t.priority, t.period_ns, body, cpu=t.cpu,
                                       start_ns=start + t.offset_ns,
                                       ring_capacity=rt.ring_capacity, index=i))
        try:
            shared.runners = _runners(rt, shared.tasks, start)
        except config.ConfigError as exc:
            _err('config error: {}'.format(exc))
            return 2
        return _serve(args, shared)
    finally:
        hard.close()


def _runners(rt: config.RuntimeConfig, rt_tasks: list[RtTask], start_ns: int) -> list[RtTask]:
    """Return the threads to run: one per task, or the frame's runner plus the others."""
    if rt.executive != 'frame':
        return list(rt_tasks)
    from m4k_rt.frame import FrameExecutive
    members = [t for t in rt_tasks if t.name in rt.frame_tasks]
    if not members:
        return list(rt_tasks)
    frame = FrameExecutive(members, start_ns=start_ns)
    return [frame.runner] + [t for t in rt_tasks if t.name not in rt.frame_tasks]


def _serve(args: argparse.Namespace, shared: SharedState) -> int:
    modeswitch.install()
    modeswitch.install_console_guard()
    shared.audit_installed = True
    sched.freeze_gc(shared.hardening)
    stop = shared.stop_event
    runners = shared.runners or shared.tasks
    try:
        for t in runners:
            t.start()
        _err('gc frozen and disabled; running {} tasks in {} threads: {}'.format(
            len(shared.tasks), len(runners), ', '.join(
                '{}({} ms, prio {}{})'.format(t.name, t.period_ns / 1e6, t.priority,
                                              '' if t.fifo else ', NOT FIFO: ' + str(
                                                  t.sched_error))
                for t in runners)))
        stop.wait(args.duration)
    finally:
        for t in runners:
            t.stop()
        stuck = [t.name for t in runners if not t.join(2.0 * t.period_ns / 1e9 + 1.0)]
        modeswitch.uninstall_console_guard()
        sched.unfreeze_gc()
    for t in shared.tasks:
        if isinstance(t.body, StatsShipper):
            t.body.ship()  # the tail of every ring, now that no task runs
    for t in shared.tasks:
        c = t.counters()
        _err('task {name}: cycles {cycles} overruns {overruns} misses {deadline_misses} '
             'body errors {body_errors} forbidden {forbidden_calls} csw vol+ {nvcsw_extra} '
             'invol {nivcsw} pf {minflt}/{majflt}'.format(**c)
             + ('' if not t.last_error else ' last error {!r} at {}'.format(
                 t.last_error, t.last_error_site)))
    if args.cycle_profile:
        _write_profile(args.cycle_profile, shared.tasks)
    if stuck:
        _err('tasks did not stop in time: {}'.format(', '.join(stuck)))
        return 1
    return 0


def _write_profile(path: str, rt_tasks: Sequence[RtTask]) -> None:
    """Write every task's cycle breakdown (µs per cycle) as JSON; one line each to stderr."""
    out = {'tasks': {t.name: dict(t.profile.summary(), period_ns=t.period_ns)
                     for t in rt_tasks if t.profile is not None}}
    for name, s in out['tasks'].items():
        _err('task {}: cycle profile (us per cycle) {}, thread CPU {}'.format(
            name, ' '.join('{} {:.1f}'.format(k, v) for k, v in s.get('parts_us', {}).items()),
            'n/a' if s.get('thread_cpu_per_cycle_us') is None
            else '{:.1f}'.format(s['thread_cpu_per_cycle_us'])))
    try:
        with open(path, 'w', encoding='utf-8') as f:
            json.dump(out, f, indent=1)
            f.write('\n')
    except OSError as exc:
        _err('cannot write the cycle profile to {}: {}'.format(path, exc))


if __name__ == '__main__':
    sys.exit(main())
