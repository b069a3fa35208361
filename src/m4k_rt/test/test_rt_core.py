"""End-to-end tests of the RT process (rt_core): configuration errors exit 2 naming the field.

The tests with NRT peers (echo peer, recorder, rt_stat) are in m4k_bench/test/test_rt_stat.py:
those tools are the bench's.
"""

import os

import pytest

from m4k_testing import rtcore

pytestmark = pytest.mark.e2e  # starts processes / ROS nodes: the end-to-end tier

SRC = os.path.join(os.path.dirname(__file__), '..')


def _env(extra=None):
    return rtcore.rt_core_env(SRC, extra)


_overlay = rtcore.write_overlay
_fast = rtcore.fast_overlay


def _start(procs, args, env=None):
    return rtcore.start_rt_core(procs, SRC, args, env)


def test_bad_priority_exits_2_naming_the_field(procs, tmp_path, m4k_runtime_dir):
    over = _overlay(tmp_path, {'tasks': {'led': {'priority': 120}}})
    p = _start(procs, ['--config', over])
    out, err = p.communicate(timeout=30)
    assert p.returncode == 2
    assert err.strip().splitlines() == [
        'rt_core: config error: tasks.led.priority: expected an int in 1..99, got 120']


def test_unknown_body_and_unknown_task_exit_2(procs, tmp_path, m4k_runtime_dir):
    over = _overlay(tmp_path, {'tasks': {'led': {'body': 'no_such_body'}}})
    p = _start(procs, ['--config', over])
    _, err = p.communicate(timeout=30)
    assert p.returncode == 2 and "tasks.led.body: unknown task body 'no_such_body'" in err
    p = _start(procs, ['--tasks', 'nope', '--echo'])
    _, err = p.communicate(timeout=30)
    assert p.returncode == 2 and "--tasks: unknown task 'nope'" in err
