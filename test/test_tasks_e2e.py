"""End to end: rt_core (robot task bodies) + driver_host (simulated devices), no ROS.

The test process plays the ROS bridge on the XDDP ports: it sends VELOCITY_CMD on ``cmd`` and
reads ODOMETRY, the forwarded sensor datagrams and the LED echo. The simulated world is the
paper's Fig. 8: a triangular obstacle 1.5 m ahead of the start, so driving straight at
0.25 m/s must end in a collision-guard stop short of it.
"""

import os
import signal
import time

import pytest
from wsenv import stack_env, start_sim_robot
import yaml

from m4k_drivers.motors import protocol as motor_protocol
from m4k_rt import protocol as p
from m4k_rt.channel import nrt_xddp_open
from m4k_rt.control import dac

OBSTACLE_X = 1.5          # flat face of the triangle (config/devices.yaml world.obstacles)
BODY_FRONT = 0.225        # half the 45 cm body: the sonar's mount


def _drain(ep):
    out = []
    while True:
        try:
            out.append(p.decode(ep.read(timeout=0.0)))
        except TimeoutError:
            return out


@pytest.fixture
def stack(procs, tmp_path, m4k_runtime_dir):
    overlay = tmp_path / 'overlay.yaml'
    overlay.write_text(yaml.safe_dump({
        'runtime': {'mlockall': False, 'cpu_dma_latency': False, 'start_delay_ms': 10}}))
    env = stack_env(m4k_runtime_dir)
    start_sim_robot(procs, env, m4k_runtime_dir)
    host = procs.start(['python', '-m', 'm4k_drivers.host'], env=env)
    core = procs.start(['python', '-m', 'm4k_rt.rt_core', '--config', str(overlay),
                        '--duration', '60'], env=env)
    eps = {}
    try:
        for label in ('cmd', 'sonar_out', 'lrf_out', 'imu_out', 'led_in'):
            eps[label] = nrt_xddp_open(label, wait=15.0, runtime_dir=m4k_runtime_dir)
        yield eps, host, core, procs
    finally:
        for ep in eps.values():
            ep.close()


def test_dac_mapping_matches_the_motor_driver():
    for code in range(0, 1024):
        assert dac.code_to_command(code) == motor_protocol.code_to_command(code)
    for u in (-1.5, -1.0, -0.4999, -0.001, 0.0, 0.3, 0.5, 0.999, 1.0, 2.0, float('nan')):
        assert dac.command_to_code(u) == motor_protocol.command_to_code(u)


def test_drive_to_the_obstacle_odometry_moves_and_the_guard_stops(stack):
    eps, host, core, procs = stack
    cmd = eps['cmd']
    odoms, seen = [], {'sonar_out': 0, 'lrf_out': 0, 'imu_out': 0}
    leds = []
    next_cmd = 0.0
    start = time.monotonic()
    deadline = start + 25.0
    stopped_since = None
    while time.monotonic() < deadline:
        now = time.monotonic()
        if now >= next_cmd:
            cmd.write(p.encode(p.Kind.VELOCITY_CMD, 0, 0, 0.25, 0.0))
            next_cmd = now + 0.05
        try:
            hdr, msg = p.decode(cmd.read(timeout=0.02))
        except TimeoutError:
            continue
        if hdr.kind == p.Kind.ODOMETRY:
            odoms.append(msg)
        for label in seen:
            seen[label] += len(_drain(eps[label]))
        leds += [m for h, m in _drain(eps['led_in'])]
        moved = len(odoms) > 1 and odoms[-1].x > 0.5
        if moved and odoms[-1].flags & p.ODOM_GUARD and abs(odoms[-1].v) < 0.02:
            stopped_since = stopped_since or now
            if now - stopped_since > 1.0:
                break
        else:
            stopped_since = None
    assert odoms, 'no ODOMETRY from the actuator task'
    assert max(o.x for o in odoms) > 0.5, 'odometry never moved'
    last = odoms[-1]
    assert stopped_since is not None, f'robot did not stop at the obstacle: {last}'
    # sonar at the body front, stop distance 0.35 m: stops ~0.9 m, well before the face
    assert 0.6 < last.x < OBSTACLE_X - BODY_FRONT
    assert abs(last.y) < 0.05
    assert not last.flags & p.ODOM_MOTOR_STALE
    # the sensor tasks forwarded their datagrams; the LED showed the obstacle (red)
    assert all(n > 0 for n in seen.values()), seen
    assert any(m.r == 255 and m.g == 0 and m.b == 0 and m.source == 0 for m in leds), leds[-3:]
    # shut down both processes cleanly
    os.killpg(core.pid, signal.SIGTERM)
    _, err = core.communicate(timeout=30)
    assert core.returncode == 0, err
    for name in ('actuator', 'imu', 'led', 'sonar', 'lrf'):
        line = next(x for x in err.splitlines() if x.startswith(f'rt_core: task {name}: '))
        assert ' body errors 0 ' in line, line
    assert procs.stop(host, signal.SIGTERM) == 0
