"""Gather every package's configuration sections and print ``docs/configuration.md``.

The RT side, the driver host and the bridge each declare their settings next to their code
(:mod:`m4k_rt.schema`, ``m4k_drivers.registry.Param``, :data:`m4k_bridge.params.SPECS`); this
module sits above all three, so gathering them here needs no upward import anywhere.
"""

from __future__ import annotations

import argparse
import sys
from typing import Sequence

from m4k_bridge import params as bridge_params
from m4k_bridge.foxglove import params as foxglove_params
from m4k_drivers.config import schema_sections, world_sections
from m4k_rt import rosargs, schema
from m4k_rt.control.params import CONTROL
from m4k_rt.schema import PORT, ROBOT, RUNTIME, Section, TASK


def rt_sections() -> list[Section]:
    """Return the sections of the RT side (m4k.yaml, control.yaml, robot.yaml) for the docs.

    Gathered here, above every package, so that :mod:`m4k_rt.schema` need not import
    :mod:`m4k_rt.control.params` (which imports it) -- not even lazily.
    """
    return [
        Section('runtime', 'runtime (config/m4k.yaml)', RUNTIME),
        Section('tasks.<name>', 'tasks.<name> (config/m4k.yaml)', TASK,
                'One entry per RT task; checked across fields: 0 <= offset_ms < period_ms, '
                'one owner per port, at least one enabled task.'),
        Section('ports', 'ports (config/m4k.yaml)', {'<label>': PORT}),
        Section('control', 'control (config/control.yaml)', CONTROL,
                'Run by the RT actuator task. Checked across fields: guard.brake_deceleration not '
                'below linear.max_deceleration; e-stop decelerations not below the normal '
                'ones. The guard, supervision and e-stop: docs/safety.md.'),
        Section('robot', 'robot (config/robot.yaml)', ROBOT,
                'The one source of the URDF, the static transforms and the simulated '
                "sensors' mounts. Every field but name is required in the layered configuration."),
    ]


def all_sections() -> list[schema.Section]:
    """Return every section: RT side, device backends, world, bridge and live view."""
    sections = rt_sections()
    sections += schema_sections()
    sections += world_sections()
    sections.append(schema.Section(
        'm4k_bridge', 'm4k_bridge ROS parameters (config/bridge.yaml)',
        {s.name: s for s in bridge_params.SPECS},
        'Declared with these descriptors (`ros2 param describe /m4k_bridge <name>`). Derived '
        'parameters are not in bridge.yaml: bringup, the launch file and a bridge started by '
        'hand compute them from the layered configuration.'))
    sections.append(schema.Section(
        'm4k_foxglove', 'm4k_foxglove ROS parameters (the live view, docs/live-view.md)',
        {s.name: s for s in foxglove_params.SPECS},
        'Read-only, set at start (`ros2 run m4k_bridge foxglove --ros-args -p name:=value`, '
        '`bringup --foxglove-address/--foxglove-port`).'))
    return sections


def main(argv: Sequence[str] | None = None) -> int:
    """Print the configuration reference (``--markdown``)."""
    ap = argparse.ArgumentParser(prog='config_doc', description='The m4k configuration schema.')
    ap.add_argument('--markdown', action='store_true',
                    help='print docs/configuration.md (every field of every section)')
    args = rosargs.parse_args(ap, argv)   # launch_ros's --ros-args section accepted
    if not args.markdown:
        ap.print_help()
        return 0
    sys.stdout.write(schema.markdown(all_sections()))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
