"""The shipped recipes under config/: generated, taken in and resolved as their consumers do.

* Generated: every recipe is ``m4k_bringup.recipes``' output for config/; a stale one fails,
  and a change of control.yaml reaches the Nav2 limits.
* Taken in: each parameter file is loaded by rcl (``rcl_yaml_param_parser``, through a real
  rclpy node of the consumer's fully qualified name, as the C++ node's rcl picks its section).
* Resolved: every topic name a consumer reads from its parameters (or has fixed in its code) is
  expanded and remapped by rcl as that node would -- its namespace, the stock launch file's
  remaps -- and the resulting graph with the m4k bridge is checked by
  ``m4k_bridge.graphcheck`` (the check ``doctor`` runs live): each subscription fed by a
  publisher of the same type and a compatible QoS (test/consumers.py).
* Keyed: each key is one the Jazzy node reads, with its type (test/upstream_keys.py).
"""

import copy
import dataclasses
import math
import os
import types

import consumers
import pytest
import upstream_keys
from wsenv import ROOT
import yaml

from m4k_bridge import fleetcheck, graphcheck, params, safety
from m4k_bringup import fleet, recipes
from m4k_bringup import robots as robots_mod
from m4k_rt import config, description
from m4k_rt.control.guard import front_offset as guard_front_offset
from m4k_rt.control.params import control_params
from m4k_rt.tasks.actuator import guard_plan

pytestmark = pytest.mark.allow_leaks('fds')  # FastDDS keeps its sockets for the process
CONFIG = os.path.join(ROOT, 'config')
NAV2 = 'nav2/nav2_params.yaml'
NAV2_MUX = 'nav2/nav2_params_twist_mux.yaml'
RECIPES = (NAV2, NAV2_MUX, 'slam_toolbox/mapper_params_online_async.yaml',
           'twist_mux/twist_mux.yaml', 'robot_localization/ekf.yaml',
           'diagnostics/aggregator.yaml')


def _load(rel):
    with open(os.path.join(CONFIG, rel), encoding='utf-8') as f:
        return yaml.safe_load(f)


def _nodes(doc):
    """Return node name -> ros__parameters of a ROS parameter file (one namespace deep too)."""
    out = {}
    for key, section in doc.items():
        assert isinstance(section, dict), key
        if 'ros__parameters' in section:
            assert set(section) == {'ros__parameters'}, key
            out[key] = section['ros__parameters']
        else:
            for sub, inner in section.items():
                assert set(inner) == {'ros__parameters'}, (key, sub)
                out['{}/{}'.format(key, sub)] = inner['ros__parameters']
    return out


def _joints():
    return description.joints(description.urdf(description.model(config.load_layered())))


def _links():
    return {j.child for j in _joints()} | {j.parent for j in _joints()}


@pytest.mark.parametrize('rel', RECIPES)
def test_recipe_is_a_ros_parameter_file_and_its_bridge_section_is_valid(rel):
    nodes = _nodes(_load(rel))
    assert nodes
    if 'm4k_bridge' in nodes:   # checked exactly as the bridge checks a --params-file
        params.check_section(_load(rel))


@pytest.mark.parametrize('rel', RECIPES)
def test_every_key_is_one_the_jazzy_node_reads_with_its_type(rel):
    # m4k_bridge sections are the bridge's own, checked above exactly as the bridge does.
    found = [p for node, params in _nodes(_load(rel)).items() if node != 'm4k_bridge'
             for p in upstream_keys.problems(node, params)]
    assert found == []


@pytest.mark.parametrize(('node', 'params', 'expected'), [
    ('local_costmap/local_costmap',
     {'plugins': ['inflation_layer'],
      'inflation_layer': {'plugin': 'nav2_costmap_2d::InflationLayer', 'inflation_radious': 0.4}},
     ['local_costmap/local_costmap.inflation_layer.inflation_radious: not read upstream']),
    ('local_costmap/local_costmap',
     {'plugins': ['obstacle_layer'],
      'obstacle_layer': {'plugin': 'nav2_costmap_2d::ObstacleLayer', 'observation_sources': 'scan',
                         'scan': {'raytrace_range': 5.6, 'inf_is_valid': 'true'}}},
     ['local_costmap/local_costmap.obstacle_layer.scan.raytrace_range: not read upstream',
      'local_costmap/local_costmap.obstacle_layer.scan.inf_is_valid: str where upstream '
      'declares bool']),
    ('local_costmap/local_costmap', {'plugins': ['range_layer'], 'range_layer': {'topics': []}},
     ['local_costmap/local_costmap.range_layer.plugin: missing']),
    ('twist_mux', {'use_stamped': False,
                   'locks': {'e_stop': {'topic': 'e_stop_state', 'timeout': 0, 'priority': 255}}},
     ['twist_mux.locks.e_stop.timeout: int where upstream declares float']),
    ('twist_mux', {'use_stamped': False, 'topics': {'nav': {'topic': 'a', 'timeout': 0.5}}},
     ['twist_mux.topics.nav.priority: missing']),
    ('twist_mux', {'topics': {}},
     ['twist_mux.use_stamped: missing (twist_mux >= 4.4.0 aborts)']),
    ('controller_server', {'controller_plugins': ['FollowPath'],
                           'FollowPath': {'plugin': 'nav2_mppi_controller::MPPIController',
                                          'az_min': -1.0, 'critics': ['CostCritc']}},
     ['controller_server.FollowPath.az_min: not read upstream',
      'controller_server.FollowPath.critics: unknown critic CostCritc']),
    ('collision_monitor', {'polygons': ['Stop'], 'observation_sources': ['scan'],
                           'Stop': {'type': 'polygon'}, 'scan': {'type': 'laser'}},
     ["collision_monitor.Stop: needs a type of ('polygon', 'circle', 'velocity_polygon') "
      'and an action_type',
      "collision_monitor.scan.type: not ('scan', 'pointcloud', 'range', 'polygon')"]),
    ('ekf_filter_node', {'odom0': 'odom', 'odom0_config': [True] * 14, 'imu1': 'imu'},
     ['ekf_filter_node.odom0_config: 14 entries, the state has 15',
      'ekf_filter_node: imu indices [1] have a gap']),
    ('ekf_filter_node', {'base_frame': 'base_footprint'},
     ['ekf_filter_node.base_frame: not read upstream']),
    ('velocity_smoother', {'max_velocity': [0.5, 0, 1.5]},
     ['velocity_smoother.max_velocity: mixed[] where upstream declares float[]']),
    ('analyzers', {'rt': {'type': 'diagnostic_aggregator/GenericAnalyzer', 'startwith': ['a']}},
     ['analyzers.rt.startwith: not read upstream', 'analyzers.rt: needs a known type and a path']),
])
def test_the_upstream_key_check_catches_misspelled_misplaced_and_mistyped_keys(
        node, params, expected):
    assert upstream_keys.problems(node, params) == expected


def test_obstacle_sources_keep_the_scan_points_at_the_laser_height():
    # Jazzy drops every point of a source above its max_obstacle_height (default 0.0) in the
    # costmap's frame: the scan plane is the laser's height above base_footprint.
    up = {j.child: (j.parent, j.xyz[2]) for j in _joints()}
    frame, height = params.spec('laser_frame').default, 0.0
    while frame != 'base_footprint':
        frame, dz = up[frame]
        height += dz
    assert height > upstream_keys.SOURCE_DEFAULT_MAX_OBSTACLE_HEIGHT
    n = _nodes(_load(NAV2))
    for costmap in ('local_costmap/local_costmap', 'global_costmap/global_costmap'):
        layer = n[costmap]['obstacle_layer']
        for src in layer['observation_sources'].split():
            s = layer[src]
            assert s.get('min_obstacle_height', 0.0) <= height, (costmap, src)
            assert s.get('max_obstacle_height', upstream_keys.SOURCE_DEFAULT_MAX_OBSTACLE_HEIGHT) \
                >= height, (costmap, src)


def test_nav2_frames_footprint_and_scan_match_the_robot():
    n = _nodes(_load(NAV2))
    links = _links()
    assert n['amcl']['base_frame_id'] == 'base_footprint' in links
    assert n['collision_monitor']['base_frame_id'] == 'base_footprint'
    layered = config.load_layered()
    body = layered['robot']['body']
    # the wheels stand outside the body: their outer faces are the footprint's sides there
    wheel_face = layered['control']['track_width'] / 2 + layered['robot']['wheel_width'] / 2
    for costmap in ('local_costmap/local_costmap', 'global_costmap/global_costmap'):
        c = n[costmap]
        assert c['robot_base_frame'] in links
        pts = yaml.safe_load(c['footprint'])
        xs, ys = [p[0] for p in pts], [p[1] for p in pts]
        assert max(xs) - min(xs) == pytest.approx(body['length']) == pytest.approx(0.45)
        assert max(ys) == -min(ys) == pytest.approx(wheel_face) == pytest.approx(0.225)
        # the body's sides are there too (not the bounding box of the wheels)
        assert sorted({abs(y) for y in ys}) == pytest.approx([body['width'] / 2, wheel_face])
        scan = c['obstacle_layer']['scan']
        assert scan['inf_is_valid'] is True and scan['data_type'] == 'LaserScan'
        assert scan['topic'] == '/' + params.spec('topics.scan').default    # absolute
    rng = n['local_costmap/local_costmap']['range_layer']
    assert rng['clear_on_max_reading'] is True
    assert rng['topics'] == ['/' + params.spec('topics.sonar').default]
    assert n['m4k_bridge']['sonar_no_echo'] == 'max_range'


@pytest.mark.parametrize('rel', (NAV2, NAV2_MUX))
def test_nav2_controller_and_smoother_limits_are_control_yaml_s(rel):
    n = _nodes(_load(rel))
    c = config.load_layered()['control']
    lin, ang = c['linear'], c['angular']
    vs, mppi = n['velocity_smoother'], n['controller_server']['FollowPath']
    assert vs['max_accel'] == [lin['max_acceleration'], 0.0, ang['max_acceleration']]
    assert vs['max_decel'] == [-lin['max_deceleration'], 0.0,
                               -(ang['max_deceleration'] or ang['max_acceleration'])]
    assert vs['max_velocity'][0] <= lin['max_velocity']
    assert vs['max_velocity'][2] == ang['max_velocity']
    assert (mppi['ax_max'], mppi['ax_min'], mppi['az_max'], mppi['wz_max']) == (
        lin['max_acceleration'], -lin['max_deceleration'], ang['max_acceleration'],
        ang['max_velocity'])
    assert mppi['vx_max'] == vs['max_velocity'][0] <= lin['max_velocity']
    assert n['behavior_server']['rotational_acc_lim'] == ang['max_acceleration']


@pytest.mark.parametrize('rel', (NAV2, NAV2_MUX))
def test_nav2_speeds_are_within_the_collision_guards_caps(rel):
    # what rt_core states at start-up: the guard's top forward speed and its reverse creep
    layered = config.load_layered(config_dir=CONFIG)
    cfg = config.parse(layered)
    plan = guard_plan(control_params(layered['control']),
                      cfg.task('actuator').period_ns * 1e-9, types.SimpleNamespace(config=cfg),
                      layered['robot'])
    n = _nodes(_load(rel))
    vs, mppi = n['velocity_smoother'], n['controller_server']['FollowPath']
    assert 0.0 < mppi['vx_max'] <= plan.top_speed and mppi['vx_min'] == -plan.reverse_creep
    assert vs['max_velocity'][0] == mppi['vx_max'] and vs['min_velocity'][0] == \
        -plan.reverse_creep


def _nav_latency(n, plan):
    # scan -> guard-side pipeline and actuation (t_react) + one period of each Nav2 loop
    return (plan.reaction_time + 1.0 / n['local_costmap/local_costmap']['update_frequency']
            + 1.0 / n['controller_server']['controller_frequency']
            + 1.0 / n['velocity_smoother']['smoothing_frequency'])


@pytest.mark.parametrize('rel', (NAV2, NAV2_MUX))
def test_nav2_can_stop_from_its_top_speed_inside_what_it_marks_plans_and_watches(rel):
    # d_nav(v) = v t_nav + v^2 / (2 a) + margin at control.yaml's deceleration: the marking
    # range holds it (ahead of the front face), the MPPI horizon lasts the stop, and the
    # collision monitor's approach starts slowing early enough to stop at that deceleration
    layered = config.load_layered(config_dir=CONFIG)
    cfg = config.parse(layered)
    params_ = control_params(layered['control'])
    plan = guard_plan(params_, cfg.task('actuator').period_ns * 1e-9,
                      types.SimpleNamespace(config=cfg), layered['robot'])
    n = _nodes(_load(rel))
    mppi = n['controller_server']['FollowPath']
    v, a = mppi['vx_max'], -mppi['ax_min']
    t_nav = _nav_latency(n, plan)
    d_nav = v * t_nav + v * v / (2 * a) + params_.guard.stop_distance
    ahead = guard_front_offset(layered['robot'], 'laser')
    for costmap in ('local_costmap/local_costmap', 'global_costmap/global_costmap'):
        scan = n[costmap]['obstacle_layer']['scan']
        assert d_nav + ahead <= scan['obstacle_max_range'] <= scan['raytrace_max_range']
    assert mppi['time_steps'] * mppi['model_dt'] >= t_nav + v / a
    assert mppi['model_dt'] == pytest.approx(1.0 / n['controller_server']['controller_frequency'])
    cm = n['collision_monitor']
    t_mon = plan.reaction_time + 1.0 / n['velocity_smoother']['smoothing_frequency']
    tbc = cm['FootprintApproach']['time_before_collision']
    assert tbc >= t_mon + v / (2 * a)
    assert v * tbc <= n['local_costmap/local_costmap']['obstacle_layer']['scan'][
        'obstacle_max_range']       # the monitor's scan source sees where it starts slowing
    # the old file's 2 m/s with 5.0 m marking could not: 5.4 m to stop at 0.37 m/s^2
    assert 2.0 * t_nav + 2.0 ** 2 / (2 * a) > 5.0


def test_a_changed_guard_or_top_speed_moves_the_nav2_speeds():
    changed = copy.deepcopy(config.load_layered(config_dir=CONFIG))
    changed['control']['linear']['max_velocity'] = 0.8
    changed['control']['guard']['reverse_creep_speed'] = 0.05
    n = _nodes(yaml.safe_load(recipes.generate(changed)[NAV2]))
    assert n['controller_server']['FollowPath']['vx_max'] == 0.8
    assert n['velocity_smoother']['min_velocity'][0] == -0.05
    # a laser that sees less than the top speed needs: the guard's (lower) cap, not 0.8
    changed['control']['guard']['laser_range'] = 1.0
    vx = _nodes(yaml.safe_load(recipes.generate(changed)[NAV2]))[
        'controller_server']['FollowPath']['vx_max']
    assert 0.0 < vx < 0.8
    # with the guard off nothing caps reverse but the base
    changed['control']['guard']['enabled'] = False
    n = _nodes(yaml.safe_load(recipes.generate(changed)[NAV2]))
    assert n['velocity_smoother']['min_velocity'][0] == -0.8


def test_the_local_costmap_reaches_as_far_as_nav2_needs_to_stop():
    layered = config.load_layered(config_dir=CONFIG)
    n = _nodes(_load(NAV2))
    local = n['local_costmap/local_costmap']
    vx = n['controller_server']['FollowPath']['vx_max']
    decel = -n['controller_server']['FollowPath']['ax_min']
    stop = vx ** 2 / (2 * decel) + layered['robot']['body']['length'] / 2
    laser = local['obstacle_layer']['scan']['raytrace_max_range']
    assert local['width'] == local['height']
    # the window reaches the stop (plus the body) ahead, or the laser's whole range
    assert local['width'] / 2 >= min(stop, laser), (local['width'], stop, laser)
    assert local['width'] / 2 <= laser + 1
    # a slow robot keeps Nav2's stock 3 m window
    slow = copy.deepcopy(layered)
    slow['control']['linear']['max_velocity'] = 0.3
    local = _nodes(yaml.safe_load(recipes.generate(slow)[NAV2]))['local_costmap/local_costmap']
    assert local['width'] == 3


def test_slam_toolbox_uses_the_urg_range_and_the_odometry_child_frame():
    p = _nodes(_load('slam_toolbox/mapper_params_online_async.yaml'))['slam_toolbox']
    assert p['max_laser_range'] == pytest.approx(5.6)
    assert p['base_frame'] == params.spec('footprint_frame').default
    assert p['odom_frame'] == params.spec('odom_frame').default
    assert p['scan_topic'].lstrip('/') == params.spec('topics.scan').default


def test_twist_mux_locks_on_e_stop_state():
    p = _nodes(_load('twist_mux/twist_mux.yaml'))['twist_mux']
    assert p['locks']['e_stop']['topic'] == '/' + params.spec('topics.e_stop_state').default
    assert p['use_stamped'] is params.spec('enable_stamped_cmd_vel').default is False
    assert p['locks']['e_stop']['priority'] > max(t['priority'] for t in p['topics'].values())
    # twist_mux subscribes to locks volatile (it never gets the latched sample) and reads an
    # unheard lock as released unless a timeout makes it expire: the timeout must outlast the
    # bridge's republish period, so the lock holds until the state is heard and after it stops.
    assert p['locks']['e_stop']['timeout'] > safety._STATE_PERIOD_S


def test_ekf_fuses_wheel_velocity_and_imu_yaw_rate_and_owns_the_transform():
    n = _nodes(_load('robot_localization/ekf.yaml'))
    p = n['ekf_filter_node']
    assert p['base_link_frame'] == 'base_footprint' and p['two_d_mode'] is True
    odom, imu = p['odom0_config'], p['imu0_config']
    assert len(odom) == len(imu) == 15
    assert [i for i, v in enumerate(odom) if v] == [6, 7, 11]     # vx, vy, vyaw
    assert [i for i, v in enumerate(imu) if v] == [11]            # yaw rate
    # Fused as docs/nav2.md says: vy is zero *observed*, so the odometry must carry a variance
    # an EKF weighs (a 1e6 "unknown" makes the fusion a no-op). Twist diagonal: vx vy vz wx wy
    # wz; every fused axis has a measured-size variance.
    twist = params.spec('odom_twist_covariance_diagonal').default
    for state, axis in ((6, 0), (7, 1), (11, 5)):
        assert odom[state] and 0.0 < twist[axis] <= 0.01, upstream_keys.EKF_STATE[state]
    # One publisher of odom -> base_footprint: the EKF's publish_tf excludes the bridge's.
    assert p['publish_tf'] is (not n['m4k_bridge']['publish_tf'])


def test_diagnostic_analyzers_cover_every_status_prefix():
    p = _nodes(_load('diagnostics/aggregator.yaml'))['analyzers']
    prefixes = {s for a in p.values() if isinstance(a, dict) for s in a['startswith']}
    assert prefixes == {'m4k_rt', 'm4k_bridge', 'm4k_drivers'}


def test_rviz_config_has_the_displays_with_the_qos_m4k_publishes():
    doc = _load('rviz/m4k.rviz')
    vm = doc['Visualization Manager']
    assert vm['Global Options']['Fixed Frame'] == 'odom'
    by_class = {d['Class'].split('/')[-1]: d for d in vm['Displays']}
    for name in ('RobotModel', 'TF', 'LaserScan', 'Range', 'Imu', 'Odometry'):
        assert name in by_class, name
    for name, topic in (('LaserScan', '/scan'), ('Range', '/sonar'), ('Imu', '/imu')):
        t = by_class[name]['Topic']
        assert t['Value'] == topic and t['Reliability Policy'] == 'Best Effort', name
    desc = by_class['RobotModel']['Description Topic']
    assert desc['Value'] == '/robot_description'
    assert desc['Durability Policy'] == 'Transient Local'
    assert by_class['Odometry']['Topic']['Value'] == '/odom'
    assert not math.isnan(float(vm['Views']['Current']['Distance']))


# --- generated ------------------------------------------------------------------------------

def test_shipped_recipes_are_what_config_generates():
    # `recipes --check`: every generated file equals the shipped one (regenerate: `recipes`)
    assert recipes.stale(CONFIG, recipes.generate(config.load_layered(config_dir=CONFIG))) == []
    assert recipes.main(['--config-dir', CONFIG, '--check']) == 0


def test_a_changed_control_yaml_makes_the_nav2_recipes_stale(tmp_path, capsys):
    changed = copy.deepcopy(config.load_layered(config_dir=CONFIG))
    changed['control']['linear']['max_acceleration'] = 0.25
    changed['control']['linear']['max_deceleration'] = 0.25
    changed['control']['angular']['max_velocity'] = 1.0
    texts = recipes.generate(changed)
    stale = recipes.stale(CONFIG, texts)
    assert len(stale) == 2 and all('/nav2/' in d.split('\n')[0] for d in stale), stale
    n = _nodes(yaml.safe_load(texts[NAV2]))
    assert n['controller_server']['FollowPath']['ax_max'] == 0.25
    assert n['controller_server']['FollowPath']['wz_max'] == 1.0
    assert n['velocity_smoother']['max_accel'][0] == 0.25
    # and the script says so, with its exit status, for a config dir whose control.yaml changed
    for name in os.listdir(CONFIG):
        src = os.path.join(CONFIG, name)
        if os.path.isfile(src):
            with open(src, encoding='utf-8') as f:
                (tmp_path / name).write_text(f.read().replace(
                    'max_acceleration: 0.37', 'max_acceleration: 0.25'))
    capsys.readouterr()
    assert recipes.main(['--config-dir', str(tmp_path), '--out', CONFIG, '--check']) == 1
    assert '+      ax_max: 0.25' in capsys.readouterr().out


# --- resolved as the consumers resolve them -------------------------------------------------

def _write(robot, out):
    """Write the robot's recipes as `recipes --robot NAME --out DIR` does; return DIR."""
    for rel, text in recipes.generate(config.load_layered(config_dir=CONFIG), robot,
                                      str(out) if robot else '').items():
        path = out / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return str(out)


def _graph(tmp_path, robots=('',), **opts):
    """Return (endpoints, parameters by node) of the documented commands for these robots:
    the bridge as `m4k.launch.py robot:=R bridge_params:=...` and every node
    `m4k_nav2.launch.py robot:=R recipes:=DIR ...` starts (m4k_bringup.fleet)."""
    eps, seen = [], {}
    for robot in robots:
        d = _write(robot, tmp_path / (robot or 'root'))
        files = fleet.recipe_paths(d, False)
        eps += consumers.bridge_endpoints(
            robot, [files['nav2']] + ([files['ekf']] if opts.get('ekf') else []))
        found, overrides = consumers.resolve(consumers.consumers_of(fleet.nodes(robot, d,
                                                                                **opts)))
        eps += found
        seen.update(overrides)
    return eps, seen


def _fed_externally(eps, topics):
    # the bridge's inputs no recipe drives (e_stop; cmd_vel when no Nav2 runs)
    return [graphcheck.Endpoint(**{**e.__dict__, 'external': True})
            if e.m4k and e.kind == 'sub' and graphcheck.base_name(e.topic) in topics else e
            for e in eps]


GRAPHS = {
    'nav2 and slam_toolbox': {},
    'nav2 through twist_mux, with the EKF': {'mux': True, 'ekf': True},
    'nav2 and AMCL on a map': {'slam': False, 'map_file': '/maps/m4k.yaml'},
}


@pytest.mark.parametrize('robot', ['', 'r1'])
@pytest.mark.parametrize('graph', sorted(GRAPHS))
def test_every_consumer_name_resolves_to_a_matching_m4k_topic(graph, robot, tmp_path):
    eps, _ = _graph(tmp_path, (robot,), **GRAPHS[graph])
    assert graphcheck.check(_fed_externally(eps, ('e_stop',))) == []
    # every sensor input is the bridge's own topic, in the robot's namespace
    bridge = {e.topic: e for e in eps if e.m4k}
    sensors = (consumers.LASER, consumers.RANGE, consumers.IMU, consumers.ODOM)
    subs = [e for e in eps if e.kind == 'sub' and e.type in sensors]
    assert subs
    for e in subs:
        assert e.topic in bridge and bridge[e.topic].kind == 'pub', e
        assert e.topic.count('/') == (2 if robot else 1), e
    # every tf listener reads its own robot's tree, which the bridge publishes
    tf_subs = [e for e in eps if e.type == consumers.TF and e.kind == 'sub']
    assert tf_subs and all(e.topic in bridge for e in tf_subs)
    assert {e.topic for e in tf_subs} == ({'/r1/tf', '/r1/tf_static'} if robot
                                          else {'/tf', '/tf_static'})


def test_three_robots_as_documented_form_three_separate_graphs(tmp_path):
    robots = ('r1', 'r2', 'r3')
    eps, _ = _graph(tmp_path, robots, mux=True, ekf=True)
    assert graphcheck.check(_fed_externally(eps, ('e_stop',))) == []
    for e in eps:   # nothing crosses robots: every name is in its node's namespace
        ns = e.node.split('/')[1]
        assert ns in robots and e.topic.startswith('/' + ns + '/'), e
    # one odom -> base_footprint broadcaster per tree: the EKF's, the bridge's is off
    tf_pubs = sorted((e.topic, e.node) for e in eps if e.type == consumers.TF
                     and e.kind == 'pub' and e.topic.endswith('/tf') and not e.m4k)
    assert tf_pubs == [('/{}/tf'.format(r), n) for r in robots
                       for n in sorted(('/{}/ekf_filter_node'.format(r),
                                        '/{}/slam_toolbox'.format(r)))]


def test_upstream_docking_cmd_vel_is_a_second_writer_on_the_bridge_s_cmd_vel(tmp_path):
    # navigation_launch.py (Jazzy) gives docking_server only the tf remaps: its TwistPublisher
    # ("cmd_vel") writes the bridge's cmd_vel beside Nav2's collision monitor
    d = _write('r1', tmp_path)
    specs = [dataclasses.replace(s, remaps=fleet.TF_REMAPS) if s.name == 'docking_server'
             else s for s in fleet.nodes('r1', d)]
    found, _ = consumers.resolve(consumers.consumers_of(specs))
    eps = consumers.bridge_endpoints('r1', [fleet.recipe_paths(d, False)['nav2']]) + found
    lines = graphcheck.check(_fed_externally(eps, ('e_stop',)))
    assert len(lines) == 1 and lines[0].startswith('/r1/cmd_vel has 2 writers'), lines
    assert '/r1/docking_server' in lines[0] and '/r1/collision_monitor' in lines[0]


def test_a_tf_remap_left_out_leaves_the_node_without_its_robot_s_tree(tmp_path):
    # slam_toolbox started as online_async_launch.py does (no remaps) in /r1
    d = _write('r1', tmp_path)
    specs = [dataclasses.replace(s, remaps=()) if s.name == 'slam_toolbox' else s
             for s in fleet.nodes('r1', d)]
    found, _ = consumers.resolve(consumers.consumers_of(specs))
    eps = consumers.bridge_endpoints('r1', [fleet.recipe_paths(d, False)['nav2']]) + found
    lines = graphcheck.check(_fed_externally(eps, ('e_stop',)))
    assert any(line.startswith('/r1/slam_toolbox subscribes /tf_static') for line in lines), \
        lines


def test_the_final_nav2_output_drives_the_bridge_after_the_smoother_and_collision_monitor(
        tmp_path):
    # the cmd_vel chain as rcl resolves it: controller -> smoother -> collision monitor ->
    # bridge; with twist_mux, collision monitor -> twist_mux -> bridge (never cmd_vel_nav);
    # docking and the behaviors into the smoother too
    for mux in (False, True):
        eps, _ = _graph(tmp_path / str(mux), mux=mux)
        by = {(e.node, e.kind): e.topic for e in eps if e.type == consumers.TWIST}
        assert by[('/controller_server', 'pub')] == '/cmd_vel_nav' \
            == by[('/velocity_smoother', 'sub')] == by[('/docking_server', 'pub')] \
            == by[('/behavior_server', 'pub')]
        assert by[('/velocity_smoother', 'pub')] == '/cmd_vel_smoothed' \
            == by[('/collision_monitor', 'sub')]
        into_bridge = [e for e in eps if e.m4k and e.kind == 'sub' and e.type == consumers.TWIST]
        feeders = [e.node for e in eps if e.kind == 'pub' and e.topic == into_bridge[0].topic]
        assert feeders == (['/twist_mux'] if mux else ['/collision_monitor'])
        if mux:
            mux_in = {e.topic for e in eps if e.node == '/twist_mux' and e.kind == 'sub'}
            assert '/cmd_vel_nav' not in mux_in and by[('/collision_monitor', 'pub')] in mux_in


def test_relative_costmap_topics_are_caught_where_jazzy_resolves_them(tmp_path):
    # navigation2 #5745: Jazzy hands a layer's topic straight to the costmap node's
    # subscription, so the old recipe's relative `scan` reads /local_costmap/scan.
    d = _write('', tmp_path)
    path = tmp_path / NAV2
    doc = yaml.safe_load(path.read_text())
    layer = doc['local_costmap']['local_costmap']['ros__parameters']
    layer['obstacle_layer']['scan']['topic'] = 'scan'
    layer['range_layer']['topics'] = ['sonar']
    path.write_text(yaml.safe_dump(doc))
    specs = [s for s in fleet.nodes('', d) if s.name == 'controller_server']
    found, _ = consumers.resolve(consumers.consumers_of(specs))
    eps = [e for e in consumers.bridge_endpoints() + found if e.type != consumers.TWIST]
    lines = [line for line in graphcheck.check(_fed_externally(eps, ('e_stop',)))
             if 'local_costmap subscribes' in line]
    assert len(lines) == 2, lines
    assert lines[0].startswith('/local_costmap/local_costmap subscribes /local_costmap/scan')
    assert 'm4k publishes /scan' in lines[0]
    assert lines[1].startswith('/local_costmap/local_costmap subscribes /local_costmap/sonar')


def _flatten(tree, prefix=''):
    out = {}
    for k, v in tree.items():
        if isinstance(v, dict):
            out.update(_flatten(v, prefix + k + '.'))
        else:
            out[prefix + k] = v
    return out


@pytest.mark.parametrize('robot', ['', 'r1'])
def test_rcl_hands_every_key_to_the_node_of_its_section(robot, tmp_path):
    # rcl_yaml_param_parser, through a node of each section's fully qualified name as the
    # launch file starts it (the robot's sections nested under its namespace): every key
    # arrives with the YAML value; a file rcl refused would raise in rclpy.init
    _, seen = _graph(tmp_path, (robot,), ekf=True, mux=True)
    texts = recipes.generate(config.load_layered(config_dir=CONFIG), robot)
    for rel in (NAV2_MUX, 'slam_toolbox/mapper_params_online_async.yaml',
                'twist_mux/twist_mux.yaml', 'robot_localization/ekf.yaml'):
        doc = yaml.safe_load(texts[rel])
        for node, expected in _nodes(doc.get(robot, doc) if robot else doc).items():
            if node in ('m4k_bridge', 'amcl'):     # amcl: only with map:=
                continue
            fqn = '/'.join(['', robot, node] if robot else ['', node])
            assert fqn in seen, (fqn, sorted(seen))
            want = _flatten(expected)
            got = {k: seen[fqn].get(k) for k in want}
            assert got == want, fqn


# --- the maintainers' graph check: the documented commands, one robot and three -----------

def _fleet_problems(tmp_path, robots=('r1', 'r2', 'r3'), plant=None, **opts):
    """Return every problem doctor would name on the graph the documented commands make:
    names/types/QoS/writers (graphcheck) and, from the nodes' parameters as rcl hands them,
    duplicate TF edges, foreign-tree publishers and collision-monitor sonar sources.
    ``plant(robot, dir, specs, bridge_files) -> (specs, bridge_files)`` breaks one robot."""
    eps, params_by_node = [], {}
    for robot in robots:
        d = _write(robot, tmp_path / robot)
        files = fleet.recipe_paths(d, False)
        bridge_files = [files['nav2']] + ([files['ekf']] if opts.get('ekf') else [])
        specs = fleet.nodes(robot, d, **opts)
        if plant:
            specs, bridge_files = plant(robot, d, specs, bridge_files)
        eps += consumers.bridge_endpoints(robot, bridge_files)
        found, seen = consumers.resolve(consumers.consumers_of(specs))
        eps += found
        params_by_node.update(seen)
        ns, values = robots_mod.robot_settings(robot)
        params_by_node[ns + '/m4k_bridge'] = {
            **{f.name: f.default for f in params.SPECS},
            **robots_mod.effective_bridge_values(values, bridge_files)}
    return (graphcheck.check(_fed_externally(eps, ('e_stop',)))
            + fleetcheck.wrong_tree_publishers(eps)
            + fleetcheck.duplicate_edges(eps, params_by_node)
            + fleetcheck.sonar_source_problems(eps, params_by_node, params_by_node))


def test_the_documented_fleet_has_no_problem(tmp_path):
    assert _fleet_problems(tmp_path, ekf=True, mux=True) == []


def _only(robot):
    def wrap(plant):
        def inner(r, d, specs, files):
            return plant(d, specs, files) if r == robot else (specs, files)
        return inner
    return wrap


@_only('r2')
def _bridge_without_the_ekf_section(d, specs, files):
    return specs, files[:1]            # the EKF recipe not given to the bridge


@_only('r1')
def _upstream_docking(d, specs, files):
    return [dataclasses.replace(s, remaps=fleet.TF_REMAPS) if s.name == 'docking_server'
            else s for s in specs], files


@_only('r3')
def _sonar_in_the_monitor(d, specs, files):
    path = fleet.recipe_paths(d, True)['nav2']      # the file Nav2 reads with twist_mux
    with open(path, encoding='utf-8') as f:
        doc = yaml.safe_load(f)
    cm = doc['r3']['collision_monitor']['ros__parameters']
    cm['observation_sources'] = ['scan', 'sonar']
    cm['sonar'] = {'type': 'range', 'topic': '/r3/sonar', 'obstacles_angle': 0.1}
    with open(path, 'w', encoding='utf-8') as f:
        yaml.safe_dump(doc, f)
    return specs, files


@_only('r3')
def _sonar_in_the_monitor_and_a_bare_bridge(d, specs, files):
    # and the base started without bridge_params: "no echo" is the default +inf
    return _sonar_in_the_monitor('r3', d, specs, files)[0], []


@_only('r2')
def _ekf_without_tf_remaps(d, specs, files):
    return [dataclasses.replace(s, remaps=()) if s.name == 'ekf_filter_node' else s
            for s in specs], files


@pytest.mark.parametrize(('plant', 'expected'), [
    (_bridge_without_the_ekf_section, 'odom -> base_footprint on /r2/tf is broadcast by 2 '
                                      'nodes (/r2/ekf_filter_node, /r2/m4k_bridge)'),
    # docking past twist_mux and its e-stop lock
    (_upstream_docking, '/r1/cmd_vel has 2 writers (/r1/docking_server, /r1/twist_mux)'),
    # the documented base has sonar_no_echo: max_range, so only the points are short
    (_sonar_in_the_monitor, '/r3/collision_monitor: Range source sonar makes 4 points'),
    (_sonar_in_the_monitor_and_a_bare_bridge,
     '/r3/collision_monitor takes the sonar as Range source sonar but the bridge publishes '
     '"no echo" as +inf'),
    (_ekf_without_tf_remaps, "/r2/ekf_filter_node publishes /tf but its robot's tree is /r2/tf"),
])
def test_each_planted_mistake_in_the_documented_fleet_is_named(tmp_path, plant, expected):
    lines = _fleet_problems(tmp_path, plant=plant, ekf=True, mux=True)
    assert any(line.startswith(expected) for line in lines), lines
