"""The shared test machinery's policies: which skips the runner refuses, which profile runs."""

import os
import subprocess
import sys

from hypothesis import settings

import m4k_testing as testing

SKIPS = [('t.py::a', 'Skipped: needs root: to chown'), ('t.py::b', 'Skipped: no tf2_msgs')]


def test_as_root_every_skip_is_refused():
    assert testing.forbidden_skips(SKIPS, 0) == SKIPS


def test_without_root_only_needs_root_skips_are_accepted():
    assert testing.forbidden_skips(SKIPS, 1000) == [SKIPS[1]]


def test_the_runner_profile_is_derandomized_without_a_database():
    # make test (and colcon test) run with M4K_HYPOTHESIS_PROFILE unset or 'ci'.
    if os.environ.get(testing.HYPOTHESIS_PROFILE_ENV, 'ci') == 'ci':
        assert settings.default.derandomize is True
        assert settings.default.database is None
        assert testing.examples(300) == 300
    else:
        assert settings.default.derandomize is False
        assert testing.examples(300) == 300 * testing.FUZZ_FACTOR


def test_a_ros2cli_skip_is_accepted_only_where_ros2cli_does_not_import(monkeypatch):
    skip = [('t.py::c', 'Skipped: ' + testing._NEEDS_ROS2CLI + 'launch_ros does not import')]
    monkeypatch.setattr(testing, 'ros2cli_available', lambda: False)
    assert testing.forbidden_skips(skip, 0) == []
    monkeypatch.setattr(testing, 'ros2cli_available', lambda: True)
    assert testing.forbidden_skips(skip, 0) == skip


def _run_ci(tmp_path, module_text):
    """Run pytest under the runner's policy (M4K_CI=1) on one module; return the result."""
    (tmp_path / 'conftest.py').write_text('from m4k_testing import *  # noqa: F401,F403\n')
    (tmp_path / 'test_mod.py').write_text(module_text)
    env = dict(os.environ, M4K_CI='1')
    return subprocess.run([sys.executable, '-m', 'pytest', '-q', '-p', 'no:cacheprovider',
                           str(tmp_path)], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=120)


def test_a_module_level_skip_fails_the_runner(tmp_path):
    r = _run_ci(tmp_path, 'import pytest\n'
                'pytest.skip("no frobnicator here", allow_module_level=True)\n'
                'def test_x():\n    pass\n')
    assert r.returncode != 0, r.stdout + r.stderr
    assert 'm4k skip policy' in r.stderr and 'no frobnicator here' in r.stderr, r.stderr


def test_an_importorskip_at_collection_fails_the_runner(tmp_path):
    r = _run_ci(tmp_path, 'import pytest\n'
                'pytest.importorskip("m4k_no_such_module_anywhere")\n'
                'def test_x():\n    pass\n')
    assert r.returncode != 0, r.stdout + r.stderr
    assert 'm4k_no_such_module_anywhere' in r.stderr, r.stderr


def test_a_module_that_runs_passes_the_runner(tmp_path):
    r = _run_ci(tmp_path, 'def test_x():\n    pass\n')
    assert r.returncode == 0, r.stdout + r.stderr


def test_a_missing_ros_package_skip_is_accepted_only_where_the_package_is_missing(monkeypatch):
    skip = [('t.py::d', 'Skipped: ' + testing._NEEDS_PKG + 'robot_state_publisher')]
    monkeypatch.setattr(testing, 'ros_package_available', lambda name: False)
    assert testing.forbidden_skips(skip, 0) == []
    monkeypatch.setattr(testing, 'ros_package_available',
                        lambda name: name == 'robot_state_publisher')
    assert testing.forbidden_skips(skip, 0) == skip


def test_the_ament_index_answers_for_a_package_it_has_and_one_it_lacks():
    assert testing.ros_package_available('m4k_rt')
    assert not testing.ros_package_available('m4k_no_such_package')
