"""How the driver host serves the sonar: REQUEST (trigger) -> one ping -> SONAR.

Every REQUEST gets an answer: a sonar that is not up, or a ping that failed, is reported as a
SONAR datagram with the fault status, so the RT side never mistakes silence for a clear path.
"""

from __future__ import annotations

import math
from typing import Any

from m4k_drivers.handler import State, Status
from m4k_drivers.registry import Replier, ServiceSpec
from m4k_drivers.sonar.handler import SonarHandler
from m4k_drivers.sonar.protocol import SonarReading
from m4k_rt.protocol import Kind, SONAR_FAULT, SonarStatus

__all__ = ['SERVICE']


def serve(handler: SonarHandler, msg: Any, tx: Replier) -> None:
    """Ping once and send the range (0.0 unless measured) with its status."""
    r = handler.read() if handler.state == State.ACTIVE else None
    if r is None or r.status != Status.OK:
        tx.send(Kind.SONAR, 0.0, SONAR_FAULT)
        return
    rng = r.value.range_m
    tx.send(Kind.SONAR, rng if math.isfinite(rng) else 0.0, r.value.status)


_NAMES: dict[int, str] = {SonarStatus.OK: 'ok', SonarStatus.NO_ECHO: 'no echo',
                          SonarStatus.TIMEOUT: 'timeout', SonarStatus.FAULT: 'invalid'}


def format_reading(value: SonarReading) -> str:
    """Return the ``--print`` line of one reading."""
    return (f'sonar range={value.range_m:.3f} m status={value.status} '
            f'({_NAMES.get(value.status, "?")})')


SERVICE: ServiceSpec[SonarHandler] = ServiceSpec(
    accepts=frozenset({Kind.REQUEST}), serve=serve, format=format_reading, path_key='chip')
