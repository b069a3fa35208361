"""Faults the simulator injects into the base: encoders lying, a wheel blocked, the e-stop.

``world.faults`` (a scenario's world too) is a list of entries, each active from ``at_s`` seconds
of world time after the simulator started until ``until_s`` (absent: to the end)::

    faults:
      - {at_s: 2.0, kind: encoder_sign_flip, wheel: left}
      - {at_s: 2.0, kind: encoder_swap}
      - {at_s: 2.0, kind: encoder_frozen, wheel: right}
      - {at_s: 2.0, kind: wheel_stall, wheel: both}
      - {at_s: 1.0, until_s: 3.0, kind: estop}

The encoder faults change what the AS5045s *mean*, never their framing: every frame stays valid
(parity, OCF, no COF/LIN), as with a motor wired the other way round, crossed encoder cables or
a magnet slipping on its shaft. Each starts continuous with the reading before it (no jump for
the unwrapper to reject): a flipped encoder counts back from where it was, swapped channels
report the other wheel's motion from there, a frozen one keeps its last value (no noise).
A stalled wheel is blocked mechanically (it does not turn; its tyre slides if the body is
pushed), and its encoder honestly reads no motion. ``estop`` opens the e-stop contact in
series with the amplifier enable: the motors coast.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any

__all__ = ['ENCODER_KINDS', 'Fault', 'FaultError', 'KINDS', 'parse_faults']

ENCODER_KINDS = ('encoder_sign_flip', 'encoder_swap', 'encoder_frozen')
KINDS = ENCODER_KINDS + ('wheel_stall', 'estop')
_NO_WHEEL = ('encoder_swap', 'estop')        # whole-robot faults: no ``wheel`` key
WHEELS = {'left': (0,), 'right': (1,), 'both': (0, 1)}


class FaultError(ValueError):
    """Raise for a bad ``faults`` entry; the message names the field."""


@dataclass(frozen=True)
class Fault:
    """One scheduled fault: what, on which wheels, from when until when (world seconds)."""

    kind: str
    sides: tuple[int, ...] = ()
    at_s: float = 0.0
    until_s: float | None = None

    def active(self, t_s: float) -> bool:
        """Return True when the fault is on at ``t_s`` seconds after the start."""
        return t_s >= self.at_s and (self.until_s is None or t_s < self.until_s)


def _seconds(v: Any, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
        raise FaultError(f'{where}: expected seconds >= 0, got {v!r}')
    return float(v)


def parse_faults(data: Any, where: str = 'world.faults') -> tuple[Fault, ...]:
    """Return the faults of a ``faults:`` list (errors name the entry and field)."""
    if data is None:
        return ()
    if not isinstance(data, list):
        raise FaultError(f'{where}: expected a list of faults, got {data!r}')
    out = []
    for i, entry in enumerate(data):
        at = f'{where}[{i}]'
        if not isinstance(entry, dict):
            raise FaultError(f'{at}: expected a mapping with at_s, kind (and wheel), '
                             f'got {entry!r}')
        unknown = sorted(set(entry) - {'at_s', 'until_s', 'kind', 'wheel'})
        if unknown:
            raise FaultError(f'{at}: unknown field(s) {unknown!r}; valid: at_s, until_s, '
                             'kind, wheel')
        kind = entry.get('kind')
        if kind not in KINDS:
            raise FaultError(f'{at}.kind: expected one of {", ".join(KINDS)}, got {kind!r}')
        if 'at_s' not in entry:
            raise FaultError(f'{at}.at_s: missing (seconds after the simulator started)')
        start = _seconds(entry['at_s'], f'{at}.at_s')
        until = entry.get('until_s')
        if until is not None:
            until = _seconds(until, f'{at}.until_s')
            if until <= start:
                raise FaultError(f'{at}.until_s: must be after at_s ({start!r}), got {until!r}')
        if kind in _NO_WHEEL:
            if 'wheel' in entry:
                raise FaultError(f'{at}.wheel: {kind} concerns both wheels; remove wheel')
            sides: tuple[int, ...] = (0, 1)
        else:
            wheel = entry.get('wheel')
            if wheel not in WHEELS:
                raise FaultError(f'{at}.wheel: expected left, right or both, got {wheel!r}')
            sides = WHEELS[wheel]
        out.append(Fault(kind, sides, start, until))
    return tuple(out)
