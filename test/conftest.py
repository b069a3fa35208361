"""Shared m4k fixtures: ROS isolation, private runtime dir, process cleanup, leak check.

The workspace tests are the end-to-end tier: every module here is marked ``e2e`` (it starts the
stack, its processes or ROS nodes) except the static checks in :data:`UNIT_MODULES`, which
``make check`` runs with the packages' unit tests. A new module is end to end unless listed.

``make test`` (tools/run-tests.sh) runs the end-to-end tier in streams: the modules in
:data:`SERIAL_MODULES` (marked ``serial``) one after the other at the caller's priority and
rights, those of them in :data:`WHOLE_MACHINE` (marked ``whole_machine``) first; the rest
confined (nice 19, no right to SCHED_FIFO or locked memory, a CPU cgroup below the default
weight): the modules in :data:`AFTER_PACKAGES` after the packages' end-to-end tests, every
other one (a new module too) in the e2e stream. The four streams run side by side, the confined
stacks starting once the whole-machine tests are done; without CPU cgroups, or with
``M4K_TEST_SERIAL_ALONE=1``, the serial stream runs after the confined ones.
"""

import pytest

from m4k_testing import *  # noqa: F401,F403

UNIT_MODULES = frozenset({
    'test_configuration_doc', 'test_hazards', 'test_layering', 'test_readme',
    'test_real_robot_docs',
    'test_recipes', 'test_skip_markers', 'test_test_summary', 'test_workspace_layout',
})

# A stop judged against its line or a drive against its limits, on the simulator's ground
# truth, or a stack that must first run calm (no host drop in the window): a stack starved of
# CPU stops later or drops commands, so these never share the machine with each other (the
# confined streams beside them use its idle time, and their stacks' RT threads run without
# SCHED_FIFO). test_fuzz_xddp and test_bench_smoke are here for their rights: rt_core got
# SCHED_FIFO and locked memory, cyclictest and the bench's RT loops ran, which the confined
# streams do not grant. A test elsewhere can be marked ``serial`` on its own
# (test_faults_devices' watchdog). The fleet and the odometry against ground truth assert
# directions, states and identities at rest, which hold on a loaded machine: confined.
SERIAL_MODULES = frozenset({
    'test_scenarios', 'test_demo', 'test_stack_e2e', 'test_tasks_e2e', 'test_fuzz_xddp',
    'test_host_drops_e2e', 'test_bench_smoke', 'test_fleet',
})

# The serial modules that load every core on purpose (the bench's stress-ng and cyclictest,
# three robots at once): the serial stream runs them before any confined stack starts, so that
# no end-to-end test of another stream has to drive beside them.
WHOLE_MACHINE = frozenset({'test_bench_smoke', 'test_fleet'})
assert WHOLE_MACHINE <= SERIAL_MODULES

# Run, confined, after the packages' end-to-end tests, in their stream; every other module (a
# new one too) is the e2e stream's. The split balances the two streams by the measured
# per-file times (docs/testing.md).
AFTER_PACKAGES = frozenset({
    'test_faults_e2e', 'test_tf_e2e', 'test_two_machines', 'test_doctor_fleet',
    'test_foxglove_rights_e2e', 'test_launch_ros_args', 'test_record_e2e', 'test_doctor',
    'test_dds_discovery_range',
})


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark every test of a module outside :data:`UNIT_MODULES` ``e2e``, and those of
    :data:`SERIAL_MODULES` ``serial``, of :data:`WHOLE_MACHINE` ``whole_machine`` and of
    :data:`AFTER_PACKAGES` ``after_packages``."""
    for item in items:
        if item.path.stem not in UNIT_MODULES:
            item.add_marker(pytest.mark.e2e)
        if item.path.stem in SERIAL_MODULES:
            item.add_marker(pytest.mark.serial)
        if item.path.stem in AFTER_PACKAGES:
            item.add_marker(pytest.mark.after_packages)
        if item.path.stem in WHOLE_MACHINE:
            item.add_marker(pytest.mark.whole_machine)
