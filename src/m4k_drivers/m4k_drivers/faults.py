"""Faults the simulator injects into the base: encoders lying, a wheel blocked, the e-stop.

``world.faults`` (a scenario's world too) is a list of entries, each active from ``at_s`` seconds
of world time after the simulator started until ``until_s`` (absent: to the end), or from a
moment of the drive -- ``start``: once the robot has truly covered ``travelled`` m and moved
for ``after`` s, as a moving obstacle's path starts -- for ``for_s`` s (absent: to the end)::

    faults:
      - {at_s: 2.0, kind: encoder_sign_flip, wheel: left}
      - {at_s: 2.0, kind: encoder_swap}
      - {at_s: 2.0, kind: encoder_frozen, wheel: right}
      - {at_s: 2.0, kind: wheel_stall, wheel: both}
      - {at_s: 1.0, until_s: 3.0, kind: estop}
      - {start: {after: 3.0}, for_s: 2.0, kind: estop}   # 3 s into the drive, for 2 s

World time alone cannot put a fault at a moment of the drive: the stack comes up in 5 s on a
quiet machine and in 20 s on a loaded one, so an e-stop at 30 s needed 40 s of commands to
be sure to fall inside them (and a straight drive that long left any world at speed).

The encoder faults change what the AS5045s *mean*, never their framing: every frame stays valid
(parity, OCF, no COF/LIN), as with a motor wired the other way round, crossed encoder cables or
a magnet slipping on its shaft. Each starts continuous with the reading before it (no jump for
the unwrapper to reject): a flipped encoder counts back from where it was, swapped channels
report the other wheel's motion from there, a frozen one keeps its last value (no noise).
A stalled wheel is blocked mechanically (it does not turn; its tyre slides if the body is
pushed), and its encoder honestly reads no motion. ``estop`` opens the e-stop contact in
series with the amplifier enable: the motors coast.

An entry's keys are declared once, in :data:`FAULT` (schema Fields: validation and docs); the
parser checks by hand only what involves several keys (``at_s`` or ``start``, ``until_s``
after ``at_s``, ``for_s`` or ``until_s``, ``wheel`` given exactly for the per-wheel kinds).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from m4k_drivers.scene import START, Start
from m4k_rt.schema import ConfigError, Field, REQUIRED, validate_tree

__all__ = ['ENCODER_KINDS', 'FAULT', 'Fault', 'FaultError', 'KINDS', 'parse_faults']

ENCODER_KINDS = ('encoder_sign_flip', 'encoder_swap', 'encoder_frozen')
KINDS = ENCODER_KINDS + ('wheel_stall', 'estop')
_NO_WHEEL = ('encoder_swap', 'estop')        # whole-robot faults: no ``wheel`` key
WHEELS = {'left': (0,), 'right': (1,), 'both': (0, 1)}


class FaultError(ConfigError):
    """Raise for a bad ``faults`` entry; the message names the field."""


# One entry of world.faults.
FAULT: dict[str, Field] = {
    'at_s': Field('float', None, 'World time after the simulator started at which the '
                  'fault begins; null: at ``start`` (one of the two).', unit='s', lo=0,
                  nullable=True, expect='seconds >= 0 or null'),
    **{'start.' + k: f for k, f in START.items()},
    'until_s': Field('float', None, 'World time it ends (after at_s; with at_s only); null: '
                     'for_s, or to the end.', unit='s', lo=0, nullable=True,
                     expect='seconds >= 0 or null'),
    'for_s': Field('float', None, 'How long it lasts from its onset (not with until_s); '
                   'null: until_s, or to the end.', unit='s', lo=0, lo_open=True,
                   nullable=True, expect='seconds > 0 or null'),
    'kind': Field('str', REQUIRED, 'encoder_sign_flip: the encoder counts backwards; '
                  'encoder_swap: the two encoder channels crossed; encoder_frozen: the magnet '
                  'slips (the reading stops); wheel_stall: the wheel blocked; estop: the e-stop '
                  'contact opens (the motors coast). Every frame stays valid.', choices=KINDS),
    'wheel': Field('str', None, 'The wheel(s) of a per-wheel kind; not given for encoder_swap '
                   'and estop (they concern both).', choices=tuple(WHEELS), nullable=True,
                   expect='left, right or both'),
}


@dataclass(frozen=True)
class Fault:
    """One scheduled fault: what, on which wheels, from when until when (world seconds).

    It begins at ``at_s``, or (``at_s`` None) at the world time its ``start`` is reached,
    which the simulator notes (``onset``); it ends at ``until_s``, or ``for_s`` after it
    began, or never.
    """

    kind: str
    sides: tuple[int, ...] = ()
    at_s: float | None = 0.0
    until_s: float | None = None
    start: Start | None = None
    for_s: float | None = None

    def active(self, t_s: float, onset: float | None = None) -> bool:
        """Return True when the fault is on at ``t_s`` seconds after the start.

        ``onset``: when a ``start`` fault began (world seconds; None: not yet).
        """
        begin = self.at_s if self.start is None else onset
        if begin is None or t_s < begin:
            return False
        end = self.until_s if self.for_s is None else begin + self.for_s
        return end is None or t_s < end


def parse_faults(data: Any, where: str = 'world.faults') -> tuple[Fault, ...]:
    """Return the faults of a ``faults:`` list (errors name the entry and field)."""
    if data is None:
        return ()
    if not isinstance(data, list):
        raise FaultError(where, f'expected a list of faults, got {data!r}')
    out = []
    for i, entry in enumerate(data):
        at = f'{where}[{i}]'
        v = validate_tree(FAULT, entry, at, FaultError)
        start, until, kind, for_s = v['at_s'], v['until_s'], v['kind'], v['for_s']
        moment = None
        if 'start' in entry:
            if start is not None:
                raise FaultError(f'{at}.start', 'give at_s (world time) or start (a moment of '
                                 'the drive), not both')
            if until is not None:
                raise FaultError(f'{at}.until_s', 'world time ends an at_s fault only; a '
                                 'start fault lasts for_s')
            moment = Start.from_flat(v)
        elif start is None:
            raise FaultError(f'{at}.at_s', 'missing: give at_s (world time) or start (a moment '
                             'of the drive)')
        if until is not None and for_s is not None:
            raise FaultError(f'{at}.for_s', 'give until_s or for_s, not both')
        if until is not None and start is not None and until <= start:
            raise FaultError(f'{at}.until_s', f'must be after at_s ({start!r}), got {until!r}')
        if kind in _NO_WHEEL:
            if 'wheel' in entry:
                raise FaultError(f'{at}.wheel', f'{kind} concerns both wheels; remove wheel')
            sides: tuple[int, ...] = (0, 1)
        elif v['wheel'] is None:
            raise FaultError(f'{at}.wheel', f'missing: {kind} needs left, right or both')
        else:
            sides = WHEELS[v['wheel']]
        out.append(Fault(kind, sides, start, until, moment, for_s))
    return tuple(out)
