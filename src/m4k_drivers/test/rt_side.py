"""The RT side of one XDDP port, played by a test: wait for the link, receive one kind."""

import time

from m4k_rt import protocol


def recv_kind(rt, kind, timeout=5.0):
    """Return the payload of the next datagram of ``kind`` (others are skipped)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        data = rt.recv()
        if data is None:
            time.sleep(0.002)
            continue
        hdr, msg = protocol.decode(data)
        if hdr.kind == kind:
            return msg
    raise AssertionError(f'no {kind!r} within {timeout} s')


def wait_linked(rt, timeout=5.0):
    """Wait until the NRT side has opened the port."""
    deadline = time.monotonic() + timeout
    while not rt.poll_peer():
        assert time.monotonic() < deadline, 'NRT side never linked'
        time.sleep(0.01)
