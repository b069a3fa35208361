"""A driver_host process reports its drops by reason on the wire, and says "no RT peer" once.

Real processes and sockets: ``python -m m4k_drivers.host --device motor`` against the
in-process sim_robot, the test playing the RT side of the ``motor`` port (a real XDDP bind).
Drops are forced by their real causes (a WHEEL_CMD stamped three periods ago, bytes that do
not decode, a kind the motors do not take) and read back from the host's own HOST_DROPS
datagram; no clock figure is asserted.
"""

import re
import time

import pytest
from rt_side import recv_kind, wait_linked

from m4k_drivers import config as dconfig
from m4k_rt import protocol
from m4k_rt.channel import rt_xddp_bind

pytestmark = pytest.mark.e2e  # starts processes: the end-to-end tier

K = protocol.Kind
CONFIG = str(dconfig.default_config_path())
MOTOR_PORT = 2          # config/m4k.yaml ports: motor


def _host(procs, log):
    return procs.start(['python', '-m', 'm4k_drivers.host', '--config', CONFIG,
                        '--device', 'motor'], stdout=log, stderr=log)


def _next_drops(rt, pred, timeout=30.0):
    """Return the first HOST_DROPS satisfying ``pred`` (the host sends one a second)."""
    deadline = time.monotonic() + timeout
    while True:
        left = deadline - time.monotonic()
        assert left > 0, 'no HOST_DROPS as expected within {} s'.format(timeout)
        d = recv_kind(rt, K.HOST_DROPS, timeout=left)
        if pred(d):
            return d


def test_each_forced_drop_is_counted_under_its_reason_in_host_drops(procs, sim_robot,
                                                                     m4k_runtime_dir, tmp_path):
    rt = rt_xddp_bind(MOTOR_PORT, 'motor', runtime_dir=m4k_runtime_dir)
    with open(tmp_path / 'host.log', 'w') as log:
        proc = _host(procs, log)
    try:
        wait_linked(rt, timeout=60)
        deadline = time.monotonic() + 60
        while recv_kind(rt, K.DEVICE_STATUS, timeout=60).state != protocol.DeviceState.ACTIVE:
            assert time.monotonic() < deadline, 'motor never active'
        base = recv_kind(rt, K.HOST_DROPS)
        assert base.device == 'motor' and base.served == 0
        assert base[2:] == (0,) * 6 + (base.reply_lost,)   # nothing came in yet
        period = dconfig.validate({'devices': {'motor': {'backend': 'sim'}}}).devices[
            'motor']['period_s']
        old = time.monotonic_ns() - round(3 * period * 1e9)
        rt.send(protocol.encode(K.WHEEL_CMD, 1, old, 700, 700, 1))        # older than 2 periods
        rt.send(b'\x4d\x4b\x01garbage')                                    # does not decode
        rt.send(protocol.encode(K.REQUEST, 2, time.monotonic_ns(), 1, 0))  # not a motor kind
        rt.send(protocol.encode(K.WHEEL_CMD, 3, time.monotonic_ns(), 512, 512, 0))  # served
        recv_kind(rt, K.ENCODERS)
        d = _next_drops(rt, lambda d: d.served >= 1)
    finally:
        assert procs.stop(proc) == 0        # before the peer goes: no reply lost on the way out
        rt.close()
    # No stall before it (nothing served yet): the stale command is the host's, not the device's.
    assert d.served == 1
    assert dict(zip(protocol.HOST_DROP_REASONS, d[2:], strict=True)) == {
        'stale_host': 1, 'stale_device': 0, 'malformed': 1, 'unexpected': 1, 'inactive': 0,
        'encode': 0, 'reply_lost': base.reply_lost}
    text = (tmp_path / 'host.log').read_text()
    assert ('motor: drops served=1 stale_host=1 stale_device=0 malformed=1 unexpected=1 '
            'inactive=0 encode=0 reply_lost={} at exit'.format(base.reply_lost)) in text, text


def test_no_rt_peer_is_logged_once_when_it_starts_and_once_when_it_ends(
        procs, sim_robot, m4k_runtime_dir, tmp_path):
    """Before: a ``drops ... reply_lost=N`` warning every second while rt_core was absent."""
    path = tmp_path / 'host.log'
    with open(path, 'w') as log:
        proc = _host(procs, log)
    rt = None
    try:
        deadline = time.monotonic() + 60
        while 'motor: no RT peer' not in path.read_text():
            assert time.monotonic() < deadline and proc.poll() is None, path.read_text()
            time.sleep(0.1)
        time.sleep(3.0)               # three status periods (1 s) without a peer
        rt = rt_xddp_bind(MOTOR_PORT, 'motor', runtime_dir=m4k_runtime_dir)
        wait_linked(rt, timeout=30)
        d = recv_kind(rt, K.HOST_DROPS, timeout=30)
    finally:
        assert procs.stop(proc) == 0        # before the peer goes: one episode only
        if rt is not None:
            rt.close()
    text = path.read_text()
    assert text.count('motor: no RT peer') == 1, text
    ended = re.findall(r'motor: RT peer linked after [\d.]+ s without one: (\d+) replies lost',
                       text)
    assert len(ended) == 1, text
    # Every lost reply is still counted, and they are all the episode's: the first HOST_DROPS
    # after linking carries the count the end line logged (>= 2: a status and its drop
    # counters at least once a second, for three seconds).
    assert int(ended[0]) == d.reply_lost >= 2, text
    drop_lines = [ln for ln in text.splitlines() if ' drops served=' in ln and 'at exit' not in ln]
    assert drop_lines == [], text
