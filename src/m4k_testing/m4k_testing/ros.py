"""Calling a ROS service from a test across processes, where the first answer can be lost.

``wait_for_service`` (and ``service_is_ready``) say the client's request writer met the
server. With Fast DDS the server may not yet have met the client's *response* reader when the
first request arrives; it answers into nothing and the client waits for ever. Seen in CI: a
``get_parameters`` call on a freshly started bridge never answered within 60 s, under load.
The remedy a ROS user applies by hand is to ask again, so a test does too: each attempt waits a
few seconds, an unanswered request is dropped from the client (``remove_pending_request``) and
sent again, until the whole timeout. Only for idempotent requests (parameters, e-stop on/off,
set_pose, reset_odometry).
"""

from __future__ import annotations

import time
from typing import Any, Callable


def call(client: Any, request: Any, spin_once: Callable[[float], Any], timeout: float,
         what: str, attempt: float = 5.0, each: Callable[[], Any] | None = None) -> Any:
    """Return ``client``'s response to ``request``, asking again every ``attempt`` seconds.

    ``spin_once(seconds)`` spins whatever executor holds the client's node; ``each`` runs
    between spins (e.g. to keep publishing a command). Raises AssertionError naming ``what``
    when no answer came within ``timeout`` seconds.
    """
    end = time.monotonic() + timeout
    asked = 0
    while time.monotonic() < end:
        future = client.call_async(request)
        asked += 1
        stop = min(end, time.monotonic() + attempt)
        while time.monotonic() < stop and not future.done():
            spin_once(0.02)
            if each is not None:
                each()
        if future.done():
            return future.result()
        client.remove_pending_request(future)
    raise AssertionError('no answer to {} within {} s ({} request(s) sent)'.format(
        what, timeout, asked))
