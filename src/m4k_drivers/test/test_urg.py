"""Driver <-> simulated URG over a real pseudo terminal through pyserial."""

import math
import os
import time

import numpy as np
import pytest

from m4k_drivers import registry
from m4k_drivers.handler import DeviceNotFoundError, State, Status
from m4k_drivers.lrf import scip
from m4k_drivers.lrf.backends import urg_opener
from m4k_drivers.lrf.handler import LrfHandler
from m4k_drivers.lrf.sim import RectRoom, UrgSim
from m4k_drivers.lrf.urg import (
    UrgDriver,
    UrgIOError,
    UrgPortError,
    UrgProtocolError,
    UrgTimeoutError,
)

AHEAD = 384 - 44            # index of the front step in a full 44..725 scan
NOISE_MM = 5.0


@pytest.fixture
def room():
    # 4 m x 3 m room, sensor in the middle facing +x: wall 2.0 m ahead, 1.5 m left/right.
    return RectRoom(-2.0, -1.5, 2.0, 1.5)


@pytest.fixture
def sim(room, tmp_path):
    device = UrgSim(room, link_path=str(tmp_path / 'ttyACM0'), noise_mm=NOISE_MM, seed=1,
                    scan_period=0.02)
    device.start()
    yield device
    device.stop()


@pytest.fixture
def driver(sim):
    drv = UrgDriver(sim.path, timeout=1.0, error_limit=3, reconnect_delay=0.05)
    yield drv
    drv.close()


# Bounds on waits only: a loaded 2-core VM may hold a thread for seconds, a healthy run never
# comes near them (a 10 Hz stream). Nothing here is a timing assertion.
WAIT_S = 10.0


def _wait(predicate, timeout=WAIT_S):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return predicate()


def test_connect_sequence_reads_geometry_from_pp(sim, driver):
    driver.open()
    assert [c for c in ('SCIP2.0', 'QT', 'VV', 'PP', 'II', 'BM') if sim.command_codes[c] == 1] \
        == ['SCIP2.0', 'QT', 'VV', 'PP', 'II', 'BM']
    assert (driver.spec.amin, driver.spec.amax, driver.spec.afrt, driver.spec.ares) == (
        44, 725, 384, 1024)
    assert driver.geometry.count == 682
    assert driver.version['PROT'] == 'SCIP 2.0'
    assert driver.status['LASR'] == 'OFF'        # II comes before BM


def test_reconnect_tolerates_device_already_in_scip2(sim, driver):
    driver.open()
    driver.close()
    driver.open()                                 # second SCIP2.0 is answered 0E
    assert sim.command_codes['SCIP2.0'] == 2
    assert driver.get_scan().ranges_mm.size == 682


def test_gd_scan_of_rectangle_room(driver):
    driver.open()
    scan = driver.get_scan()
    assert scan.ranges_mm.size == 682
    assert abs(int(scan.ranges_mm[AHEAD]) - 2000) <= 5 * NOISE_MM
    assert abs(int(scan.ranges_mm[AHEAD + 256]) - 1500) <= 5 * NOISE_MM     # +90 deg, left
    assert abs(int(scan.ranges_mm[AHEAD - 256]) - 1500) <= 5 * NOISE_MM     # -90 deg, right
    assert scan.geometry.angle_min == pytest.approx(-340 * 2 * math.pi / 1024)
    assert driver.stats().scans == 1


def test_md_stream_delivers_successive_scans(sim, driver):
    driver.open()
    driver.start_stream()
    seen = []
    while len(seen) < 5:
        scan = driver.wait_scan(seen[-1].seq if seen else 0, timeout=WAIT_S)
        assert scan is not None
        seen.append(scan)
    driver.stop_stream()
    assert [s.seq for s in seen] == sorted({s.seq for s in seen})
    assert all(b.stamp_ms > a.stamp_ms for a, b in zip(seen, seen[1:], strict=False))
    assert all(abs(int(s.ranges_mm[AHEAD]) - 2000) <= 5 * NOISE_MM for s in seen)
    assert sim.command_codes['MD'] == 1 and sim.command_codes['QT'] == 2


def test_corrupted_gd_checksum_is_counted_and_next_scan_recovers(sim, driver):
    driver.open()
    sim.corrupt_next_checksums(1)
    with pytest.raises(UrgProtocolError, match='checksum'):
        driver.get_scan()
    assert driver.stats().checksum_errors == 1
    assert driver.get_scan().ranges_mm.size == 682
    assert driver.stats().consecutive_errors == 0


def test_corrupted_stream_checksums_are_counted_and_stream_continues(sim, driver):
    driver.open()
    driver.start_stream()
    first = driver.wait_scan(0, WAIT_S)
    sim.corrupt_next_checksums(2)
    assert _wait(lambda: driver.stats().checksum_errors == 2)
    later = driver.wait_scan(first.seq + 1, WAIT_S)
    assert later is not None
    assert driver.stats().reconnects == 0          # 2 < error_limit 3


def test_stray_bytes_are_skipped_and_counted(sim, driver):
    driver.open()
    junk = b'\x00\xff noise \x10'
    sim.inject_stray(junk)
    assert driver.get_scan().ranges_mm.size == 682
    assert driver.stats().stray_bytes == len(junk)


def test_unplug_and_replug_at_same_symlink_reconnects_stream(sim, driver, tmp_path):
    link = str(tmp_path / 'ttyACM0')
    assert driver.port == link
    driver.open()
    driver.start_stream()
    before = driver.wait_scan(0, WAIT_S)
    sim.unplug()
    assert not os.path.exists(link)
    assert _wait(lambda: driver.stats().io_errors >= 1)
    # A scan that arrived between ``before`` and the unplug is not one from after the replug:
    # wait for one newer than the last scan the driver had when the stream broke.
    stale = driver.latest()
    assert stale is not None and stale.seq >= before.seq
    sim.replug()
    assert os.readlink(link) == sim.slave_path and sim.plugs == 2
    after = driver.wait_scan(stale.seq, WAIT_S)
    assert after is not None
    stats = driver.stats()
    assert stats.reconnects == 1
    assert sim.command_codes['SCIP2.0'] == 2     # the connect sequence ran again
    assert abs(int(after.ranges_mm[AHEAD]) - 2000) <= 5 * NOISE_MM


def test_unplug_and_replug_in_poll_mode(sim, driver):
    driver.open()
    driver.get_scan()
    sim.unplug()
    with pytest.raises(UrgIOError, match='ttyACM0'):
        driver.get_scan()
    with pytest.raises(UrgIOError, match='reconnect failed'):
        driver.get_scan()                            # the link is gone until replug
    sim.replug()
    assert _wait(lambda: _try_scan(driver))
    assert driver.stats().reconnects == 1


def _try_scan(driver):
    try:
        driver.get_scan()
    except Exception:  # noqa: BLE001 - the retry loop of the test
        return False
    return True


def test_error_limit_triggers_reconnect(sim, driver):
    driver.open()
    driver.start_stream()
    first = driver.wait_scan(0, WAIT_S)
    sim.corrupt_next_checksums(3)                  # error_limit is 3
    assert _wait(lambda: driver.stats().reconnects == 1)
    assert driver.wait_scan(first.seq + 1, WAIT_S) is not None
    assert driver.stats().checksum_errors == 3
    assert sim.command_codes['SCIP2.0'] == 2 and sim.command_codes['MD'] == 2


def test_timestamps_unwrap_across_device_counter_wrap(room, tmp_path):
    with UrgSim(room, scan_period=0.05, timestamp_start=scip.TIMESTAMP_MODULO - 200) as dev:
        drv = UrgDriver(dev.path, timeout=0.5)
        try:
            drv.open()
            drv.start_stream()
            scans = []
            while len(scans) < 8:
                scan = drv.wait_scan(scans[-1].seq if scans else 0, WAIT_S)
                assert scan is not None
                scans.append(scan)
        finally:
            drv.close()
    raw = [s.device_stamp for s in scans]
    assert any(b < a for a, b in zip(raw, raw[1:], strict=False))  # 24-bit wrap
    assert all(b.stamp_ms > a.stamp_ms for a, b in zip(scans, scans[1:], strict=False))


def test_silent_device_times_out():
    master, slave = os.openpty()
    try:
        drv = UrgDriver(os.ttyname(slave), timeout=0.2)
        with pytest.raises(UrgTimeoutError, match='SCIP2.0'):
            drv.open()
        assert drv.stats().timeouts == 1
        assert not drv.connected
    finally:
        os.close(master)
        os.close(slave)


def test_missing_port_error_names_the_path(tmp_path):
    path = str(tmp_path / 'no' / 'ttyACM9')
    drv = UrgDriver(path)
    with pytest.raises(UrgPortError, match='ttyACM9') as info:
        drv.open()
    assert info.value.path == path
    assert isinstance(info.value, DeviceNotFoundError)


# --- handler ------------------------------------------------------------------------------------

def test_handler_lifecycle_on_an_opener_of_the_sim_pty(room, tmp_path):
    link = str(tmp_path / 'ttyACM0')
    with UrgSim(room, link_path=link, scan_period=0.02, noise_mm=0.0) as dev:
        h = LrfHandler(urg_opener(link, {'timeout': 0.5}))
        try:
            assert h.driver is None                   # nothing opened before configure()
            h.configure()
            assert h.state == State.INACTIVE and h.driver.connected
            h.activate()
            r1 = h.read()
            assert r1.status == Status.OK and r1.value.fresh
            assert int(r1.value.ranges_mm[AHEAD]) == 2000
            assert r1.value.geometry.count == 682
            r2 = h.read()
            assert r2.value.fresh == (r2.value.seq != r1.value.seq)
            qt_before = dev.command_codes['QT']
        finally:
            h.shutdown()
        assert h.state == State.FINALIZED and h.driver is None
        assert dev.command_codes['QT'] > qt_before    # stream stopped, laser off on cleanup


def test_handler_poll_mode_reads_one_gd_per_read(room):
    with UrgSim(room, noise_mm=0.0) as dev:
        h = LrfHandler(urg_opener(dev.path, {}), mode='poll')
        try:
            h.configure()
            h.activate()
            readings = [h.read() for _ in range(3)]
            assert [r.value.seq for r in readings] == [1, 2, 3]
            assert all(r.value.fresh for r in readings)
            assert dev.command_codes['GD'] == 3
        finally:
            h.shutdown()


def test_handler_rejects_an_unknown_mode():
    with pytest.raises(ValueError, match="lrf.mode: must be one of stream, poll, got 'scan'"):
        LrfHandler(urg_opener('/dev/ttyACM0', {}), mode='scan')


def test_real_backend_with_missing_port_fails_configure_naming_it(tmp_path):
    from m4k_drivers import config as dconfig
    section = {'backend': 'real', 'port': str(tmp_path / 'ttyACM0')}
    h = registry.create('lrf', dconfig.validate({'devices': {'lrf': section}}).devices['lrf'],
                        registry.BuildContext())
    assert isinstance(h, LrfHandler)
    with pytest.raises(DeviceNotFoundError, match='ttyACM0'):
        h.configure()
    assert h.state == State.ERROR


def test_registry_sim_backend_reads_the_sim_robot_world(m4k_runtime_dir):
    from m4k_drivers import config as dconfig
    from m4k_drivers.sim_robot import SimRobot
    from m4k_rt.channel import ensure_runtime_dir
    section = {'backend': 'sim', 'noise_mm': 0.0, 'scan_period': 0.02, 'mode': 'poll'}
    rd = ensure_runtime_dir(m4k_runtime_dir)
    robot = SimRobot(dconfig.validate({'devices': {'lrf': section}}), rd).start()
    ctx = registry.BuildContext(runtime_dir=rd)
    h = registry.create('lrf', dconfig.validate({'devices': {'lrf': section}}).devices['lrf'],
                        ctx)
    try:
        h.configure()
        h.activate()
        reading = h.read().value
        world = robot.world
        x, y, yaw = world.pose()
        expected = world.raycast_many((x, y), [yaw], 5.6)[0] * 1000.0
        got = int(reading.ranges_mm[AHEAD])
        if np.isfinite(expected):
            assert got == round(expected)
        else:
            assert got < scip.RANGE_ERROR_LIMIT
    finally:
        h.shutdown()
        robot.close()


@pytest.mark.hardware
def test_real_urg04lx_on_ttyacm0():
    drv = UrgDriver('/dev/ttyACM0', timeout=2.0)
    try:
        drv.open()
        scan = drv.get_scan()
        assert scan.ranges_mm.size == drv.geometry.count
        assert drv.spec.model.startswith('URG-04LX')
    finally:
        drv.close()
