"""Fault injection for the bench: one task's body overruns now and then (rt_core body module).

``M4K_SLOW_BODY=TASK:MS:EVERY`` (e.g. ``sonar:15:10``) with ``rt_core --body-module
m4k_bench.slowbody`` (or ``M4K_BODY_MODULES``): task TASK's own body runs as usual, and every
EVERY-th cycle it then spins for MS ms of CPU in Python (holding the GIL as a long parse would,
giving it up only at the switch interval). The bench runs this under both executives and
reports what the actuator's release latency and overruns do (issue 42, "preemption"): with one
thread per task the actuator's higher priority takes the CPU and, at the next switch interval,
the GIL; in a frame it waits for the whole body.
"""

from __future__ import annotations

import importlib
import os
import time
from typing import Any, Callable

from m4k_rt.tasks import register_body

__all__ = ['ENV', 'parse', 'slow']

ENV = 'M4K_SLOW_BODY'


def parse(text: str) -> tuple[str, float, int]:
    """Return (task, ms, every) from ``TASK:MS:EVERY``; ValueError naming the field."""
    parts = text.split(':')
    if len(parts) != 3 or not parts[0]:
        raise ValueError(f'{ENV}: expected TASK:MS:EVERY, got {text!r}')
    ms, every = float(parts[1]), int(parts[2])
    if not 0 < ms < 1000 or every < 1:
        raise ValueError(f'{ENV}: MS in (0, 1000) and EVERY >= 1, got {text!r}')
    return parts[0], ms, every


def slow(body: Callable[[Any], object], ms: float, every: int) -> Callable[[Any], object]:
    """Return ``body`` that spins ``ms`` ms of CPU after every ``every``-th cycle."""
    spin_ns = int(ms * 1e6)
    n = [0]

    def run(ctx: Any) -> object:
        out = body(ctx)
        n[0] += 1
        if n[0] % every == 0:
            end = time.thread_time_ns() + spin_ns     # CPU time: a preempted spin is not cut
            while time.thread_time_ns() < end:
                pass
        return out
    return run


def _install(text: str) -> None:
    task, ms, every = parse(text)
    make = getattr(importlib.import_module('m4k_rt.tasks.' + task), 'make_' + task)

    def factory(t: Any, ports: Any, shared: Any) -> Callable[[Any], object]:
        return slow(make(t, ports, shared), ms, every)
    register_body(task, factory)


if os.environ.get(ENV):
    _install(os.environ[ENV])
