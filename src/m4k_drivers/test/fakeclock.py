"""The one fake clock of the driver tests: simulated time that moves only when a test moves it.

``FakeClock`` is what ``World``, the handlers and ``SimRobot`` take as ``clock`` (a callable
returning monotonic nanoseconds) and, through :meth:`FakeClock.sleep`, as ``sleep``; the
``fake_clock`` fixture (conftest.py) hands a fresh one to a test. :class:`SteppingStop` is a
stop event whose ``wait`` advances the clock instead of blocking, so a calibration or a jog
runs in simulated time and takes no wall time.
"""

from __future__ import annotations

import threading


class FakeClock:
    """A monotonic clock in ns: ``clock()`` reads it, tests set or advance ``clock.t``.

    ``step_ns``: advance by this much before every read (a handler polled once per period sees
    time pass without the test moving it).
    """

    def __init__(self, t: int = 0, step_ns: int = 0) -> None:
        self.t = t
        self.step_ns = step_ns

    def __call__(self) -> int:
        self.t += self.step_ns
        return self.t

    def seconds(self) -> float:
        return self.t * 1e-9

    def sleep(self, s: float) -> None:
        self.t += int(s * 1e9)


class SteppingStop(threading.Event):
    """A stop event whose ``wait(timeout)`` advances ``clock`` by the timeout instead.

    ``min_step_ns``: the least a wait advances (a zero timeout would otherwise never let
    simulated time pass); ``stop_after_s``: set the event once the clock reaches it (Ctrl-C).
    """

    def __init__(self, clock: FakeClock, stop_after_s: float | None = None,
                 min_step_ns: int = 1000) -> None:
        super().__init__()
        self.clock, self.stop_after_s, self.min_step_ns = clock, stop_after_s, min_step_ns

    def wait(self, timeout: float | None = None) -> bool:
        self.clock.t += max(int((timeout or 0.0) * 1e9), self.min_step_ns)
        if self.stop_after_s is not None and self.clock.seconds() >= self.stop_after_s:
            self.set()
        return self.is_set()
