"""Parameters of the planner node (``m4k_planner``): one schema Field each (pure, no ROS).

The node's own parameters are declared here (:data:`NODE`), the planner's ``dwa.*`` ones on
:class:`m4k_bench.planning.dwa.DwaConfig` (:data:`m4k_bench.planning.dwa.DWA`). The node
builds its ROS ParameterDescriptors from these Fields (``m4k_bridge.descriptors``) and judges
each value with :meth:`m4k_rt.schema.Field.problem`; the docs are generated from them
(``m4k_bench.configdoc``).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from m4k_bench.planning.dwa import DWA
from m4k_rt.schema import ConfigError, Field

__all__ = ['NODE', 'ParamError', 'SPECS', 'problem']


class ParamError(ConfigError):
    """Raise for a bad node parameter; the message names it."""


def _f(name: str, type_: str, default: Any, description: str, unit: str = '',
       **kw: Any) -> Field:
    return Field(type_, default, description, unit=unit, name=name, **kw)


NODE: dict[str, Field] = {f.name: f for f in (
    _f('rate_hz', 'float', 20.0, 'cmd_vel publication rate (the paper: every 50 ms).', 'Hz',
       lo=1.0, hi=100.0),
    _f('goal_x', 'float', math.nan, 'Goal x in the odom frame; NaN (both): no goal. Changeable '
       'at run time (ros2 param set).', 'm'),
    _f('goal_y', 'float', math.nan, 'Goal y in the odom frame; NaN (both): no goal.', 'm'),
    _f('laser_mount', 'float[]', [0.0, 0.0, 0.0], 'Laser pose in base_link: x m, y m, yaw rad. '
       'Must match the real mounting (sim: devices.lrf.mount); a wrong value shifts every '
       'obstacle.', length=3, read_only=True, expect='[x, y, yaw] (3 finite numbers)'),
    _f('use_stamped_vel', 'bool', False, 'true: publish geometry_msgs/TwistStamped on cmd_vel.',
       read_only=True),
    _f('odom_timeout', 'float', 0.5, 'Without odometry this long: zero command.', 's', lo=0,
       lo_open=True),
    _f('scan_timeout', 'float', 1.0, 'Without a scan this long: zero command.', 's', lo=0,
       lo_open=True),
    _f('memory_s', 'float', 2.0, 'Scans remembered this long (the laser sees 240 deg only).',
       's', lo=0, lo_open=True),
    _f('base_frame', 'str', 'base_link', 'Frame of a TwistStamped cmd_vel.', read_only=True),
)}

# Every parameter of the node: its own, then the planner's as ``dwa.<field>``.
SPECS: dict[str, Field] = {**NODE, **{f'dwa.{k}': dataclasses.replace(f, name=f'dwa.{k}')
                                       for k, f in DWA.items()}}


def problem(name: str, value: Any) -> str | None:
    """Return why ``value`` is wrong for parameter ``name`` (None: fine).

    A goal coordinate may be NaN (no goal); every other value is judged by its Field.
    """
    if name in ('goal_x', 'goal_y') and isinstance(value, float) and math.isnan(value):
        return None
    return SPECS[name].problem(value)
