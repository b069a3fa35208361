"""The shared test machinery's policies: which skips the runner refuses, which profile runs."""

import os

from hypothesis import settings

from m4k_rt import testing

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
