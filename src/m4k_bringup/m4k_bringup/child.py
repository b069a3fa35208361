"""One child process of the stack: the one process wrapper of m4k.

Every tool that starts a process of the stack -- bringup's supervisor, the bench, the demo, the
scenario runner, fuzz and soak, and the tests' ``procs`` fixture (m4k_testing) -- starts it as a
:class:`Child`:

* in a process group of its own: a new session (``start_new_session``), or, for bringup's
  ``supervised`` children, a new process group in bringup's session (a terminal Ctrl-C reaches
  bringup only), with ``setpriv --pdeathsig TERM`` when available and the stop signals blocked
  until the child has installed its handlers;
* its output (stdout and stderr) either copied line by line to ``on_line`` (bringup's console)
  or written to the log file ``log_path`` (appended to unless ``log_append`` is false, headed by
  the command line unless ``log_header`` is false; ``os.devnull`` discards it), or inherited;
  the streams named in ``pipes`` (``stdin``, ``stdout``, ``stderr``) are text pipes the caller
  reads or writes through ``proc`` instead (a tool that parses its child's output); those named
  in ``streams`` go to what the caller already holds open -- a file or descriptor,
  ``subprocess.DEVNULL``, or ``subprocess.STDOUT`` for stderr -- and stay the caller's to close
  (the tests' process fixture, whose tests keep stdout and stderr in separate files);
* stopped by the one stop ladder, :func:`m4k_rt.proc.stop_process`: ``sig`` to the
  process (or to its whole group with ``group=True``), wait ``timeout`` s, then SIGKILL
  (``on_escalate(timeout)`` called first) and wait ``kill_timeout`` s, then SIGKILL whatever
  is left in its group; the exit code is returned and kept in ``last_rc``.

The options come in three small groups, by what they are for: :class:`Output` (where the
output goes), :class:`Stopping` (the stop ladder) and :class:`Launch` (supervision,
readiness, CPU).

ROS-free and import-light, so the bench imports it without loading bringup's launch machinery.
The supervisor's restart bookkeeping (``restarts``, ``failures``, ``next_start``) lives here
too: it belongs to the process, and tools that do not restart simply leave it at zero.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
import os
import shutil
import signal
import subprocess
import threading
import time
from typing import Any, BinaryIO, Callable, IO, Mapping, Sequence

from m4k_rt.proc import stop_process
from m4k_rt.stopsignals import blocked_stop_signals

__all__ = ['Child', 'Launch', 'Output', 'STOP_TIMEOUT_S', 'Stopping']

STOP_TIMEOUT_S = 8.0      # default wait after the stop signal, then SIGKILL
_STREAMS = frozenset({'stdin', 'stdout', 'stderr'})


@dataclass(frozen=True)
class Output:
    """Where the child's stdout and stderr go (the module docstring says how each works).

    A log file (``log_path``, appended to unless ``log_append`` is false, headed by the command
    line unless ``log_header`` is false), or the console (``on_line``), or neither (inherited);
    ``pipes``: the streams the caller reads or writes through ``proc``; ``streams``: streams
    given to what the caller holds open.
    """

    log_path: str | None = None
    log_append: bool = True
    log_header: bool = True
    on_line: Callable[[str], None] | None = None
    pipes: Sequence[str] = ()
    streams: Mapping[str, int | IO[Any]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        """Refuse combinations that cannot work, naming them."""
        object.__setattr__(self, 'pipes', tuple(self.pipes))
        object.__setattr__(self, 'streams', dict(self.streams or {}))
        if self.log_path is not None and self.on_line is not None:
            raise ValueError('a child logs to a file or to on_line, not both')
        pipes, streams = self.pipes, self.streams
        if set(pipes) - _STREAMS or (pipes and self.on_line is not None):
            raise ValueError('pipes are stdin, stdout and stderr, and not with on_line, got '
                             '{!r}'.format(pipes))
        if (set(streams) - _STREAMS or set(streams) & set(pipes)
                or (streams and self.on_line is not None)
                or subprocess.PIPE in streams.values()
                or subprocess.STDOUT in (streams.get('stdin'), streams.get('stdout'))):
            raise ValueError('streams are stdin, stdout and stderr (STDOUT for stderr only), '
                             'never PIPE (pipes says that), not with on_line, got {!r}'
                             .format(dict(streams)))


@dataclass(frozen=True)
class Stopping:
    """How the child is stopped: the steps of the one stop ladder (``stop_process``).

    ``sig`` to the process (to its whole group with ``group``), ``timeout`` s, then SIGKILL
    (``on_escalate(timeout)`` first) and ``kill_timeout`` s. ``must_end``: :meth:`Child.stop`
    raises AssertionError when even SIGKILL did not end it (the bench's children) instead of
    returning None (bringup's, which stops the others).
    """

    sig: int = signal.SIGTERM
    group: bool = False
    timeout: float = STOP_TIMEOUT_S
    kill_timeout: float = 5.0
    on_escalate: Callable[[float], None] | None = None
    must_end: bool = False


@dataclass(frozen=True)
class Launch:
    """How the child is started: under bringup's supervision, when it counts as up, where.

    ``supervised``: a process group in bringup's session (not a session of its own), the stop
    signals blocked until it has its handlers, ``setpriv --pdeathsig TERM`` when available.
    ``ready``: a check that it is up (bringup starts the next child then). ``cpu``: pinned.
    """

    supervised: bool = False
    ready: Callable[[], bool] | None = None
    cpu: int | None = None


class Child:
    """One child process: started in its own process group, logged, stopped by the ladder.

    Nothing runs until :meth:`start`. ``env`` None inherits this process's environment. Its
    options, by what they are for: :class:`Output`, :class:`Stopping`, :class:`Launch`.
    """

    def __init__(self, name: str, argv: Sequence[str], env: Mapping[str, str] | None = None,
                 *, output: Output = Output(), stopping: Stopping = Stopping(),
                 launch: Launch = Launch()) -> None:
        """Describe the child; :meth:`start` starts it."""
        self.name = name
        self.argv = list(argv)
        self.env = dict(env) if env is not None else None
        self.output = output
        self.stopping = stopping
        self.launch = launch
        self.proc: subprocess.Popen | None = None
        self.pid = 0
        self.restarts = 0
        self.failures = 0          # consecutive failures (backoff exponent)
        self.started_at = 0.0
        self.next_start = 0.0      # monotonic time of a pending restart (0: none)
        self.last_rc: int | None = None
        self._log: BinaryIO | None = None
        self._reader: threading.Thread | None = None

    def start(self) -> Child:
        """Start the process; return self."""
        argv = list(self.argv)
        o = self.output
        out: int | BinaryIO | None = None
        if o.log_path is not None:
            log = open(o.log_path, 'ab' if o.log_append else 'wb')  # noqa: SIM115
            if o.log_header:
                log.write('$ {}\n'.format(' '.join(argv)).encode())
                log.flush()
            out = self._log = log      # closed in _finish
        elif o.on_line is not None:
            out = subprocess.PIPE
        supervised = self.launch.supervised
        if supervised:
            setpriv = shutil.which('setpriv')
            if setpriv:
                argv = [setpriv, '--pdeathsig', 'TERM', '--', *argv]
        console = o.on_line is not None   # lines for the console: text, line-buffered
        text = console or bool(o.pipes)
        pipe = subprocess.PIPE
        given = o.streams
        # Stop signals blocked until a supervised child has its handlers (it unblocks them
        # then): a SIGTERM from stop() while it still starts up stops it cleanly, never kills it.
        with blocked_stop_signals() if supervised else contextlib.nullcontext():
            self.proc = subprocess.Popen(
                argv, env=self.env,
                stdin=(pipe if 'stdin' in o.pipes
                       else given.get('stdin', subprocess.DEVNULL)),
                stdout=pipe if 'stdout' in o.pipes else given.get('stdout', out),
                stderr=(pipe if 'stderr' in o.pipes else subprocess.STDOUT if console
                        else given.get('stderr', out)),
                start_new_session=not supervised,
                process_group=0 if supervised else None,
                text=text, errors='replace' if text else None, bufsize=1 if console else -1)
        self.pid = self.proc.pid
        if self.launch.cpu is not None:
            os.sched_setaffinity(self.pid, {self.launch.cpu})
        self.started_at = time.monotonic()
        self.next_start = 0.0
        if o.on_line is not None:
            self._reader = threading.Thread(target=self._copy, args=(self.proc,),
                                            name='bringup:' + self.name, daemon=True)
            self._reader.start()
        return self

    def _copy(self, proc: subprocess.Popen) -> None:
        on_line = self.output.on_line
        assert proc.stdout is not None and on_line is not None
        for line in proc.stdout:
            on_line(line.rstrip('\n'))

    def alive(self) -> bool:
        """Tell whether the process runs."""
        return self.proc is not None and self.proc.poll() is None

    @property
    def returncode(self) -> int | None:
        """Return the exit code once the process has ended (None while it runs)."""
        return self.proc.returncode if self.proc is not None else self.last_rc

    def send_signal(self, sig: int) -> None:
        """Send ``sig`` to the process (not its group) while it runs."""
        if self.proc is not None:
            self.proc.send_signal(sig)

    def wait(self, timeout: float) -> int | None:
        """Wait up to ``timeout`` s for the exit; return the code or None."""
        if self.proc is None:
            return self.last_rc
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            return None

    def reap(self) -> int | None:
        """Return the exit code once the process has ended (after its output is copied)."""
        if self.proc is None:
            return None
        rc = self.proc.poll()
        if rc is None:
            return None
        self._finish()
        self.last_rc = rc
        self.proc = None
        return rc

    def _finish(self) -> None:
        if self._reader is not None:
            self._reader.join(2.0)
            self._reader = None
        if self.proc is not None:
            for stream in (self.proc.stdin, self.proc.stdout, self.proc.stderr):
                if stream is not None:
                    with contextlib.suppress(OSError):
                        stream.close()
        if self._log is not None:
            self._log.close()
            self._log = None

    def stop(self, grace_s: float | None = None,
             on_escalate: Callable[[float], None] | None = None) -> int | None:
        """Send the stop signal, wait ``grace_s`` (default ``stopping.timeout``), then SIGKILL.

        Return the exit code (None if not running, or if even SIGKILL did not end it and
        ``must_end`` is false).
        """
        proc = self.proc
        self.next_start = 0.0
        if proc is None:
            return None
        st = self.stopping
        rc = stop_process(proc, st.sig, st.timeout if grace_s is None else grace_s,
                          group=st.group, kill_timeout=st.kill_timeout, close_streams=False,
                          on_escalate=on_escalate or st.on_escalate)
        self._finish()
        self.last_rc = rc
        self.proc = None
        assert rc is not None or not st.must_end, f'{self.name} survived SIGKILL'
        return rc

    def tail(self, lines: int = 6) -> list[str]:
        """Return the last lines of the log file ([] without one)."""
        log_path = self.output.log_path
        if log_path is None:
            return []
        try:
            with open(log_path, 'rb') as f:
                return f.read().decode(errors='replace').strip().splitlines()[-lines:]
        except OSError:
            return []
