"""The bridge's health bookkeeping (pure, no rclpy): outages, counters, the status inputs.

Time is passed in (CLOCK_MONOTONIC ns chosen by the test) and the ports are plain records with
a PortPump's counters, so every transition is driven step by step.
"""

from dataclasses import dataclass

import pytest

from m4k_bridge import params
from m4k_bridge.health import BridgeHealth, DEVICE_PORTS, STALE_FLOOR_S, STALE_PERIODS
from m4k_rt import protocol

S = 1_000_000_000
STALE_S = 3.0


@dataclass
class Port:
    """One port's counters, as the node's PortPump exposes them."""

    linked: bool = False
    links: int = 0
    lost: int = 0
    last_link_error: str = ''
    received: int = 0
    sent: int = 0
    dropped_unlinked: int = 0
    dropped_overflow: int = 0
    last_rx_ns: int = 0
    error: BaseException | None = None


class Rig:
    """A BridgeHealth, the bridge's ports, and the RT side's behaviour on them."""

    def __init__(self, start_ns=10 * S):
        self.now = start_ns
        self.health = BridgeHealth(start_ns, '/run/m4k-test')
        self.ports = {role: Port() for role in params.PORT_ROLES}

    def link(self):
        for p in self.ports.values():
            p.linked = True
            p.links += 1

    def drop_links(self):
        """The RT process closed its sockets: every linked port reports the broken link."""
        for p in self.ports.values():
            if p.linked:
                p.linked = False
                p.lost += 1

    def receive(self, role='status'):
        port = self.ports[role]
        port.received += 1
        port.last_rx_ns = self.now

    def advance(self, seconds):
        self.now += int(seconds * S)

    def watch(self):
        return self.health.watch(self.now, self.ports, STALE_S)

    def kinds(self):
        return [e.kind for e in self.watch()]


def _devices(rig, reported=()):
    labels = {role: role for role in rig.ports}
    return {s.name: s for s in rig.health.device_statuses(rig.now, rig.ports, labels, reported)}


def test_first_link_is_logged_once_as_info_with_the_wait():
    rig = Rig()
    assert rig.watch() == []                     # nothing linked, nothing received yet
    rig.link()
    rig.advance(2.0)
    rig.receive()
    (ev,) = rig.watch()
    assert (ev.kind, ev.severity) == ('linked', 'info')
    assert ev.gap_s == pytest.approx(2.0) and 'after 2.0 s' in ev.message
    rig.advance(0.25)
    rig.receive()
    assert rig.watch() == []                     # no second line while data flows
    assert rig.health.rt_alive and rig.health.outages == 0


def test_a_datagram_without_a_linked_port_does_not_count_as_linked():
    rig = Rig()
    rig.receive()                                # e.g. the last datagram of a closing link
    assert rig.watch() == [] and not rig.health.rt_alive


def test_silence_starts_an_outage_once_and_the_next_datagram_ends_it_with_the_gap():
    rig = Rig()
    rig.link()
    rig.receive()
    rig.kinds()
    last_rx = rig.now
    rig.advance(STALE_S - 0.5)
    assert rig.watch() == []                     # within rt_stale_timeout: still alive
    rig.advance(1.0)
    (ev,) = rig.watch()
    assert (ev.kind, ev.severity) == ('outage_start', 'warning')
    assert 'no datagram for 3.0 s' in ev.message
    assert not rig.health.rt_alive and rig.health.outages == 1
    for _ in range(5):                           # logged once, however long it lasts
        rig.advance(1.0)
        assert rig.watch() == []
    rig.receive()
    (ev,) = rig.watch()
    assert (ev.kind, ev.severity) == ('outage_end', 'warning')
    gap = (rig.now - last_rx) / S
    assert ev.gap_s == pytest.approx(gap) and rig.health.last_gap_s == pytest.approx(gap)
    assert '{:.1f} s gap (outage 1)'.format(gap) in ev.message
    assert rig.health.rt_alive and rig.health.outages == 1
    rig.advance(0.1)
    rig.receive()
    assert rig.watch() == []


def test_peer_restart_between_two_checks_is_still_one_outage():
    # The RT process died and came back before the next watch: the links broke (lost
    # counted by XDDP) although fresh data already arrives again.
    rig = Rig()
    rig.link()
    rig.receive()
    rig.kinds()
    last_seen = rig.now                          # the newest datagram the last check saw
    rig.advance(0.1)
    rig.drop_links()
    rig.advance(0.05)
    rig.link()
    rig.receive()                                # the new RT process already sends
    (ev,) = rig.watch()
    assert ev.kind == 'outage_start' and 'link broken' in ev.message
    assert rig.health.outages == 1 and not rig.health.rt_alive
    # The datagram seen at the check that noticed the break does not end the outage ...
    assert rig.watch() == []
    rig.advance(0.2)
    rig.receive()                                # ... the first one after it does
    (ev,) = rig.watch()
    assert ev.kind == 'outage_end' and rig.health.outages == 1
    assert ev.gap_s == pytest.approx((rig.now - last_seen) / S)
    rig.advance(0.25)
    rig.receive()
    assert rig.watch() == []                     # the lost count stays: no second outage


def test_repeated_outages_are_counted_and_each_reports_its_own_gap():
    rig = Rig()
    rig.link()
    rig.receive()
    rig.kinds()
    gaps = []
    for n, silence in enumerate((4.0, 7.5, 12.0), start=1):
        last = rig.now
        rig.advance(silence)
        assert rig.kinds() == ['outage_start']
        rig.advance(0.5)
        rig.receive()
        (ev,) = rig.watch()
        assert ev.kind == 'outage_end' and '(outage {})'.format(n) in ev.message
        gaps.append(ev.gap_s)
        assert ev.gap_s == pytest.approx((rig.now - last) / S)
    assert rig.health.outages == 3
    assert gaps == sorted(gaps) and gaps[0] != gaps[-1]
    assert rig.health.last_gap_s == gaps[-1]


def test_a_link_that_breaks_for_good_is_lost_and_the_link_status_says_so():
    rig = Rig()
    rig.link()
    rig.receive()
    rig.kinds()
    assert rig.health.link_status(rig.now, rig.ports).level == protocol.LEVEL_OK
    rig.drop_links()
    rig.advance(0.25)
    assert rig.kinds() == ['outage_start']
    rig.advance(2.05)
    st = rig.health.link_status(rig.now, rig.ports)
    assert st.level == protocol.LEVEL_STALE
    assert st.message == 'RT process lost 2.3 s ago; re-linking'
    assert st.values['outages'] == 1 and st.values['linked_ports'] == 0
    assert st.values['last_datagram_age_s'] == pytest.approx(2.3)


def test_waiting_link_status_names_the_link_error():
    rig = Rig()
    rig.ports['cmd'].last_link_error = 'no RT socket at /run/m4k-test/1'
    st = rig.health.link_status(rig.now, rig.ports)
    assert st.level == protocol.LEVEL_STALE
    assert st.message == 'waiting for the RT process: no RT socket at /run/m4k-test/1'
    assert st.values['last_datagram_age_s'] == float('inf')
    assert (st.name, st.hardware_id) == ('m4k_bridge: rt link', 'm4k_rt')


def test_link_status_totals_the_ports_and_lists_the_link_counters():
    rig = Rig()
    rig.link()
    rig.link()                                   # every port re-linked once
    rig.ports['cmd'].sent, rig.ports['led_in'].sent = 5, 2
    rig.ports['cmd'].dropped_unlinked = 3
    rig.ports['lrf_out'].dropped_overflow = 4
    rig.receive('imu_out')
    rig.receive('imu_out')
    rig.health.count('malformed_cmd')
    rig.health.on_seq('imu_out', 7)
    rig.health.on_seq('imu_out', 10)             # 8 and 9 never arrived
    rig.health.count('cmd_vel_forwarded')        # not a link counter
    v = rig.health.link_status(rig.now, rig.ports).values
    assert v['relinks'] == len(params.PORT_ROLES)
    assert (v['bridge_sent'], v['bridge_received']) == (7, 2)
    assert (v['bridge_dropped_unlinked'], v['bridge_dropped_overflow']) == (3, 4)
    assert v['malformed_cmd'] == 1 and v['lost_imu_out'] == 2
    assert 'cmd_vel_forwarded' not in v and v['runtime_dir'] == '/run/m4k-test'


def test_a_failed_port_reader_is_reported_once():
    rig = Rig()
    rig.ports['sonar_out'].error = OSError(9, 'Bad file descriptor')
    (ev,) = rig.watch()
    assert (ev.kind, ev.severity) == ('port_failed', 'error') and "'sonar_out'" in ev.message
    assert rig.watch() == []


@pytest.mark.parametrize('role', sorted(DEVICE_PORTS))
def test_device_goes_stale_after_its_expected_period_times_n(role):
    device, period = DEVICE_PORTS[role]
    stale_after = max(STALE_PERIODS * period, STALE_FLOOR_S)
    rig = Rig()
    rig.link()
    rig.receive('status')
    rig.receive(role)
    rig.kinds()
    name = 'm4k_drivers: ' + device
    rig.advance(stale_after * 0.9)
    rig.receive('status')                        # the RT process itself is alive
    st = _devices(rig)[name]
    assert (st.level, st.message) == (protocol.LEVEL_OK, 'data flowing')
    assert st.values['source'] == 'data_arrival' and st.values['port'] == role
    rig.advance(stale_after * 0.2)
    rig.receive('status')
    st = _devices(rig)[name]
    assert st.level == protocol.LEVEL_STALE and st.message.startswith('no data for')
    assert st.values['data_age_s'] == pytest.approx(stale_after * 1.1)


def test_devices_are_stale_while_the_rt_process_is_lost_even_with_fresh_data():
    rig = Rig()
    for role in DEVICE_PORTS:
        rig.receive(role)
    assert not rig.health.rt_alive
    assert {s.level for s in _devices(rig).values()} == {protocol.LEVEL_STALE}


def test_a_device_report_replaces_data_arrival_and_an_unknown_device_is_listed_too():
    rig = Rig()
    reported = [('lrf', protocol.LEVEL_ERROR, 'ERROR (error), last error: io',
                 {'state': 'error', 'faults': 7}),
                ('bumper', protocol.LEVEL_WARN, 'WARN (active)', {'state': 'active'})]
    st = _devices(rig, reported)
    lrf = st['m4k_drivers: lrf']
    assert (lrf.level, lrf.hardware_id) == (protocol.LEVEL_ERROR, 'lrf')
    assert lrf.values['faults'] == 7 and lrf.values['source'] == 'device_status'
    assert 'data_age_s' in lrf.values and lrf.values['port'] == 'lrf_out'
    assert st['m4k_drivers: bumper'].values['source'] == 'device_status'
    assert list(st)[-1] == 'm4k_drivers: bumper'   # after the devices with ports


def _odom(flags):
    return protocol.Odometry(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, flags)


def test_motor_stale_flag_raises_the_motor_to_error_while_linked():
    rig = Rig()
    rig.link()
    rig.receive('cmd')
    rig.kinds()
    rig.health.on_odometry(_odom(protocol.ODOM_MOTOR_STALE), rig.now)
    motor = _devices(rig)['m4k_drivers: motor']
    assert motor.level == protocol.LEVEL_ERROR and 'no encoder feedback' in motor.message
    assert motor.values['odom_flags'] == protocol.ODOM_MOTOR_STALE
    rig.health.on_odometry(_odom(0), rig.now)
    assert _devices(rig)['m4k_drivers: motor'].level == protocol.LEVEL_OK


def test_device_extras_sonar_faults_imu_not_ready_led_shown():
    rig = Rig()
    rig.health.on_sonar(protocol.SONAR_OK)
    rig.health.on_sonar(protocol.SONAR_NO_ECHO)      # no echo is a reading, not a fault
    rig.health.on_sonar(protocol.SONAR_NO_ECHO + 1)
    rig.health.count('imu_not_ready')
    rig.health.on_led_shown(protocol.Led(1, 2, 3, 4, 1))
    st = _devices(rig)
    assert st['m4k_drivers: sonar'].values['range_faults'] == 1
    assert st['m4k_drivers: imu'].values['not_ready'] == 1
    assert st['m4k_drivers: led'].values['shown'] == (1, 2, 3, 4, 1)


def test_command_is_commanded_then_idle_after_the_timeout():
    rig = Rig()
    st = rig.health.cmd_status(rig.now, 0.5, 0)
    assert st.message.startswith('idle') and st.values['last_cmd_age_s'] == float('inf')
    rig.health.on_cmd_vel_forwarded(rig.now)
    rig.advance(0.4)
    st = rig.health.cmd_status(rig.now, 0.5, 0)
    assert (st.level, st.message) == (protocol.LEVEL_OK, 'commanded')
    assert st.values['last_cmd_age_s'] == pytest.approx(0.4)
    rig.advance(0.2)
    st = rig.health.cmd_status(rig.now, 0.5, 0)
    assert st.level == protocol.LEVEL_OK and st.message.startswith('idle')
    assert st.values['forwarded'] == 1


def test_rejected_and_clamped_commands_are_counted_and_warn_within_the_window():
    rig = Rig()
    h = rig.health
    assert [h.on_cmd_problem('cmd_vel_rejected_nonfinite', rig.now)
            for _ in range(3)] == [1, 2, 3]
    h.on_cmd_problem('cmd_vel_clamped', rig.now)
    h.count('led_rejected_nonfinite')
    h.count('led_forwarded')
    h.on_cmd_vel_forwarded(rig.now)                 # fresh, yet WARN wins
    st = h.cmd_status(rig.now, 0.5, 6, window_s=10.0)
    assert (st.level, st.message) == (protocol.LEVEL_WARN,
                                      'commands rejected or clamped in the last 10 s')
    assert st.values == {'forwarded': 1, 'rejected_nonfinite': 3, 'clamped': 1,
                         'last_cmd_age_s': 0.0, 'dropped_no_rt': 6, 'led_forwarded': 1,
                         'led_rejected_nonfinite': 1, 'type_mismatch': 'none'}
    assert (st.name, st.hardware_id) == ('m4k_bridge: cmd_vel', 'm4k_bridge')
    # One clamped command does not leave the status WARN for the whole session.
    rig.advance(9.9)
    assert h.cmd_status(rig.now, 0.5, 6, window_s=10.0).level == protocol.LEVEL_WARN
    rig.advance(0.2)
    st = h.cmd_status(rig.now, 0.5, 6, window_s=10.0)
    assert st.level == protocol.LEVEL_OK and st.values['clamped'] == 1   # still counted


def test_a_cmd_vel_publisher_of_the_other_type_warns():
    rig = Rig()
    h = rig.health
    h.cmd_vel_type_mismatch = ('geometry_msgs/msg/TwistStamped published, '
                               'geometry_msgs/msg/Twist subscribed')
    st = h.cmd_status(rig.now, 0.5, 0)
    assert st.level == protocol.LEVEL_WARN and 'TwistStamped' in st.message
    assert st.values['type_mismatch'] == h.cmd_vel_type_mismatch


def test_sequence_gaps_count_lost_datagrams_per_port():
    h = BridgeHealth(0, '')
    h.on_seq('imu_out', 100)
    h.on_seq('imu_out', 101)
    h.on_seq('sonar_out', 5)
    assert h.counters['lost_imu_out'] == 0 and h.counters['lost_sonar_out'] == 0
    h.on_seq('imu_out', 105)
    assert h.counters['lost_imu_out'] == 3 and h.counters['lost_sonar_out'] == 0


def test_guard_fallback_follows_a_fresh_odometry_flag_only():
    h = BridgeHealth(0, '')
    assert not h.guard_fallback(5 * S)
    h.on_odometry(_odom(protocol.ODOM_GUARD), 5 * S)
    assert h.guard_fallback(5 * S + S // 2)
    assert not h.guard_fallback(6 * S + 1)
    h.on_odometry(_odom(0), 7 * S)
    assert not h.guard_fallback(7 * S)
