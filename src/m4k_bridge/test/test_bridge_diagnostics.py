"""RT timing -> RtStatus / DiagnosticStatus aggregation of the bridge (pure, no rclpy)."""

import pytest

from m4k_bridge.diagnostics import degraded_reasons, make_status, RtMonitor, TaskWindow
from m4k_rt import protocol

P = 10_000_000


def _stats(first, n, cycles=None, response=1_000_000, name='actuator'):
    samples = tuple(protocol.TaskSample(i * P, i * P + 20_000, i * P + 20_000 + response, 1)
                    for i in range(first, first + n))
    return protocol.TaskStats(name, 0, 90, -1, P, cycles if cycles is not None else first + n,
                              0, 0, 0, 0, samples)


def test_window_drops_duplicates_and_keeps_only_the_window():
    w = TaskWindow('actuator', window_ns=50 * P)
    w.add(_stats(0, 40), 1)
    w.add(_stats(30, 40), 2)          # rows 30..39 repeated (same batch on two ports)
    assert w.duplicates == 10
    assert w.rows[0][0] == 19 * P and w.rows[-1][0] == 69 * P  # 50 periods kept
    a = w.analyze()
    assert a.cycles == 51 and a.response.max == pytest.approx(1_000_000)


def test_window_restarts_when_the_rt_process_restarted():
    w = TaskWindow('actuator', window_ns=10**12)
    w.add(_stats(100, 10), 1)
    w.add(_stats(0, 5), 2)            # cycles went backwards: a new RT process
    assert len(w.rows) == 5 and w.rows[0][0] == 0


def test_stalled_task_is_an_error_and_silent_task_is_stale():
    m = RtMonitor(window_s=10.0, stale_s=1.0)
    m.feed(protocol.Kind.TASK_STATS, _stats(0, 10), 0)
    m.feed(protocol.Kind.TASK_STATS, _stats(10, 0, cycles=10), 0)
    (st,) = m.task_statuses(now_ns=0)
    assert st.level == b'\x02' and 'stopped' in st.message
    (st,) = m.task_statuses(now_ns=2_000_000_000)
    assert st.level == b'\x03'


def test_deadline_misses_warn_and_make_the_set_unschedulable():
    m = RtMonitor()
    m.feed(protocol.Kind.TASK_STATS, _stats(0, 10, response=12_000_000), 0)
    (st,) = m.task_statuses(now_ns=0)
    assert st.level == b'\x01' and '10 deadline misses' in st.message
    msg = m.rt_status_msg(0, 0.0)
    assert msg.tasks[0].deadline_misses == 10 and not msg.schedulable
    assert msg.total_utilization > 1.0


def test_device_status_reports_pass_through_and_go_stale():
    m = RtMonitor(stale_s=1.0)
    m.feed(protocol.Kind.DEVICE_STATUS, protocol.DeviceStatus('lrf', 3, 1, 4, 6), 0)
    (name, level, _, values), = m.device_levels(0)
    assert (name, level, values['faults']) == ('lrf', 1, 4)
    (_, level, msg, _), = m.device_levels(5_000_000_000)
    assert level == protocol.LEVEL_STALE and 'RT process' in msg


@pytest.mark.parametrize('level, text', [
    (protocol.LEVEL_OK, 'OK'), (protocol.LEVEL_WARN, 'WARN'), (protocol.LEVEL_ERROR, 'ERROR'),
    (protocol.LEVEL_STALE, 'silent')])
def test_device_levels_map_rep107_and_name_state_and_error(level, text):
    m = RtMonitor(stale_s=1.0)
    rx = 10_000_000_000
    m.feed(protocol.Kind.DEVICE_STATUS, protocol.DeviceStatus('motor', 3, level, 2, 4), rx,
           stamp_ns=rx - 1_500_000_000)           # the RT side got the report 1.5 s earlier
    (name, got, msg, values), = m.device_levels(rx + 500_000_000)
    assert name == 'motor' and got == level and text in msg
    assert values['state'] == 'active' and values['last_error'] == 'io'
    assert values['faults'] == 2 and values['age_s'] == pytest.approx(2.0)
    st = make_status('m4k_drivers: motor', got, msg, values)
    assert st.level == bytes((level,))
    assert {kv.key for kv in st.values} == {'state', 'faults', 'last_error', 'age_s'}


def test_unknown_device_codes_are_shown_as_numbers():
    m = RtMonitor()
    m.feed(protocol.Kind.DEVICE_STATUS, protocol.DeviceStatus('x', 77, 0, 0, 99), 0)
    (_, _, _, values), = m.device_levels(0)
    assert (values['state'], values['last_error']) == ('77', '99')


def test_degraded_reasons_name_what_is_missing():
    rs = protocol.RtStatus(0, 0, 1, 0, 0x2, 6, 100)
    reasons = degraded_reasons(rs)
    assert any('SCHED_FIFO' in r for r in reasons)
    assert any('mlockall' in r for r in reasons)
    assert any('garbage collector' in r for r in reasons)
    assert not any('cpu_dma_latency' in r for r in reasons)


def test_collision_guard_comes_from_rt_status_when_it_carries_it():
    m = RtMonitor(stale_s=1.0)
    valid = protocol.RT_FLAG_GUARD_VALID
    m.feed(protocol.Kind.RT_STATUS, protocol.RtStatus(1, 1, 0, 1, valid, 6, 100), 0)
    assert m.collision_guard(0) is True
    assert m.rt_status_msg(0, 0.0, guard_fallback=False).collision_guard_active
    m.feed(protocol.Kind.RT_STATUS, protocol.RtStatus(1, 1, 0, 0, valid, 6, 100), 0)
    assert not m.rt_status_msg(0, 0.0, guard_fallback=True).collision_guard_active


@pytest.mark.parametrize('flags, rx_ns', [
    (protocol.RT_FLAG_AUDIT, 0),                         # old RT: guard_active = audit flag
    (protocol.RT_FLAG_GUARD_VALID, -2_000_000_000),       # RT_STATUS older than stale_s
])
def test_collision_guard_falls_back_when_rt_status_is_old(flags, rx_ns):
    m = RtMonitor(stale_s=1.0)
    m.feed(protocol.Kind.RT_STATUS, protocol.RtStatus(1, 1, 0, 1, flags, 6, 100), rx_ns)
    assert m.collision_guard(0) is None
    assert not m.rt_status_msg(0, 0.0, guard_fallback=False).collision_guard_active
    assert m.rt_status_msg(0, 0.0, guard_fallback=True).collision_guard_active


def test_collision_guard_without_rt_status_is_the_fallback():
    m = RtMonitor()
    assert m.collision_guard(0) is None
    assert m.rt_status_msg(0, 0.0, guard_fallback=True).collision_guard_active


def _port(label, port, linked=1, malformed=0):
    return protocol.PortStats(label, port, linked, 10, 20, 1, 2, 3, malformed, 4)


def test_port_stats_become_xddp_ports_in_port_order():
    m = RtMonitor(stale_s=1.0)
    assert m.port_msgs(0) == []
    m.feed(protocol.Kind.PORT_STATS, _port('cmd', 1, malformed=5), 0)
    m.feed(protocol.Kind.PORT_STATS, _port('status', 0), 0)
    m.feed(protocol.Kind.PORT_STATS, _port('stat', 11, linked=0), 0)
    ports = m.port_msgs(0)
    assert [(x.port, x.label, x.linked) for x in ports] == [
        (0, 'status', True), (1, 'cmd', True), (11, 'stat', False)]
    cmd = ports[1]
    assert (cmd.sent, cmd.received, cmd.dropped_no_peer, cmd.dropped_full,
            cmd.dropped_oversize, cmd.malformed, cmd.peer_restarts) == (10, 20, 1, 2, 3, 5, 4)


def test_port_stats_of_a_gone_rt_process_are_kept_unlinked_and_old_ports_dropped():
    m = RtMonitor(stale_s=1.0)
    m.feed(protocol.Kind.PORT_STATS, _port('old', 20), 0)
    m.feed(protocol.Kind.PORT_STATS, _port('cmd', 1), 5_000_000_000)   # a new RT process
    ports = m.port_msgs(5_000_000_000)
    assert [(x.port, x.linked) for x in ports] == [(1, True)]
    ports = m.port_msgs(9_000_000_000)                                  # now it is gone too
    assert [(x.port, x.linked, x.sent) for x in ports] == [(1, False, 10)]


def _drops(device, served, **reasons):
    counts = [reasons.pop(r, 0) for r in protocol.HOST_DROP_REASONS]
    assert not reasons
    return protocol.HostDrops(device, served, *counts)


def _host_status(m, now):
    (st,) = m.host_drop_statuses(now)
    return st.level, st.message, {kv.key: kv.value for kv in st.values}


def test_host_drops_warn_while_a_counter_moved_within_the_window_then_ok():
    s = 1_000_000_000
    m = RtMonitor(window_s=10.0, stale_s=3.0)
    assert m.host_drop_statuses(0) == []          # no report: no status
    m.feed(protocol.Kind.HOST_DROPS, _drops('motor', 100, inactive=4), 1 * s, 1 * s)
    level, msg, values = _host_status(m, 1 * s)
    # counts older than the bridge's first report are not judged as recent
    assert level == b'\x00' and msg == 'no drops in the last 0.0 s (4 since the host started)'
    m.feed(protocol.Kind.HOST_DROPS, _drops('motor', 200, inactive=4, stale_host=5,
                                            stale_device=1), 3 * s, 3 * s)
    level, msg, values = _host_status(m, 3 * s)
    assert level == b'\x01'
    assert msg == '6 dropped in the last 2.0 s (3/s): stale_host 5, stale_device 1'
    assert (values['window_drops'], values['window_drops_per_s'], values['served']) == (
        '6', '3', '200')
    assert (values['stale_host'], values['stale_device'], values['inactive']) == ('5', '1', '4')
    for t in range(4, 15):                        # quiet for more than the window
        m.feed(protocol.Kind.HOST_DROPS, _drops('motor', 200 + t, inactive=4, stale_host=5,
                                                stale_device=1), t * s, t * s)
    level, msg, values = _host_status(m, 14 * s)
    assert level == b'\x00' and values['window_drops'] == '0' and values['window_s'] == '10'
    assert values['stale_host'] == '5'            # the cumulative counts stay
    level, msg, _ = _host_status(m, 18 * s)       # nothing forwarded for 4 s (> stale_s)
    assert level == b'\x03' and 'nothing forwarded' in msg
    # the RT monitor keeps forwarding the host's last report: stale once it is older than
    # the window (its counts no longer cover it), not before
    last = _drops('motor', 214, inactive=4, stale_host=5, stale_device=1)
    m.feed(protocol.Kind.HOST_DROPS, last, 23 * s, 14 * s)
    assert _host_status(m, 23 * s)[0] == b'\x00'
    m.feed(protocol.Kind.HOST_DROPS, last, 25 * s, 14 * s)
    level, msg, _ = _host_status(m, 25 * s)
    assert level == b'\x03' and msg == 'no drop report from the driver host for 11.0 s'


def test_host_drops_of_a_restarted_host_count_from_zero():
    s = 1_000_000_000
    m = RtMonitor(window_s=10.0, stale_s=3.0)
    m.feed(protocol.Kind.HOST_DROPS, _drops('motor', 900, stale_host=40), 1 * s, 1 * s)
    m.feed(protocol.Kind.HOST_DROPS, _drops('motor', 5, reply_lost=2), 2 * s, 2 * s)
    level, msg, values = _host_status(m, 2 * s)
    assert level == b'\x01' and msg.endswith(': reply_lost 2')
    assert values['window_drops'] == '2' and values['stale_host'] == '0'
