"""Shared m4k fixtures: ROS isolation, private runtime dir, process cleanup, leak check.

The workspace tests are the end-to-end tier: every module here is marked ``e2e`` (it starts the
stack, its processes or ROS nodes) except the static checks in :data:`UNIT_MODULES`, which
``make check`` runs with the packages' unit tests. A new module is end to end unless listed.

``make test`` (tools/run-tests.sh) runs the end-to-end tier in four streams side by side: the
modules in :data:`SERIAL_MODULES` (marked ``serial``) one after the other at the caller's
priority and rights, and the rest in three streams confined to nice 19 without the right to
SCHED_FIFO or locked memory -- the modules in :data:`AFTER_PACKAGES` after the package tier,
those in :data:`SECOND_E2E`, and every other one (a new module too).
"""

import pytest

from m4k_testing import *  # noqa: F401,F403

UNIT_MODULES = frozenset({
    'test_configuration_doc', 'test_hazards', 'test_layering', 'test_readme',
    'test_real_robot_docs',
    'test_recipes', 'test_skip_markers', 'test_test_summary', 'test_workspace_layout',
})

# A stop judged against its line or a drive against its limits, on the simulator's ground
# truth: a stack starved of CPU stops later, so these never share the machine with each other
# (the confined streams beside them use its idle time, and their stacks' RT threads run
# without SCHED_FIFO). test_fuzz_xddp is here for its rights: it asserts that rt_core got
# SCHED_FIFO and locked memory, which the confined streams do not grant. The kill, e-stop and
# cut-link tests judge states (at rest, stays there, nothing moves it), not times, and run in
# the other streams.
SERIAL_MODULES = frozenset({
    'test_scenarios', 'test_demo', 'test_stack_e2e', 'test_tasks_e2e', 'test_tf_e2e',
    'test_fleet', 'test_fuzz_xddp',
})

# The confined streams beside the serial one, balanced on the measured times of a fresh
# clone's run (docs/testing.md): the package tier then AFTER_PACKAGES; SECOND_E2E; every other
# module (a new one too).
AFTER_PACKAGES = frozenset({'test_bench_smoke'})
SECOND_E2E = frozenset({
    'test_doctor', 'test_doctor_fleet', 'test_faults_e2e', 'test_foxglove_e2e',
    'test_host_drops_e2e', 'test_launch_ros_args', 'test_record_e2e', 'test_two_machines',
})


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark every test of a module outside :data:`UNIT_MODULES` ``e2e``, and those of
    :data:`SERIAL_MODULES` ``serial``, of :data:`AFTER_PACKAGES` ``after_packages`` and of
    :data:`SECOND_E2E` ``second_e2e``."""
    for item in items:
        if item.path.stem not in UNIT_MODULES:
            item.add_marker(pytest.mark.e2e)
        if item.path.stem in SERIAL_MODULES:
            item.add_marker(pytest.mark.serial)
        if item.path.stem in AFTER_PACKAGES:
            item.add_marker(pytest.mark.after_packages)
        if item.path.stem in SECOND_E2E:
            item.add_marker(pytest.mark.second_e2e)
