"""calibrate's arithmetic on analytic data, and the simulated robot as built (world.robot)."""

import math

import numpy as np
import pytest

from m4k_drivers import config as dconfig
from m4k_drivers.calibrate import fit
from m4k_drivers.world import LEFT, RIGHT, RobotParams, World, WorldConfig, WorldConfigError


def _angle(t, steps, tau):
    """Angle of a first-order wheel commanded through ``steps`` [(t0, speed)] (closed form).

    Each change of command adds (w_j - w_j-1) * (dt - tau (1 - exp(-dt / tau))) from its t0.
    """
    t = np.asarray(t)
    out = np.zeros_like(t)
    prev = 0.0
    for t0, w in steps:
        dt = np.maximum(t - t0, 0.0)
        out += (w - prev) * (dt - tau * (1 - np.exp(-dt / tau)))
        prev = w
    return out


def test_tau_is_the_gap_between_the_angle_asymptotes():
    tau = 0.08
    steps = [(0.0, 0.0), (1.2, 2.0), (2.4, 5.0), (3.6, 1.0)]     # (t0, speed)
    plateaus = []
    for t0, _ in steps:
        t = np.linspace(t0 + 0.6, t0 + 1.2, 60)              # the steady part of each plateau
        plateaus.append(fit.fit_plateau(0, t0, list(t), list(_angle(t, steps, tau))))
    assert [p.speed for p in plateaus] == pytest.approx([0.0, 2.0, 5.0, 1.0], abs=1e-3)
    assert fit.tau_from_plateaus(plateaus, 0.5) == pytest.approx(tau, rel=1e-3)
    with pytest.raises(fit.FitError, match='no speed step'):
        fit.tau_from_plateaus(plateaus[:1], 0.5)


def test_speed_lines_leave_out_the_dead_band_and_give_trim_and_full_scale():
    k, zero, band = 0.04, -7.0, 19.0        # rad/s per code, amplifier zero, dead band (codes)

    def speed(x):
        u = x - zero
        return math.copysign(max(abs(u) - band, 0.0), u) * k
    points = [(x, speed(x)) for x in range(-128, 129, 16)]
    m = fit.wheel_model(points, min_speed=0.5)
    assert m.zero_offset == pytest.approx(zero)
    assert m.deadband_codes == pytest.approx(band)
    assert m.full_scale == pytest.approx(k * 511)
    # The trim that cancels it: written code = 512 + trim + sign * x.
    assert fit.new_trim(m.zero_offset, 1, 0) == pytest.approx(-7.0)
    assert fit.new_trim(m.zero_offset, -1, 3) == pytest.approx(10.0)
    with pytest.raises(fit.FitError, match='backward: 0 level'):
        fit.wheel_model([(x, w) for x, w in points if x > -40], min_speed=0.5)


def test_geometry_and_pi_gains():
    assert fit.radius_from_run(1.0, 9.9, 10.1) == pytest.approx(0.1)
    assert fit.track_from_turn(0.1, -13.2, 13.2, 2 * math.pi) == pytest.approx(0.42016, rel=1e-4)
    with pytest.raises(fit.FitError, match='disagree in sign'):
        fit.track_from_turn(0.1, 13.2, -13.2, 2 * math.pi)
    kp, ki = fit.pi_gains(20.0, 0.08, 0.2)
    assert (kp, ki) == pytest.approx((0.02, 0.25))        # zero on the pole: ki/kp = 1/tau


def test_the_simulated_robot_is_the_configured_one_unless_world_robot_says_otherwise():
    control = {'wheel_radius': 0.1, 'track_width': 0.45, 'full_scale_wheel_speed': 18.0}
    cfg = dconfig.validate({'world': {}}, control=control)
    rob = cfg.world.robot
    assert (rob.wheel_radius_m, rob.track_width_m) == pytest.approx((0.1, 0.45))
    assert rob.max_wheel_rad_s == pytest.approx(18.0)
    built = dconfig.validate({'world': {'robot': {'track_width_m': 0.5}}}, control=control)
    assert built.world.robot.track_width_m == 0.5
    assert built.world.robot.wheel_radius_m == pytest.approx(0.1)
    with pytest.raises(WorldConfigError, match=r'control\.wheel_radius: must be > 0, got -1'):
        RobotParams.from_control({'wheel_radius': -1})
    with pytest.raises(dconfig.ConfigError, match=r'control: expected a mapping'):
        dconfig.validate({}, control=[0.1])


@pytest.mark.parametrize('robot, message', [
    ({'deadband_v': -0.1}, r'world\.robot\.deadband_v: must be >= 0'),
    ({'amp_offset_left_v': 30.0}, r'world\.robot\.amp_offset_left_v: must be within the supply'),
])
def test_bad_as_built_values_are_refused_by_name(robot, message):
    with pytest.raises(WorldConfigError, match=message):
        WorldConfig.from_dict({'robot': robot})


def test_amplifier_offset_and_dead_band_on_ground_truth():
    # The left offset beyond dead band and friction (creeps), the right one inside (still).
    cfg = WorldConfig.from_dict({'robot': {'amp_offset_left_v': 2.0, 'amp_offset_right_v': 0.3,
                                           'deadband_v': 0.9}, 'obstacles': []})
    t = [0]
    world = World(cfg, clock=lambda: t[0], t0_ns=0)
    t[0] = int(2e9)                                   # zero volts for 2 s
    world.now()
    left, right = world.state().wheel_speed
    rob = cfg.robot
    # the motor's speed line at (2.0 - 0.9) V, less the friction's share (drive.py)
    assert left == pytest.approx(rob.steady_wheel_speed(0.0, LEFT), rel=1e-4)
    assert 0.0 < left < (2.0 - 0.9) / 24.0 * rob.max_wheel_rad_s
    assert right == 0.0                                                 # inside: still
    world.set_enable_until(t[0])                      # enable dropped: no drive, offset gone
    t[0] += int(2e9)
    world.now()
    assert world.state().wheel_speed[LEFT] == pytest.approx(0.0, abs=1e-6)
    world.set_enable_until(None)
    world.set_motor_voltage(RIGHT, 6.0)
    t[0] += int(2e9)
    world.now()
    assert world.state().wheel_speed[RIGHT] == pytest.approx(
        rob.steady_wheel_speed(6.0, RIGHT), rel=1e-4)


def test_sim_robot_refuses_a_control_section_it_cannot_build_a_robot_from(tmp_path, capsys,
                                                                          m4k_runtime_dir):
    from m4k_drivers import sim_robot
    overlay = tmp_path / 'bad.yaml'
    overlay.write_text('control: {wheel_radius: big}\n')
    assert sim_robot.main(['--overlay', str(overlay), '--runtime-dir', m4k_runtime_dir,
                           '--priority', '0']) == 2
    assert "control.wheel_radius: expected a number, got 'big'" in capsys.readouterr().err


def test_the_simulated_footprint_is_the_robot_body_and_the_shipped_world_sets_no_geometry():
    body = {'length': 0.5, 'width': 0.3}
    rob = dconfig.validate({'world': {}}, control={}, body=body).world.robot
    assert (rob.length_m, rob.width_m) == (0.5, 0.3)
    with pytest.raises(WorldConfigError, match=r'robot\.body\.width: must be > 0, got 0'):
        RobotParams.from_control({}, {'width': 0})
    # One source per physical value: the shipped world.robot leaves wheel, track, gear, top
    # speed and footprint to control.yaml and robot.yaml.
    import yaml

    from m4k_rt.config import find_config_dir
    with open(f'{find_config_dir()}/devices.yaml', encoding='utf-8') as f:
        shipped = yaml.safe_load(f)['world']['robot']
    assert not {'wheel_diameter_m', 'track_width_m', 'gear_ratio', 'top_speed_mps',
                'length_m', 'width_m'} & set(shipped), shipped


def test_brake_results_go_to_the_guards_keys_of_the_overlay():
    from m4k_drivers.calibrate import cli
    res = {'brake': {'decel_mps2': 2.83, 'reaction_s': 0.012, 'speed_mps': 0.48, 'points': 7,
                     'radius_m': 0.1016}}
    doc = cli.overlay_doc(res)
    # the actuation part of t_react only: there is no key that replaces the whole t_react
    assert doc == {'control': {'guard': {'brake_deceleration': 2.83, 'amplifier_lag': 0.012}}}
    assert any('brake_deceleration' in line for line in cli._comments(res))
    res['brake']['reaction_s'] = -0.001            # noise before the write: never negative
    doc = cli.overlay_doc(res)
    assert doc['control']['guard']['amplifier_lag'] == cli.ACTUATION_FLOOR_S
    from m4k_rt.config import deep_merge, load_layered
    from m4k_rt.control.params import control_params
    control_params(deep_merge(load_layered()['control'], doc['control']))


def test_a_calibrated_robot_keeps_the_stop_distance_its_sensors_need_at_top_speed():
    """calibrate's overlay, then rt_core's plan: d(top) still pays the laser's delay.

    The issue-39 failure: the measured 12 ms replaced the whole t_react and d(2 m/s) fell from
    2.64 m to 1.08 m, shorter than a laser-only obstacle needs. The physical need at top
    speed: the laser's delay (2 periods + a sweep) at v, plus braking at the calibrated
    deceleration, plus the margin -- whatever calibrate measured.
    """
    from m4k_drivers.calibrate import cli
    from m4k_rt.config import deep_merge, load_layered, parse
    from m4k_rt.control.guard import stop_distance
    from m4k_rt.control.params import control_params
    from m4k_rt.control.reaction import reaction
    from m4k_rt.tasks.actuator import guard_plan
    raw = load_layered()
    for measured in (0.012, -0.001, 0.3):
        doc = cli.overlay_doc({'brake': {'decel_mps2': 2.83, 'reaction_s': measured,
                                         'speed_mps': 0.48, 'points': 7, 'radius_m': 0.1016}})
        merged = deep_merge(raw, doc)
        params = control_params(merged['control'])
        cfg = parse(merged)
        periods = {t.name: t.period_ns * 1e-9 for t in cfg.tasks}
        shared = type('S', (), {'config': cfg})()
        plan = guard_plan(params, periods['actuator'], shared)
        v = plan.top_speed
        assert v == params.linear.max_velocity == 2.0
        sensor_delay = 2 * periods['lrf'] + params.guard.laser_scan_time
        need = v * sensor_delay + v * v / (2 * 2.83) + params.guard.stop_distance
        d = stop_distance(v, plan.reaction_time, plan.brake_deceleration, plan.margin)
        assert d > need, (measured, d, need)
        # the one derivation: the plan's t_react is the three parts, the actuation measured
        # (the stop zone's sensor part also covers the sensors' staleness timeouts)
        r = reaction(params.guard, 'laser', periods['lrf'], periods['actuator'], timeouts=True)
        assert plan.reaction_time == r.total
        assert r.actuation_part == max(measured, cli.ACTUATION_FLOOR_S)
        assert r.sensor_part == max(sensor_delay, params.guard.laser_timeout,
                                    params.guard.sonar_timeout)
