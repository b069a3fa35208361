"""TF, robot_description and joint_states of the running stack, through real rclpy and DDS.

A plain ROS 2 user subscribes to /tf, /tf_static (transient local, as a tf2 listener does),
/robot_description and /joint_states next to odom, scan, imu and sonar. Checks: the tf2_msgs
type is the real Jazzy one (type hash), every frame the stack stamps its messages with
connects to ``odom`` through the published transforms, the description's wheel joints are the
ones joint_states names, and after a drive the wheel joint positions and the odom -> base_link
transform agree with the simulator's ground truth (never with the odometry under test).
"""

import math
import time

from geometry_msgs.msg import Twist
import pytest
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from test_bringup import start_bringup, write_overlay
from test_stack_e2e import RosUser
from tf2_msgs.msg import TFMessage
from wsenv import ground_truth

from m4k_rt import config, description
from m4k_rt.control.supervision import COUNT

JAZZY_TF_HASH = 'RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087'
START = [0.0, 0.9, 0.0]
STILL_M = 0.005        # m of true travel at rest (test_estop_e2e)
# rad a wheel joint may differ from the true wheel angle: a few counts of the 12-bit encoders
JOINT_TOL_RAD = 0.01
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
pytestmark = pytest.mark.allow_leaks('fds')  # FastDDS keeps its sockets for the process


@pytest.fixture
def robot(procs, tmp_path, m4k_runtime_dir):
    overlay = write_overlay(tmp_path, {'world': {'start': START}})
    proc = start_bringup(procs, tmp_path, m4k_runtime_dir, overlay, extra=['--no-status'])
    user = RosUser()
    n = user.node
    for name, typ, qos in (('tf', TFMessage, 100), ('tf_static', TFMessage, LATCHED),
                           ('robot_description', String, LATCHED),
                           ('joint_states', JointState, 10)):
        box = user.got[name] = []
        n.create_subscription(typ, name, box.append, qos)
    topics = ('odom', 'scan', 'imu', 'sonar', 'tf', 'tf_static', 'robot_description',
              'joint_states')
    try:
        try:
            user.spin_until(lambda: all(user.got[k] for k in topics)
                            or proc.poll() is not None, 60, 'every topic')
        except AssertionError:
            missing = [k for k in topics if not user.got[k]]
            raise AssertionError('no message on {}: {}'.format(
                missing, (tmp_path / 'bringup.err').read_text()[-3000:])) from None
        assert proc.poll() is None, (tmp_path / 'bringup.err').read_text()[-3000:]
        yield user, proc
    finally:
        user.close()
        if proc.poll() is None:
            proc.terminate()
            proc.wait(40)


def _parents(user):
    out = {}
    for box in ('tf_static', 'tf'):
        for msg in user.got[box]:
            for t in msg.transforms:
                out[t.child_frame_id] = t.header.frame_id
    return out


def _root(frame, parents):
    seen = [frame]
    while frame in parents and len(seen) < 50:
        frame = parents[frame]
        seen.append(frame)
    return seen


def test_tf_is_the_jazzy_type_and_every_published_frame_connects_to_odom(robot):
    user, _ = robot
    infos = user.node.get_publishers_info_by_topic('/tf') + \
        user.node.get_publishers_info_by_topic('/tf_static')
    assert infos and {str(i.topic_type_hash) for i in infos} == {JAZZY_TF_HASH}
    static = user.node.get_publishers_info_by_topic('/tf_static')
    assert static[0].qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
    parents = _parents(user)
    odom = user.got['odom'][-1]
    frames = {odom.header.frame_id, odom.child_frame_id}
    frames |= {user.got[k][-1].header.frame_id for k in ('scan', 'imu', 'sonar')}
    urdf = user.got['robot_description'][-1].data
    frames |= {j.child for j in description.joints(urdf)}          # wheels, casters too
    assert {'odom', 'base_footprint', 'base_link', 'laser', 'imu_link', 'sonar_link',
            'left_wheel_link', 'right_wheel_link'} <= frames
    for f in frames:
        chain = _root(f, parents)
        assert chain[-1] == 'odom', 'frame {!r} ends at {!r}: {}'.format(f, chain[-1], chain)


def test_description_and_joint_states_follow_the_configuration(robot):
    user, _ = robot
    urdf = user.got['robot_description'][-1].data
    doc = config.load_layered()
    expected = {j.child: j for j in description.fixed_joints(
        description.urdf(description.model(doc)))}
    static = {t.child_frame_id: t for m in user.got['tf_static'] for t in m.transforms}
    for sensor in description.SENSORS:
        frame = doc['robot']['sensors'][sensor]['frame']
        tr = static[frame].transform.translation
        assert (tr.x, tr.y, tr.z) == pytest.approx(expected[frame].xyz)
    js = user.got['joint_states'][-1]
    assert list(js.name) == [j.name for j in description.wheel_joints(urdf)]
    assert len(js.position) == len(js.velocity) == 2
    # Stamped like odom: each joint_states carries the stamp of an odom message.
    odom_stamps = {(m.header.stamp.sec, m.header.stamp.nanosec) for m in user.got['odom']}
    assert any((m.header.stamp.sec, m.header.stamp.nanosec) in odom_stamps
               for m in user.got['joint_states'])


def test_wheel_joints_and_odom_tf_follow_the_ground_truth_of_a_drive(robot, m4k_runtime_dir):
    user, _ = robot
    r = config.load_layered()['control']['wheel_radius']
    user.spin_until(lambda: ground_truth(m4k_runtime_dir) is not None, 20, 'ground truth')
    before = ground_truth(m4k_runtime_dir)
    pos0 = list(user.got['joint_states'][-1].position)
    pub = user.publisher(Twist, 'cmd_vel')
    cmd = Twist()
    cmd.linear.x = 0.25
    user.spin_for(2.5, each=lambda: pub.publish(cmd), period=0.05)
    pub.publish(Twist())
    user.wait_still(20)

    def joints_settled():
        # the last ten joint_states agree within two encoder counts: the stack sees the wheels
        # at rest now, not a message a starved bridge sent while they still turned
        last = user.got['joint_states'][-10:]
        return len(last) == 10 and all(
            max(m.position[k] for m in last) - min(m.position[k] for m in last) <= 2 * COUNT
            for k in (0, 1))
    user.spin_until(joints_settled, 20, 'joint_states at rest')
    since = time.monotonic()
    user.spin_until(lambda: ground_truth(m4k_runtime_dir) is not None
                    and time.monotonic() - since > 0.6, 10, 'a fresh ground truth report')
    after = ground_truth(m4k_runtime_dir)
    (x0, y0, th0), (x1, y1, _) = before['pose'], after['pose']
    dist = math.hypot(x1 - x0, y1 - y0)
    # It drove forward (how far in 2.5 s of commands is the load's: printed, not asserted).
    ahead = (x1 - x0) * math.cos(th0) + (y1 - y0) * math.sin(th0)
    assert ahead > STILL_M * 10, 'the robot did not drive forward: {} -> {}'.format(
        before['pose'], after['pose'])
    pos1 = list(user.got['joint_states'][-1].position)
    turned = [pos1[k] - pos0[k] for k in (0, 1)]
    print('tf_e2e: drove {:.3f} m; wheels {:.3f} / {:.3f} m at the rim'.format(
        dist, turned[0] * r, turned[1] * r))
    # Each wheel joint turned as far as the simulator's wheel truly did, at rest, whatever the
    # load: the encoders count the true wheel angle, the odometry integrates every step.
    for k, side in enumerate(('left', 'right')):
        true_turn = after['wheel_angle_' + side] - before['wheel_angle_' + side]
        assert true_turn > 0, (side, true_turn)
        assert turned[k] == pytest.approx(true_turn, abs=JOINT_TOL_RAD), (side, turned, true_turn)
    odom_tf = [t for m in user.got['tf'] for t in m.transforms
               if t.header.frame_id == 'odom' and t.child_frame_id == 'base_footprint'][-1]
    x = odom_tf.transform.translation.x
    y = odom_tf.transform.translation.y
    # odom starts at the robot's start pose: compare displacements.
    assert math.hypot(x, y) == pytest.approx(dist, abs=0.03)


def test_a_namespaced_stack_keeps_one_tree_from_odom_to_every_sensor_on_absolute_tf(
        procs, tmp_path, m4k_runtime_dir):
    # bringup --namespace r1 (as ros2 launch ... namespace:=r1): the bridge's topics move to
    # /r1/..., while /tf, /tf_static and /diagnostics stay absolute, where tf2 listeners,
    # robot_state_publisher and the diagnostic aggregator are.
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Imu, LaserScan, Range
    overlay = write_overlay(tmp_path, {'world': {'start': START}})
    proc = start_bringup(procs, tmp_path, m4k_runtime_dir, overlay,
                         extra=['--no-status', '--namespace', 'r1'])
    user = RosUser()
    try:
        n = user.node
        for name, typ, qos in (('/tf', TFMessage, 100), ('/tf_static', TFMessage, LATCHED),
                               ('/r1/odom', Odometry, 10),
                               ('/r1/scan', LaserScan, qos_profile_sensor_data),
                               ('/r1/imu', Imu, qos_profile_sensor_data),
                               ('/r1/sonar', Range, qos_profile_sensor_data),
                               ('/diagnostics', DiagnosticArray, 10)):
            box = user.got[name] = []
            n.create_subscription(typ, name, box.append, qos)
        wanted = ('/tf', '/tf_static', '/r1/odom', '/r1/scan', '/r1/imu', '/r1/sonar',
                  '/diagnostics')
        user.spin_until(lambda: all(user.got[k] for k in wanted) or proc.poll() is not None,
                        60, 'the namespaced topics')
        assert proc.poll() is None, (tmp_path / 'bringup.err').read_text()[-3000:]
        assert not n.get_publishers_info_by_topic('/r1/tf')
        assert not n.get_publishers_info_by_topic('/r1/tf_static')
        parents = {}
        for box in ('/tf_static', '/tf'):
            for msg in user.got[box]:
                for t in msg.transforms:
                    parents[t.child_frame_id] = t.header.frame_id
        odom = user.got['/r1/odom'][-1]
        assert (odom.header.frame_id, odom.child_frame_id) == ('odom', 'base_footprint')
        frames = {odom.child_frame_id} | {user.got[k][-1].header.frame_id
                                          for k in ('/r1/scan', '/r1/imu', '/r1/sonar')}
        for f in frames:
            chain = _root(f, parents)
            assert chain[-1] == 'odom', 'frame {!r} ends at {!r}: {}'.format(f, chain[-1], chain)
        assert parents['base_link'] == 'base_footprint'
    finally:
        user.close()
        if proc.poll() is None:
            proc.terminate()
            proc.wait(40)
