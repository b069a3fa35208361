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
from wsenv import ROOT
import yaml

from m4k_bridge import params
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


def _links():
    urdf = description.urdf(description.model(config.load_layered()))
    return {j.child for j in description.joints(urdf)} | {j.parent for j in
                                                          description.joints(urdf)}


@pytest.mark.parametrize('rel', RECIPES)
def test_recipe_is_a_ros_parameter_file_and_its_bridge_section_is_valid(rel):
    nodes = _nodes(_load(rel))
    assert nodes
    if 'm4k_bridge' in nodes:   # checked exactly as the bridge checks a --params-file
        params.check_section(_load(rel))


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
