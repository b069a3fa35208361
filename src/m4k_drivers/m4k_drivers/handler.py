"""Device handler lifecycle, error hierarchy and retry policy shared by every m4k driver.

The lifecycle follows ros2_control hardware components::

    UNCONFIGURED --configure()--> INACTIVE --activate()--> ACTIVE
         ^                           |  ^                     |
         +-------cleanup()-----------+  +----deactivate()-----+
    any --shutdown()--> FINALIZED;  a failed transition --> ERROR (configure() may retry)

configure() opens the transport and identifies the device, activate() turns outputs on,
read()/write() return a :class:`Status`, deactivate() makes outputs safe (motors at zero) and
cleanup() closes the transport.  Subclasses implement the ``on_*`` hooks only; the base class
keeps the state machine, counts faults and remembers the last error code for DEVICE_STATUS.

Exceptions (all derive from :class:`DriverError`)::

    DriverError
      DeviceNotFoundError     the device node / bus does not exist (ENOENT, ENODEV, ENXIO)
      DevicePermissionError   EACCES / EPERM on the device node
      DeviceIOError           any other OSError talking to the device (retryable)
      DeviceIdentityError     the device answered but is not what the config says
      DeviceProtocolError     a frame failed validation (parity, status bits, jump, range)
      LifecycleError          a transition that is not allowed from the current state
"""

from __future__ import annotations

import enum
import errno as errno_mod
import logging
import math
import os
import time
from typing import Any, Callable, NamedTuple, TypeVar

from m4k_rt.protocol import DeviceError, DeviceState, Level

__all__ = [
    'DeviceHandler', 'DeviceIOError', 'DeviceIdentityError', 'DeviceNotFoundError',
    'DevicePermissionError', 'DeviceProtocolError', 'DriverError', 'ErrorCode', 'LifecycleError',
    'Reading', 'RetryPolicy', 'State', 'Status', 'retry', 'wrap_os_error',
]

T = TypeVar('T')

# DEVICE_STATUS.last_error codes and lifecycle states: the wire protocol owns them.
ErrorCode = DeviceError
State = DeviceState


class DriverError(Exception):
    """Base class of every m4k driver error; ``code`` is an :class:`ErrorCode`."""

    code: int = ErrorCode.OTHER


class DeviceNotFoundError(DriverError):
    """Raise when a device node or bus is missing; the message names the path."""

    code = ErrorCode.NOT_FOUND


class DevicePermissionError(DriverError):
    """Raise when the device node exists but may not be opened."""

    code = ErrorCode.PERMISSION


class DeviceIOError(DriverError):
    """Raise on a transient I/O failure (retryable)."""

    code = ErrorCode.IO


class DeviceIdentityError(DriverError):
    """Raise when the device answers with the wrong identity (e.g. WHO_AM_I)."""

    code = ErrorCode.IDENTITY


class DeviceProtocolError(DriverError):
    """Raise when a frame from the device fails validation."""

    code = ErrorCode.PROTOCOL


class LifecycleError(DriverError):
    """Raise on a lifecycle transition that the current state does not allow."""

    code = ErrorCode.LIFECYCLE



class Status(enum.IntEnum):
    """Result of read()/write(), like ros2_control's return_type."""

    OK = 0
    ERROR = 1


class Reading(NamedTuple):
    """What read() returns: a status, the decoded value (None on error), the error if any."""

    status: Status
    value: Any = None
    error: DriverError | None = None


_NOT_FOUND_ERRNOS = {errno_mod.ENOENT, errno_mod.ENODEV, errno_mod.ENXIO}
_PERMISSION_ERRNOS = {errno_mod.EACCES, errno_mod.EPERM}


def wrap_os_error(exc: OSError, path: str, action: str = '') -> DriverError:
    """Translate an OSError into the matching DriverError naming the path and errno."""
    err = exc.errno
    text = os.strerror(err) if err else str(exc)
    where = f'{path}: {action}: ' if action else f'{path}: '
    message = f'{where}{text} (errno {err})'
    if err in _NOT_FOUND_ERRNOS:
        return DeviceNotFoundError(message)
    if err in _PERMISSION_ERRNOS:
        return DevicePermissionError(message)
    return DeviceIOError(message)


class RetryPolicy(NamedTuple):
    """Exponential backoff: delay_k = min(base_s * factor**k, max_s), ``attempts`` tries."""

    attempts: int = 3
    base_s: float = 0.02
    factor: float = 2.0
    max_s: float = 1.0

    def delay(self, k: int) -> float:
        """Return the sleep after failed attempt ``k`` (0-based), for any k.

        ``factor ** k`` overflows a float at k = 1024 (factor 2): capped before it is formed.
        """
        if self.factor <= 1.0 or self.base_s <= 0.0:
            return min(self.base_s, self.max_s)
        # Smallest k at which base * factor**k reaches max_s; beyond it the delay is max_s.
        k_max = math.ceil(math.log(max(self.max_s / self.base_s, 1.0), self.factor))
        return min(self.base_s * self.factor ** min(k, k_max), self.max_s)

    def delays(self) -> list[float]:
        """Return the sleeps between attempts (one fewer than attempts)."""
        return [self.delay(k) for k in range(max(self.attempts - 1, 0))]


def retry(fn: Callable[[], T], policy: RetryPolicy, *,
          retry_on: tuple[type[BaseException], ...] = (DeviceIOError,),
          sleep: Callable[[float], None] = time.sleep,
          on_retry: Callable[[int, BaseException], None] | None = None) -> T:
    """Call ``fn`` until it succeeds, sleeping with exponential backoff between tries."""
    delays = policy.delays()
    for attempt in range(len(delays) + 1):
        try:
            return fn()
        except retry_on as exc:
            if attempt >= len(delays):
                raise
            if on_retry is not None:
                on_retry(attempt + 1, exc)
            sleep(delays[attempt])
    raise AssertionError('unreachable')  # pragma: no cover


class DeviceHandler:
    """Lifecycle base class of a device handler; subclasses implement the ``on_*`` hooks."""

    kind: str = 'device'

    def __init__(self, name: str | None = None, *, retry_policy: RetryPolicy | None = None,
                 logger: logging.Logger | None = None,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.name = name or self.kind
        self.retry_policy = retry_policy or RetryPolicy()
        self.log = logger or logging.getLogger(f'm4k_drivers.{self.name}')
        self._sleep = sleep
        self.state = State.UNCONFIGURED
        self.faults = 0
        self.last_error = ErrorCode.NONE
        self.last_exception: DriverError | None = None
        self.state_changes = 0

    # -- hooks for subclasses -------------------------------------------------------------
    def on_configure(self) -> None:
        """Open the transport and identify the device (may raise DriverError)."""

    def on_activate(self) -> None:
        """Turn outputs on."""

    def on_read(self) -> Any:
        """Read and decode one sample (may raise DriverError)."""
        raise NotImplementedError

    def on_write(self, command: Any) -> None:
        """Send one command to the device (may raise DriverError)."""
        raise NotImplementedError

    def on_deactivate(self) -> None:
        """Make outputs safe (motors at zero)."""

    def on_cleanup(self) -> None:
        """Close the transport; must not raise."""

    # -- lifecycle ------------------------------------------------------------------------
    def _set_state(self, state: State) -> None:
        if state != self.state:
            self.state = state
            self.state_changes += 1

    def record_fault(self, exc: DriverError) -> None:
        """Count a fault and remember it as the last error."""
        self.faults += 1
        self.last_exception = exc
        self.last_error = ErrorCode(getattr(exc, 'code', ErrorCode.OTHER))

    def configure(self) -> None:
        """Open and identify the device, retrying transient errors with backoff."""
        if self.state not in (State.UNCONFIGURED, State.ERROR):
            raise LifecycleError(f'{self.name}: configure() from state {self.state.name}')

        def attempt() -> None:
            try:
                self.on_configure()
            except DeviceIOError:
                self.on_cleanup()
                raise

        try:
            retry(attempt, self.retry_policy, sleep=self._sleep,
                  on_retry=lambda n, e: self.log.warning('%s: configure retry %d: %s',
                                                         self.name, n, e))
        except DriverError as exc:
            self.record_fault(exc)
            self.on_cleanup()
            self._set_state(State.ERROR)
            raise
        self._set_state(State.INACTIVE)

    def activate(self) -> None:
        """Turn outputs on (INACTIVE -> ACTIVE)."""
        if self.state != State.INACTIVE:
            raise LifecycleError(f'{self.name}: activate() from state {self.state.name}')
        try:
            self.on_activate()
        except DriverError as exc:
            self.record_fault(exc)
            raise
        self._set_state(State.ACTIVE)

    def read(self) -> Reading:
        """Read one sample; errors are counted and returned, never raised."""
        if self.state not in (State.ACTIVE, State.INACTIVE):
            err = LifecycleError(f'{self.name}: read() in state {self.state.name}')
            return Reading(Status.ERROR, None, err)
        try:
            return Reading(Status.OK, self.on_read())
        except DriverError as exc:
            self.record_fault(exc)
            return Reading(Status.ERROR, None, exc)

    def write(self, command: Any) -> Status:
        """Send one command (only when ACTIVE); errors are counted and returned."""
        if self.state != State.ACTIVE:
            self.record_fault(LifecycleError(f'{self.name}: write() in state {self.state.name}'))
            return Status.ERROR
        try:
            self.on_write(command)
        except DriverError as exc:
            self.record_fault(exc)
            return Status.ERROR
        return Status.OK

    def deactivate(self) -> None:
        """Make outputs safe (ACTIVE -> INACTIVE); a safe-output failure is counted."""
        if self.state != State.ACTIVE:
            return
        try:
            self.on_deactivate()
        except DriverError as exc:
            self.record_fault(exc)
            self.log.error('%s: deactivate could not make outputs safe: %s', self.name, exc)
        self._set_state(State.INACTIVE)

    def cleanup(self) -> None:
        """Close the transport (INACTIVE/ERROR -> UNCONFIGURED)."""
        if self.state == State.ACTIVE:
            self.deactivate()
        if self.state in (State.INACTIVE, State.ERROR):
            self.on_cleanup()
            self._set_state(State.UNCONFIGURED)

    def shutdown(self) -> None:
        """Deactivate and clean up from any state, ending FINALIZED."""
        self.deactivate()
        self.cleanup()
        self._set_state(State.FINALIZED)

    def status_level(self) -> int:
        """Return the DEVICE_STATUS level: OK, WARN (faults seen) or ERROR (error state)."""
        if self.state == State.ERROR:
            return Level.ERROR
        return Level.WARN if self.faults else Level.OK

    def __enter__(self) -> DeviceHandler:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()
