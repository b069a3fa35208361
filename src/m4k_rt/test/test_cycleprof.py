"""The cycle profile (m4k_rt.cycleprof): timed ports and tasks when on, nothing when off."""

import json
import time

from fake_peers import Ports
import pytest

from m4k_rt import cycleprof
from m4k_rt import protocol as p
from m4k_rt.task import RtTask
from m4k_rt.tasks.portio import PortReader, PortWriter


@pytest.fixture
def rig(m4k_runtime_dir):
    r = Ports(m4k_runtime_dir, 'cmd')
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


def test_profiled_task_times_its_ports_and_reports_every_part(rig):
    cycleprof.enable()
    try:
        reader = PortReader(rig.rt['cmd'])
        writer = PortWriter(rig.rt['cmd'])

        def body(ctx):
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
    h, m = p.decode(rig.nrt['cmd'].read(timeout=1.0))    # the timed writer really sent
    assert h.kind == p.Kind.ODOM_RESET and m.request_id == 1


def test_unprofiled_ports_and_tasks_have_no_profile(rig):
    assert not cycleprof.enabled()
    assert type(PortReader(rig.rt['cmd'])) is PortReader
    assert type(PortWriter(rig.rt['cmd'])) is PortWriter
    assert RtTask('plain', 10, 1_000_000, lambda ctx: None).profile is None


def test_rt_core_writes_the_breakdown_of_every_task(procs, tmp_path, m4k_runtime_dir,
                                                    monkeypatch):
    # The real robot bodies with the motor and bridge sides faked; $M4K_CYCLE_PROFILE on.
    from fake_peers import FakeMotor, NrtPeers
    from test_tasks_rtcore import _drive, _start

    from m4k_rt.control.params import control_params
    out = tmp_path / 'profile.json'
    monkeypatch.setenv(cycleprof.ENV, str(out))
    proc = _start(procs, tmp_path, {'guard': {'enabled': False}}, 3)
    link = NrtPeers(m4k_runtime_dir, 'cmd', 'motor')
    try:
        motor = FakeMotor(link, control_params(None).full_scale_wheel_speed)
        assert _drive(link, motor, (0.25, 0.0), 1.5)
    finally:
        link.close()
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    prof = json.loads(out.read_text())['tasks']
    assert set(prof) == {'actuator', 'imu', 'led', 'sonar', 'lrf', 'monitor'}
    act = prof['actuator']
    assert act['period_ns'] == 10_000_000 and act['cycles'] > 50
    assert set(act['parts_us']) == set(cycleprof.PARTS)
    assert act['parts_us']['drain'] > 0.0 and act['parts_us']['send'] > 0.0
    assert act['drain_calls'] >= 2 * act['cycles']    # two ports drained every cycle
    assert act['send_calls'] >= act['cycles']         # WHEEL_CMD every cycle
    assert 'rt_core: task actuator: cycle profile' in err
