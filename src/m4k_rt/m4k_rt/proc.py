"""Stop a child process and everything it left in its process group: the one stop ladder.

Every m4k tool that starts processes -- bringup's supervisor, the bench, the demo, the scenario
runner, fuzz, the soak (the stack's processes through ``m4k_bringup.child.Child``, the one
process wrapper) and the tests' process fixture -- starts them in a process group of their own
and stops them through :func:`stop_process`: signal, wait, escalate to SIGKILL, then SIGKILL
whatever is left in the group (grandchildren), reap, close the pipes. NRT code, ROS-free, in
the lowest package so that the RT core's own tests use it too.
"""

from __future__ import annotations

import os
import signal
import subprocess
from typing import Any, Callable


def _killpg(pid: int, sig: int) -> bool:
    """Signal the group ``pid``; return False when it no longer exists."""
    try:
        os.killpg(pid, sig)
    except ProcessLookupError:
        return False
    except PermissionError:  # the group's leader is gone and its id reused by another user
        return False
    return True


def stop_process(proc: subprocess.Popen[Any], sig: int = signal.SIGTERM,
                 timeout: float = 10.0, *, group: bool = True, kill_timeout: float = 5.0,
                 on_escalate: Callable[[float], None] | None = None,
                 close_streams: bool = True) -> int | None:
    """Stop ``proc`` (started with ``process_group=0`` or ``start_new_session=True``).

    Send ``sig`` to its process group (``group=True``) or to the process only, wait up to
    ``timeout`` s, then SIGKILL (calling ``on_escalate(timeout)`` first) and wait up to
    ``kill_timeout`` s; finally SIGKILL whatever is still in the group. Return the exit code
    (None only if even SIGKILL did not reap it within ``kill_timeout``).
    """
    if proc.poll() is None:
        if group:
            _killpg(proc.pid, sig)
        else:
            try:
                proc.send_signal(sig)
            except ProcessLookupError:
                pass
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            if on_escalate is not None:
                on_escalate(timeout)
            _killpg(proc.pid, signal.SIGKILL)
            proc.kill()
            try:
                proc.wait(kill_timeout)
            except subprocess.TimeoutExpired:
                pass
    _killpg(proc.pid, signal.SIGKILL)  # anything it left in its group
    if close_streams:
        for stream in (proc.stdout, proc.stderr, proc.stdin):
            if stream is not None:
                stream.close()
    return proc.returncode
