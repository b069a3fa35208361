"""Absolute periodic timers on CLOCK_MONOTONIC through timerfd (ctypes, or ``os`` on 3.13+).

A task's release times come from one timerfd armed with ``TFD_TIMER_ABSTIME`` at an absolute
first release and a fixed interval, so releases never drift with the task's own run time. A
blocking ``read`` returns the number of expirations since the previous read: 1 in a normal
cycle, more after an overrun (the kernel folds missed releases into one wake-up, so the loop
skips ahead instead of bursting).
"""

import ctypes
import ctypes.util
import errno as _errno
import os
import sys
import time

__all__ = [
    'CLOCK_MONOTONIC', 'TimerFd', 'TimerFdError', 'monotonic_ns',
]

CLOCK_MONOTONIC = time.CLOCK_MONOTONIC
TFD_CLOEXEC = 0o2000000
TFD_NONBLOCK = 0o4000
TFD_TIMER_ABSTIME = 1
_NS = 1_000_000_000

# os.timerfd_* exist from Python 3.13; older interpreters go through libc with ctypes. Spelled
# as a version check (not hasattr) so the type checker knows which branch exists.
_HAVE_OS_TIMERFD = sys.version_info >= (3, 13)


class TimerFdError(OSError):
    """A timerfd system call failed (errno and the operation are kept)."""


def monotonic_ns() -> int:
    """Return CLOCK_MONOTONIC in nanoseconds (the clock every timerfd here runs on)."""
    return time.clock_gettime_ns(CLOCK_MONOTONIC)


class _Timespec(ctypes.Structure):
    _fields_ = [('tv_sec', ctypes.c_long), ('tv_nsec', ctypes.c_long)]


class _Itimerspec(ctypes.Structure):
    _fields_ = [('it_interval', _Timespec), ('it_value', _Timespec)]


_libc = None


def _lib() -> ctypes.CDLL:
    global _libc
    if _libc is None:
        lib = ctypes.CDLL(ctypes.util.find_library('c') or 'libc.so.6', use_errno=True)
        lib.timerfd_create.argtypes = [ctypes.c_int, ctypes.c_int]
        lib.timerfd_create.restype = ctypes.c_int
        lib.timerfd_settime.argtypes = [
            ctypes.c_int, ctypes.c_int, ctypes.POINTER(_Itimerspec), ctypes.POINTER(_Itimerspec)]
        lib.timerfd_settime.restype = ctypes.c_int
        _libc = lib
    return _libc


def _raise(op: str) -> None:
    err = ctypes.get_errno()
    raise TimerFdError(err, '{}: {}'.format(op, os.strerror(err)))


class TimerFd:
    """A CLOCK_MONOTONIC timerfd armed at absolute times; ``read`` returns expirations."""

    def __init__(self, *, nonblocking: bool = False) -> None:
        """Create the timer (disarmed); close-on-exec always, non-blocking on request."""
        flags = TFD_CLOEXEC | (TFD_NONBLOCK if nonblocking else 0)
        if sys.version_info >= (3, 13):
            try:
                self._fd: int = os.timerfd_create(CLOCK_MONOTONIC, flags=flags)
            except OSError as exc:
                raise TimerFdError(exc.errno, 'timerfd_create: {}'.format(exc.strerror)) from exc
        else:
            fd: int = _lib().timerfd_create(CLOCK_MONOTONIC, flags)
            if fd < 0:
                _raise('timerfd_create')
            self._fd = fd
        self._spec = _Itimerspec()

    def fileno(self) -> int:
        """Return the file descriptor (for poll/select, -1 once closed)."""
        return self._fd

    @property
    def closed(self) -> bool:
        """Tell whether the timer was closed."""
        return self._fd < 0

    def set_abs(self, first_ns: int, interval_ns: int) -> None:
        """Arm the timer: first expiry at absolute ``first_ns``, then every ``interval_ns``."""
        if not isinstance(first_ns, int) or first_ns <= 0:
            raise ValueError('first_ns must be a positive int (ns), got {!r}'.format(first_ns))
        if not isinstance(interval_ns, int) or interval_ns < 0:
            raise ValueError(
                'interval_ns must be an int >= 0 (ns), got {!r}'.format(interval_ns))
        if self._fd < 0:
            raise TimerFdError(_errno.EBADF, 'timerfd_settime: timer is closed')
        if sys.version_info >= (3, 13):
            try:
                os.timerfd_settime_ns(self._fd, flags=TFD_TIMER_ABSTIME,
                                      initial=first_ns, interval=interval_ns)
            except OSError as exc:
                raise TimerFdError(
                    exc.errno, 'timerfd_settime: {}'.format(exc.strerror)) from exc
            return
        spec = self._spec
        spec.it_value.tv_sec, spec.it_value.tv_nsec = divmod(first_ns, _NS)
        spec.it_interval.tv_sec, spec.it_interval.tv_nsec = divmod(interval_ns, _NS)
        if _lib().timerfd_settime(self._fd, TFD_TIMER_ABSTIME, ctypes.byref(spec), None) < 0:
            _raise('timerfd_settime')

    def disarm(self) -> None:
        """Stop the timer (a blocked ``read`` then waits forever: wake it with ``set_abs``)."""
        if sys.version_info >= (3, 13):
            os.timerfd_settime_ns(self._fd, flags=0, initial=0, interval=0)
            return
        spec = _Itimerspec()
        if _lib().timerfd_settime(self._fd, 0, ctypes.byref(spec), None) < 0:
            _raise('timerfd_settime')

    def read(self) -> int:
        """Wait for the next expiry and return the number of expirations since the last read.

        Returns 0 only in non-blocking mode when nothing expired yet. The GIL is released
        while blocked, so other tasks run.
        """
        try:
            data = os.read(self._fd, 8)
        except BlockingIOError:
            return 0
        return int.from_bytes(data, 'little')

    def close(self) -> None:
        """Close the descriptor (idempotent)."""
        if self._fd >= 0:
            fd, self._fd = self._fd, -1
            os.close(fd)

    def __enter__(self) -> 'TimerFd':
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except OSError:
            pass
