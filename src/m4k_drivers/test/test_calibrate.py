"""calibrate end to end: a sim_robot built unlike its configuration, the tool recovers it.

The simulated robot "as built" (``world.robot``) has a wheel radius 3 % smaller, a track 5 %
wider and a higher top speed than ``config/control.yaml`` says, amplifier zero errors on both
wheels (the right one beyond the dead band, so that wheel creeps at code 512) and a motor dead
band.  The tool runs as a process against the sim_robot process; the "person measuring" is
the test reading the simulator's ground truth (``sim_truth``'s socket).  Every identified value
is compared with the simulator's TRUE value, never the configured one.
"""

import json
import math
import os
import signal
import subprocess
import threading
import time

import pytest
import yaml

from m4k_drivers import config as dconfig
from m4k_drivers.sim_robot import wait_ready
from m4k_drivers.simbus import read_truth
from m4k_drivers.world import RobotParams
from m4k_rt import config as rtconfig
from m4k_rt.control.params import control_params

# Starts processes (the end-to-end tier); its fit of the robot's time constants runs on the
# simulator's wall-clock physics, so make test runs it in the serial stream (tools/run-tests.sh).
pytestmark = [pytest.mark.e2e, pytest.mark.serial]

CALIBRATE = ['python', '-m', 'm4k_drivers.calibrate.cli']   # `ros2 run m4k_drivers calibrate`
R_CFG, TRACK_CFG = 0.1016, 0.40
# drive_load_fraction 1.0 (no caster load), as test_calibrate_closed_loop: with the casters'
# share (the simulator's default 0.5 since issue 39) calibrate's sweep puts the zero trims
# about 1.4-2 codes low -- a gap of the sweep's fit with a caster-loaded body, reported in
# docs/real-robot.md's calibration section, not yet fixed.
TRUE = {'wheel_diameter_m': 2 * R_CFG * 0.97, 'track_width_m': TRACK_CFG * 1.05,
        'top_speed_mps': 2.1, 'amp_offset_left_v': 0.3, 'amp_offset_right_v': -1.6,
        'deadband_v': 0.9, 'supply_v': 24.0, 'drive_load_fraction': 1.0}
ROBOT = RobotParams(**TRUE)        # the simulator's physics for it (m4k_drivers.drive)
R_TRUE = TRUE['wheel_diameter_m'] / 2
# The motor's speed line: 1 / (ke N) rad/s per armature volt, 24 V per unit command; friction
# shifts it by R * I_load volts, which the identification sees as dead band (docs/sim-physics.md).
FULL_SCALE_TRUE = ROBOT.supply_v / (ROBOT.ke * ROBOT.gear_ratio)
I_LOAD = (ROBOT.no_load_current_a + ROBOT.rolling_force_n * R_TRUE
          / (ROBOT.gear_ratio * ROBOT.ke)) / ROBOT.gear_efficiency
TRIM_TRUE = [-TRUE['amp_offset_left_v'] / 24.0 * 511, -TRUE['amp_offset_right_v'] / 24.0 * 511]
DEADBAND_TRUE = (TRUE['deadband_v'] + ROBOT.motor_resistance_ohm * I_LOAD) / 24.0 * 511
# The sweep turns in place: each wheel drives its wheel inertia and half the yaw inertia
# seen at the rim, against the back-EMF damping N^2 ke^2 eta / R. The lag step drives straight:
# each wheel carries half the body's mass too -- the simulator's motor_tau_s.
TAU_STRAIGHT_TRUE = ROBOT.motor_tau_s
TAU_TURN_TRUE = ((ROBOT.wheel_inertia_total + ROBOT.yaw_inertia_kgm2 * R_TRUE ** 2
             / (2 * (TRUE['track_width_m'] / 2) ** 2))
            / (ROBOT.gear_ratio ** 2 * ROBOT.ke ** 2 * ROBOT.gear_efficiency
               / ROBOT.motor_resistance_ohm))


@pytest.fixture
def as_built(tmp_path, m4k_runtime_dir, procs):
    """Start sim_robot with the as-built robot; yield (overlay path, runtime dir)."""
    overlay = tmp_path / 'my_robot.yaml'
    overlay.write_text(yaml.safe_dump({
        'devices': {k: {'enabled': False} for k in ('imu', 'sonar', 'led', 'lrf')},
        'world': {'walls': {'rectangle': [-6.0, -6.0, 6.0, 6.0]}, 'obstacles': [],
                  'robot': {k: TRUE[k] for k in TRUE if k != 'supply_v'}},
    }))
    sim = procs.start(['python', '-m', 'm4k_drivers.sim_robot', '--overlay', str(overlay),
                       '--runtime-dir', m4k_runtime_dir,
                       '--world-report', str(tmp_path / 'world.json')])
    if not wait_ready(m4k_runtime_dir, 20.0):
        procs.stop(sim)
        pytest.fail(f'sim_robot did not come up: {sim.stderr.read()}')
    yield str(overlay), m4k_runtime_dir
    assert procs.stop(sim) == 0


class Dialogue:
    """Read the tool's stdout as it comes; answer its prompts."""

    def __init__(self, proc):
        self.proc = proc
        self.text = ''
        self.pos = 0
        self.cond = threading.Condition()
        self.reader = threading.Thread(target=self._read, name='calibrate-stdout')
        self.reader.start()

    def _read(self):
        while True:
            chunk = os.read(self.proc.stdout.fileno(), 4096)
            with self.cond:
                if not chunk:
                    self.text += '\0'
                    self.cond.notify_all()
                    return
                self.text += chunk.decode()
                self.cond.notify_all()

    def next_prompt(self, timeout=120.0):
        """Return the output up to the next prompt ('[y/N] ' or ']: '), None at the end."""
        deadline = time.monotonic() + timeout
        with self.cond:
            while True:
                rest = self.text[self.pos:]
                ends = [i + len(m) for m in ('[y/N] ', ']: ') for i in [rest.find(m)] if i >= 0]
                if ends:
                    end = min(ends)
                    self.pos += end
                    return rest[:end]
                if '\0' in rest:
                    return None
                left = deadline - time.monotonic()
                assert left > 0, f'no prompt; output so far:\n{self.text}'
                self.cond.wait(left)

    def answer(self, line):
        self.proc.stdin.write(line + '\n')
        self.proc.stdin.flush()


def _unwrapped(start, end, plan):
    """Return the heading change nearest the plan: what a person counting turns reads."""
    d = math.atan2(math.sin(end - start), math.cos(end - start))
    return d + 2 * math.pi * round((plan - d) / (2 * math.pi))


def _run_calibration(procs, overlay, rd, out, report):
    proc = procs.start([*CALIBRATE, '--overlay', overlay, '--runtime-dir', rd, '--output', out,
                        '--report', report, '--levels', '5', '--hold', '1.5'],
                       stdin=subprocess.PIPE, text=True)
    talk = Dialogue(proc)
    start = None
    prompts = []
    while True:
        prompt = talk.next_prompt()
        if prompt is None:
            break
        prompts.append(prompt.strip().splitlines()[-1])
        if prompt.endswith('[y/N] '):
            if 'Straight run' in prompt or 'Turn:' in prompt:
                start = read_truth(rd)            # the person marks the start on the floor
            talk.answer('y')
        elif 'Measured distance' in prompt:
            end = read_truth(rd)
            talk.answer(repr(math.hypot(end['x'] - start['x'], end['y'] - start['y'])))
        elif 'Measured angle' in prompt:
            end = read_truth(rd)
            plan = (1 if 'counter-clockwise' in prompt else -1) * 2 * math.pi
            talk.answer(repr(abs(math.degrees(_unwrapped(start['theta'], end['theta'], plan)))))
        else:
            pytest.fail(f'unexpected prompt: {prompt!r}')
    rc = proc.wait(60)
    talk.reader.join(5)
    return rc, talk.text, proc.stderr.read(), prompts


def test_calibrate_recovers_the_true_robot_not_the_configured_one(tmp_path, as_built, procs):
    overlay, rd = as_built
    out, report = str(tmp_path / 'calibrated.yaml'), str(tmp_path / 'report.json')
    rc, text, err, prompts = _run_calibration(procs, overlay, rd, out, report)
    assert rc == 0, f'{text}\n{err}'
    doc = yaml.safe_load(open(out))
    ctl = doc['control']
    assert ctl['wheel_radius'] == pytest.approx(R_TRUE, rel=0.01)
    assert ctl['track_width'] == pytest.approx(TRUE['track_width_m'], rel=0.01)
    assert ctl['full_scale_wheel_speed'] == pytest.approx(FULL_SCALE_TRUE, rel=0.01)
    # The user's overlay is kept (merged), so the file replaces it.
    assert doc['world']['robot']['deadband_v'] == TRUE['deadband_v']
    rep = json.load(open(report))
    trims = doc['devices']['motor']['dac_zero_trim']
    for code, exact, true in zip(trims, rep['dac_zero_trim_exact'], TRIM_TRUE, strict=True):
        assert exact == pytest.approx(true, abs=0.01 * abs(true) + 0.05)
        # The file holds the measured trim rounded; the true offset (25.55 codes on the right)
        # may sit near a half code, so within the tolerance above either neighbour is right.
        assert code == round(exact) and abs(code - true) < 1, (code, exact, true)
    for db in rep['deadband_codes']:
        # within a DAC code, the resolution the robot uses it at (the intercept of the speed
        # line moves with how settled each step's speed was: 25.83 for 26.20 codes in a
        # make-test run beside the confined streams, within 1 % alone)
        print(f'dead band {db:.2f} codes, true {DEADBAND_TRUE:.2f}')
        assert db == pytest.approx(DEADBAND_TRUE, abs=1.0)
    # The lags are timed from the host's write, so they include the command path's latency
    # (what the speed loop sees too): a looser bound than the steady-state values.
    # The latency's share depends on the machine's load (0.092 s for 0.082 seen with make
    # test's streams side by side): asserted is what physics bounds -- never faster than the
    # simulated drive's own time constant (less 10 % for the fit) -- the rest is printed.
    assert rep['tau_turn_s'] >= TAU_TURN_TRUE * 0.9, rep['tau_turn_s']
    assert rep['tau_s'] >= TAU_STRAIGHT_TRUE * 0.9, rep['tau_s']
    print(f"calibrate: tau {rep['tau_s']:.4f} s (true {TAU_STRAIGHT_TRUE:.4f}), turn "
          f"{rep['tau_turn_s']:.4f} s (true {TAU_TURN_TRUE:.4f})")
    kp, ki = ctl['pi']['kp'], ctl['pi']['ki']        # lambda tuning of the straight-line plant
    assert ki == pytest.approx(1 / (FULL_SCALE_TRUE * 0.15), rel=0.02)
    # The integral time is the measured lag (the tuning rule, exactly); how near that lag is
    # to the drive's own time constant is the load's, bounded from below above and printed.
    assert kp / ki == pytest.approx(rep['tau_s'], rel=1e-3)
    print(f'calibrate: kp/ki {kp / ki:.4f} s (the drive alone {TAU_STRAIGHT_TRUE:.4f})')
    # The zero hold had the amplifier enabled: the right wheel (zero error beyond the dead
    # band) crept before the trim and stood still after it.
    assert rep['zero_hold_before']['creeping'] == ['right']
    assert rep['zero_hold_after']['creeping'] == []
    assert any('Zero hold before' in p for p in prompts)
    # The overlay is a valid configuration for the whole stack.
    raw = rtconfig.load(overlay=out).raw
    assert control_params(raw['control']).track_width == ctl['track_width']
    dconfig.validate({'devices': raw['devices']})
    # At the end: no heartbeat any more, so the amplifier enable has dropped.
    deadline = time.monotonic() + 10
    while read_truth(rd)['motor_enabled'] and time.monotonic() < deadline:
        time.sleep(0.05)
    assert read_truth(rd)['motor_enabled'] is False


def test_sigint_mid_sweep_stops_the_motors_and_writes_nothing(tmp_path, as_built, procs):
    overlay, rd = as_built
    out = tmp_path / 'calibrated.yaml'
    proc = procs.start([*CALIBRATE, '--overlay', overlay, '--runtime-dir', rd, '--output',
                        str(out), '--steps', 'sweep', '--yes'])
    deadline = time.monotonic() + 60
    while abs(read_truth(rd)['w']) < 0.5:                # turning in place: sweep under way
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()
        time.sleep(0.02)
    os.kill(proc.pid, signal.SIGINT)
    assert proc.wait(30) == 1
    assert 'motors at zero, nothing written' in proc.stderr.read()
    assert not out.exists()
    deadline = time.monotonic() + 30
    while (read_truth(rd)['motor_enabled'] or abs(read_truth(rd)['w']) > 1e-3) \
            and time.monotonic() < deadline:
        time.sleep(0.05)
    truth = read_truth(rd)
    assert truth['motor_enabled'] is False and abs(truth['w']) <= 1e-3


@pytest.mark.parametrize('args, message', [
    (['--max-speed', '0.5'], '--max-speed: must be in [0.02, 0.3]'),
    (['--overlay', 'HEARTBEAT_OFF'], 'devices.motor.heartbeat: False refused with real motors'),
    (['--distance', '5'], '--distance: must be in [0.2, 3.0]'),
    (['--steps', 'zero,dance'], "--steps: unknown ['dance']"),
    (['--report', '/nonexistent/dir/r.json'], "--report: directory '/nonexistent/dir' does not"),
])
def test_out_of_bounds_arguments_are_refused_before_anything_moves(tmp_path, capsys, args,
                                                                   message):
    from m4k_drivers.calibrate import cli
    if 'HEARTBEAT_OFF' in args:             # real motors (paths never opened), enable strapped
        overlay = tmp_path / 'strapped.yaml'
        overlay.write_text(yaml.safe_dump({'devices': {'motor': {
            'backend': 'real', 'heartbeat': False, 'left_dac': '/nonexistent/spidev0.0',
            'right_dac': '/nonexistent/spidev0.1', 'left_enc': '/nonexistent/spidev1.0',
            'right_enc': '/nonexistent/spidev1.1'}}}))
        args = ['--overlay', str(overlay)]
    rc = cli.main(['--output', str(tmp_path / 'o.yaml'), *args])
    assert rc == 2 and message in capsys.readouterr().err
    assert not (tmp_path / 'o.yaml').exists()
