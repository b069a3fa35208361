"""The motor-enable acceptance test of docs/real-robot.md, run against the simulated robot.

On the robot: jog a wheel on blocks, ``kill -STOP`` the driver host, the amplifier enable must
fall within the monostable's hold time and the wheel coast to rest although the DAC still
holds the jog code; ``kill -CONT`` and the jog ends with the DACs at zero.  Here the same
commands run against sim_robot's enable monostable, judged on its ground truth.
"""

import os
import signal
import time

import pytest

from m4k_drivers.motors import protocol as p

pytestmark = pytest.mark.e2e  # starts processes / ROS nodes: the end-to-end tier


def _truth_at(robot, t_ns, timeout_s=10.0):
    """Return the ground truth once the world has been advanced to at least ``t_ns``."""
    deadline = time.monotonic() + timeout_s
    while True:
        truth = robot.truth()
        if truth['t_ns'] >= t_ns or time.monotonic() > deadline:
            return truth
        time.sleep(0.005)


def _wait(robot, pred, what, timeout_s=20.0):
    deadline = time.monotonic() + timeout_s
    while True:
        truth = robot.truth()
        if pred(truth):
            return truth
        assert time.monotonic() < deadline, f'no {what}: {truth}'
        time.sleep(0.01)


# A jog under way, then the host frozen within the heartbeat's hold, in wall-clock time: run
# alone, with the rights (make test's serial stream); starved, the jog never got under way.
@pytest.mark.serial
def test_sigstop_of_the_driver_host_drops_the_enable_within_the_hold(sim_robot, procs):
    hold_s = sim_robot.cfg.devices['motor']['heartbeat_hold_s']
    host = procs.start(['python', '-m', 'm4k_drivers.host', '--device', 'motor', '--jog',
                        'left', '0.1', '--duration', '5', '--yes'])
    try:
        before = _wait(sim_robot, lambda t: t['motor_enabled'] and t['wheel_speed_left'] > 1.5,
                       'jog under way')
        t_stop = time.monotonic_ns()
        os.kill(host.pid, signal.SIGSTOP)
        after = _truth_at(sim_robot, t_stop + int(hold_s * 1e9) + 1_000_000)
        assert after['heartbeat_last_edge_ns'] <= t_stop       # no edge from a frozen host
        assert not after['motor_enabled'], after                # fell within the hold time
        # The DAC still holds the jog code: the enable, not a reset, takes the drive away ...
        assert after['motor_volts'][0] > 0.5, after
        # ... and the wheel coasts to rest.
        rest = _wait(sim_robot, lambda t: t['wheel_speed_left'] == 0.0, 'coast to rest')
        assert not rest['motor_enabled'] and rest['motor_volts'][0] > 0.5
        assert before['heartbeat_edges'] > 0
    finally:
        os.kill(host.pid, signal.SIGCONT)
    assert host.wait(30) == 0, host.stderr.read()
    assert 'turned forward' in host.stdout.read()
    end = sim_robot.truth()                                     # the jog zeroed the DACs
    assert [dac.last.code for dac in (sim_robot.spi['left_dac'], sim_robot.spi['right_dac'])] \
        == [p.DAC_ZERO, p.DAC_ZERO]
    assert end['motor_volts'] == [0.0, 0.0]
