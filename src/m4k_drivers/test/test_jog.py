"""Wheel jog (bring-up) against the simulated motor backend: direction, caps, prompt, zero."""

import io

from fakeclock import FakeClock, SteppingStop
import pytest

from m4k_drivers import host
from m4k_drivers.motors import protocol as p
from m4k_drivers.motors.handler import MotorHandler
from m4k_drivers.motors.jog import check_jog, JOG_MAX_DURATION_S, JOG_MAX_SPEED, JogError, run_jog
from m4k_drivers.motors.sim import open_sim_bus
from m4k_drivers.world import LEFT, RIGHT, World, WorldConfig


class Tty(io.StringIO):
    def __init__(self, text, tty=True):
        super().__init__(text)
        self.tty = tty

    def isatty(self):
        return self.tty



def _stop(clock, **kw):
    """The jog's stop: each wait advances the clock by exactly its timeout."""
    return SteppingStop(clock, min_step_ns=0, **kw)

def _rig(**kw):
    clock = FakeClock()
    world = World(WorldConfig(), clock=clock, t0_ns=0)
    dacs = []

    def opener():
        bus = open_sim_bus(world, noise_lsb=0.0)
        dacs.extend(port.dev for port in bus.dacs)
        return bus
    return MotorHandler(opener, clock=clock, **kw), world, clock, dacs


def _angles(world):
    return world.wheel_angle_at(LEFT), world.wheel_angle_at(RIGHT)


@pytest.mark.parametrize('side, sign', [('left', 1), ('right', 1), ('left', -1)])
def test_jog_turns_only_the_chosen_wheel_then_zero(side, sign):
    h, world, clock, dacs = _rig()
    out = io.StringIO()
    rc = run_jog(h, side, 0.1 * sign, 1.0, _stop(clock), out=out, assume_yes=True,
                 clock=clock.seconds)
    assert rc == 0
    idx = 0 if side == 'left' else 1
    turned = _angles(world)
    assert turned[idx] * sign > 0.5                      # ground truth: ~1 rad in 1 s
    assert abs(turned[1 - idx]) < 1e-6                   # the other wheel held at zero
    assert [d.last.code for d in dacs] == [512, 512]     # zero at the end, outputs active
    assert all(d.last.active for d in dacs)
    assert 'turned forward' in out.getvalue()


def test_jog_with_a_mirrored_dac_reports_backward():
    h, world, clock, dacs = _rig(dac_sign=(-1, 1))
    out = io.StringIO()
    run_jog(h, 'left', 0.1, 0.5, _stop(clock), out=out, assume_yes=True,
            clock=clock.seconds)
    assert _angles(world)[0] < 0
    assert 'BACKWARD' in out.getvalue()


def test_ctrl_c_ends_the_jog_early_with_motors_at_zero():
    h, world, clock, dacs = _rig()
    out = io.StringIO()
    rc = run_jog(h, 'right', 0.2, JOG_MAX_DURATION_S, _stop(clock, stop_after_s=0.3),
                 out=out, assume_yes=True, clock=clock.seconds)
    assert rc == 0 and clock.seconds() < 0.5
    assert [d.last.code for d in dacs] == [512, 512]
    assert 'stopped early' in out.getvalue()


@pytest.mark.parametrize('answer, moved', [('y\n', True), ('yes\n', True), ('n\n', False),
                                           ('\n', False)])
def test_confirmation_prompt_on_a_tty(answer, moved):
    h, world, clock, dacs = _rig()
    out = io.StringIO()
    rc = run_jog(h, 'left', 0.1, 0.5, _stop(clock), out=out, stdin=Tty(answer),
                 clock=clock.seconds)
    assert 'Robot on blocks' in out.getvalue()
    assert (rc == 0) == moved
    assert (abs(_angles(world)[0]) > 0.1) == moved
    if not moved:
        assert dacs == []                                # never even opened the bus


def test_no_tty_and_no_yes_is_refused_before_anything_moves():
    h, world, clock, dacs = _rig()
    with pytest.raises(JogError, match='needs confirmation'):
        run_jog(h, 'left', 0.1, 0.5, _stop(clock), out=io.StringIO(),
                stdin=Tty('y\n', tty=False), clock=clock.seconds)
    assert dacs == []


@pytest.mark.parametrize('side, speed, duration, match', [
    ('front', 0.1, 1.0, 'left or right'),
    ('left', JOG_MAX_SPEED + 0.01, 1.0, r'within \+/-0\.25'),
    ('left', -0.3, 1.0, r'within \+/-0\.25'),
    ('left', 0.0, 1.0, 'non-zero'),
    ('left', float('nan'), 1.0, 'non-zero'),
    ('left', 0.1, JOG_MAX_DURATION_S + 0.1, r'\(0, 5\.0\] s'),
    ('left', 0.1, 0.0, r'\(0, 5\.0\] s'),
])
def test_caps_are_refused_not_clamped(side, speed, duration, match):
    with pytest.raises(JogError, match=match):
        check_jog(side, speed, duration)


def test_cli_refuses_over_cap_and_wrong_device(capsys):
    assert host.main(['--device', 'motor', '--jog', 'left', '0.9', '--yes']) == 2
    assert 'within +/-0.25' in capsys.readouterr().err
    assert host.main(['--device', 'imu', '--jog', 'left', '0.1', '--yes']) == 2
    assert '--device motor alone' in capsys.readouterr().err


def test_cli_jog_on_the_sim_backend(capsys, sim_robot):
    assert host.main(['--device', 'motor', '--jog', 'right', '0.1', '--duration', '0.3',
                      '--yes']) == 0
    text = capsys.readouterr().out
    assert 'jog right code=563' in text and 'turned forward' in text
    assert p.command_to_code(0.1) == 563
