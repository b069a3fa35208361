"""Print ``docs/bench-configuration.md``: the planner's parameters and the scenario files.

The bench sits above bringup, whose ``config_doc`` writes ``docs/configuration.md`` (the
stack's settings); the settings the bench declares -- the planner node's parameters
(:data:`m4k_bench.planning.params.SPECS`, the ``dwa.*`` ones on ``DwaConfig``) and the keys
of a scenario file (:mod:`m4k_bench.scenarios.spec`) -- are documented here, from the same
schema Fields that validate them. A test compares the committed page with the generated one.
Run: ``python -m m4k_bench.configdoc --markdown > docs/bench-configuration.md``.
"""

from __future__ import annotations

import argparse
import sys
from typing import Sequence

from m4k_bench.planning import params as planner_params
from m4k_bench.scenarios import spec
from m4k_rt import schema
from m4k_rt.schema import Section

__all__ = ['TITLE', 'main', 'markdown', 'sections']

TITLE = 'Bench configuration reference'
SOURCE = '`python -m m4k_bench.configdoc --markdown` from the schema Fields of m4k_bench'


def sections() -> list[Section]:
    """Return the planner's and the scenario files' sections."""
    return [
        Section('m4k_planner', 'm4k_planner ROS parameters (the DWA local planner, '
                'm4k_bench.planning.node)', planner_params.SPECS,
                'Declared with these descriptors (`ros2 param describe /m4k_planner <name>`); '
                'a bad value stops the node with exit code 2, naming it. Checked across '
                'fields: goal_x and goal_y both finite or both NaN; -max_v <= dwa.min_v <= '
                'max_v; dwa.sim_step <= dwa.horizon; dwa.probe_step <= dwa.probe_length; '
                'dwa.clearance_ref > dwa.margin; dwa.recovery_w <= dwa.max_w.'),
        Section('scenario', 'A scenario file (config/scenarios/*.yaml)', spec.SCENARIO,
                'Run by `python -m m4k_bench.scenarios`; docs/scenarios.md.'),
        Section('commands[]', 'commands[]: one cmd_vel segment of a scenario', spec.COMMAND,
                'Either w or heading: hold.'),
        Section('faults[]', 'faults[]: a process a scenario kills', spec.KILL,
                'Exactly one of at.travelled and at.after.'),
        Section('expect', 'expect: what a scenario must show', spec.EXPECT,
                'At least one key.'),
    ]


def markdown() -> str:
    """Return the page."""
    return schema.markdown(sections(), title=TITLE, source=SOURCE)


def main(argv: Sequence[str] | None = None) -> int:
    """Print the bench configuration reference (``--markdown``)."""
    ap = argparse.ArgumentParser(prog='python -m m4k_bench.configdoc',
                                 description="The bench's configuration schema.")
    ap.add_argument('--markdown', action='store_true',
                    help='print docs/bench-configuration.md')
    args = ap.parse_args(argv)
    if not args.markdown:
        ap.print_help()
        return 0
    sys.stdout.write(markdown())
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
