"""Who may do what through the live view: rights, the single-driver lock, rate limits (pure).

Three rights, each including the ones before it:

* ``view``: subscribe and read parameters. A view client's ``serverInfo`` offers neither
  ``clientPublish`` nor ``services``, so the apps show no publish or call controls at all.
* ``drive``: publish ``cmd_vel``, ``led`` (and the 3D panel's nav topics), engage the e-stop
  (``e_stop`` true, ``~/e_stop`` true), ``~/reset_odometry``.
* ``safety``: release the e-stop (``e_stop`` false, ``~/e_stop`` false),
  ``~/reset_motor_fault``, ``~/set_pose``, and any further service an operator puts on the
  allow-list (a service nobody classified is a safety matter until someone says otherwise).

Engaging the e-stop is never refused to a client that may publish at all: it bypasses the
driver lock, the rate limits and the request queue. Motion (``cmd_vel``, ``led``, nav goals)
is published for one client at a time, the driver (:class:`DriverLock`).
"""

from __future__ import annotations

import dataclasses
from typing import Literal

__all__ = ['BRIDGE_SERVICE_RIGHTS', 'DriverLock', 'RIGHTS', 'TokenBucket', 'at_least',
           'capabilities', 'service_right']

Right = Literal['view', 'drive', 'safety']
RIGHTS: tuple[str, ...] = ('view', 'drive', 'safety')
# The bridge's own services (relative to the bridge node) and the right each needs; ``e_stop``
# is ``drive`` to be called at all, and its release (data false) is checked as ``safety``.
BRIDGE_SERVICE_RIGHTS: dict[str, Right] = {
    'e_stop': 'drive', 'reset_odometry': 'drive',
    'reset_motor_fault': 'safety', 'set_pose': 'safety'}


def at_least(have: str, need: str) -> bool:
    """Return True when right ``have`` includes right ``need``."""
    return RIGHTS.index(have) >= RIGHTS.index(need)


def capabilities(right: str, offered: tuple[str, ...]) -> tuple[str, ...]:
    """Return the capabilities a client with ``right`` is told of (view: no writes at all)."""
    if at_least(right, 'drive'):
        return offered
    return tuple(c for c in offered if c not in ('clientPublish', 'services'))


def service_right(name: str, bridge_fqn: str) -> Right:
    """Return the right a call of service ``name`` needs (unknown ones: ``safety``)."""
    prefix = bridge_fqn.rstrip('/') + '/'
    if name.startswith(prefix):
        return BRIDGE_SERVICE_RIGHTS.get(name[len(prefix):], 'safety')
    return 'safety'


@dataclasses.dataclass
class TokenBucket:
    """``rate`` tokens a second, at most ``burst`` saved; one token per message."""

    rate: float
    burst: float
    tokens: float = -1.0
    stamp: float = 0.0
    refused: int = 0
    throttled: bool = False       # refused since the last message that passed

    def take(self, now: float) -> bool:
        """Spend a token if there is one (``now``: a monotonic clock, s)."""
        if self.tokens < 0:
            self.tokens, self.stamp = self.burst, now
        self.tokens = min(self.burst, self.tokens + (now - self.stamp) * self.rate)
        self.stamp = now
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            self.throttled = False
            return True
        self.refused += 1
        return False


class DriverLock:
    """One client drives at a time.

    The first client with ``drive`` that sends motion takes the lock; it keeps it while it
    sends motion at least every ``idle_s``. Another client takes it over when the driver
    leaves (disconnects, unadvertises), falls silent for ``idle_s``, or -- at any time --
    when that client holds ``safety`` (a supervisor can always take the controls).
    """

    def __init__(self, idle_s: float) -> None:
        self.idle_s = idle_s
        self.owner: int | None = None
        self.owner_name = ''
        self.last = 0.0
        self.changes = 0

    def claim(self, client: int, name: str, right: str, now: float) -> tuple[bool, bool]:
        """Return (may publish, the owner changed) for motion from ``client`` at ``now``."""
        if self.owner == client:
            self.last = now
            return True, False
        free = self.owner is None or now - self.last > self.idle_s
        if not free and not at_least(right, 'safety'):
            return False, False
        self.owner, self.owner_name, self.last = client, name, now
        self.changes += 1
        return True, True

    def release(self, client: int) -> bool:
        """Free the lock if ``client`` holds it (it left); return True when it did."""
        if self.owner != client:
            return False
        self.owner, self.owner_name = None, ''
        self.changes += 1
        return True
