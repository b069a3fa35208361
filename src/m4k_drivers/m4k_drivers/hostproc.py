"""The driver host's processes: an RT-facing device is served by a process of its own.

Why a process and not a thread (docs/design-notes.md, "The driver host's processes"): every
thread of one CPython process takes the same GIL, so a SCHED_FIFO service thread still waits for
whichever normal-priority service thread holds it (up to the switch interval, and for as long
as that thread's C call runs without releasing it).  The kernel's priorities only order
threads that can run; the GIL makes a FIFO 50 motor thread wait on a SCHED_OTHER laser thread
that was itself preempted by load -- priority inversion with no inheritance.  A process of its
own gives the motor service its own interpreter and GIL: nothing of lower priority can hold a
lock it needs.

Which devices: those whose section asks for a real-time priority (``sched_priority`` > 0, the
motors: their amplifier-enable heartbeat and watchdog are the RT side's wheel commands one hop
on).  Each gets its own child process, serving it from the process's main thread (no other
thread in it); the rest share the parent, one thread each, as before.

The child dies with the parent (``PR_SET_PDEATHSIG`` SIGKILL): a killed driver host must stop
toggling the heartbeat at once, exactly as one process did (test_motor_safety).  The parent
forwards a stop signal to its children and waits for them; a child that exits on its own ends
the parent with exit 1, so the supervisor (bringup) restarts the whole host.
"""

from __future__ import annotations

import ctypes
import logging
import os
import signal
import sys
import time
from typing import Any, Iterable, Mapping, Sequence

__all__ = ['Children', 'fork_groups', 'groups', 'own_process']

LOG = logging.getLogger('m4k_drivers.host')

_PR_SET_PDEATHSIG = 1
STOP_WAIT_S = 5.0          # a child gets this long to make its outputs safe after SIGTERM


def own_process(section: Mapping[str, Any]) -> bool:
    """Tell whether a device section asks for a real-time priority (served by its own process)."""
    return int(section.get('sched_priority') or 0) > 0


def groups(enabled: Sequence[str], sections: Mapping[str, Mapping[str, Any]]) -> list[list[str]]:
    """Return the processes' device lists: one per RT-facing device, then the rest together.

    The last group is the parent's (possibly empty when every device is RT-facing and there is
    more than one); a single group means no child at all.
    """
    own = [[k] for k in enabled if own_process(sections[k])]
    rest = [k for k in enabled if not own_process(sections[k])]
    if not own:
        return [rest]
    if not rest and len(own) == 1:
        return own
    return [*own, rest]


def _die_with_parent(parent: int) -> None:
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) != 0:
        err = ctypes.get_errno()
        LOG.error('prctl(PR_SET_PDEATHSIG): %s', os.strerror(err))
    if os.getppid() != parent:        # the parent died before the prctl: nobody supervises us
        os._exit(1)


class Children:
    """The parent's view of its device processes: supervise, forward stops, reap."""

    def __init__(self, pids: dict[int, str]) -> None:
        """Keep ``pid -> device list`` (for the log)."""
        self.pids = dict(pids)
        self.codes: dict[str, int] = {}

    def __bool__(self) -> bool:
        return bool(self.pids)

    def poll(self) -> str | None:
        """Reap exited children; return the first one's description, or None when all run."""
        gone = None
        for pid, name in list(self.pids.items()):
            try:
                done, status = os.waitpid(pid, os.WNOHANG)
            except ChildProcessError:
                done, status = pid, 0
            if done:
                del self.pids[pid]
                self.codes[name] = os.waitstatus_to_exitcode(status)
                gone = gone or '{} (pid {}) exited {}'.format(name, pid, self.codes[name])
        return gone

    def exited_clean(self) -> bool:
        """Tell whether every child reaped so far exited 0 (stopped as asked)."""
        return all(code == 0 for code in self.codes.values())

    def stop(self, timeout_s: float = STOP_WAIT_S) -> bool:
        """SIGTERM every child, wait for them (SIGKILL after ``timeout_s``); True when clean.

        A child ended by this SIGTERM itself (a stop that came while it was still starting, its
        own handler not yet installed) stopped as asked; one that exited non-zero before the
        stop, or had to be killed, did not.
        """
        before = dict(self.codes)
        for pid in self.pids:
            try:
                os.kill(pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
        end = time.monotonic() + timeout_s
        while self.pids and time.monotonic() < end:
            self.poll()
            time.sleep(0.02)
        clean = not self.pids
        for pid, name in list(self.pids.items()):
            LOG.error('%s (pid %d) did not stop in %.0f s: killed', name, pid, timeout_s)
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            del self.pids[pid]
        asked = [c for n, c in self.codes.items() if n not in before]
        return clean and all(c == 0 for c in before.values()) and all(
            c in (0, -signal.SIGTERM) for c in asked)


def fork_groups(device_groups: Iterable[list[str]]) -> tuple[list[str], Children]:
    """Fork a child for every group but the last; return (this process's devices, children).

    Called before any device is opened or thread started (fork copies only the calling
    thread).  In a child the children are empty and the devices are its group.
    """
    parts = list(device_groups)
    parent = os.getpid()
    pids: dict[int, str] = {}
    for group in parts[:-1]:
        sys.stdout.flush()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:
            _die_with_parent(parent)
            return group, Children({})
        pids[pid] = ','.join(group)
    return parts[-1], Children(pids)
