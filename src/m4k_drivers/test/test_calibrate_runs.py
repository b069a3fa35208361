"""calibrate's runs in simulated time: motors at zero on every way out, bounds that hold."""

from fakeclock import FakeClock, SteppingStop
import pytest

from m4k_drivers.calibrate import runs
from m4k_drivers.motors.handler import MotorHandler
from m4k_drivers.motors.sim import open_sim_bus
from m4k_drivers.world import World, WorldConfig
from m4k_rt.config import shipped_period_s

PERIOD_S = shipped_period_s('actuator')   # the actuator task's, as shipped


def _rig():
    clock = FakeClock()
    world = World(WorldConfig.from_dict({'obstacles': [],
                                         'walls': {'rectangle': [-9, -9, 9, 9]}}),
                  clock=clock, t0_ns=0)
    bus = {}

    def opener():
        bus['bus'] = open_sim_bus(world, noise_lsb=0.0)
        return bus['bus']
    handler = MotorHandler(opener, clock=clock, period_s=PERIOD_S)
    stop = SteppingStop(clock)
    return runs.MotorRig(handler, stop, clock=clock.seconds), world, bus, stop


def _dac_codes(bus):
    return [port.dev.last.code for port in bus['bus'].dacs]


def test_an_encoder_fault_mid_run_aborts_with_the_motors_at_zero():
    rig, world, bus, _ = _rig()
    with pytest.raises(runs.Aborted, match='encoder frame/jump error'):
        with rig:
            rig.run_for(600, 424, 0.5)                   # turning in place
            bus['bus'].encoders[0].dev.fault = {'cof': True}   # CORDIC overflow: invalid angle
            rig.run_for(600, 424, 0.5)
    assert _dac_codes(bus) == [512, 512]
    assert rig.handler.bus is None                       # shut down: SPI endpoints closed
    assert not world.drive_enabled() or world.motor_voltage(0) == 0.0


def test_an_isolated_bad_reading_is_skipped_not_fatal():
    rig, world, bus, _ = _rig()
    with rig:
        rig.run_for(600, 424, 0.3)
        dev = bus['bus'].encoders[0].dev
        dev.fault = {'lin': True}                       # two readings with invalid angles
        _, a = rig.command(600, 424)
        _, b = rig.command(600, 424)
        dev.fault = None
        t0, samples = rig.run_for(600, 424, 0.3)
    assert rig.bad_samples == 2 and a is b              # the last good reading, repeated
    assert len({s.t for s in samples}) == len(samples) and samples[-1].t - t0 >= 0.3
    assert _dac_codes(bus) == [512, 512]


def test_a_stop_request_aborts_and_zeroes():
    rig, world, bus, stop = _rig()
    with pytest.raises(runs.Aborted, match='stopped'):
        with rig:
            rig.run_for(600, 600, 0.3)
            stop.set()                                   # Ctrl-C
            rig.run_for(600, 600, 0.3)
    assert _dac_codes(bus) == [512, 512]


def test_a_stuck_encoder_ends_the_straight_run_within_its_window_not_at_the_time_limit():
    rig, world, bus, _ = _rig()
    with rig:
        rig.run_for(512, 512, 0.2)
        for port in bus['bus'].encoders:                 # magnet fell off: a valid, fixed angle
            frozen = port.dev.raw()
            port.dev.raw = lambda t_ns=None, frozen=frozen: frozen
        with pytest.raises(runs.Aborted, match='encoder or drive fault'):
            runs.straight(rig, 1.0, 0.1016, 0.15, limit_s=60.0)
    # Ground truth: it drove a little over one second at 0.3 m/s, not for a minute.
    assert 0.05 < world.pose().x < 0.6
    assert _dac_codes(bus) == [512, 512]


def test_commands_beyond_the_cap_are_refused():
    rig, world, bus, _ = _rig()
    with rig:
        with pytest.raises(runs.Aborted, match='beyond the calibration cap'):
            rig.command(512 + 200, 512)
        with pytest.raises(runs.Aborted, match=r'sweep speed must be in \(0, 0\.3\]'):
            runs.sweep(rig, 0.5, 3, 0.2, 0.2, print)
        with pytest.raises(runs.Aborted, match=r'lag run speed must be in \(0, 0\.3\]'):
            runs.lag(rig, 0.4, 0.2, 0.2, print)
    assert world.pose().x == 0.0


@pytest.mark.parametrize('robot', [{}, {'amp_current_limit_a': 2.0, 'mass_kg': 40.0}])
def test_brake_run_measures_the_simulators_braking_and_a_reaction_within_two_periods(robot):
    """The braking run on the simulator agrees with its physics (issue 28.1, calibrate).

    Tolerances: deceleration within 5 % of RobotParams.braking_decel_mps2() (the current limit's
    braking, as the simulator's ground truth peak shows too); reaction time within half a
    period before and two periods after the write: the simulated amplifier acts on the zero
    at once (no current rise modelled), so the fit finds ~0 up to the encoder noise.
    """
    from m4k_drivers.calibrate import fit
    clock = FakeClock()
    world = World(WorldConfig.from_dict({'obstacles': [], 'robot': robot,
                                         'walls': {'rectangle': [-9, -9, 9, 9]}}),
                  clock=clock, t0_ns=0)
    handler = MotorHandler(lambda: open_sim_bus(world, noise_lsb=0.5), clock=clock,
                           period_s=PERIOD_S)
    stop = SteppingStop(clock)
    with runs.MotorRig(handler, stop, clock=clock.seconds) as rig:
        t_zero, before, after = runs.brake(rig, 0.25, 1.5)
    r = world.robot.wheel_radius_m
    b = fit.braking(t_zero, [(s.t, 0.5 * (s.left + s.right)) for s in before],
                    [(s.t, 0.5 * (s.left + s.right)) for s in after], r)
    truth = world.robot.braking_decel_mps2()
    assert world.peak_decel == pytest.approx(truth, rel=0.01)      # the physics itself
    assert b.decel_mps2 == pytest.approx(truth, rel=0.05)
    assert -0.5 * handler.period_s <= b.reaction_s <= 2 * handler.period_s
    assert b.speed_mps == pytest.approx(0.25 * world.robot.top_speed_mps, rel=0.1)
    assert abs(world.state().v) < 0.01                              # stopped at the end


@pytest.mark.parametrize('robot', [{}, {'mass_kg': 40.0, 'motor_resistance_ohm': 0.8,
                                    'deadband_v': 0.9}])
def test_lag_run_times_the_simulators_straight_line_time_constant(robot):
    """The lag run's small straight steps give the drive's time constant (docs/sim-physics.md).

    Truth: RobotParams.motor_tau_s, derived from the simulator's physical parameters (the
    straight-line back-EMF damping against half the body's mass); within 5 % with encoder
    noise. The steps stay below the current limit (the linear region), so the fit is not the
    current-limited ramp of a step from rest, and the plateaus start above the dead band.
    """
    from m4k_drivers.calibrate import fit
    clock = FakeClock()
    world = World(WorldConfig.from_dict({'obstacles': [], 'robot': robot,
                                         'walls': {'rectangle': [-9, -9, 9, 9]}}),
                  clock=clock, t0_ns=0)
    handler = MotorHandler(lambda: open_sim_bus(world, noise_lsb=0.5), clock=clock,
                           period_s=PERIOD_S)
    band = robot.get('deadband_v', 0.0) / 24.0 * fit.DAC_SPAN
    with runs.MotorRig(handler, SteppingStop(clock), clock=clock.seconds) as rig:
        plateaus = runs.lag(rig, 0.15, 0.6, 0.6, print, band)
    speeds = [pl.speed for pl in plateaus]
    assert speeds[0] > 0.5 and speeds[0] < speeds[1] < speeds[2]
    tau = fit.tau_from_plateaus(plateaus, 0.1 * speeds[-1])
    assert tau == pytest.approx(world.robot.motor_tau_s, rel=0.05)
    assert abs(world.state().v) < 0.01                              # stopped at the end


def test_brake_fit_refuses_a_run_without_braking():
    from m4k_drivers.calibrate import fit
    flat = [(i * 0.01, i * 0.05) for i in range(50)]
    with pytest.raises(fit.FitError, match='braking: 0 speed sample'):
        fit.braking(0.25, flat[:25], flat[25:], 0.1)
