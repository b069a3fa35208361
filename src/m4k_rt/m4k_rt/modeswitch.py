"""The mode-switch analogue: what Xenomai's MSW counter and slackspot tell, for Python threads.

On Xenomai an RT task that makes a Linux system call drops to secondary mode (MSW). A Python
RT thread has no modes, but the same mistakes cost the same: blocking on something other than
its timer, being preempted, faulting pages, or calling file/console I/O, imports, sleeps,
subprocesses or socket creation from inside its loop. This module measures them per task:

* :class:`ThreadRusage` -- ``getrusage(RUSAGE_THREAD)`` deltas since the loop started:
  voluntary context switches beyond one per cycle (one is the timer wait), involuntary ones,
  minor and major page faults;
* :class:`SiteTable` + an audit hook (``sys.addaudithook``) and a console guard on
  ``sys.stdout``/``sys.stderr`` -- forbidden calls made while the calling thread is flagged
  "inside an RT loop", with the call site (file, line, function). The hook never raises and
  allocates only when a forbidden call actually happens.

What it measures travels as the FORBIDDEN_SITE and TASK_HEALTH datagrams of
:mod:`m4k_rt.protocol` (``stat`` port; see docs/internals.md).
"""

import dataclasses
import io
import os
import resource
import sys
import sysconfig
import threading
import time
from types import FrameType
from typing import Any, Callable, NamedTuple, SupportsIndex

from m4k_rt.protocol import EVENT_CODES, EVENT_NAMES

__all__ = [
    'EVENT_CODES', 'EVENT_NAMES', 'ConsoleGuard', 'Site', 'SiteTable', 'ThreadRusage',
    'allow_file', 'current_table', 'enter_rt', 'install', 'install_console_guard', 'leave_rt',
    'uninstall_console_guard',
]

# The audit events an RT loop must not raise and their wire codes are the protocol's
# (FORBIDDEN_SITE); re-exported here for the audit hook's readers.

_tls = threading.local()
_Sleep = Callable[[float | SupportsIndex], None]  # time.sleep's signature
_installed = False
_install_lock = threading.Lock()
_THIS_FILE = __file__
_STDLIB = sysconfig.get_paths()['stdlib'] + os.sep
# Sanctioned in-loop callers: the channel's RT side (its ports and, over shm, the link's
# rings) accepts a (re)connecting NRT peer without blocking from inside the loop, which
# creates a socket object by design (like a Xenomai XDDP port, whose peer may come and go
# while the RT task runs).
_CHANNEL_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'channel')
_ALLOWED_FILES = {os.path.join(_CHANNEL_DIR, f) for f in ('port.py', 'shm.py', 'shmring.py')}


class Site(NamedTuple):
    """One call site of a forbidden call."""

    event: str
    file: str
    line: int
    func: str
    calls: int


class SiteTable:
    """Per-task table of forbidden calls: total, per event, and the last N distinct sites.

    Preallocated: recording a call at a known site only increments counters; a new site
    overwrites the oldest slot once the table is full.
    """

    def __init__(self, capacity: int = 8) -> None:
        """Preallocate ``capacity`` site slots."""
        if capacity < 1:
            raise ValueError('site capacity must be >= 1, got {!r}'.format(capacity))
        self.capacity = capacity
        self.total = 0
        self.by_event = [0] * (max(EVENT_NAMES) + 1)
        # Each slot: [event code, file, line, func, count]; code 0 = empty.
        self._slots: list[list[Any]] = [[0, '', 0, '', 0] for _ in range(capacity)]
        self._next = 0
        self.seq = 0  # bumped on every record, so a reader can tell the table changed

    def record(self, code: int, file: str, line: int, func: str) -> None:
        """Count one forbidden call at a site."""
        self.total += 1
        self.by_event[code] += 1
        self.seq += 1
        for slot in self._slots:
            if slot[0] == code and slot[2] == line and slot[1] == file:
                slot[4] += 1
                return
        slot = self._slots[self._next]
        slot[0], slot[1], slot[2], slot[3], slot[4] = code, file, line, func, 1
        self._next = (self._next + 1) % self.capacity

    def sites(self) -> list[Site]:
        """Return the recorded sites, oldest first."""
        n = self.capacity
        order = [self._slots[(self._next + i) % n] for i in range(n)]
        return [Site(EVENT_NAMES[s[0]], s[1], s[2], s[3], s[4]) for s in order if s[0]]

    def slot(self, i: int) -> list[Any]:
        """Return raw slot ``i`` ([code, file, line, func, count]; code 0 = empty)."""
        return self._slots[i]


def enter_rt(table: SiteTable) -> None:
    """Flag the calling thread as inside an RT loop; forbidden calls go to ``table``."""
    _tls.table = table


def leave_rt() -> None:
    """Clear the calling thread's RT-loop flag."""
    _tls.table = None


def current_table() -> SiteTable | None:
    """Return the calling thread's table when it is inside an RT loop, else None."""
    return getattr(_tls, 'table', None)


def allow_file(path: str) -> None:
    """Treat forbidden calls made directly from the source file ``path`` as sanctioned."""
    _ALLOWED_FILES.add(os.path.abspath(path))


def _caller_site(frame: FrameType | None) -> tuple[str, int, str] | None:
    # Walk out of the standard library, frozen importlib and this module, so the site is the
    # task code that made the call, not subprocess.py or socket.py. None: sanctioned caller.
    f = frame
    while f is not None:
        fn = f.f_code.co_filename
        if not (fn.startswith('<frozen') or fn == _THIS_FILE
                or (fn.startswith(_STDLIB) and 'packages' + os.sep not in fn)):
            if fn in _ALLOWED_FILES:
                return None
            return fn, f.f_lineno, f.f_code.co_name
        f = f.f_back
    return '?', 0, '?'


def _record(table: SiteTable, code: int, frame: FrameType | None) -> None:
    site = _caller_site(frame)
    if site is not None:
        table.record(code, *site)


def _audit_hook(event: str, args: tuple[object, ...]) -> None:
    code = EVENT_CODES.get(event)
    if code is None:
        return
    table = getattr(_tls, 'table', None)
    if table is None:
        return
    try:
        _record(table, code, sys._getframe(1))
    except BaseException:  # noqa: B036 -- an audit hook that raises would break the call
        pass


def install() -> None:
    """Install the audit hook (once per process; audit hooks cannot be removed).

    Interpreters whose ``time.sleep`` raises no audit event (3.11) get a guarded
    ``time.sleep`` instead; code that bound ``from time import sleep`` earlier escapes it.
    """
    global _installed
    with _install_lock:
        if _installed:
            return
        sys.addaudithook(_audit_hook)
        _installed = True
        probe = SiteTable(1)
        prev = getattr(_tls, 'table', None)
        _tls.table = probe
        try:
            time.sleep(0)
        finally:
            _tls.table = prev
        if probe.total == 0:
            time.sleep = _make_guarded_sleep(time.sleep)


def _make_guarded_sleep(real_sleep: _Sleep) -> _Sleep:
    def sleep(secs: float | SupportsIndex) -> None:
        table = getattr(_tls, 'table', None)
        if table is not None:
            try:
                _record(table, EVENT_CODES['time.sleep'], sys._getframe(1))
            except BaseException:  # noqa: B036 -- never break the caller's sleep
                pass
        real_sleep(secs)
    sleep.__doc__ = real_sleep.__doc__
    return sleep


class ConsoleGuard(io.TextIOBase):
    """Wrap a text stream: writes from a thread inside an RT loop are recorded, then done."""

    def __init__(self, stream: io.TextIOBase) -> None:
        """Wrap ``stream``."""
        self.wrapped = stream

    def write(self, s: str) -> int:
        """Record a write made inside an RT loop, then delegate."""
        table = getattr(_tls, 'table', None)
        if table is not None:
            try:
                _record(table, EVENT_CODES['console'], sys._getframe(1))
            except BaseException:  # noqa: B036 -- never break the caller's write
                pass
        return self.wrapped.write(s)

    def flush(self) -> None:
        """Delegate."""
        self.wrapped.flush()

    def fileno(self) -> int:
        """Delegate."""
        return self.wrapped.fileno()

    def isatty(self) -> bool:
        """Delegate."""
        return self.wrapped.isatty()

    def __getattr__(self, name: str) -> object:
        return getattr(self.wrapped, name)


def install_console_guard() -> None:
    """Wrap sys.stdout and sys.stderr in :class:`ConsoleGuard` (idempotent)."""
    for name in ('stdout', 'stderr'):
        stream = getattr(sys, name)
        if stream is not None and not isinstance(stream, ConsoleGuard):
            setattr(sys, name, ConsoleGuard(stream))


def uninstall_console_guard() -> None:
    """Put the original sys.stdout and sys.stderr back."""
    for name in ('stdout', 'stderr'):
        stream = getattr(sys, name)
        if isinstance(stream, ConsoleGuard):
            setattr(sys, name, stream.wrapped)


@dataclasses.dataclass
class ThreadRusage:
    """Context-switch and page-fault counters of one task thread since its loop started."""

    nvcsw: int = 0
    nivcsw: int = 0
    minflt: int = 0
    majflt: int = 0
    nvcsw_extra: int = 0  # voluntary switches beyond the one timer wait per cycle
    _base: tuple[int, int, int, int] = (0, 0, 0, 0)

    def start(self) -> None:
        """Take the baseline; call from the task thread just before its loop."""
        ru = resource.getrusage(resource.RUSAGE_THREAD)
        self._base = (ru.ru_nvcsw, ru.ru_nivcsw, ru.ru_minflt, ru.ru_majflt)

    def update(self, cycles: int) -> None:
        """Refresh from the calling (task) thread; ``cycles`` waits were expected to block."""
        ru = resource.getrusage(resource.RUSAGE_THREAD)
        b = self._base
        self.nvcsw = ru.ru_nvcsw - b[0]
        self.nivcsw = ru.ru_nivcsw - b[1]
        self.minflt = ru.ru_minflt - b[2]
        self.majflt = ru.ru_majflt - b[3]
        extra = self.nvcsw - cycles
        self.nvcsw_extra = extra if extra > 0 else 0
