"""Fuzz every XDDP port of the running robot task set: nothing crashes, every bad datagram counts.

Bounded form of ``python -m m4k_bench.fuzz`` (which sends 1e5 datagrams per port): the RT
task set runs in this process as rt_core builds it (real bodies, real ports, one timerfd
thread per task); a sender process per port writes a deterministic stream of valid, mutated,
random and oversize datagrams; the RT counters must match the prediction exactly.
"""

import math
import signal
import socket
import struct
import time

import pytest

from m4k_bench import fuzz
from m4k_rt import protocol, xddp

SAMPLE = 150  # datagrams per port here; the benchmark script sends 1e5


@pytest.fixture
def harness(m4k_runtime_dir, tmp_path):
    overlay = tmp_path / 'fast.yaml'
    overlay.write_text('runtime: {mlockall: false, cpu_dma_latency: false}\n')
    with fuzz.RtHarness(str(overlay), period_ms=5, runtime_dir=m4k_runtime_dir) as h:
        yield h


def _cycles(h):
    return {t.name: t.cycles for t in h.shared.tasks}


def test_every_port_counts_every_bad_datagram_and_every_task_keeps_cycling(harness):
    labels = list(harness.ports)
    assert set(labels) == set(fuzz.ACCEPTS), 'fuzz.ACCEPTS must cover every configured port'
    before = _cycles(harness)
    results = [fuzz.fuzz_port(harness, label, SAMPLE, seed=7) for label in labels]
    for r in results:
        assert r.ok, '{}: {}'.format(r.label, r.problems)
        e = r.expected
        assert e.sent == SAMPLE and e.malformed > 0 and e.unexpected > 0
        assert r.malformed == e.malformed and r.unexpected == e.unexpected
        assert r.oversize == e.oversize and r.body_errors == 0
    after = _cycles(harness)
    assert all(after[name] > before[name] for name in before), (before, after)
    time.sleep(0.1)
    assert all(t.is_alive() and t.body_errors == 0 for t in harness.shared.tasks)
    assert _cycles(harness)['actuator'] > after['actuator']


def test_fuzz_stream_covers_every_input_class():
    acc = fuzz.ACCEPTS['cmd']
    seen = {fuzz.classify(d, acc, protocol.MAX_DATAGRAM) for d in fuzz.datagrams('cmd', 400, 3)}
    assert seen == {'oversize', 'malformed', 'unexpected', 'accepted'}
    reasons = set()
    for d in fuzz.datagrams('motor', 2000, 3):
        try:
            protocol.decode(d)
        except protocol.ProtocolError as exc:
            reasons.add(exc.reason)
    assert {'short', 'magic', 'version', 'kind', 'length', 'nonfinite', 'range'} <= reasons
    assert list(fuzz.datagrams('led', 50, 9)) == list(fuzz.datagrams('led', 50, 9))


def _velocity(lin, ang):
    return struct.pack('<HBBIqdd', protocol.MAGIC, protocol.VERSION, protocol.Kind.VELOCITY_CMD,
                       1, time.monotonic_ns(), lin, ang)


def test_nonfinite_velocity_commands_never_reach_the_controller(harness):
    body = harness.owner['cmd'].body
    sock = harness.ports['cmd']
    before, mal0 = body.ctl.commands, sock.counters.malformed
    bad = [_velocity(x, 0.0) for x in (math.nan, math.inf, -math.inf)] + \
          [_velocity(0.1, y) for y in (math.nan, math.inf, -math.inf)]
    with xddp.nrt_xddp_open('cmd', wait=5.0) as ep:
        for d in bad:
            ep.write(d, 5.0)
        assert harness.settled('cmd', len(bad), 10.0)
        # -0.0 and a huge finite value are valid: accepted, then limited by the controller.
        # (one per cycle: within a cycle the latest command wins)
        ep.write(_velocity(-0.0, -0.0), 5.0)
        assert harness.settled('cmd', len(bad) + 1, 10.0)
        ep.write(_velocity(1e308, -1e308), 5.0)
        assert harness.settled('cmd', len(bad) + 2, 10.0)
    assert sock.counters.malformed - mal0 == len(bad)
    assert body.ctl.commands - before == 2
    assert math.isfinite(body.ctl.v) and math.isfinite(body.ctl.w)
    assert abs(body.ctl.v) <= body.params.linear.max_velocity
    assert 0 <= body.ctl.left_code <= 1023 and 0 <= body.ctl.right_code <= 1023


def test_hostile_raw_peers_are_counted_not_fatal(harness, m4k_runtime_dir):
    sock = harness.ports['motor']
    c = sock.counters
    lost0, busy0 = c.peer_lost, c.busy_rejects
    path = xddp.port_path('motor', m4k_runtime_dir)
    # An empty datagram reads as EOF: the RT side drops that peer (counted) and carries on.
    raw = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    try:
        raw.settimeout(5.0)
        raw.connect(path)
        assert raw.recv(1) == xddp.HANDSHAKE_OK
        raw.send(b'')
        end = time.monotonic() + 5.0
        while c.peer_lost == lost0 and time.monotonic() < end:
            time.sleep(0.01)
    finally:
        raw.close()
    assert c.peer_lost == lost0 + 1
    # A peer that never reads: the RT side's sends are dropped and counted, it never blocks.
    with xddp.nrt_xddp_open('motor', wait=5.0) as ep:
        full0 = c.dropped_full
        end = time.monotonic() + 10.0
        while c.dropped_full == full0 and time.monotonic() < end:
            time.sleep(0.02)
        assert c.dropped_full > full0
        with pytest.raises(xddp.XddpBusyError):
            xddp.nrt_xddp_open('motor', wait=1.0)
        assert c.busy_rejects == busy0 + 1
        ep.write(protocol.encode(protocol.Kind.REQUEST, 0, 0, 1, 2), 5.0)
    assert all(t.is_alive() and t.body_errors == 0 for t in harness.shared.tasks)


def test_rt_core_process_survives_fuzz_on_every_port(procs, tmp_path, m4k_runtime_dir):
    overlay = tmp_path / 'fast.yaml'
    overlay.write_text('runtime: {mlockall: false, cpu_dma_latency: false, start_delay_ms: 10}\n'
                       'tasks: {monitor: {period_ms: 100}}\n')
    core = procs.start(['python', '-m', 'm4k_rt.rt_core', '--config', str(overlay)])
    labels = list(fuzz.ACCEPTS)
    for label in labels:
        # Opening waits for the port: the first one also waits for rt_core's start-up.
        fuzz.send(label, 60, seed=11, runtime_dir=m4k_runtime_dir, timeout=10.0,
                  hold=lambda: time.sleep(0.3))
    assert core.poll() is None, core.stderr.read() if core.poll() is not None else ''
    core.send_signal(signal.SIGINT)
    _, err = core.communicate(timeout=20)
    assert core.returncode == 0, err
    summary = [line for line in err.splitlines() if line.startswith('rt_core: task ')]
    assert len(summary) == 6, err
    for line in summary:
        assert ' body errors 0 ' in line and ' cycles 0 ' not in line, line
