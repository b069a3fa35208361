"""The driver host's drop counters, read from its log: drops per 10 000 commands, by reason.

The host logs ``<device>: drops served=N stale_host=a stale_device=b ...`` when a counter moves
and ``... at exit`` when a service ends (m4k_drivers.host.DROP_REASONS). The bench takes the
last line per device. ``stale_device`` is what the simulation causes (the loop was held by a
device transaction longer than the command's age limit: sim_robot answering late over the sim
bus); every other reason is the host's own and would happen on a real robot too.
"""

from __future__ import annotations

import re
from typing import Any

__all__ = ['LINE', 'REPLY_REASONS', 'SIM_REASONS', 'counts_of', 'parse', 'per_10k', 'read',
           'rt_side']

SIM_REASONS = ('stale_device',)
# Reasons that lose a command on its way in; ``encode`` and ``reply_lost`` lose a reply (e.g.
# the ENCODERS after the RT side stopped, at every shutdown) and are reported, not counted.
REPLY_REASONS = ('encode', 'reply_lost')
LINE = re.compile(r'(?P<dev>[\w-]+): drops served=(?P<served>\d+)(?P<rest>(?: \w+=\d+)*)')


def parse(text: str) -> dict[str, dict[str, int]]:
    """Return device -> {'served': n, reason: count, ...} from the last drops line of each."""
    return {m.group('dev'): counts_of(m) for m in LINE.finditer(text)}


def counts_of(m: re.Match[str]) -> dict[str, int]:
    """Return {'served': n, reason: count, ...} of one :data:`LINE` match."""
    counts = {'served': int(m.group('served'))}
    for kv in m.group('rest').split():
        k, v = kv.split('=')
        counts[k] = int(v)
    return counts


def per_10k(counts: dict[str, int]) -> dict[str, Any]:
    """Return one device's drops per 10 000 commands: total, host's own, simulation's, by reason.

    The denominator is every command that reached the host: served + dropped on the way in;
    reply-side counts are in ``by_reason`` only.
    """
    reasons = {k: v for k, v in counts.items() if k != 'served'}
    dropped = sum(v for k, v in reasons.items() if k not in REPLY_REASONS)
    total = counts.get('served', 0) + dropped
    sim = sum(reasons.get(k, 0) for k in SIM_REASONS)

    def rate(n: int) -> float | None:
        return 1e4 * n / total if total else None
    return {'commands': total, 'dropped': dropped, 'per_10k': rate(dropped),
            'host_per_10k': rate(dropped - sim), 'sim_per_10k': rate(sim),
            'by_reason': reasons}


def read(path: str, device: str = 'motor') -> dict[str, Any] | None:
    """Return :func:`per_10k` of ``device`` from a driver host log, or None when absent."""
    try:
        with open(path, encoding='utf-8', errors='replace') as f:
            counts = parse(f.read()).get(device)
    except OSError:
        return None
    return per_10k(counts) if counts else None


def rt_side(ps: Any) -> dict[str, Any] | None:
    """Return the RT side's send-side drops of the motor port (a PortStats), per 10 000.

    ``queue``: the host's receive queue was full (``dropped_full``); ``link``: no host linked
    (``dropped_no_peer``: before it links, and while it restarts). Denominator: every
    WHEEL_CMD the actuator tried to send.
    """
    if ps is None:
        return None
    queue, link = int(ps.dropped_full), int(ps.dropped_no_peer)
    total = int(ps.sent) + queue + link
    return {'sent': int(ps.sent), 'queue': queue, 'link': link,
            'queue_per_10k': 1e4 * queue / total if total else None,
            'link_per_10k': 1e4 * link / total if total else None}
