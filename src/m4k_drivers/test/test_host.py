import os
import re
import signal
import threading
import time

import pytest
from rt_side import recv_kind, wait_linked

from m4k_drivers import config as dconfig
from m4k_drivers import registry
from m4k_drivers.handler import State
from m4k_drivers.host import DeviceService, main
from m4k_rt import protocol
from m4k_rt.channel import rt_xddp_bind

pytestmark = pytest.mark.e2e  # starts processes / ROS nodes: the end-to-end tier

CONFIG = str(dconfig.default_config_path())


def _run(procs, *args, timeout=40):
    proc = procs.start(['python', '-m', 'm4k_drivers.host', '--config', CONFIG, *args])
    out, err = proc.communicate(timeout=timeout)
    return proc.returncode, out, err


def test_print_imu_sim_prints_plausible_values(procs, sim_robot):
    rc, out, err = _run(procs, '--device', 'imu', '--print', '--count', '5', '--rate', '50')
    assert rc == 0, err
    lines = [ln for ln in out.splitlines() if ln.startswith('imu ')]
    assert len(lines) == 5
    for ln in lines:
        az = float(re.search(r'acc=\([^,]+,[^,]+,([^)]+)\)', ln).group(1))
        yaw = float(re.search(r'rpy=\([^,]+,[^,]+,([^)]+)\)', ln).group(1))
        assert 9.6 < az < 10.0 and abs(yaw) < 1.0 and ln.endswith('status=0')


def test_print_sonar_sim_sees_obstacle(procs, sim_robot):
    rc, out, err = _run(procs, '--device', 'sonar', '--print', '--count', '3', '--rate', '20')
    assert rc == 0, err
    ranges = [float(m) for m in re.findall(r'sonar range=([\d.]+) m status=0 \(ok\)', out)]
    # triangle face 1.5 m ahead, sensor 0.225 m ahead of base_link, noise sd 3 mm
    assert len(ranges) == 3 and all(abs(r - 1.275) < 0.02 for r in ranges)


def test_print_unknown_backend_exits_2_naming_field(procs):
    rc, out, err = _run(procs, '--device', 'imu', '--backend', 'i2c', '--print')
    assert rc == 2
    assert "devices.imu.backend: unknown backend 'i2c' for device 'imu'; " \
           'valid backends: real, sim' in err


def test_print_missing_bus_exits_1_naming_path(procs):
    rc, out, err = _run(procs, '--device', 'imu', '--bus', '97', '--print', '--count', '1')
    assert rc == 1
    assert '/dev/i2c-97: No such file or directory (errno 2)' in err


def _serving_host(procs):
    """Start a host serving the motors and the LED; return (proc, motor pid, LED pid)."""
    proc = procs.start(['python', '-m', 'm4k_drivers.host', '--config', CONFIG,
                        '--device', 'motor', '--device', 'led'])
    deadline = time.monotonic() + 30
    seen = ''
    while time.monotonic() < deadline and seen.count('serving') < 2:
        seen += proc.stderr.readline()
    motor = re.search(r'serving motor@motor \(pid (\d+)\)', seen)
    led = re.search(r'serving led@led \(pid (\d+)\)', seen)
    assert motor and led, seen
    return proc, int(motor.group(1)), int(led.group(1))


def test_host_sigterm_exits_0(procs, sim_robot, m4k_runtime_dir):
    # The motors (sched_priority > 0) in a process of their own, the LED in the host's;
    # devices.yaml alone: each found by its label.
    proc, child, led = _serving_host(procs)
    assert led == proc.pid and child != proc.pid
    assert procs.stop(proc) == 0, proc.stderr.read()
    with pytest.raises(ProcessLookupError):      # the parent reaped its device process
        os.kill(child, 0)


def test_a_group_stop_the_device_process_acts_on_first_still_exits_0(procs, sim_robot,
                                                                     m4k_runtime_dir):
    # The worst order of a stop signal to the whole group (the CI saw it under load): the
    # motor process (SCHED_FIFO) has stopped and been reaped before the host's own handler ran.
    proc, child, _ = _serving_host(procs)
    os.kill(child, signal.SIGTERM)
    time.sleep(0.6)                              # the host's supervision poll has reaped it
    os.kill(proc.pid, signal.SIGTERM)
    assert proc.wait(timeout=30) == 0, proc.stderr.read()


@pytest.mark.parametrize('sig', [signal.SIGTERM, signal.SIGKILL], ids=['stopped', 'killed'])
def test_a_device_process_gone_alone_ends_the_host_with_exit_1(procs, sim_robot,
                                                               m4k_runtime_dir, sig):
    # The supervisor (bringup) watches the host's pid only: a motor process gone on its own
    # (killed, or stopped alone: exit 0 without a stop of the host) must not leave a host that
    # serves the sensors but never the wheels; it ends, and its supervisor restarts all of it.
    proc, child, _ = _serving_host(procs)
    os.kill(child, sig)
    assert proc.wait(timeout=30) == 1
    code = 0 if sig == signal.SIGTERM else -sig
    assert f'device process motor (pid {child}) exited {code}: stopping the driver host' in \
        proc.stderr.read()


def test_motor_service_serves_wheel_cmd_relinks_and_stops_safe(m4k_runtime_dir, sim_robot):
    cfg = dconfig.validate({'devices': {'motor': {'backend': 'sim'}}})
    ctx = registry.BuildContext()
    handler = registry.create('motor', cfg.devices['motor'], ctx)
    stop = threading.Event()
    rt = rt_xddp_bind(2, runtime_dir=m4k_runtime_dir)
    svc = DeviceService('motor', handler, cfg.devices['motor'], 2, stop, m4k_runtime_dir)
    svc.start()
    try:
        wait_linked(rt)
        st = recv_kind(rt, protocol.Kind.DEVICE_STATUS)
        assert st.device == 'motor'
        rt.send(protocol.encode(protocol.Kind.WHEEL_CMD, 1, time.monotonic_ns(), 700, 700, 1))
        enc = recv_kind(rt, protocol.Kind.ENCODERS)
        assert 0 <= enc.left_raw < 4096 and enc.status & 0x10 == 0
        assert handler.codes == (700, 700)
        rt.send(b'garbage')
        rt.send(protocol.encode(protocol.Kind.REQUEST, 2, 0, 1, 0))
        deadline = time.monotonic() + 5
        while svc.malformed < 1 or svc.unexpected < 1:
            assert time.monotonic() < deadline
            time.sleep(0.01)
        # RT side goes away: motors safe at once, then the host relinks to a new RT side
        rt.close()
        deadline = time.monotonic() + 5
        while handler.codes != (512, 512):
            assert time.monotonic() < deadline, 'motors not made safe after RT loss'
            time.sleep(0.01)
        rt = rt_xddp_bind(2, runtime_dir=m4k_runtime_dir)
        wait_linked(rt, timeout=10)
        rt.send(protocol.encode(protocol.Kind.WHEEL_CMD, 3, time.monotonic_ns(), 600, 600, 1))
        recv_kind(rt, protocol.Kind.ENCODERS)
        assert svc.link.relinks >= 1
    finally:
        stop.set()
        svc.thread.join(5)
        rt.close()
    assert not svc.thread.is_alive()
    assert handler.state == State.FINALIZED
    world = sim_robot.world      # the simulator's DACs latched the safe word
    assert world.motor_voltage(0) == 0.0 and world.motor_voltage(1) == 0.0


def test_a_wheel_cmd_older_than_two_periods_is_dropped_not_replayed(m4k_runtime_dir, sim_robot):
    # After a driver-host stall the socket holds commands the RT side sent long ago: replayed,
    # each would drive the DACs and toggle the heartbeat, re-enabling a dropped amplifier.
    cfg = dconfig.validate({'devices': {'motor': {'backend': 'sim'}}})
    handler = registry.create('motor', cfg.devices['motor'], registry.BuildContext())
    stop = threading.Event()
    rt = rt_xddp_bind(2, runtime_dir=m4k_runtime_dir)
    svc = DeviceService('motor', handler, cfg.devices['motor'], 2, stop, m4k_runtime_dir)
    svc.start()
    try:
        wait_linked(rt)
        recv_kind(rt, protocol.Kind.DEVICE_STATUS)
        edges = sim_robot.enable.edges
        old = time.monotonic_ns() - round(3 * cfg.devices['motor']['period_s'] * 1e9)
        for seq in (1, 2, 3):
            rt.send(protocol.encode(protocol.Kind.WHEEL_CMD, seq, old, 900, 900, 1))
        deadline = time.monotonic() + 5
        while svc.stale < 3:
            assert time.monotonic() < deadline, f'stale {svc.stale}, served {svc.served}'
            time.sleep(0.01)
        assert svc.served == 0 and handler.codes == (512, 512)
        assert sim_robot.enable.edges == edges and not sim_robot.world.drive_enabled()
        rt.send(protocol.encode(protocol.Kind.WHEEL_CMD, 4, time.monotonic_ns(), 700, 700, 1))
        recv_kind(rt, protocol.Kind.ENCODERS)          # a fresh one is served
        assert handler.codes == (700, 700) and svc.served == 1
    finally:
        stop.set()
        svc.thread.join(5)
        rt.close()


def test_sensor_and_led_services_answer(m4k_runtime_dir, sim_robot):
    kinds = (('sonar', 7), ('led', 5), ('imu', 3), ('lrf', 9))
    cfg = dconfig.validate({'devices': {k: {'backend': 'sim'} for k, _ in kinds}})
    ctx = registry.BuildContext()
    stop = threading.Event()
    rts = {k: rt_xddp_bind(p, runtime_dir=m4k_runtime_dir) for k, p in kinds}
    handlers = {k: registry.create(k, cfg.devices[k], ctx) for k in rts}
    svcs = [DeviceService(k, handlers[k], cfg.devices[k], rts[k].port, stop, m4k_runtime_dir)
            for k in rts]
    for s in svcs:
        s.start()
    try:
        for rt in rts.values():
            wait_linked(rt)
        rts['sonar'].send(protocol.encode(protocol.Kind.REQUEST, 1, 0, 1, 1))
        sonar = recv_kind(rts['sonar'], protocol.Kind.SONAR)
        assert sonar.status == 0 and abs(sonar.range_m - 1.275) < 0.02
        rts['imu'].send(protocol.encode(protocol.Kind.REQUEST, 1, 0, 1, 0))
        imu = recv_kind(rts['imu'], protocol.Kind.IMU)
        assert 9.6 < imu.az < 10.0 and abs(imu.qw) > 0.99 and imu.status == 0
        rts['lrf'].send(protocol.encode(protocol.Kind.REQUEST, 1, 0, 1, 0))
        scan = recv_kind(rts['lrf'], protocol.Kind.LASER_SCAN, timeout=10)
        front = scan.ranges[len(scan.ranges) // 2]
        assert len(scan.ranges) > 600 and abs(front - 1500) < 60     # obstacle face, mm
        strip = sim_robot.leds          # the LED-class files the simulator watches
        rts['led'].send(protocol.encode(protocol.Kind.LED, 1, 0, 255, 128, 0, 200, 0))
        want = pytest.approx((200 / 255, 128 * 200 / 255 ** 2, 0.0))
        deadline = time.monotonic() + 5
        while strip.poll() != want:
            assert time.monotonic() < deadline, strip.levels
            time.sleep(0.01)
    finally:
        stop.set()
        for s in svcs:
            s.thread.join(5)
        for rt in rts.values():
            rt.close()
    assert strip.poll() == (0.0, 0.0, 0.0) and strip.errors == 0    # deactivate: off


def test_a_crashed_service_ends_the_host_with_exit_1_outputs_safe(m4k_runtime_dir, sim_robot,
                                                                   monkeypatch, caplog):
    # A bug in a service thread is not a stop: the host does not go on serving the rest.
    from m4k_drivers import host

    def boom(self, force=False):
        raise RuntimeError('a bug')

    monkeypatch.setattr(DeviceService, '_send_status', boom)
    cfg = dconfig.validate({'devices': {'led': {'backend': 'sim'}}})
    handler = registry.create('led', cfg.devices['led'], registry.BuildContext())
    stop = threading.Event()
    rc = []
    serve = threading.Thread(target=lambda: rc.append(
        host._serve({'led': handler}, cfg, {}, {}, m4k_runtime_dir, stop)))
    serve.start()
    serve.join(10)
    stop.set()                                   # (bounds the test if the host went on)
    serve.join(10)
    assert rc == [1] and handler.state == State.FINALIZED
    assert 'service led crashed: stopping the driver host' in caplog.text


def test_main_rejects_print_without_single_device(capsys):
    assert main(['--config', CONFIG, '--print']) == 2
    assert '--print needs exactly one enabled --device' in capsys.readouterr().err


@pytest.mark.hardware
def test_print_real_lrf(procs):
    rc, out, err = _run(procs, '--device', 'lrf', '--port', '/dev/ttyACM0', '--print',
                        '--count', '3')
    assert rc == 0 and out.count('lrf seq=') == 3


def test_world_report_tracks_ground_truth_and_counts_a_collision(procs, m4k_runtime_dir,
                                                                 sim_robot):
    import json
    import pathlib
    report = pathlib.Path(sim_robot.report_path)
    rt = rt_xddp_bind(2, 'motor')
    proc = procs.start(['python', '-m', 'm4k_drivers.host', '--config', CONFIG,
                        '--device', 'motor'])
    try:
        wait_linked(rt, timeout=30)
        buf = bytearray(64)
        seq = 0
        deadline = time.monotonic() + 30
        doc = {}
        while time.monotonic() < deadline:
            seq += 1  # full forward on both wheels: straight into the triangle 1.5 m ahead
            n = protocol.encode_into(buf, 0, protocol.Kind.WHEEL_CMD, seq, time.monotonic_ns(),
                                     1023, 1023, 1)
            rt.send(bytes(buf[:n]))
            while rt.recv() is not None:
                pass
            time.sleep(0.02)
            if report.exists():
                doc = json.loads(report.read_text())
                # in contact flickers while the wheels creep into the face: wait for it
                if doc['collisions'] >= 1 and doc['in_contact']:
                    break
        assert doc.get('collisions', 0) >= 1, doc
        assert doc['in_contact'] is True
        assert 1.0 < doc['pose'][0] < 1.6, doc  # stopped by the obstacle's face at x = 1.5 m
    finally:
        procs.stop(proc)
        rt.close()


@pytest.mark.parametrize('kind, pattern', [
    ('motor', r'^motor raw=\(\d+,\d+\) angle=\([+-]\d+\.\d+,[+-]\d+\.\d+\) rad status=0x'),
    ('imu', r'^imu rpy=\('),
    ('sonar', r'^sonar range=\d+\.\d+ m status=\d \('),
    ('led', r'^led shown=#000000@0$'),
    ('lrf', r'^lrf seq=\d+ n=682 valid=\d+ '),
])
def test_print_works_for_every_device(capsys, sim_robot, kind, pattern):
    assert set(registry.kinds()) == {'motor', 'imu', 'sonar', 'led', 'lrf'}
    assert main(['--config', CONFIG, '--device', kind, '--print', '--count', '2',
                 '--rate', '20']) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 2 and all(re.match(pattern, line) for line in lines), lines


def test_simulated_sensors_are_mounted_where_the_robot_description_says(tmp_path):
    from m4k_drivers.host import load_raw_config
    overlay = tmp_path / 'moved.yaml'
    overlay.write_text('robot:\n  sensors:\n    laser:\n      frame: laser\n'
                       '      pose: [0.12, -0.03, 0.3, 0.0, 0.0, 0.5]\n')
    raw = load_raw_config(None, str(overlay))
    assert raw['devices']['lrf']['mount'] == pytest.approx([0.12, -0.03, 0.5])
    sonar = raw['robot']['sensors']['sonar']['pose']
    assert raw['devices']['sonar']['mount'] == pytest.approx([sonar[0], sonar[1], sonar[5]])
