"""The e-stop read-back (issue 28.4): the enable after the contact, read on a GPIO input.

End to end over the sim-bus: the motor handler (sim backend, the registry's factory) talks to
a SimRobot on a fake clock; the contact is opened on the world, the verdict is the ENCODERS
status bit the handler sends to the RT side.
"""

from fakeclock import FakeClock
import pytest

from m4k_drivers import config as dconfig
from m4k_drivers import registry
from m4k_drivers.motors import WheelCommand
from m4k_drivers.motors.real import ReadbackLine
from m4k_drivers.sim_robot import SimRobot
from m4k_rt.channel import ensure_runtime_dir
from m4k_rt.protocol import EncoderStatus

MS = 1_000_000
OPEN = EncoderStatus.ESTOP_OPEN


@pytest.fixture
def rig(m4k_runtime_dir):
    made = []

    def build(readback_line=26, faults=None, heartbeat=True, active='high'):
        clock = FakeClock()
        motor = {'backend': 'sim', 'estop_readback_line': readback_line,
                 'heartbeat': heartbeat, 'estop_readback_active': active}
        world = {'walls': {'rectangle': [-9, -9, 9, 9]}, 'obstacles': []}
        if faults:
            world['faults'] = faults
        cfg = dconfig.validate({'devices': {'motor': motor}, 'world': world})
        rd = ensure_runtime_dir(m4k_runtime_dir)
        robot = SimRobot(cfg, rd, clock=clock, sleep=clock.sleep).start()
        ctx = registry.BuildContext(clock=clock, sleep=clock.sleep, runtime_dir=rd)
        h = registry.create('motor', cfg.devices['motor'], ctx)
        made.append((h, robot))
        h.configure()
        h.activate()
        return h, robot, clock
    yield build
    for h, robot in made:
        h.shutdown()
        robot.close()


def _cycle(h, clock, n=1, code=600):
    """n actuator periods: a fresh command, then the ENCODERS reading; return the statuses."""
    out = []
    for _ in range(n):
        clock.t += 10 * MS
        h.write(WheelCommand(code, code, 1))
        out.append(h.read().value.status)
    return out


def test_open_contact_sets_estop_open_in_every_reading_and_release_clears_it(rig):
    h, robot, clock = rig()
    assert isinstance(h.bus.readback, ReadbackLine)
    assert h.estop_readback.endswith('line 26 (e-stop read-back)')
    assert not any(s & OPEN for s in _cycle(h, clock, 20))
    robot.world.set_estop_open(True)
    pressed = _cycle(h, clock, 30)
    assert all(s & OPEN for s in pressed)
    assert robot.truth()['estop_open'] and not robot.truth()['motor_enabled']
    assert robot.truth()['heartbeat_enabled']          # the heartbeat itself is still live
    robot.world.set_estop_open(False)
    assert not any(s & OPEN for s in _cycle(h, clock, 10))


def test_scheduled_estop_fault_is_seen_through_the_readback(rig):
    h, robot, clock = rig(faults=[{'at_s': 0.2, 'until_s': 0.5, 'kind': 'estop'}])
    statuses = _cycle(h, clock, 70)                   # 0.7 s
    flags = [bool(s & OPEN) for s in statuses]
    assert not any(flags[:19]) and all(flags[21:49]) and not any(flags[51:])


def test_no_heartbeat_is_not_an_open_contact(rig):
    h, robot, clock = rig()
    _cycle(h, clock, 5)
    clock.t += 200 * MS                               # no command: the monostable runs out
    robot.world.now()
    assert not robot.world.drive_enabled()
    assert not h.driving_enable()
    assert not h.read().value.status & OPEN           # read-back low, but nobody drives it


def test_enable_strapped_on_an_open_contact_is_seen_without_commands(rig):
    h, robot, clock = rig(heartbeat=False)
    robot.world.set_estop_open(True)
    clock.t += 10 * MS
    assert h.read().value.status & OPEN


def test_without_a_readback_line_the_bit_is_never_set_and_configure_says_so(rig, caplog):
    with caplog.at_level('WARNING'):
        h, robot, clock = rig(readback_line=None)
    assert 'no e-stop read-back' in caplog.text and h.estop_readback == 'none'
    robot.world.set_estop_open(True)
    assert not any(s & OPEN for s in _cycle(h, clock, 10))


def test_readback_on_the_heartbeat_line_is_refused_naming_the_field():
    cfg = dconfig.validate({'devices': {'motor': {'backend': 'sim',
                                                  'estop_readback_line': 25}}})
    with pytest.raises(ValueError, match=r'estop_readback_line: 25 is the heartbeat output'):
        registry.create('motor', cfg.devices['motor'], registry.BuildContext())


def test_bad_readback_line_is_a_config_error():
    with pytest.raises(dconfig.ConfigError, match=r'devices\.motor\.estop_readback_line'):
        dconfig.validate({'devices': {'motor': {'backend': 'sim', 'estop_readback_line': -1}}})


@pytest.mark.parametrize('active', ['high', 'low'])
def test_either_read_back_polarity_gives_the_same_estop_state_over_the_sim_bus(rig, active):
    h, robot, clock = rig(active=active)
    assert all(not s & OPEN for s in _cycle(h, clock, 3))
    robot.world.set_estop_open(True)
    assert all(s & OPEN for s in _cycle(h, clock, 3))
    robot.world.set_estop_open(False)
    assert all(not s & OPEN for s in _cycle(h, clock, 3))


@pytest.mark.parametrize('stall_periods', [3, 4, 5, 8, 12])
@pytest.mark.parametrize('phase', [0, 1])           # the stall after a rising or a falling edge
@pytest.mark.parametrize('served', ['in_time', 'in_a_burst'])
def test_a_host_stall_reads_no_open_contact_and_the_first_command_after_it_drives(
        rig, stall_periods, phase, served):
    # The handler times its heartbeat from the last rising edge, as the monostable does: timed
    # from the last toggle (a falling edge every other command), a 40 ms stall whose queued
    # readings were served in a burst read an open contact four times in a row.
    h, robot, clock = rig()
    assert not any(s & OPEN for s in _cycle(h, clock, 20 + phase))
    statuses = []
    if served == 'in_time':          # the RT side's requests answered, its commands lost
        for _ in range(stall_periods):
            clock.t += 10 * MS
            statuses.append(h.read().value.status)
    else:                            # the host stalled whole; its queue served at once
        clock.t += stall_periods * 10 * MS
        statuses += [h.read().value.status for _ in range(stall_periods)]
    # the last rising edge was the last command (phase 1) or the one before it (phase 0)
    since_rise_ms = stall_periods * 10 + 10 * (1 - phase)
    assert robot.truth()['motor_enabled'] == (since_rise_ms < 50)     # the 50 ms hold
    clock.t += 10 * MS
    h.write(WheelCommand(600, 600, 1))
    # the first command after a lapse re-arms the monostable, whatever the line's level was
    assert robot.truth()['motor_enabled']
    statuses.append(h.read().value.status)
    statuses += _cycle(h, clock, 10)
    assert not any(s & OPEN for s in statuses)
