"""Pure arithmetic of a bench made of repeated rounds (dicts and numbers in, dicts out).

* :func:`spread` -- median with min and max over the rounds (the verdict is on the median;
  the spread is reported next to it);
* :func:`per_round_ratios` -- one ratio per round from two measurements taken in that round;
* :func:`attribute_stall` -- was a stall the host's? A stall that sets a condition's maximum is
  checked against the cyclictest that ran *concurrently*: when cyclictest saw a stall of at
  least :data:`HOST_SHARE` of the same size in the same round, the host (hypervisor, other
  tenants) stalled both, and the report says so with both numbers;
* :func:`hardening_label` -- what an rt_core run really had (RT_STATUS), never "m4k" when
  degraded;
* :func:`cpu_per_cycle_us` -- process CPU over the cycles run, for the floor comparison.
"""

from __future__ import annotations

import math
import statistics
from typing import Any, Iterable, Mapping, Sequence, TypeGuard

__all__ = ['HOST_SHARE', 'attribute_stall', 'cpu_per_cycle_us', 'hardening_label',
           'per_round_ratios', 'spread']

# A stall in m4k counts as the host's when the concurrent cyclictest saw at least half of it.
# cyclictest is a C loop at the same priority and period: what stalls it is below any Python.
HOST_SHARE = 0.5


def _finite(v: Any) -> TypeGuard[float]:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def spread(values: Iterable[Any]) -> dict[str, Any] | None:
    """Return median, min, max and n of the finite values (None when there is none).

    ``values`` keeps the per-round list as given (None for a round without a value).
    """
    given = list(values)
    ok = [float(v) for v in given if _finite(v)]
    if not ok:
        return None
    return {'median': statistics.median(ok), 'min': min(ok), 'max': max(ok), 'n': len(ok),
            'values': [float(v) if _finite(v) else None for v in given]}


def _get(d: Any, path: Sequence[str]) -> Any:
    for key in path:
        if not isinstance(d, Mapping) or key not in d:
            return None
        d = d[key]
    return d


def per_round_ratios(rounds: Sequence[Mapping[str, Any]], num: Sequence[str],
                     den: Sequence[str]) -> list[float | None]:
    """Return num / den for every round (None when either side is missing, zero or not finite).

    ``num`` and ``den`` are key paths into one round's dict, e.g.
    ``('m4k_idle', 'latency_us', 'p99')``.
    """
    out: list[float | None] = []
    for r in rounds:
        a, b = _get(r, num), _get(r, den)
        out.append(float(a) / float(b) if _finite(a) and _finite(b) and b != 0 else None)
    return out


def attribute_stall(stall_us: float | None, cyclictest_max_us: float | None,
                    period_us: float) -> dict[str, Any] | None:
    """Tell whose stall set a maximum: ``'host'``, ``'own'`` or ``'unknown'``.

    ``'own'``: the measured process's; ``'unknown'``: no concurrent cyclictest result.

    ``stall_us``: the condition's maximum (release latency or response) in one round;
    ``cyclictest_max_us``: the maximum of the cyclictest that ran concurrently in that round.
    Only stalls longer than a tenth of the period are attributed (shorter ones are no stall).
    """
    if not _finite(stall_us) or stall_us <= period_us / 10.0:
        return None
    if not _finite(cyclictest_max_us):
        return {'stall_us': stall_us, 'cyclictest_max_us': None, 'owner': 'unknown'}
    owner = 'host' if cyclictest_max_us >= HOST_SHARE * stall_us else 'own'
    return {'stall_us': stall_us, 'cyclictest_max_us': cyclictest_max_us, 'owner': owner}


def hardening_label(rt_status: Mapping[str, Any] | None) -> dict[str, Any]:
    """Summarise RT_STATUS: policy, locked memory, degraded; ``ok`` only for the real thing.

    A run without RT_STATUS, with a policy other than SCHED_FIFO, without locked memory or
    flagged degraded is not an m4k run in the paper's sense and must not be labelled one.
    """
    if not rt_status:
        return {'ok': False, 'policy': None, 'mem_locked': None, 'degraded': None,
                'why': 'no RT_STATUS received'}
    fifo = rt_status.get('policy') == 1
    locked = bool(rt_status.get('mem_locked'))
    degraded = bool(rt_status.get('degraded'))
    why = [w for w, bad in (('not SCHED_FIFO', not fifo), ('memory not locked', not locked),
                            ('degraded', degraded)) if bad]
    return {'ok': not why, 'policy': 'SCHED_FIFO' if fifo else 'SCHED_OTHER',
            'mem_locked': locked, 'degraded': degraded, 'why': ', '.join(why)}


def cpu_per_cycle_us(cpu_s: float | None, window_s: float,
                     rates_hz: Iterable[float]) -> float | None:
    """Return CPU µs per task cycle: ``cpu_s`` over ``window_s`` × the summed task rates."""
    cycles = window_s * sum(rates_hz)
    if not _finite(cpu_s) or not cycles > 0:
        return None
    return cpu_s * 1e6 / cycles
