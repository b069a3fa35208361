"""The pure ROS-argument parser of the non-rclpy executables (m4k_rt.rosargs)."""

import argparse
import logging

import pytest

from m4k_rt import rosargs


def _tool() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='rt_core')
    ap.add_argument('--config')
    return ap


def test_launch_ros_node_command_line_is_split_off():
    # What launch_ros's Node builds: exe, arguments, --ros-args, -r __node, --params-file of
    # the dict parameters, -p rules, -r __ns, remappings (node.py, in that order).
    argv = ['--config', 'o.yaml', '--ros-args', '-r', '__node:=rt_core', '--params-file',
            '/tmp/launch_params_abc', '-p', 'x:=1.5', '-r', '__ns:=/robot1', '-r',
            'odom:=odom2']
    rest, ros = rosargs.split(argv, 'rt_core')
    assert rest == ['--config', 'o.yaml']
    assert ros.present and ros.node_name == 'rt_core' and ros.namespace == '/robot1'
    assert ros.params_files == ['/tmp/launch_params_abc'] and ros.params == {'x': '1.5'}
    assert ros.remaps == [(None, 'odom', 'odom2')]
    assert ros.name('x') == '/robot1/rt_core'


def test_sections_end_at_double_dash_and_may_repeat():
    argv = ['--ros-args', '--log-level', 'debug', '--', '--config', 'a', '--ros-args', '-e',
            '/enc', '--enable-rosout-logs', '--disable-stdout-logs', '--log-level',
            'rt_core:=warn']
    rest, ros = rosargs.split(argv)
    assert rest == ['--config', 'a']
    assert ros.log_levels == {'': 'debug', 'rt_core': 'warn'} and ros.enclave == '/enc'
    assert ros.switches == {'rosout-logs': True, 'stdout-logs': False}
    assert rosargs.python_level(ros) == logging.DEBUG
    assert rosargs.python_level(ros, 'rt_core') == logging.WARNING


def test_node_prefixed_rules_apply_to_their_node_only():
    _, ros = rosargs.split(['--ros-args', '-r', 'other:__node:=x', '-r', 'me:__ns:=/n'], 'me')
    assert ros.node_name is None and ros.namespace == '/n'


def test_no_ros_args_leaves_everything():
    rest, ros = rosargs.split(['--config', 'x', '--', 'y'])
    assert rest == ['--config', 'x', '--', 'y'] and not ros.present


@pytest.mark.parametrize('argv, words', [
    (['--ros-args', '-r'], '-r needs a value'),
    (['--ros-args', '--params-file'], '--params-file needs a value'),
    (['--ros-args', '--config', 'x'], "unknown ROS argument '--config'"),
    (['--ros-args', '-r', 'nosep'], 'expected [node:]from:=to'),
    (['--ros-args', '-r', '__ns:=relative'], 'must be absolute'),
    (['--ros-args', '-p', ':=3'], 'expected name:=value'),
    (['--ros-args', '--log-level', 'loud'], 'unknown severity'),
])
def test_malformed_sections_name_the_argument(argv, words):
    with pytest.raises(rosargs.RosArgsError, match=words.replace('[', r'\[')):
        rosargs.split(argv)


def test_parse_args_hands_the_rest_to_argparse(capsys):
    ns = rosargs.parse_args(_tool(), ['--ros-args', '-r', '__node:=core', '--', '--config',
                                      'f.yaml'])
    assert ns.config == 'f.yaml' and ns.ros_args.node_name == 'core'
    with pytest.raises(SystemExit) as info:
        rosargs.parse_args(_tool(), ['--ros-args', '--bogus'])
    assert info.value.code == 2
    assert "unknown ROS argument '--bogus'" in capsys.readouterr().err


def test_parse_args_sets_the_python_log_level():
    root = logging.getLogger()
    old = root.level
    try:
        rosargs.parse_args(_tool(), ['--ros-args', '--log-level', 'ERROR'])
        assert root.level == logging.ERROR
    finally:
        root.setLevel(old)


def test_rosargs_does_not_import_rclpy():
    import subprocess
    import sys
    code = ('import sys, m4k_rt.rosargs, m4k_rt.rt_core, m4k_rt.description; '
            'sys.exit(1 if "rclpy" in sys.modules else 0)')
    assert subprocess.run([sys.executable, '-c', code], timeout=60).returncode == 0
