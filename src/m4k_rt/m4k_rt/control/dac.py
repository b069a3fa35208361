"""Normalized motor command <-> 10-bit DAC code (pure).

The WHEEL_CMD datagram carries one 10-bit code per wheel: 512 is zero, 1023 full speed
forward, 1 full speed reverse (0 is clamped to the same -1.0 so the scale is symmetric:
one code step is 1/511 of full scale in both directions). The driver's motor handler uses the
same mapping; a test cross-checks both.
"""

from __future__ import annotations

from m4k_rt.protocol import DAC_MAX, DAC_ZERO  # the wire format owns the codes

__all__ = ['DAC_MAX', 'DAC_MIN', 'DAC_SPAN', 'DAC_ZERO', 'code_to_command', 'command_to_code']

DAC_MIN = 0
DAC_SPAN = DAC_MAX - DAC_ZERO  # 511 codes per unit normalized command


def command_to_code(command: float) -> int:
    """Return the DAC code for a normalized command in [-1, 1] (clamped; NaN gives zero)."""
    if not command == command:  # NaN: never let it reach the DAC as a silently wrong value
        return DAC_ZERO
    if command >= 1.0:
        return DAC_MAX
    if command <= -1.0:
        return DAC_ZERO - DAC_SPAN
    return DAC_ZERO + round(command * DAC_SPAN)


def code_to_command(code: int) -> float:
    """Return the normalized command in [-1, 1] for a DAC code 0..1023."""
    if code < DAC_MIN or code > DAC_MAX:
        raise ValueError(f'DAC code must be in {DAC_MIN}..{DAC_MAX}, got {code!r}')
    c = (code - DAC_ZERO) / DAC_SPAN
    return -1.0 if c < -1.0 else c
