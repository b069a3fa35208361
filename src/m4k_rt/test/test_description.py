"""The robot description generated from the configuration (m4k_rt.description)."""

import math

import pytest
from urdf_parser_py.urdf import URDF

from m4k_rt import config, description


@pytest.fixture(scope='module')
def doc():
    return config.load_layered()


def test_urdf_parses_with_the_ros_urdf_parser_and_matches_table_2(doc):
    robot = URDF.from_xml_string(description.urdf(description.model(doc)).encode())
    assert robot.get_root() == 'base_footprint'
    links = {link.name: link for link in robot.links}
    body = links['base_link'].visual.geometry.size
    assert body == pytest.approx([0.45, 0.28, 0.20])            # paper Table 2
    total = sum(link.inertial.mass for link in robot.links if link.inertial is not None)
    assert total == pytest.approx(30.0)
    joints = {j.name: j for j in robot.joints}
    for name, side in zip(description.WHEEL_JOINTS, (1.0, -1.0), strict=True):
        j = joints[name]
        assert j.type == 'continuous' and j.axis == [0.0, 1.0, 0.0]
        assert j.origin.xyz == pytest.approx([0.0, side * doc['control']['track_width'] / 2,
                                              0.0])
        wheel = links[j.child].collision.geometry
        assert 2 * wheel.radius == pytest.approx(0.2032)        # Table 2: 20.32 cm
    casters = [j for j in robot.joints if 'caster' in j.name]
    assert len(casters) == 2
    for j in casters:  # a caster touches the ground plane the wheels stand on
        r = links[j.child].collision.geometry.radius
        assert j.origin.xyz[2] - r == pytest.approx(-doc['control']['wheel_radius'])


def test_base_footprint_is_the_ground_point_under_base_link(doc):
    # TurtleBot3 / Kobuki layout: base_footprint (root, on the ground) -> base_link (axle).
    robot = URDF.from_xml_string(description.urdf(description.model(doc)).encode())
    base = {j.name: j for j in robot.joints}['base_joint']
    assert (base.type, base.parent, base.child) == ('fixed', 'base_footprint', 'base_link')
    assert base.origin.xyz == pytest.approx([0.0, 0.0, doc['control']['wheel_radius']])
    # The lowest point of a wheel is on the footprint's plane (z = 0 in base_footprint).
    r = doc['control']['wheel_radius']
    assert base.origin.xyz[2] - r == pytest.approx(0.0)
    old = URDF.from_xml_string(description.urdf(description.model(doc, 'base_link', ''))
                               .encode())
    assert old.get_root() == 'base_link' and 'base_joint' not in {j.name for j in old.joints}
    with pytest.raises(description.DescriptionError):
        description.model(doc, 'base_link', 'base_link')


def test_sensor_links_sit_at_the_configured_mounts(doc):
    text = description.urdf(description.model(doc))
    fixed = {j.child: j for j in description.fixed_joints(text)}
    for sensor in description.SENSORS:
        m = doc['robot']['sensors'][sensor]
        j = fixed[m['frame']]
        assert j.parent == 'base_link'
        assert list(j.xyz) + list(j.rpy) == pytest.approx(m['pose'])


def test_an_overlay_moves_the_sensor_in_the_urdf_and_the_simulator(doc):
    moved = config.deep_merge(doc, {'robot': {'sensors': {'laser': {
        'pose': [0.1, -0.05, 0.3, 0.0, 0.0, math.pi / 2]}}}})
    j = {j.child: j for j in description.fixed_joints(description.urdf(
        description.model(moved)))}['laser']
    assert j.xyz == pytest.approx((0.1, -0.05, 0.3)) and j.rpy[2] == pytest.approx(math.pi / 2)
    sim = description.fill_sim_mounts(moved)
    assert sim['devices']['lrf']['mount'] == pytest.approx([0.1, -0.05, math.pi / 2])
    assert sim['devices']['sonar']['mount'] == pytest.approx([0.225, 0.0, 0.0])


def test_a_mount_written_in_the_device_section_wins(doc):
    own = config.deep_merge(doc, {'devices': {'lrf': {'mount': [0.5, 0.0, 0.0]}}})
    assert description.fill_sim_mounts(own)['devices']['lrf']['mount'] == [0.5, 0.0, 0.0]


@pytest.mark.parametrize('patch, field', [
    ({'robot': {'body': {'length': -1}}}, 'robot.body.length'),
    ({'robot': {'sensors': {'imu': {'pose': [0, 0, 0]}}}}, 'robot.sensors.imu.pose'),
    ({'robot': {'sensors': {'sonar': {'frame': 'laser'}}}}, 'frame ids must differ'),
    ({'robot': {'caster_radius': 0.5}}, 'robot.caster_radius'),
    ({'control': {'wheel_radius': 'big'}}, 'control.wheel_radius'),
])
def test_a_bad_robot_section_names_the_field(doc, patch, field):
    with pytest.raises(description.DescriptionError, match=field):
        description.model(config.deep_merge(doc, patch))


@pytest.mark.parametrize('text, words', [
    ('<robot', 'not valid XML'),
    ('<model/>', 'root element must be <robot>'),
    ('<robot><link name="a"/><joint name="j" type="fixed"><parent link="a"/>'
     '<child link="b"/></joint></robot>', 'not both defined'),
    ('<robot><link name="base_link"/></robot>', 'no joint left_wheel_joint'),
])
def test_an_unusable_description_is_refused(text, words):
    with pytest.raises(description.DescriptionError, match=words):
        description.wheel_joints(text)


@pytest.mark.parametrize('kind, section', [
    ('lrf', {'backend': 'real', 'port': '/dev/ttyACM0'}),
    ('sonar', {'backend': 'gpio', 'chip': '/dev/gpiochip0', 'trigger_line': 23,
               'echo_line': 24}),
    ('sonar', {'backend': 'iio', 'device': '/sys/bus/iio/devices/iio:device0'}),
])
def test_a_real_sensor_gets_no_simulated_mount(doc, kind, section):
    # README "On the real robot": the overlay replaces the backend; the mount is a field of the
    # sim backend only (the real schemas refuse it), so it must not be added.
    real = config.deep_merge(doc, {'devices': {kind: section}})
    real['devices'][kind] = section
    out = description.fill_sim_mounts(real)
    assert 'mount' not in out['devices'][kind]
    other = 'sonar' if kind == 'lrf' else 'lrf'
    assert out['devices'][other]['mount'] == description.mount_2d(doc, {
        'lrf': 'laser', 'sonar': 'sonar'}[other])
