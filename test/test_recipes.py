"""The shipped recipes under config/: ROS parameter files and the RViz configuration.

Each parameter file must load as a ROS parameter file (every node section, possibly nested one
namespace deep as Nav2's costmaps are, holds ``ros__parameters``) and name the frames, topics
and limits the m4k stack really has: the frames of the generated robot description, the
bridge's topic names, the footprint of paper Table 2 and the URG-04LX range. The RViz file is
YAML with the displays a user needs, subscribed with the QoS m4k publishes with.
"""

import math
import os

import pytest
import upstream_keys
from wsenv import ROOT
import yaml

from m4k_bridge import params, safety
from m4k_rt import config, description

CONFIG = os.path.join(ROOT, 'config')
RECIPES = ('nav2/nav2_params_overlay.yaml', 'slam_toolbox/mapper_params_online_async.yaml',
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
    ('twist_mux', {'locks': {'e_stop': {'topic': 'e_stop_state', 'timeout': 0, 'priority': 255}}},
     ['twist_mux.locks.e_stop.timeout: int where upstream declares float']),
    ('twist_mux', {'topics': {'nav': {'topic': 'a', 'timeout': 0.5}}},
     ['twist_mux.topics.nav.priority: missing']),
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
    n = _nodes(_load('nav2/nav2_params_overlay.yaml'))
    for costmap in ('local_costmap/local_costmap', 'global_costmap/global_costmap'):
        layer = n[costmap]['obstacle_layer']
        for src in layer['observation_sources'].split():
            s = layer[src]
            assert s.get('min_obstacle_height', 0.0) <= height, (costmap, src)
            assert s.get('max_obstacle_height', upstream_keys.SOURCE_DEFAULT_MAX_OBSTACLE_HEIGHT) \
                >= height, (costmap, src)


def test_nav2_overlay_frames_footprint_and_scan_match_the_robot():
    n = _nodes(_load('nav2/nav2_params_overlay.yaml'))
    links = _links()
    assert n['amcl']['base_frame_id'] == 'base_footprint' in links
    assert n['collision_monitor']['base_frame_id'] == 'base_footprint'
    body = config.load_layered()['robot']['body']
    for costmap in ('local_costmap/local_costmap', 'global_costmap/global_costmap'):
        c = n[costmap]
        assert c['robot_base_frame'] in links
        pts = yaml.safe_load(c['footprint'])
        xs, ys = [p[0] for p in pts], [p[1] for p in pts]
        assert max(xs) - min(xs) == pytest.approx(body['length']) == pytest.approx(0.45)
        assert max(ys) - min(ys) == pytest.approx(body['width']) == pytest.approx(0.28)
        scan = c['obstacle_layer']['scan']
        assert scan['inf_is_valid'] is True and scan['data_type'] == 'LaserScan'
        assert scan['topic'] == params.spec('topics.scan').default
    rng = n['local_costmap/local_costmap']['range_layer']
    assert rng['clear_on_max_reading'] is True
    assert rng['topics'] == [params.spec('topics.sonar').default]
    assert n['m4k_bridge']['sonar_no_echo'] == 'max_range'
    control = config.load_layered()['control']
    vs = n['velocity_smoother']
    assert vs['max_velocity'][0] <= control['linear']['max_velocity']
    assert vs['max_accel'][0] <= control['linear']['max_acceleration']


def test_slam_toolbox_uses_the_urg_range_and_the_odometry_child_frame():
    p = _nodes(_load('slam_toolbox/mapper_params_online_async.yaml'))['slam_toolbox']
    assert p['max_laser_range'] == pytest.approx(5.6)
    assert p['base_frame'] == params.spec('footprint_frame').default
    assert p['odom_frame'] == params.spec('odom_frame').default
    assert p['scan_topic'].lstrip('/') == params.spec('topics.scan').default


def test_twist_mux_locks_on_e_stop_state():
    p = _nodes(_load('twist_mux/twist_mux.yaml'))['twist_mux']
    assert p['locks']['e_stop']['topic'] == params.spec('topics.e_stop_state').default
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
