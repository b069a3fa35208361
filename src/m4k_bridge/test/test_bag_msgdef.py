"""m4k_bridge.bag.msgdef: ros2msg schema texts with nested definitions, and RIHS01 hashes."""

import json

import pytest

from m4k_bridge.bag import msgdef


@pytest.fixture
def share(tmp_path):
    files = {
        'pkg/msg/Top.msg': ('# a comment\npkg/Header header\nInner[] inners\n'
                            'other/Leaf[<=3] leaves  # bounded\nuint8 MODE_A = 1\n'
                            'string<=8 name\nfloat64[36] covariance\n'),
        'pkg/msg/Header.msg': 'uint32 seq\n',
        'pkg/msg/Inner.msg': 'other/Leaf leaf\npkg/Header header\n',
        'other/msg/Leaf.msg': 'int32 x\n',
        'pkg/msg/Top.json': json.dumps({'type_hashes': [
            {'type_name': 'pkg/msg/Inner', 'hash_string': 'RIHS01_bb'},
            {'type_name': 'pkg/msg/Top', 'hash_string': 'RIHS01_aa'}]}),
    }
    for rel, text in files.items():
        p = tmp_path / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    return lambda package: str(tmp_path / package)


def test_dependencies_resolve_same_package_names_arrays_and_bounds():
    text = 'Inner a\nother/Leaf[] b\nother/msg/Leaf[3] c\nstring<=4 s\nint8 K=1\n# x/Y z\n'
    assert msgdef.dependencies(text, 'pkg') == ['pkg/Inner', 'other/Leaf']


def test_definition_holds_every_nested_type_once_depth_first(share):
    text = msgdef.message_definition('pkg/msg/Top', share)
    headers = [line for line in text.splitlines() if line.startswith('MSG: ')]
    assert headers == ['MSG: pkg/Header', 'MSG: pkg/Inner', 'MSG: other/Leaf']
    assert text.startswith('# a comment\npkg/Header header\n')
    assert text.count('=' * 80) == 3


def test_type_hash_is_the_named_types_own(share):
    assert msgdef.type_hash('pkg/msg/Top', share) == 'RIHS01_aa'
    assert msgdef.type_hash('pkg/msg/Inner', share) == ''       # no Inner.json installed


def test_missing_definition_names_the_type(share):
    with pytest.raises(msgdef.MsgDefError, match='pkg/msg/Nope'):
        msgdef.message_definition('pkg/msg/Nope', share)
    with pytest.raises(msgdef.MsgDefError, match='not a message type'):
        msgdef.split_type('a/b/c/d')


def test_definition_of_an_installed_type_decodes_real_cdr_with_mcap_ros2():
    from mcap.records import Schema
    from mcap_ros2.decoder import DecoderFactory
    from nav_msgs.msg import Odometry
    from rclpy.serialization import serialize_message
    text = msgdef.message_definition('nav_msgs/msg/Odometry')
    msg = Odometry()
    msg.header.frame_id = 'odom'
    msg.child_frame_id = 'base_link'
    msg.pose.pose.position.x = 1.25
    msg.pose.covariance[35] = 0.01
    msg.twist.twist.angular.z = -0.5
    decode = DecoderFactory().decoder_for(
        'cdr', Schema(id=1, name='nav_msgs/msg/Odometry', encoding='ros2msg',
                      data=text.encode()))
    out = decode(serialize_message(msg))
    assert (out.header.frame_id, out.child_frame_id) == ('odom', 'base_link')
    assert out.pose.pose.position.x == 1.25 and out.pose.covariance[35] == 0.01
    assert out.twist.twist.angular.z == -0.5
    assert msgdef.type_hash('nav_msgs/msg/Odometry').startswith('RIHS01_')
