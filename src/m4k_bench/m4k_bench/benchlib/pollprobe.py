"""What one poll per frame over all ports would save: N empty-port polls vs one poll of N ports.

``python -m m4k_bench.benchlib.pollprobe [PORTS] [FRAMES]``: with PORTS Unix seqpacket pairs
(the frame's receive ports, each a listener and a peer fd as in m4k_rt.channel) and nothing
pending -- the usual state of a port the RT side polls -- time, in thread CPU per frame:

* ``per_port``: what the tasks do today, one ``poll(0)`` per port (its two fds) per cycle;
* ``one_poll``: one ``poll(0)`` over every port's fds, once per frame.

Prints one JSON line (µs per frame, medians of 5 batches of FRAMES frames each).
"""

from __future__ import annotations

import json
import select
import socket
import statistics
import sys
import time
from typing import Callable, Sequence

__all__ = ['measure']


def _batch(fn: Callable[[], object], frames: int) -> float:
    t0 = time.thread_time_ns()
    for _ in range(frames):
        fn()
    return (time.thread_time_ns() - t0) / frames / 1e3


def measure(ports: int = 8, frames: int = 20000) -> dict[str, float | int]:
    """Return µs per frame: per-port polls and one poll over all, and their difference."""
    pairs = [socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET) for _ in range(2 * ports)]
    per = []
    for i in range(ports):
        p = select.poll()
        for s in (pairs[2 * i][0], pairs[2 * i + 1][0]):      # listener + peer of one port
            p.register(s, select.POLLIN)
        per.append(p.poll)
    one = select.poll()
    for a, _ in pairs:
        one.register(a, select.POLLIN)
    one_poll = one.poll

    def per_port() -> None:
        for poll in per:
            poll(0)

    def all_at_once() -> None:
        one_poll(0)
    try:
        per_us = statistics.median(_batch(per_port, frames) for _ in range(5))
        one_us = statistics.median(_batch(all_at_once, frames) for _ in range(5))
    finally:
        for x, y in pairs:
            x.close()
            y.close()
    return {'ports': ports, 'per_port_us': per_us, 'one_poll_us': one_us,
            'saved_us': per_us - one_us}


def main(argv: Sequence[str] | None = None) -> int:
    """Print the measurement as one JSON line."""
    args = list(sys.argv[1:] if argv is None else argv)
    ports = int(args[0]) if args else 8
    frames = int(args[1]) if len(args) > 1 else 20000
    print(json.dumps(measure(ports, frames)))
    return 0


if __name__ == '__main__':
    sys.exit(main())
