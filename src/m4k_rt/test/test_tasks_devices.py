import math

from fake_peers import ctx, FakeMotor, MS, Ports
import pytest

from m4k_rt import protocol as p
from m4k_rt.control.base import MODE_BRAKING, MODE_DRIVING, MODE_FAULT, MODE_IDLE
from m4k_rt.control.params import control_params
from m4k_rt.tasks import led as led_mod
from m4k_rt.tasks.actuator import ActuatorBody
from m4k_rt.tasks.imu import ImuBody
from m4k_rt.tasks.led import LedBody
from m4k_rt.tasks.lrf import LrfBody, SCAN_REQUEST
from m4k_rt.tasks.sonar import SonarBody, TRIGGER
from m4k_rt.tasks.state import DEVICE_SLOTS, RobotState

IMU_FIELDS = (0.0, 0.0, 0.0, 1.0, 0.01, 0.02, 0.03, 0.1, 0.2, 9.81, 0)


@pytest.fixture
def ports(m4k_runtime_dir):
    made = []

    def make(*labels):
        made.append(Ports(m4k_runtime_dir, *labels))
        return made[-1]
    yield make
    for pr in made:
        pr.close()


def test_imu_requests_each_cycle_and_forwards_the_latest_sample(ports):
    rig = ports('imu', 'imu_out')
    state = RobotState()
    body = ImuBody(rig.rt['imu'], rig.rt['imu_out'], state)
    body(ctx(10 * MS))
    reqs = rig.read_all('imu')
    assert [h.kind for h, _ in reqs] == [p.Kind.REQUEST]
    assert rig.read_all('imu_out') == []           # nothing to forward yet
    # two samples arrive before the next cycle: only the newest is forwarded, bytes unchanged
    rig.write('imu', p.Kind.IMU, *IMU_FIELDS, seq=1, stamp=11 * MS)
    newest = p.encode(p.Kind.IMU, 2, 12 * MS, *IMU_FIELDS[:-2], 9.7, 0)
    rig.nrt['imu'].write(newest)
    rig.write('imu', p.Kind.DEVICE_STATUS, 'imu', 3, p.LEVEL_WARN, 1, 0)
    body(ctx(20 * MS))
    out = rig.nrt['imu_out'].read(timeout=1.0)
    assert out == newest
    assert rig.read_all('imu_out') == []
    assert body.superseded == 1
    assert state.imu_level == p.LEVEL_WARN
    assert state.imu_rx_ns == 20 * MS
    assert len(rig.read_all('imu')) == 1


def test_sonar_publishes_ranges_for_the_guard_and_forwards(ports):
    rig = ports('sonar', 'sonar_out')
    state = RobotState()
    body = SonarBody(rig.rt['sonar'], rig.rt['sonar_out'], state)
    body(ctx(30 * MS))
    (h, req), = rig.read_all('sonar')
    assert req.arg == TRIGGER
    rig.write('sonar', p.Kind.SONAR, 0.75, p.SONAR_OK, stamp=40 * MS)
    body(ctx(60 * MS))
    assert state.sonar_range == pytest.approx(0.75)
    # aged from the ping: the echo's stamp less its flight time (1.5 m at 343 m/s)
    assert state.sonar_rx_ns == 40 * MS - int(2e9 * 0.75 / 343.0)
    assert state.sonar_sighting.range_m == pytest.approx(0.75)
    assert state.sonar_sighting.acquired_ns == state.sonar_rx_ns
    assert p.decode(rig.nrt['sonar_out'].read(timeout=1.0))[1].range_m == pytest.approx(0.75)
    # no echo: free ahead, still a fresh reading
    rig.write('sonar', p.Kind.SONAR, 0.0, p.SONAR_NO_ECHO, stamp=85 * MS)
    body(ctx(90 * MS))
    assert state.sonar_range == math.inf and state.sonar_rx_ns == 85 * MS
    # a stamp from the future (a clock step) is taken as now, never younger
    rig.write('sonar', p.Kind.SONAR, 0.0, p.SONAR_NO_ECHO, stamp=500 * MS)
    body(ctx(100 * MS))
    assert state.sonar_rx_ns == 100 * MS
    # a timeout does not refresh the reading: it can go stale
    rig.write('sonar', p.Kind.SONAR, 0.0, p.SONAR_TIMEOUT)
    body(ctx(120 * MS))
    assert state.sonar_rx_ns == 100 * MS
    assert state.sonar_status == p.SONAR_TIMEOUT
    assert body.failed == 1
    assert len(rig.read_all('sonar_out')) == 3    # every reply is forwarded to the bridge


def _scan(front_mm):
    ranges = [4000] * 683
    ranges[384] = front_mm                        # index 384 is 0 deg for the URG-04LX
    inc = math.radians(360.0 / 1024)
    return (-384 * inc, inc, 0.02, 5.6, 0.1, 0.1 / 1024, 1234, ranges)


def test_lrf_front_sector_minimum_reaches_the_state(ports):
    rig = ports('lrf', 'lrf_out')
    state = RobotState()
    body = LrfBody(rig.rt['lrf'], rig.rt['lrf_out'], state, half_width=0.19)
    body(ctx(200 * MS))
    (h, req), = rig.read_all('lrf')
    assert req.arg == SCAN_REQUEST
    data = p.encode(p.Kind.LASER_SCAN, 5, 250 * MS, *_scan(800))
    rig.nrt['lrf'].write(data)
    body(ctx(400 * MS))
    assert state.laser_front_min == pytest.approx(0.8)
    assert state.laser_rx_ns == 250 * MS          # the scan's own stamp: its sweep's start
    assert state.laser_sighting.gap == pytest.approx(0.8)
    assert not state.laser_sighting.unknown
    assert rig.nrt['lrf_out'].read(timeout=1.0) == data
    rig.nrt['lrf'].write(b'MK\x01\x07' + b'\x00' * 40)   # truncated scan: counted, ignored
    body(ctx(600 * MS))
    assert rig.rt['lrf'].counters.malformed == 1
    assert state.laser_rx_ns == 250 * MS


def _shown(rig):
    return [m for h, m in rig.read_all('led')]


def test_led_shows_state_and_bridge_override_until_release(ports):
    rig = ports('led', 'led_in')
    state = RobotState()
    body = LedBody(rig.rt['led'], rig.rt['led_in'], state)
    state.mode = MODE_IDLE
    body(ctx(20 * MS))
    assert _shown(rig)[-1] == p.Led(*led_mod.IDLE, 0)
    assert rig.read_all('led_in')[-1][1] == p.Led(*led_mod.IDLE, 0)   # echoed
    state.mode = MODE_DRIVING
    body(ctx(40 * MS))
    assert _shown(rig)[-1] == p.Led(*led_mod.DRIVING, 0)
    state.mode = MODE_BRAKING
    body(ctx(60 * MS))
    assert _shown(rig)[-1] == p.Led(*led_mod.BRAKING, 0)
    rig.write('led_in', p.Kind.LED, 10, 20, 30, 99, 1)
    body(ctx(80 * MS))
    assert _shown(rig)[-1] == p.Led(10, 20, 30, 99, 1)
    assert state.led_override
    state.mode = MODE_DRIVING
    body(ctx(100 * MS))
    assert _shown(rig)[-1] == p.Led(10, 20, 30, 99, 1)      # override holds
    rig.write('led_in', p.Kind.LED, 0, 0, 0, 0, 0)            # release
    body(ctx(120 * MS))
    assert _shown(rig)[-1] == p.Led(*led_mod.DRIVING, 0)
    echoes = [m for h, m in rig.read_all('led_in')]
    assert p.Led(10, 20, 30, 99, 1) in echoes
    assert echoes[-1] == p.Led(*led_mod.DRIVING, 0)
    # unchanged colour: no echo until a second has passed
    body(ctx(140 * MS))
    assert rig.read_all('led_in') == []
    body(ctx(1200 * MS))
    assert len(rig.read_all('led_in')) == 1


def test_led_blinks_on_fault_and_device_error(ports):
    rig = ports('led', 'led_in')
    state = RobotState()
    body = LedBody(rig.rt['led'], rig.rt['led_in'], state)
    state.mode = MODE_FAULT
    brightness = []
    for k in range(1, 51):                     # 1 s at 20 ms
        body(ctx(k * 20 * MS))
        brightness.append(_shown(rig)[-1].brightness)
    assert set(brightness) == {0, 255}
    assert sum(1 for a, b in zip(brightness, brightness[1:], strict=False) if a != b) in (3, 4)
    state.mode = MODE_IDLE
    rig.write('led', p.Kind.DEVICE_STATUS, 'led', 3, p.LEVEL_ERROR, 1, 5)
    body(ctx(2000 * MS))
    assert state.led_level == p.LEVEL_ERROR
    assert _shown(rig)[-1][:3] == (255, 0, 0)


def test_sonar_reading_stops_the_actuator_on_its_next_cycle(ports):
    rig = ports('cmd', 'motor', 'sonar', 'sonar_out')
    state = RobotState()
    params = control_params({'guard': {'use_laser': False}})
    act = ActuatorBody(rig.rt['cmd'], rig.rt['motor'], state, params, 0.01)
    son = SonarBody(rig.rt['sonar'], rig.rt['sonar_out'], state)
    motor = FakeMotor(rig, params.full_scale_wheel_speed)
    sonar_range = [2.0]
    t = 0
    stopped_at = None
    obstacle_reply_at = None
    for k in range(300):
        t += 10 * MS
        if k % 5 == 0:
            rig.write('cmd', p.Kind.VELOCITY_CMD, 0.25, 0.0)
        # rate-monotonic order at a common release: the actuator runs before the sonar task
        act(ctx(t))
        motor.serve(t + 2 * MS)
        if k % 3 == 0:
            for _ in rig.read_all('sonar'):  # fake sonar handler answers each trigger
                rng = sonar_range[0]
                rig.write('sonar', p.Kind.SONAR, rng, p.SONAR_OK, stamp=t)
                if rng < 0.35 and obstacle_reply_at is None:
                    obstacle_reply_at = k
            son(ctx(t + MS))
        if k == 150:
            assert act.ctl.v == pytest.approx(0.25)
            sonar_range[0] = 0.3
        if obstacle_reply_at is not None and stopped_at is None and act.ctl.v == 0.0:
            stopped_at = k
    assert obstacle_reply_at is not None
    # the sonar task read the reply at tick obstacle_reply_at; the actuator's next cycle
    # (10 ms later) already limits forward velocity to zero
    assert stopped_at == obstacle_reply_at + 1
    assert state.guard_active


@pytest.mark.parametrize('device, ports_, make', [
    ('motor', ('cmd', 'motor'),
     lambda r, s: ActuatorBody(r.rt['cmd'], r.rt['motor'], s, control_params(None), 0.01)),
    ('imu', ('imu', 'imu_out'), lambda r, s: ImuBody(r.rt['imu'], r.rt['imu_out'], s)),
    ('led', ('led', 'led_in'), lambda r, s: LedBody(r.rt['led'], r.rt['led_in'], s)),
    ('sonar', ('sonar', 'sonar_out'),
     lambda r, s: SonarBody(r.rt['sonar'], r.rt['sonar_out'], s)),
    ('lrf', ('lrf', 'lrf_out'), lambda r, s: LrfBody(r.rt['lrf'], r.rt['lrf_out'], s)),
])
def test_device_task_keeps_the_last_device_status_and_when_it_arrived(ports, device, ports_,
                                                                      make):
    rig = ports(*ports_)
    state = RobotState()
    body = make(rig, state)
    status_attr, rx_attr = DEVICE_SLOTS[device]
    body(ctx(10 * MS))
    assert getattr(state, status_attr) is None and getattr(state, rx_attr) == 0
    dev_port = ports_[1] if device == 'motor' else ports_[0]
    rig.write(dev_port, p.Kind.DEVICE_STATUS, device, 3, p.LEVEL_WARN, 1, 4)
    rig.write(dev_port, p.Kind.DEVICE_STATUS, device, 5, p.LEVEL_ERROR, 2, 6)
    body(ctx(20 * MS))
    assert getattr(state, status_attr) == p.DeviceStatus(device, 5, p.LEVEL_ERROR, 2, 6)
    assert getattr(state, rx_attr) == 20 * MS
    body(ctx(30 * MS))                               # nothing new: kept, arrival unchanged
    assert getattr(state, status_attr).faults == 2 and getattr(state, rx_attr) == 20 * MS
