"""The standstill hold (``control.hold``) in the closed loop, judged on ground truth (hazard C19).

The RT controller drives the simulated base in virtual time (m4k_bench.virtualbase), with the
hold switched on (``hold.enabled``, as shipped), on a floor
that slopes (``world.floor`` ``grade_deg``: gravity pulls the body along its heading). With
zero setpoints and the wheels stopped, or pulled faster than the zero word would let them
roll, a PI at zero speed holds each wheel where it came to rest. Judged: on a 4.8 deg ramp
(a wheelchair ramp's steepest, 1:12) the robot stays put after every kind of stop and latches
nothing; with the hold off it rolls and the still test latches (so the ramp is a real test);
on the level the hold never backs a robot up; a start uphill from the hold does not roll back
first; a fault while holding is still judged. Deterministic: fixed seeds, no wall clock.
"""

import pytest

from m4k_bench.latch import BASES
from m4k_bench.virtualbase import VirtualBase
from m4k_rt.control.supervision import cause_text

RAMP_DEG = 4.8
DOWN_X = 0.0          # the ramp falls toward +x: forward is downhill
UP_X = 180.0          # the ramp rises toward +x: forward is uphill
HELD_M = 0.005        # how far a held robot may still move on ground truth in 5 s


HOLD = {'hold': {'enabled': True}}     # as shipped; stated so the ramp tests keep their subject


def _ramp(grade=RAMP_DEG, downhill=DOWN_X, robot=None, control=HOLD, seed=3, **kw):
    floor = [{'rectangle': [-30.0, -30.0, 30.0, 30.0], 'mu': 0.6, 'grade_deg': grade,
              'downhill_deg': downhill}]
    return VirtualBase(world={'seed': seed, 'floor': floor, 'robot': robot or {}},
                       control=control, **kw)


def _x(vb):
    return vb.world.state().pose.x


def _stop(vb, how):
    """Drive and stop the robot one way; return when the stop's command ends."""
    if how == 'placed':                   # put down on the ramp, never commanded
        vb.run(0.5, None)
    elif how == 'zero command, downhill':
        vb.run(2.5, 0.5)
        vb.run(2.0, 0.0)
    elif how == 'guard stop, downhill':
        vb.run(3.5, 1.0)
        vb.run(2.0, 1.0, forward_cap=0.0, guard_active=True)
    elif how == 'zero command, reversing uphill':
        vb.run(2.0, -0.2)
        vb.run(2.0, 0.0)
    elif how == 'zero command, turning':
        vb.run(2.0, 0.2, 0.4)
        vb.run(2.0, 0.0, 0.0)
    else:
        raise AssertionError(how)


STOPS = ['placed', 'zero command, downhill', 'guard stop, downhill',
         'zero command, reversing uphill', 'zero command, turning']


def _held_after(vb, how):
    """Stop one way, then 5 s of zero commands: held, nothing latched, still on ground truth."""
    _stop(vb, how)
    assert not vb.faulted(), cause_text(vb.ctl.supervisor.cause)
    assert vb.ctl.holding
    x0 = _x(vb)
    vb.run(5.0, 0.0)
    assert not vb.faulted(), cause_text(vb.ctl.supervisor.cause)
    assert abs(_x(vb) - x0) < HELD_M, (how, _x(vb) - x0)


@pytest.mark.parametrize('base', list(BASES))
@pytest.mark.parametrize('how', STOPS)
def test_stopped_on_a_4_8_deg_ramp_the_robot_stays_put_and_latches_nothing(how, base):
    vb = _ramp(robot=BASES[base])
    try:
        _held_after(vb, how)
        assert abs(vb.world.state().v) < 0.01
    finally:
        vb.close()


def test_with_the_hold_off_the_robot_rolls_down_the_ramp_and_the_still_test_latches():
    # the negative control: the ramp above is a test of the hold, not of friction
    vb = _ramp(control={'hold': {'enabled': False}})
    try:
        x0 = _x(vb)
        assert vb.run(3.0, None, until=vb.faulted) is not None
        vb.run(3.0, None)
        assert _x(vb) - x0 > 0.1          # rolled on after the category-1 stop cut the power
    finally:
        vb.close()


@pytest.mark.parametrize('base', list(BASES))
@pytest.mark.parametrize('how', ['zero command, downhill', 'guard stop, downhill',
                                 'zero command, turning'])
def test_on_the_level_the_hold_never_backs_the_robot_up(how, base):
    vb = _ramp(grade=0.0, robot=BASES[base])
    try:
        _stop(vb, how)
        seen = []
        for _ in range(300):
            vb.cycle(0.0, 0.0)
            seen.append(vb.world.state().v)
        assert vb.ctl.holding and not vb.faulted()
        assert min(seen) > -0.005, min(seen)
    finally:
        vb.close()


@pytest.mark.parametrize('seed', [1, 2, 3])
@pytest.mark.parametrize('base', list(BASES))
@pytest.mark.parametrize('trip_s, release_s', [(0.3, 0.1), (0.25, 0.15), (0.5, 0.2)])
def test_a_guard_chattering_at_its_release_line_never_backs_the_robot_up(trip_s, release_s,
                                                                        base, seed):
    # On the stack, robots resting at a leg or a person right at the guard's release line
    # tripped and released it again and again: each release a creep (the slow floor), each
    # trip a hold whose integral grew against the creep's last roll while the wheel still
    # braked -- then drove the stopped wheels back (4 cm/s in virtual time) and latched a
    # still fault. Hold off, the robot never moves backwards here: with it, no more than
    # the hold's hunting of a count.
    vb = _ramp(grade=0.0, robot=BASES[base], seed=seed)
    try:
        vb.run(3.0, 0.5)
        seen = []
        for _ in range(12):
            for _ in range(round(trip_s / 0.01)):
                vb.cycle(0.5, 0.0, forward_cap=0.0, guard_active=True)
                seen.append(vb.world.state().v)
            for _ in range(round(release_s / 0.01)):
                vb.cycle(0.5, 0.0, forward_cap=0.05)
                seen.append(vb.world.state().v)
        assert not vb.faulted(), cause_text(vb.ctl.supervisor.cause)
        assert min(seen) > -0.005, min(seen)
    finally:
        vb.close()


@pytest.mark.parametrize('base', list(BASES))
def test_a_start_uphill_from_the_hold_does_not_roll_back_first(base):
    vb = _ramp(downhill=UP_X, robot=BASES[base])
    try:
        vb.run(1.0, None)
        assert vb.ctl.holding
        x0 = _x(vb)
        lowest = x0
        for _ in range(200):
            vb.cycle(0.1, 0.0)
            lowest = min(lowest, _x(vb))
        assert not vb.faulted(), cause_text(vb.ctl.supervisor.cause)
        assert x0 - lowest < HELD_M, x0 - lowest
        assert _x(vb) - x0 > 0.05         # and it drove up
    finally:
        vb.close()


def test_a_sign_flipped_encoder_while_holding_moves_nothing_and_latches_at_the_start():
    # The hold's integral moves only with the counts: a flip under a held wheel changes
    # nothing while it stands, and the drive that follows is judged as any other.
    vb = _ramp()
    try:
        vb.run(1.0, None)
        assert vb.ctl.holding and not vb.faulted()
        vb.world.set_fault('encoder_sign_flip', 'left')
        x0 = _x(vb)
        vb.run(2.0, None)
        assert abs(_x(vb) - x0) < HELD_M and not vb.faulted()
        dt = vb.run(1.0, 0.1, until=vb.faulted)
        assert dt is not None and dt <= 0.3, dt
        assert not vb.ctl.holding
    finally:
        vb.close()


@pytest.mark.parametrize('w', [0.01, -0.02])
def test_a_heading_correction_while_the_guard_holds_the_robot_on_the_ramp_moves_nothing(w):
    # Seen on the stack (ramp_down_wall_4_8deg): stopped by the guard, the runner's heading
    # hold went on sending w of ~0.01 rad/s; both wheel setpoints were then a few hundredths
    # of a rad/s, below what the encoders resolve, the PIs dropped the effort that held the
    # wheels whenever they read still, and the robot crept down at 5 mm/s into the wall.
    vb = _ramp()
    try:
        vb.run(2.5, 0.5)
        vb.run(1.5, 0.5, forward_cap=0.0, guard_active=True)
        assert vb.ctl.holding and not vb.faulted()
        x0 = _x(vb)
        vb.run(10.0, 0.5, w, forward_cap=0.0, guard_active=True)
        assert not vb.faulted(), cause_text(vb.ctl.supervisor.cause)
        assert abs(_x(vb) - x0) < HELD_M, _x(vb) - x0
    finally:
        vb.close()


@pytest.mark.parametrize('every', [2, 3, 4, 5, 6, 8])
@pytest.mark.parametrize('how', STOPS)
def test_with_encoder_samples_every_few_cycles_the_ramp_hold_keeps_the_robot(how, every):
    # Hazard C22 on the ramp: a starved driver host or RT process delivers an encoder sample
    # every few cycles (3-10 in the fault traces of starved test stacks). The hold integrates
    # once per sample over the time since the last one, judges a wheel pulled and brakes it
    # on a new sample only, and steps its boost at most a cycle's worth per sample: held on
    # 4.8 deg after every kind of stop, the robot stays put and nothing latches. (Before, at
    # 5-8 cycles the guard stop downhill and the turning stop rocked the robot into "turns
    # while commanded still", and it rolled 1.2-1.7 m.) At 10 (100 ms, motor_timeout itself)
    # the reversing stop still latches: C22's residual.
    vb = _ramp(encoder_every=every)
    try:
        _held_after(vb, how)
    finally:
        vb.close()
