"""A condition whose reference is broken gives no verdict (issue 42).

Every latency ratio divides by cyclictest, the machine's own floor at the actuator's period and
priority. When cyclictest's own tail shows the host stalling -- its p99 above the period (a
release missed outright), or its p99 more than :data:`TAIL_FACTOR` times its p50 and above
:data:`TAIL_FLOOR_US` (a hypervisor descheduling the vCPU, not scheduling noise) -- the
denominator measures the host, not the program: a ratio over it reads as "met" for any program
(committed runs: cyclictest p50 19-33 µs, p99 6,954-12,806 µs under stress-ng, and the
actuator's ratio 0.11). Such a round is left out of every ratio that uses the condition, with
the reason; a target left with no valid round is reported INVALID, never met.
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

__all__ = ['TAIL_FACTOR', 'TAIL_FLOOR_US', 'broken_reference', 'condition_reference',
           'round_invalid']

TAIL_FACTOR = 20.0       # p99 / p50 above this: a tail of stalls, not of scheduling noise
TAIL_FLOOR_US = 500.0    # ... and only once the tail is this long (idle VMs: p99 ~ 5-10x p50)


def _num(v: Any) -> float | None:
    return float(v) if isinstance(v, (int, float)) and math.isfinite(v) else None


def broken_reference(ref: Mapping[str, Any] | None, period_us: float) -> str | None:
    """Return why a cyclictest result (p50/p99 in µs) is no reference, or None when it is one."""
    if not isinstance(ref, Mapping):
        return None                     # no reference at all: the ratio is already missing
    p50, p99 = _num(ref.get('p50')), _num(ref.get('p99'))
    if p99 is None:
        return None
    if p99 > period_us:
        return 'cyclictest p99 {:.0f} µs > the period {:.0f} µs (the host skipped releases)'\
            .format(p99, period_us)
    if p50 is not None and p50 > 0 and p99 > TAIL_FACTOR * p50 and p99 > TAIL_FLOOR_US:
        return 'cyclictest p99 {:.0f} µs = {:.0f}× its p50 {:.0f} µs (the host stalls)'.format(
            p99, p99 / p50, p50)
    return None


def condition_reference(rnd: Mapping[str, Any], cond: str) -> Mapping[str, Any] | None:
    """Return the cyclictest result that is ``cond``'s reference in one round.

    A cyclictest-alone condition (``ct_*``) is its own reference; any other condition's is the
    cyclictest that ran beside it.
    """
    c = rnd.get(cond)
    if not isinstance(c, Mapping):
        return None
    ref = c.get('latency_us') if cond.startswith('ct_') else c.get('cyclictest')
    return ref if isinstance(ref, Mapping) else None


def round_invalid(rnd: Mapping[str, Any], conds: Sequence[str],
                  period_us: float) -> str | None:
    """Return why a ratio over ``conds`` (its numerator's and denominator's) has no verdict."""
    for cond in dict.fromkeys(conds):
        why = broken_reference(condition_reference(rnd, cond), period_us)
        if why:
            return '{}: {}'.format(cond, why)
    return None
