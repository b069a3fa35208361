"""Helpers shared by the XDDP tests of both transports (test_xddp, test_xddp_shm)."""

import threading
import time

from m4k_rt import channel

WAIT = 10.0  # generous upper bound for anything that must happen; never asserted as timing


def until(predicate, what, step=None):
    """Wait until ``predicate()`` is true, calling ``step`` between tries; fail after WAIT."""
    deadline = time.monotonic() + WAIT
    while not predicate():
        if step:
            step()
        assert time.monotonic() < deadline, 'timed out waiting for ' + what
        time.sleep(0.001)


def open_while_polling(rt_socks, *args, **kwargs):
    """Run nrt_xddp_open in a thread while this (RT) thread polls its socket(s)."""
    socks = rt_socks if isinstance(rt_socks, (list, tuple)) else [rt_socks]
    result = {}

    def target():
        try:
            result['ep'] = channel.nrt_xddp_open(*args, **kwargs)
        except Exception as exc:  # handed to the test thread
            result['exc'] = exc

    thread = threading.Thread(target=target)
    thread.start()
    try:
        until(lambda: not thread.is_alive(), 'nrt_xddp_open',
              step=lambda: [s.poll_peer() for s in socks])
    finally:
        thread.join()
    if 'exc' in result:
        raise result['exc']
    return result['ep']
