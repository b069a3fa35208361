"""Motor-enable heartbeat: the handler toggles on fresh commands only; the monostable model."""

from fakeclock import FakeClock
import pytest

from m4k_drivers import config as dconfig
from m4k_drivers import registry
from m4k_drivers.drive import RobotParams
from m4k_drivers.motors import MotorHandler, WheelCommand
from m4k_drivers.motors.real import EnableLine
from m4k_drivers.motors.sim import EnableMonostable, open_sim_bus
from m4k_drivers.world import LEFT, RIGHT, World, WorldConfig

MS = 1_000_000


def _rig(hold_s=0.05):
    clock = FakeClock()
    # no dynamic brake wired: losing the enable lets the motors coast (the brake:
    # test_drive_physics)
    world = World(WorldConfig(obstacles=(), robot=RobotParams(dynamic_brake_ohm=None)),
                  clock=clock, t0_ns=0)
    mono = EnableMonostable(world, hold_s)

    def opener():
        bus = open_sim_bus(world, noise_lsb=0.0)
        bus.enable = EnableLine(mono, 'sim:heartbeat')
        return bus
    h = MotorHandler(opener, clock=clock, period_s=0.01, watchdog_periods=10)
    h.configure()
    h.activate()
    return h, world, mono, clock


def test_fresh_commands_keep_the_enable_on_and_its_loss_lets_the_wheels_coast():
    h, world, mono, clock = _rig()
    assert not world.drive_enabled()                  # no heartbeat yet: no drive
    for _ in range(100):                              # 1 s of commands at 10 ms
        clock.t += 10 * MS
        h.write(WheelCommand(900, 900, 1))
    world.now()
    assert world.drive_enabled() and mono.edges == 50     # a rising edge every 2nd command
    last = mono.last_edge_ns
    clock.t = last + 49 * MS                          # the hold is not over yet
    world.now()
    assert world.drive_enabled()
    clock.t = last + 50 * MS                          # the hold ends: the enable drops
    world.now()
    assert not world.drive_enabled()
    fast = world.state().wheel_speed[LEFT]
    assert fast > 5.0
    # Enable off: the outputs float, no current, no braking -- friction alone takes the
    # configured rim deceleration, not the 80 ms motor lag (which would be at 0.7 % by now).
    rob = world.robot
    slow = rob.coast_decel_mps2 / rob.wheel_radius_m          # rad/s per s
    clock.t += 400 * MS
    world.now()
    assert world.state().wheel_speed[LEFT] == pytest.approx(fast - 0.4 * slow, abs=0.05)
    assert world.motor_voltage(LEFT) > 0 and world.motor_voltage(RIGHT) > 0   # still latched
    clock.t += round((fast / slow) * 1e9)             # the whole coast-down: at rest
    world.now()
    assert list(world.state().wheel_speed) == [0.0, 0.0]


def test_watchdog_safe_writes_do_not_feed_the_heartbeat():
    h, world, mono, clock = _rig()
    clock.t += 10 * MS
    h.write(WheelCommand(900, 900, 1))
    toggles = h.bus.enable.toggles
    for _ in range(30):                               # no commands: the watchdog trips
        clock.t += 10 * MS
        h.read()
    assert h.safe and h.watchdog_trips == 1 and h.bus.enable.toggles == toggles
    h.shutdown()


def test_hold_shorter_than_three_periods_is_refused_naming_the_field():
    cfg = dconfig.validate({'devices': {'motor': {'backend': 'sim', 'heartbeat_hold_s': 0.02}}})
    with pytest.raises(ValueError, match=r'devices\.motor\.heartbeat_hold_s: must be >= 3'):
        registry.create('motor', cfg.devices['motor'], registry.BuildContext())
    off = dconfig.validate({'devices': {'motor': {'backend': 'sim', 'heartbeat': False,
                                                  'heartbeat_hold_s': 0.02}}})
    registry.create('motor', off.devices['motor'], registry.BuildContext())   # not used: fine
