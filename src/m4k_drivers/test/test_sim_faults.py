"""Fault injection in the simulator (issue 28.3): encoders that lie in valid frames, a stalled
wheel, the e-stop contact -- seen through the real motor handler and AS5045 frames, judged on
the world's ground truth."""


from fakeclock import FakeClock
import pytest

from m4k_drivers.faults import parse_faults
from m4k_drivers.motors import MotorHandler, WheelCommand
from m4k_drivers.motors import protocol as mp
from m4k_drivers.motors.sim import open_sim_bus
from m4k_drivers.world import LEFT, RIGHT, World, WorldConfig, WorldConfigError
from m4k_rt.protocol import EncoderStatus

MS = 1_000_000
FWD = mp.command_to_code(0.125)         # 0.25 m/s open loop


def _rig(faults=None, robot=None):
    clock = FakeClock()
    world_raw = {'walls': {'rectangle': [-20, -20, 20, 20]}, 'obstacles': []}
    if robot is not None:
        world_raw['robot'] = robot
    if faults is not None:
        world_raw['faults'] = faults
    world = World(WorldConfig.from_dict(world_raw), clock=clock, t0_ns=0)
    h = MotorHandler(lambda: open_sim_bus(world, noise_lsb=0.0), clock=clock, period_s=0.01,
                     watchdog_periods=10)
    h.configure()
    h.activate()
    return h, world, clock


def _drive(h, clock, left, right, seconds):
    """Command (left, right) codes every 10 ms; return the encoder readings."""
    out = []
    for _ in range(round(seconds / 0.01)):
        clock.t += 10 * MS
        h.write(WheelCommand(left, right, 1))
        r = h.read()
        out.append(r.value)
    return out


def _valid(readings):
    return all(r.status & EncoderStatus.INVALID == 0 for r in readings)


def test_sign_flip_counts_backwards_in_valid_frames_while_the_wheel_goes_forward():
    h, world, clock = _rig([{'at_s': 1.0, 'kind': 'encoder_sign_flip', 'wheel': 'left'}])
    before = _drive(h, clock, FWD, FWD, 1.0)
    truth0 = world.state().wheel_angle
    after = _drive(h, clock, FWD, FWD, 1.0)
    truth1 = world.state().wheel_angle
    assert _valid(before + after)
    assert truth1[LEFT] - truth0[LEFT] > 1.0                # the wheel turned forward
    moved_l = after[-1].left_angle - before[-1].left_angle
    moved_r = after[-1].right_angle - before[-1].right_angle
    assert moved_l == pytest.approx(-(truth1[LEFT] - truth0[LEFT]), abs=0.02)
    assert moved_r == pytest.approx(truth1[RIGHT] - truth0[RIGHT], abs=0.02)
    assert world.active_faults() == [{'kind': 'encoder_sign_flip', 'wheel': 'left'}]
    h.shutdown()


def test_swapped_channels_report_the_other_wheel():
    h, world, clock = _rig([{'at_s': 0.5, 'kind': 'encoder_swap'}])
    before = _drive(h, clock, FWD, FWD, 0.5)
    t0 = world.state().wheel_angle
    back = mp.command_to_code(-0.125)
    after = _drive(h, clock, back, FWD, 1.0)                # turn in place: left back
    t1 = world.state().wheel_angle
    assert _valid(before + after)
    assert t1[LEFT] < t0[LEFT] and t1[RIGHT] > t0[RIGHT]
    assert after[-1].left_angle - before[-1].left_angle == pytest.approx(
        t1[RIGHT] - t0[RIGHT], abs=0.02)
    assert after[-1].right_angle - before[-1].right_angle == pytest.approx(
        t1[LEFT] - t0[LEFT], abs=0.02)
    h.shutdown()


def test_frozen_encoder_keeps_returning_the_same_valid_frame():
    h, world, clock = _rig([{'at_s': 0.5, 'kind': 'encoder_frozen', 'wheel': 'right'}])
    _drive(h, clock, FWD, FWD, 0.6)
    frozen = _drive(h, clock, FWD, FWD, 1.0)
    assert _valid(frozen)
    assert len({r.right_raw for r in frozen}) == 1                  # the same value
    assert frozen[-1].left_angle - frozen[0].left_angle > 1.0       # the other one moves
    assert world.state().wheel_speed[RIGHT] > 1.0                    # and so does the wheel
    h.shutdown()


def test_stalled_wheel_does_not_turn_and_its_encoder_reads_no_motion():
    h, world, clock = _rig([{'at_s': 0.5, 'kind': 'wheel_stall', 'wheel': 'left'}])
    _drive(h, clock, FWD, FWD, 0.5)
    stalled = _drive(h, clock, FWD, FWD, 1.0)
    s = world.state()
    assert _valid(stalled)
    assert s.wheel_speed[LEFT] == 0.0
    assert stalled[-1].left_angle == pytest.approx(stalled[0].left_angle, abs=0.01)
    assert s.w > 0.1           # the right wheel pivots the robot about the blocked left one
    world.set_fault('wheel_stall', 'left', active=False)       # forced faults add to the list
    assert world.active_faults() == [{'kind': 'wheel_stall', 'wheel': 'left'}]   # scheduled
    h.shutdown()


def test_estop_contact_pressed_and_released_on_schedule_cuts_the_enable():
    # no dynamic brake wired: the motors coast (the brake: test_drive_physics)
    h, world, clock = _rig([{'at_s': 1.0, 'until_s': 2.0, 'kind': 'estop'}],
                           robot={'dynamic_brake_ohm': None})
    _drive(h, clock, FWD, FWD, 0.99)
    assert world.drive_enabled() and not world.estop_open
    v0 = world.state().v
    _drive(h, clock, FWD, FWD, 0.5)
    s = world.state()
    assert world.estop_open and not world.drive_enabled()
    # coasting on friction, whatever the DACs say
    assert s.v == pytest.approx(v0 - 0.5 * world.robot.coast_decel_mps2, abs=0.01)
    _drive(h, clock, FWD, FWD, 0.6)
    assert not world.estop_open and world.drive_enabled()


def test_an_estop_at_a_moment_of_the_drive_opens_then_and_lasts_for_s():
    """``start`` (a moment of the drive, as a moving obstacle's path starts) and ``for_s``: the
    contact opens 0.5 s after the robot first moved, however long the world stood before
    (a stack coming up late), and closes 1 s later; one entry, noted once."""
    h, world, clock = _rig([{'start': {'after': 0.5}, 'for_s': 1.0, 'kind': 'estop'}],
                           robot={'dynamic_brake_ohm': None})
    _drive(h, clock, mp.DAC_ZERO, mp.DAC_ZERO, 3.0)           # 3 s standing: nothing
    assert world.drive_enabled() and not world.estop_open
    opened = closed = None
    for k in range(300):
        _drive(h, clock, FWD, FWD, 0.01)
        t = (k + 1) * 0.01
        if opened is None and world.estop_open:
            opened = t
        if opened is not None and closed is None and not world.estop_open:
            closed = t
    moved_at = world._moving_since * 1e-9 - 3.0                # s into the drive
    assert opened == pytest.approx(moved_at + 0.5, abs=0.015), (opened, moved_at)
    assert closed == pytest.approx(opened + 1.0, abs=0.015), (opened, closed)
    assert world.drive_enabled()


def test_a_turn_in_place_is_a_first_motion_too():
    """A turn in place travels nowhere: the drive's first motion is 5 mm at the wheels' rim
    (an e-stop cell turning in place never opened its contact when only the path counted)."""
    h, world, clock = _rig([{'start': {'after': 0.3}, 'for_s': 0.5, 'kind': 'estop'}])
    opened = False
    for _ in range(200):
        _drive(h, clock, FWD, mp.command_to_code(-0.125), 0.01)
        opened = opened or world.estop_open
    assert world.travelled < 0.005 and opened


def test_a_fault_after_a_distance_begins_where_the_robot_truly_got():
    h, world, clock = _rig([{'start': {'travelled': 0.2}, 'kind': 'encoder_frozen',
                             'wheel': 'left'}])
    while world.travelled < 0.19:
        _drive(h, clock, FWD, FWD, 0.01)
        assert world.active_faults() == []
    _drive(h, clock, FWD, FWD, 0.1)
    assert world.active_faults() == [{'kind': 'encoder_frozen', 'wheel': 'left'}]


def test_forced_fault_from_a_test_and_its_release():
    h, world, clock = _rig()
    _drive(h, clock, FWD, FWD, 0.5)
    world.set_fault('encoder_frozen', 'left')
    a = _drive(h, clock, FWD, FWD, 0.3)
    assert len({r.left_raw for r in a}) == 1
    world.set_fault('encoder_frozen', 'left', active=False)
    b = _drive(h, clock, FWD, FWD, 0.3)
    assert len({r.left_raw for r in b}) > 10 and world.active_faults() == []
    with pytest.raises(ValueError, match='fault kind must be'):
        world.set_fault('gremlins')
    h.shutdown()


@pytest.mark.parametrize('faults, match', [
    ('x', r'world\.faults: expected a list'),
    ([{'kind': 'encoder_sign_flip', 'wheel': 'left'}], r'world\.faults\[0\]\.at_s: missing'),
    ([{'at_s': 1, 'kind': 'gremlins'}], r'world\.faults\[0\]\.kind: expected one of'),
    ([{'at_s': 1, 'kind': 'wheel_stall', 'wheel': 'middle'}],
     r'world\.faults\[0\]\.wheel: expected left, right or both'),
    ([{'at_s': 1, 'kind': 'encoder_swap', 'wheel': 'left'}], r'world\.faults\[0\]\.wheel'),
    ([{'at_s': 2, 'until_s': 1, 'kind': 'estop'}], r'world\.faults\[0\]\.until_s: must be after'),
    ([{'at_s': -1, 'kind': 'estop'}], r'world\.faults\[0\]\.at_s: expected seconds >= 0'),
    ([{'at_s': 1, 'kind': 'estop', 'when': 3}],
     r'world\.faults\[0\]\.when: unknown key \(allowed: at_s, for_s, kind, start, until_s, '
     r'wheel\)'),
    ([{'at_s': 1, 'start': {'after': 1}, 'kind': 'estop'}],
     r'world\.faults\[0\]\.start: give at_s \(world time\) or start'),
    ([{'start': {'after': 1}, 'until_s': 5, 'kind': 'estop'}],
     r'world\.faults\[0\]\.until_s: world time ends an at_s fault only'),
    ([{'at_s': 1, 'until_s': 5, 'for_s': 1, 'kind': 'estop'}],
     r'world\.faults\[0\]\.for_s: give until_s or for_s'),
    ([{'start': {'after': 1}, 'for_s': 0, 'kind': 'estop'}], r'world\.faults\[0\]\.for_s'),
    ([{'start': {'soon': 1}, 'kind': 'estop'}], r'world\.faults\[0\]\.start\.soon'),
])
def test_bad_fault_entries_are_refused_naming_the_field(faults, match):
    with pytest.raises(WorldConfigError, match=match):
        WorldConfig.from_dict({'faults': faults})


def test_fault_schedule_parses_wheels():
    (f,) = parse_faults([{'at_s': 1.5, 'kind': 'wheel_stall', 'wheel': 'both'}])
    assert f.sides == (0, 1) and f.active(1.5) and not f.active(1.4)
