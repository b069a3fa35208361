"""PortGroup (one poll for a body's receive ports) and the cycle profile's timed ports."""

import threading
import time

from fake_peers import Ports
import pytest

from m4k_rt import cycleprof
from m4k_rt import protocol as p
from m4k_rt.task import RtTask
from m4k_rt.tasks.portio import (
    DATAGRAM,
    NOTHING,
    PortGroup,
    PortReader,
    PortWriter,
    SOMETHING,
)
from m4k_rt.xddp import nrt_xddp_open


@pytest.fixture
def rig(m4k_runtime_dir):
    r = Ports(m4k_runtime_dir, 'cmd', 'motor')
    yield r
    r.close()


def _drain(reader):
    reader.start_cycle()
    got = []
    while (x := reader.next()) is not None:
        got.append(x)
    return got


def _until(pred, timeout=5.0):
    end = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < end, 'condition not met within {} s'.format(timeout)
        time.sleep(0.001)


# A write on the NRT side of a Unix socket is queued on the RT side when it returns, so the
# tests need no wait between writing and polling.


def test_group_poll_marks_only_the_ports_holding_datagrams(rig):
    cmd, motor = PortReader(rig.rt['cmd']), PortReader(rig.rt['motor'])
    group = PortGroup((motor, cmd))
    group.poll()
    assert (motor.ready, cmd.ready) == (NOTHING, NOTHING)
    assert _drain(motor) == [] and _drain(cmd) == []
    rig.write('cmd', p.Kind.VELOCITY_CMD, 0.5, 0.1, seq=3)
    rig.write('cmd', p.Kind.VELOCITY_CMD, 0.25, 0.0, seq=4)
    group.poll()
    assert (motor.ready, cmd.ready) == (NOTHING, DATAGRAM)
    got = _drain(cmd)                     # a ready port drains everything pending, in order
    assert [(h.seq, m) for h, m in got] == [(3, p.VelocityCmd(0.5, 0.1)),
                                            (4, p.VelocityCmd(0.25, 0.0))]
    group.poll()
    assert (motor.ready, cmd.ready) == (NOTHING, NOTHING)


def test_a_datagram_arriving_after_the_group_poll_is_read_next_cycle(rig):
    motor = PortReader(rig.rt['motor'])
    group = PortGroup((motor,))
    group.poll()
    rig.write('motor', p.Kind.ENCODERS, 1, 2, 0.5, 0.25, 0, seq=9)
    assert _drain(motor) == []            # this cycle's poll found nothing
    group.poll()
    (h, m), = _drain(motor)
    assert h.seq == 9 and m.left_angle == 0.5


def test_group_follows_a_restarted_peer(rig, m4k_runtime_dir):
    motor = PortReader(rig.rt['motor'])
    group = PortGroup((motor,))
    group.poll()
    rig.nrt['motor'].close()              # the driver host dies ...
    group.poll()
    assert motor.ready == SOMETHING       # ... its hang-up is something to do
    assert _drain(motor) == []
    assert not rig.rt['motor'].connected and rig.rt['motor'].counters.peer_lost == 1
    box = {}
    opener = threading.Thread(target=lambda: box.update(
        ep=nrt_xddp_open('motor', wait=5.0, runtime_dir=m4k_runtime_dir)))
    opener.start()                        # ... and comes back: an opener on the listener
    end = time.monotonic() + 5.0
    while opener.is_alive():
        group.poll()
        if motor.ready == SOMETHING:
            _drain(motor)                 # the drain accepts it
        assert time.monotonic() < end
        opener.join(0.001)
    rig.nrt['motor'] = box['ep']
    assert rig.rt['motor'].connected and rig.rt['motor'].counters.peer_restarts == 1
    rig.write('motor', p.Kind.ENCODERS, 1, 2, 0.5, 0.25, 0, seq=1)
    group.poll()                          # the new peer's fd is polled
    assert motor.ready == DATAGRAM
    assert len(_drain(motor)) == 1


def test_group_of_sockets_that_cannot_be_polled_leaves_readers_draining():
    class Stub:
        def recv_into(self, buf):
            return 0

    r = PortReader(Stub())
    group = PortGroup((r,))
    group.poll()
    assert r.ready == SOMETHING
    r.start_cycle()
    assert r.budget > 0


def test_profiled_task_times_its_ports_and_reports_every_part(rig):
    cycleprof.enable()
    try:
        reader = PortReader(rig.rt['cmd'])
        writer = PortWriter(rig.rt['cmd'])
        group = PortGroup((reader,))

        def body(ctx):
            group.poll()
            _drain(reader)
            writer.send(p.Kind.ODOM_RESET, ctx.t_start, 1)

        task = RtTask('prof', 10, 2_000_000, body, block_signals=False)
    finally:
        cycleprof.enable(False)
    assert task.profile is not None
    assert type(reader) is not PortReader and isinstance(reader, PortReader)
    task.start()
    try:
        _until(lambda: task.cycles >= 80)
    finally:
        task.stop()
        assert task.join(5.0)
    s = task.profile.summary()
    assert s['cycles'] == task.cycles
    assert s['send_calls'] == task.cycles or s['send_calls'] == task.cycles + 1
    assert set(s['parts_us']) == set(cycleprof.PARTS)
    assert all(v >= 0.0 for v in s['parts_us'].values())
    assert s['parts_us']['drain'] > 0.0 and s['parts_us']['send'] > 0.0
    assert s['thread_cpu_per_cycle_us'] > 0.0
    assert rig.nrt['cmd'].read(timeout=1.0)    # the timed writer really sent


def test_unprofiled_ports_and_tasks_have_no_profile(rig):
    assert not cycleprof.enabled()
    assert type(PortReader(rig.rt['cmd'])) is PortReader
    assert type(PortWriter(rig.rt['cmd'])) is PortWriter
    assert type(PortGroup(())) is PortGroup
    assert RtTask('plain', 10, 1_000_000, lambda ctx: None).profile is None


def test_oversize_first_datagram_of_a_reported_port_is_dropped_and_the_next_one_read(rig):
    motor = PortReader(rig.rt['motor'], 64)
    group = PortGroup((motor,))
    rig.nrt['motor'].write(bytes(100))    # larger than the reader's buffer
    rig.write('motor', p.Kind.ENCODERS, 1, 2, 0.5, 0.25, 0, seq=5)
    group.poll()
    assert motor.ready == DATAGRAM
    (h, _), = _drain(motor)
    assert h.seq == 5
    assert rig.rt['motor'].counters.dropped_oversize == 1
