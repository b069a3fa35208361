"""Every executable takes the command line launch_ros's ``Node`` builds, and stops on SIGTERM.

``ros2 launch`` runs ``<exe> [arguments] --ros-args -r __node:=NAME [-r __ns:=/NS]
[--params-file /tmp/launch_params_XXXX] [-r from:=to]`` (launch_ros/actions/node.py: the node
name at construction; namespace, then the parameter file written from ``parameters=[{...}]``
keyed by the fully qualified node name, then remappings, when the action executes).
:func:`launch_cmdline` builds exactly that; each console script of ``src/*/setup.py`` is run
with it. Servers must come up and end with exit code 0 on SIGTERM (what launch sends after
SIGINT); tools must get past argument parsing and do their job.
"""

import ast
import glob
import os
import re
import signal
import sys
import time

import pytest
import rclpy
from wsenv import ROOT, stack_env
import yaml

from m4k_bringup import bringup

NS = '/m4k_launch_test'
# Servers: the output line that says "up" (None: an rclpy node, found in the ROS graph).
SERVERS = {
    'rt_core': ([], r'running \d+ tasks'),
    'driver_host': (['--runtime-dir', '{rt}'], r'serving '),
    'bridge': ([], r'waiting for the RT process'),
    'bringup': (['--python-m', '--no-status'], r'starting '),
    'baseline': ([], None),
    'echo_peer': (['cmd'], r'echo peer: serving cmd'),
    'record': (['odom', '-o', '{tmp}/bag'], None),
    'sim_robot': (['--runtime-dir', '{rt}'], r'simulating '),
    'foxglove': ([], None),
}
# ROS parameters a server needs besides use_sim_time (port 0: any free port, not 8765).
SERVER_PARAMS = {'foxglove': {'port': 0}}
# Tools: arguments for a short real run, and what their output must show.
TOOLS = {
    'rt_stat': (['--wait', '0'], 1, r'no RT core'),
    'sim_truth': (['--runtime-dir', '{rt}'], 1, r'no sim_robot answering'),
    'xddp_bench': (['-n', '20', '--runtime-dir', '{rt}'], 0, r'xddp/raw p50 ratio'),
    # Exit code not judged: besides the port's counters, fuzz judges timing (overruns).
    'fuzz': (['--count', '1', '--seed', '1', '--ports', 'cmd', '--quiet-s', '0.5', '--results',
              '{tmp}/fuzz'], None, r'\ncmd +1 +1 .* ok\n'),
    'core_bench': (['--duration', '0.2', '--rtt', '10'], 0, r'task machinery per cycle'),
    'loop_ab': (['--variant', 'x={tmp}'], 2, r'expected NAME=DIR with DIR/m4k_rt'),
    'bench_combine': (['{tmp}/none'], 2, r'bench_combine: .*summary.json'),
    'bench': (['--duration', '-1'], 2, r'must be > 0 s, got -1.0'),      # its own check
    'demo': (['--timeout', '-1'], 2, r'demo: bad arguments: timeout -1.0'),
    'config_doc': (['--markdown'], 0, r'## runtime \(config/m4k.yaml\)'),
    'calibrate': (['--hold', '0', '--output', '{tmp}/o.yaml'], 2, r'--hold: must be in'),
    'liveview': (['--drive-s', '-1'], 2, r'--drive-s must be > 0 s, got -1.0'),
    'scenarios': (['{tmp}/none.yaml'], 2, r'scenarios: .*No such file'),
    'doctor': (['--help'], 0, r'usage: doctor'),
    'recipes': (['--help'], 0, r'usage: '),
    'reaction': (['--help'], 0, r'usage: '),
    'sonar_echo_width': (['--help'], 0, r'usage: '),
    'bringup_check': (['--help'], 0, r'usage: bringup_check'),
    'flightrec_bench': (['--help'], 0, r'usage: '),
    'soak': (['--duration', '0.5', '--warmup', '0', '--no-stress', '--results', '{tmp}'],
             None, r'Files: summary.json'),
}
NEEDS_SIM = {'baseline'}
pytestmark = pytest.mark.allow_leaks('fds')  # the graph check keeps FastDDS sockets


def console_scripts():
    """Return {executable: (package, module)} from every src/*/setup.py."""
    out = {}
    for setup in sorted(glob.glob(os.path.join(ROOT, 'src', '*', 'setup.py'))):
        tree = ast.parse(open(setup, encoding='utf-8').read())
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and re.match(
                    r'^\w+ = [\w.]+:\w+$', node.value):
                exe, target = node.value.split(' = ')
                out[exe] = (os.path.basename(os.path.dirname(setup)), target)
    return out


def launch_cmdline(argv, name, namespace, params, tmp_path):
    """Return ``argv`` + what launch_ros's Node appends for name, namespace, parameters."""
    cmd = [*argv, '--ros-args', '-r', '__node:={}'.format(name)]
    if namespace:
        cmd += ['-r', '__ns:={}'.format(namespace)]
    if params is not None:
        path = tmp_path / 'launch_params_{}'.format(name)
        with open(path, 'w', encoding='utf-8') as f:
            yaml.dump({'{}/{}'.format(namespace, name): {'ros__parameters': params}}, f,
                      default_flow_style=False)
        cmd += ['--params-file', str(path)]
    return cmd + ['-r', 'unused_topic:=other_topic']


def _argv(module):
    # The console script's entry point, run by this interpreter from the source tree.
    mod, func = module.split(':')
    return [sys.executable, '-c', 'import sys; from {} import {} as m; sys.exit(m())'.format(
        mod, func)]


def _subst(args, rt, tmp):
    return [a.format(rt=rt, tmp=tmp) for a in args]


def test_every_console_script_is_covered():
    assert set(console_scripts()) == set(SERVERS) | set(TOOLS)


def _node_seen(name, namespace, timeout):
    context = rclpy.context.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('launch_args_probe', context=context)
    try:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if (name, namespace) in node.get_node_names_and_namespaces():
                return True
            time.sleep(0.1)
        return False
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)


@pytest.mark.parametrize('exe', sorted(SERVERS))
def test_server_starts_with_launch_arguments_and_stops_on_sigterm(procs, tmp_path,
                                                                   m4k_runtime_dir, exe):
    package, module = console_scripts()[exe]
    args, ready = SERVERS[exe]
    if exe in NEEDS_SIM:   # its motor is a sim-bus device: the simulated robot must run
        procs.start([sys.executable, '-m', 'm4k_drivers.sim_robot', '--runtime-dir',
                     m4k_runtime_dir], env=stack_env(m4k_runtime_dir))
        end = time.monotonic() + 30
        while not bringup.sim_ready(m4k_runtime_dir) and time.monotonic() < end:
            time.sleep(0.1)
        assert bringup.sim_ready(m4k_runtime_dir), 'sim_robot did not come up'
    params = {'use_sim_time': False, **SERVER_PARAMS.get(exe, {})}
    cmd = launch_cmdline(_argv(module) + _subst(args, m4k_runtime_dir, tmp_path), exe,
                         NS, params, tmp_path)
    log = tmp_path / 'out.txt'
    with open(log, 'w') as out:
        proc = procs.start(cmd, env=dict(stack_env(m4k_runtime_dir), PYTHONUNBUFFERED='1'),
                           stdout=out, stderr=out)
    text = lambda: log.read_text()  # noqa: E731
    if ready is None:
        assert _node_seen(exe, NS, 30), text()   # __node and __ns were applied
    else:
        end = time.monotonic() + 40
        while not re.search(ready, text()) and proc.poll() is None and time.monotonic() < end:
            time.sleep(0.1)
        assert re.search(ready, text()), 'rc {}: {}'.format(proc.poll(), text()[-2000:])
    assert proc.poll() is None, text()[-2000:]
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(40) == 0, text()[-3000:]
    assert 'unrecognized arguments' not in text() and 'unknown ROS argument' not in text()


@pytest.mark.parametrize('exe', sorted(TOOLS))
def test_tool_runs_with_launch_arguments(procs, tmp_path, m4k_runtime_dir, exe):
    package, module = console_scripts()[exe]
    args, rc, shows = TOOLS[exe]
    cmd = launch_cmdline(_argv(module) + _subst(args, m4k_runtime_dir, tmp_path), exe,
                         NS, None, tmp_path)
    proc = procs.start(cmd, env=stack_env(m4k_runtime_dir), stderr=-2)  # stderr -> stdout
    out, _ = proc.communicate(timeout=240)
    assert 'unrecognized arguments' not in out and 'unknown ROS argument' not in out, out
    assert re.search(shows, out), out[-3000:]
    if rc is not None:
        assert proc.returncode == rc, out[-3000:]


def test_a_malformed_ros_section_is_a_usage_error(procs, m4k_runtime_dir):
    proc = procs.start([sys.executable, '-m', 'm4k_rt.rt_core', '--ros-args', '-r'],
                       env=stack_env(m4k_runtime_dir))
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and '-r needs a value' in err
