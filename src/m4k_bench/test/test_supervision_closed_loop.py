"""Wheel supervision and category-1 stops in the closed loop, judged on ground truth.

The RT controller drives the simulated base in virtual time (m4k_bench.virtualbase: the motor
handler over the simulated SPI DACs and AS5045s, the IMU handler over the myAHRS+ registers
with the simulator's noise and bias, the heartbeat monostable, the drive physics). A fault is
injected once the robot runs at its speed (the simulator's own fault kinds: the encoders keep
sending valid frames); the supervision must latch within 0.3 s of the onset, and the robot
must come to rest on ground truth. Healthy drives at a creep, with starts, stops, turns and
reversals, must latch nothing. Deterministic: fixed seeds, no wall clock.
"""

import pytest

from m4k_bench.virtualbase import VirtualBase
from m4k_rt.control.supervision import cause_text

LATCH_S = 0.3


def _at_speed(v, w, faults=(), robot=None, seed=3):
    vb = VirtualBase(world={'seed': seed, 'robot': robot or {}})
    ramp = max(abs(v) / 0.37, abs(w) / 1.85) + 0.5
    assert vb.run(ramp, v, w, until=vb.faulted) is None, cause_text(vb.ctl.supervisor.cause)
    for kind, wheel in faults:
        vb.world.set_fault(kind, wheel)
    return vb


@pytest.mark.parametrize('kind, wheel', [('encoder_frozen', 'left'), ('encoder_sign_flip', 'left'),
                                         ('wheel_stall', 'left'), ('encoder_frozen', 'right')])
@pytest.mark.parametrize('v, w', [(0.02, 0.0), (0.02, 0.05), (0.0, 0.1)],
                         ids=['creep-straight', 'creep-turning', 'creep-in-place'])
def test_a_fault_at_a_creep_latches_within_0_3_s_and_the_robot_stops(kind, wheel, v, w):
    vb = _at_speed(v, w, [(kind, wheel)])
    try:
        dt = vb.run(1.0, v, w, until=vb.faulted)
        assert dt is not None and dt <= LATCH_S, (dt, cause_text(vb.ctl.supervisor.cause))
        assert vb.run(2.0, v, w, until=vb.at_rest) is not None
        assert vb.world.peak_speed < 0.1                 # no runaway on ground truth
    finally:
        vb.close()


@pytest.mark.parametrize('v, w', [(0.02, 0.05), (0.0, 0.1), (0.25, 0.4), (0.0, 0.8)],
                         ids=['creep-turning', 'creep-in-place', 'cruise-turning',
                              'cruise-in-place'])
def test_swapped_encoder_channels_latch_within_0_3_s_when_the_wheels_differ(v, w):
    vb = _at_speed(v, w)
    vb.world.set_fault('encoder_swap')
    try:
        dt = vb.run(1.0, v, w, until=vb.faulted)
        assert dt is not None and dt <= LATCH_S, (dt, cause_text(vb.ctl.supervisor.cause))
    finally:
        vb.close()


def test_a_wheel_driven_at_a_zero_command_latches():
    # an amplifier input offset of 1 V: the left wheel turns with the DAC at zero volts
    vb = VirtualBase(world={'seed': 1, 'robot': {'amp_offset_left_v': 1.0}})
    try:
        dt = vb.run(1.0, 0.0, 0.0, until=vb.faulted)
        assert dt is not None and dt <= LATCH_S
        assert 'commanded still' in cause_text(vb.ctl.supervisor.cause)
    finally:
        vb.close()


@pytest.mark.parametrize('v', [0.02, 0.05])
def test_an_encoder_frozen_from_the_start_at_a_creep_never_runs_away(v):
    vb = VirtualBase(world={'seed': 1, 'faults': [{'at_s': 0.0, 'kind': 'encoder_frozen',
                                                     'wheel': 'left'}]})
    try:
        assert vb.run(1.0, v, 0.0, until=vb.faulted) is not None
        vb.run(3.0, v, 0.0)
        assert vb.world.peak_speed < 0.1 and vb.world.travelled < 0.05
    finally:
        vb.close()


def test_a_fault_stop_brakes_with_the_drive_then_drops_the_enable():
    vb = _at_speed(1.0, 0.0, [('encoder_frozen', 'left')])
    try:
        assert vb.run(1.0, 1.0, until=vb.faulted) is not None
        ctl = vb.ctl
        assert (ctl.left_code, ctl.right_code, ctl.enable) == (512, 512, 1)
        assert vb.world.drive_enabled()                  # category 1: the drive brakes
        assert vb.run(1.0, 1.0, until=vb.at_rest) is not None
        # the peak braking is the drive's (current limit), not coasting's friction
        assert vb.world.peak_decel > 3.0 * vb.world.robot.coast_decel_mps2
        bound = vb.params.linear.max_velocity / vb.params.guard.brake_deceleration
        vb.run(bound, 1.0)
        assert ctl.enable == 0 and not vb.world.drive_enabled()   # then power is cut
    finally:
        vb.close()


@pytest.mark.parametrize('seed', [1, 2])
def test_healthy_creeping_starts_stops_and_turns_latch_nothing(seed):
    vb = VirtualBase(world={'seed': seed})
    segments = [(0.01, 0.0, 0.8), (0.0, 0.0, 0.4), (0.02, 0.0, 0.8), (0.0, 0.0, 0.4),
                (0.02, 0.05, 0.8), (0.0, 0.1, 0.8), (0.0, -0.2, 0.8), (0.05, 0.0, 0.8),
                (-0.05, 0.0, 0.8), (0.0, 0.0, 0.5)]
    try:
        for v, w, t in segments:
            assert vb.run(t, v, w, until=vb.faulted) is None, \
                (v, w, cause_text(vb.ctl.supervisor.cause))
    finally:
        vb.close()


def test_healthy_guard_stop_from_speed_and_reversal_in_place_latch_nothing():
    vb = VirtualBase(world={'seed': 2})
    try:
        assert vb.run(3.5, 1.0, 0.0, until=vb.faulted) is None
        assert vb.run(1.0, 1.0, 0.0, until=vb.faulted, forward_cap=0.0,
                      guard_active=True) is None
        for w in (1.5, -1.5, 0.0):
            assert vb.run(1.5, 0.0, w, until=vb.faulted) is None, \
                cause_text(vb.ctl.supervisor.cause)
    finally:
        vb.close()
