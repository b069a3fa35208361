"""Shared m4k fixtures: ROS isolation, private runtime dir, process cleanup, leak check.

The workspace tests are the end-to-end tier: every module here is marked ``e2e`` (it starts the
stack, its processes or ROS nodes) except the static checks in :data:`UNIT_MODULES`, which
``make check`` runs with the packages' unit tests. A new module is end to end unless listed.
"""

import pytest

from m4k_testing import *  # noqa: F401,F403

UNIT_MODULES = frozenset({
    'test_configuration_doc', 'test_hazards', 'test_layering', 'test_readme',
    'test_real_robot_docs',
    'test_recipes', 'test_skip_markers', 'test_test_summary', 'test_workspace_layout',
})


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark every test of a module outside :data:`UNIT_MODULES` ``e2e``."""
    for item in items:
        if item.path.stem not in UNIT_MODULES:
            item.add_marker(pytest.mark.e2e)
