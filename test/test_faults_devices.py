"""Device faults through the driver host's DeviceService: counted, diagnosed, recovered.

Each test runs one real DeviceService (the driver host's per-device thread, sim backend, talking
to an in-process SimRobot over the sim-bus) against an RT side played by the test over a real
XDDP port, then injects a fault into the simulated device: an RT process that hangs or dies
(motor watchdog), encoder frame errors and jumps, a sonar that never answers, a laser unplugged
and replugged, bad checksums and line noise.
Nothing stale may be sent as fresh; every fault must show up in the counters and in
DEVICE_STATUS; the device must recover without a restart.
"""

import math
import threading
import time

import pytest

from m4k_drivers import config as dconfig
from m4k_drivers import registry
from m4k_drivers.handler import State
from m4k_drivers.host import DeviceService, load_raw_config
from m4k_drivers.motors import protocol as mp
from m4k_drivers.sim_robot import SimRobot
from m4k_rt import channel, protocol
from m4k_rt.protocol import EncoderStatus

K = protocol.Kind
PORTS = {'motor': 2, 'imu': 3, 'sonar': 7, 'lrf': 9}


class Rig:
    """One DeviceService and the test's RT side of its port."""

    def __init__(self, kind: str, runtime_dir: str, **overrides):
        raw = load_raw_config()
        devices = {kind: dict(raw['devices'][kind], **overrides)}
        cfg = dconfig.validate({'devices': devices, 'world': raw.get('world') or {}})
        self.robot = SimRobot(cfg, channel.ensure_runtime_dir(runtime_dir)).start()
        self.ctx = registry.BuildContext(runtime_dir=runtime_dir)
        self.handler = registry.create(kind, cfg.devices[kind], self.ctx)
        self.rt = channel.rt_xddp_bind(PORTS[kind], kind, runtime_dir=runtime_dir)
        self.stop = threading.Event()
        self.runtime_dir = runtime_dir
        self.svc = DeviceService(kind, self.handler, cfg.devices[kind], kind, self.stop,
                                 runtime_dir)
        self.buf = bytearray(8192)
        self.seq = 0
        self.svc.start()

    def send(self, kind, *fields):
        self.seq += 1
        return self.rt.send(protocol.encode(kind, self.seq, time.monotonic_ns(), *fields))

    def drain(self):
        out = []
        while True:
            n = self.rt.recv_into(self.buf)
            if not n:
                return out
            out.append(protocol.decode(bytes(self.buf[:n])))

    def run(self, seconds, kind=None, fields=(), period=0.01):
        """Act as the RT task for ``seconds``: send one datagram per period, collect replies."""
        got = []
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            if kind is not None:
                self.send(kind, *fields)
            time.sleep(period)
            got += self.drain()
        return got

    def until(self, pred, kind=None, fields=(), timeout=5.0, period=0.01):
        """Like run(), but until ``pred()`` holds (a noisy VM delays the host's thread)."""
        got = []
        end = time.monotonic() + timeout
        while not pred():
            assert time.monotonic() < end, 'condition not reached within {} s'.format(timeout)
            got += self.run(period, kind, fields, period)
        return got

    def wait_linked(self, timeout=10.0):
        end = time.monotonic() + timeout
        while not self.rt.poll_peer():
            assert time.monotonic() < end, 'driver host did not link'
            time.sleep(0.01)

    def rebind(self):
        self.rt.close()
        self.rt = channel.rt_xddp_bind(self.rt.port, self.rt.label, runtime_dir=self.runtime_dir)

    def close(self):
        self.stop.set()
        self.svc.thread.join(10.0)
        self.rt.close()
        self.robot.close()


@pytest.fixture
def rig(m4k_runtime_dir):
    made = []

    def make(kind, **overrides):
        r = Rig(kind, m4k_runtime_dir, **overrides)
        made.append(r)
        r.wait_linked()
        return r
    yield make
    for r in made:
        r.close()


def _of(kind, items):
    return [m for h, m in items if h.kind == kind]


# The motor watchdog against an RT side that hangs, in wall-clock time: run alone (make test's
# serial stream); starved beside three streams it counted one trip of two.
@pytest.mark.serial
def test_motor_watchdog_on_rt_hang_safe_on_rt_loss_and_resume_only_on_fresh_command(rig):
    r = rig('motor')
    h = r.handler
    drive = (700, 300, 1)
    got = r.until(lambda: h.codes == (700, 300), K.WHEEL_CMD, drive)
    got += r.run(0.2, K.WHEEL_CMD, drive)
    # One ENCODERS reply per command: wait for them rather than for 0.2 s (a loaded VM delays
    # the host's thread), sending commands all along, so the watchdog must stay quiet.
    end = time.monotonic() + 30.0
    while len(_of(K.ENCODERS, got)) <= 5 and time.monotonic() < end:
        got += r.run(0.05, K.WHEEL_CMD, drive)
    assert h.codes == (700, 300) and not h.safe
    assert len(_of(K.ENCODERS, got)) > 5
    # RT process hangs (no WHEEL_CMD, link still up): watchdog -> outputs safe. This test's
    # own command loop is no RT task: on a loaded VM it can miss the 100 ms watchdog while
    # "driving" above (a trip, re-armed by the next command). So count from the hang on: one
    # trip now, or none if one already happened after the last command (still safe, and it
    # stays safe -- a second trip without a command in between is the bug this catches).
    trips0, safe0 = h.watchdog_trips, h.safe
    r.until(lambda: h.safe)
    assert h.codes == (mp.DAC_ZERO, mp.DAC_ZERO)
    assert h.watchdog_trips == trips0 + (0 if safe0 else 1)
    # It stays safe without a fresh command, and a fresh command drives again.
    r.run(0.2)
    assert h.codes == (mp.DAC_ZERO, mp.DAC_ZERO)
    r.until(lambda: h.codes == (700, 300), K.WHEEL_CMD, drive)
    # RT process dies (socket gone): outputs safe at once, relink to the restarted RT side.
    lost0 = r.svc.link.lost
    r.rt.close()
    end = time.monotonic() + 5.0
    while r.svc.link.lost == lost0 and time.monotonic() < end:
        time.sleep(0.01)
    assert r.svc.link.lost == lost0 + 1
    # The service thread makes the outputs safe right after it counts the loss; wait for that
    # step (not 50 ms) -- no command can reach the DACs in between, the RT side is gone.
    end = time.monotonic() + 5.0
    while not h.safe and time.monotonic() < end:
        time.sleep(0.01)
    assert h.safe and h.codes == (mp.DAC_ZERO, mp.DAC_ZERO)
    r.rt = channel.rt_xddp_bind(2, 'motor', runtime_dir=r.runtime_dir)
    t0 = time.monotonic()
    r.wait_linked()
    relink_s = time.monotonic() - t0
    got = r.run(0.3)
    status = _of(K.DEVICE_STATUS, got)
    assert status and status[0].state == State.ACTIVE, 'hello DEVICE_STATUS after relink'
    assert h.codes == (mp.DAC_ZERO, mp.DAC_ZERO)
    r.until(lambda: h.codes == (700, 300), K.WHEEL_CMD, drive)
    assert r.svc.link.relinks >= 1
    print('motor relink after RT restart: {:.3f} s'.format(relink_s))


def test_encoder_frame_errors_and_jumps_are_flagged_never_fresh_angles(rig):
    # The jump check is angle over the host's real gap between reads (an AS5045 read late still
    # reports the true angle): at the default 30 rad/s, half a turn is plausible after ~0.1 s,
    # a gap a loaded machine produces. The wheels stand still here (code 512), so a 1 rad/s
    # ceiling keeps the injected half turn implausible for any gap under ~3 s.
    r = rig('motor', max_wheel_rad_s=1.0)
    enc = r.robot.spi['left_enc']
    r.run(0.1, K.WHEEL_CMD, (512, 512, 1))
    faults0 = r.handler.faults
    enc.fault = {'ocf': False}          # left encoder frame invalid (offset compensation)
    bad = []
    end = time.monotonic() + 5.0
    while not bad and time.monotonic() < end:
        bad = _of(K.ENCODERS, r.run(0.1, K.WHEEL_CMD, (512, 512, 1)))
    enc.fault = None
    assert bad and all(m.status & EncoderStatus.LEFT_FRAME for m in bad)
    assert len({m.left_angle for m in bad}) == 1, 'a bad frame must not move the angle'
    real_raw = enc.raw
    enc.raw = lambda t_ns=None: (real_raw(t_ns) + 2048) % mp.ENC_COUNTS   # half a turn: a jump
    jumped = []
    end = time.monotonic() + 5.0       # a busy machine may answer nothing within one window
    while not jumped and time.monotonic() < end:
        # a bad frame read before the frame came good may still be on its way (a starved
        # host): it says what it was, and is no answer to the jump
        jumped = [m for m in _of(K.ENCODERS, r.run(0.05, K.WHEEL_CMD, (512, 512, 1)))
                  if not m.status & EncoderStatus.LEFT_FRAME]
    enc.raw = real_raw
    assert jumped and jumped[0].status & EncoderStatus.LEFT_JUMP, jumped
    assert jumped[0].left_angle == bad[-1].left_angle
    assert r.handler.faults - faults0 >= len(bad) + 1
    after = r.run(1.2, K.WHEEL_CMD, (512, 512, 1))
    ok = _of(K.ENCODERS, after)
    assert ok and ok[-1].status & 0x0F == 0, 'recovered without a restart'
    levels = [m.level for m in _of(K.DEVICE_STATUS, after)]
    assert levels and levels[-1] == protocol.LEVEL_WARN
    assert _of(K.DEVICE_STATUS, after)[-1].faults == r.handler.faults


def test_sonar_that_never_answers_reports_faults_not_ranges(rig):
    r = rig('sonar')
    trig = r.robot.sonar_trigger
    good = _of(K.SONAR, r.run(0.3, K.REQUEST, (0, 1), period=0.03))
    assert good and all(m.status in (protocol.SONAR_OK, protocol.SONAR_NO_ECHO) for m in good)
    trig.dead = True
    dead = _of(K.SONAR, r.run(0.5, K.REQUEST, (0, 1), period=0.03))
    trig.dead = False
    assert dead and all(m.status in (protocol.SONAR_TIMEOUT, protocol.SONAR_FAULT) for m in dead)
    assert r.handler.timeouts + r.handler.faults > 0
    back = _of(K.SONAR, r.run(0.3, K.REQUEST, (0, 1), period=0.03))
    assert back and back[-1].status in (protocol.SONAR_OK, protocol.SONAR_NO_ECHO)


def test_laser_unplug_replug_checksums_and_noise_no_stale_scan_sent_as_fresh(rig):
    r = rig('lrf')
    sim = r.robot.urg
    scans = _of(K.LASER_SCAN, r.run(0.6, K.REQUEST, (0, 1), period=0.1))
    assert len(scans) >= 3
    # Bad sums and line noise: those scans are dropped by the driver, later ones go through.
    sim.corrupt_next_checksums(2)
    sim.inject_stray(b'\x00garbage\xff\n\nGD00\n')
    noisy = _of(K.LASER_SCAN, r.run(1.0, K.REQUEST, (0, 1), period=0.1))
    assert noisy
    stamps = [m.device_stamp for m in scans + noisy]
    assert len(set(stamps)) == len(stamps), 'every scan sent must be a new device scan'
    # Unplugged: not one LASER_SCAN may go out (the last scan is stale), faults counted.
    faults0 = r.handler.faults
    sim.unplug()
    # Wait for the host to notice (a fault counted), not for a fixed time: a scan it read
    # before the unplug may still be on its way under load; once a fault is counted, every
    # earlier reply has been sent (one thread per device), so the drain takes them all.
    r.until(lambda: r.handler.faults > faults0, K.REQUEST, (0, 1), timeout=30.0, period=0.1)
    r.drain()
    gone = r.run(1.5, K.REQUEST, (0, 1), period=0.1)
    assert _of(K.LASER_SCAN, gone) == [], [m.device_stamp for m in _of(K.LASER_SCAN, gone)]
    assert r.handler.faults > faults0
    status = _of(K.DEVICE_STATUS, gone)
    assert status and status[-1].level >= protocol.LEVEL_WARN
    sim.replug()
    # Scans resume when the host's bring-up retry reopens the port: its backoff (0.5 s
    # doubling to 10 s, host.BRINGUP_BACKOFF) decides when, not a fixed 4 s.
    back = []
    end = time.monotonic() + 60.0
    while not back:
        assert time.monotonic() < end, 'scans resume after replug without restarting the host'
        back += _of(K.LASER_SCAN, r.run(0.5, K.REQUEST, (0, 1), period=0.1))
    # The replug is a power cycle: the device's ms counter restarts, so a fresh scan may carry
    # a stamp an old one had. A stale scan resent is the same scan: same stamp, same ranges
    # (the simulated range noise makes every real scan's ranges differ).
    sent = {(m.device_stamp, m.ranges) for m in scans + noisy}
    assert not [m.device_stamp for m in back if (m.device_stamp, m.ranges) in sent]


def _sound_at_rest(m):
    """Tell whether an IMU datagram is what the robot at rest measures (the world's truth)."""
    unit = abs(math.hypot(m.qx, m.qy, m.qz, m.qw) - 1) < 1e-6
    still = max(abs(m.gx), abs(m.gy), abs(m.gz)) < 1.0
    return m.status == protocol.ImuStatus.OK and unit and still and abs(m.az - 9.80665) < 1.0


@pytest.mark.parametrize('garble', ['zeros', 'ones', 'quaternion', 'gyro_rail'])
def test_imu_garbage_registers_are_counted_faults_never_an_imu_datagram(rig, garble):
    # A myAHRS+ on a noisy bus or mid-reset returns register images no sensor measured: a
    # quaternion far from unit norm (all zero, all 0xFF, corrupted) or a rate at the rail. The
    # robot stands still, so every sound sample is the world's truth at rest.
    r = rig('imu')
    model = r.robot.imu
    good = _of(K.IMU, r.run(0.3, K.REQUEST, (0, 0)))
    assert good and all(_sound_at_rest(m) for m in good)
    faults0 = r.handler.faults
    model.garble = garble
    got = r.run(0.5, K.REQUEST, (0, 0))
    garbage = [m for m in _of(K.IMU, got) if not _sound_at_rest(m)]
    assert not garbage, 'garbage sent as IMU samples: {}'.format(garbage[:2])
    got += r.until(lambda: r.handler.faults - faults0 >= 2, K.REQUEST, (0, 0))
    model.garble = None
    assert not [m for m in _of(K.IMU, got) if not _sound_at_rest(m)]
    reason = 'gyro_full_scale' if garble == 'gyro_rail' else 'quaternion_norm'
    st = _of(K.DEVICE_STATUS, got)
    assert st and st[-1].level == protocol.LEVEL_WARN
    assert st[-1].last_error == protocol.DeviceError.PROTOCOL
    back, end = [], time.monotonic() + 5.0
    while not _of(K.IMU, back):
        assert time.monotonic() < end, 'no IMU sample after the bus recovered'
        back += r.run(0.05, K.REQUEST, (0, 0))
    assert _sound_at_rest(_of(K.IMU, back)[-1]), 'recovered without a restart'
    # every rejected read a fault, each once -- compared once a sound sample is out: the
    # handler counts a read's rejection and then its fault, and a request still in flight
    # when the bus recovered could fall between two reads of the counters
    assert set(r.handler.rejected) == {reason}
    assert sum(r.handler.rejected.values()) == r.handler.faults - faults0
