"""Every node the documented Nav2 command starts for one robot of a fleet (pure, no launch).

    ros2 launch m4k_bringup m4k_nav2.launch.py robot:=r1 recipes:=DIR [twist_mux:=true]
        [ekf:=true] [slam:=true | map:=FILE]

``m4k_nav2.launch.py`` is a thin adapter over :func:`nodes`: it turns each :class:`NodeSpec`
into a ``launch_ros`` ``Node`` and nothing else, so the tests (``test/consumers.py``) and the
maintainers' check against the real launch (``tools/verify_nav2_launch.py``) take the same
list as their input. The layout is Nav2's multi-robot one: every node of robot ``r1`` in
``/r1``, ``/tf`` and ``/tf_static`` remapped to the namespace's ``tf`` and ``tf_static`` (as
``nav2_bringup``'s launch files remap them), frames unprefixed (``odom``, ``base_footprint``)
in each robot's own tree. The bridge runs the same way (``m4k.launch.py robot:=r1``:
``tf_namespaced``).

Where this differs from ``nav2_bringup``'s ``navigation_launch.py`` (Jazzy) and why:

* the namespace is pushed on every node (``navigation_launch.py namespace:=r1`` alone only
  nests the parameters under ``r1``; its nodes stay in ``/``);
* ``docking_server`` publishes ``cmd_vel`` through ``cmd_vel_nav`` (the velocity smoother and
  the collision monitor, and so twist_mux's e-stop lock); upstream leaves it unremapped, a
  second writer on the base's ``cmd_vel``;
* no composition (one process per node, so each node's remaps are its own).
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any, Mapping

__all__ = ['NAV2_LIFECYCLE', 'NodeSpec', 'TF_REMAPS', 'command', 'nodes', 'recipe_paths']

# Namespaced tf, as nav2_bringup's launch files remap every node (navigation_launch.py):
# tf2_ros listeners and broadcasters use the absolute /tf and /tf_static.
TF_REMAPS = (('/tf', 'tf'), ('/tf_static', 'tf_static'))
# The controller's raw output, the smoother's input (navigation_launch.py's remap).
CMD_VEL_NAV = (('cmd_vel', 'cmd_vel_nav'),)

# (package, executable, node name, extra remaps) in navigation_launch.py's lifecycle order
NAV2_LIFECYCLE = (
    ('nav2_controller', 'controller_server', 'controller_server', CMD_VEL_NAV),
    ('nav2_smoother', 'smoother_server', 'smoother_server', ()),
    ('nav2_planner', 'planner_server', 'planner_server', ()),
    ('nav2_route', 'route_server', 'route_server', ()),
    ('nav2_behaviors', 'behavior_server', 'behavior_server', CMD_VEL_NAV),
    ('nav2_velocity_smoother', 'velocity_smoother', 'velocity_smoother', CMD_VEL_NAV),
    ('nav2_collision_monitor', 'collision_monitor', 'collision_monitor', ()),
    ('nav2_bt_navigator', 'bt_navigator', 'bt_navigator', ()),
    ('nav2_waypoint_follower', 'waypoint_follower', 'waypoint_follower', ()),
    # upstream: unremapped (a second writer on the base's cmd_vel, past the monitor and mux)
    ('opennav_docking', 'opennav_docking', 'docking_server', CMD_VEL_NAV),
)


@dataclasses.dataclass(frozen=True)
class NodeSpec:
    """One node as the launch file starts it: its process, name, namespace, remaps, params."""

    package: str
    executable: str
    name: str
    namespace: str                            # absolute, '/' for the root
    remaps: tuple[tuple[str, str], ...]
    params_files: tuple[str, ...] = ()        # recipe files, absolute paths
    values: Mapping[str, Any] = dataclasses.field(default_factory=dict)  # inline parameters

    @property
    def fqn(self) -> str:
        """Return the node's fully qualified name (/r1/controller_server)."""
        return self.namespace.rstrip('/') + '/' + self.name


def recipe_paths(recipes_dir: str, mux: bool) -> dict[str, str]:
    """Return the recipe files (by tool) that the launch file hands its nodes."""
    nav2 = 'nav2/nav2_params_twist_mux.yaml' if mux else 'nav2/nav2_params.yaml'
    rel = {'nav2': nav2, 'twist_mux': 'twist_mux/twist_mux.yaml',
           'ekf': 'robot_localization/ekf.yaml',
           'slam': 'slam_toolbox/mapper_params_online_async.yaml'}
    return {k: os.path.join(recipes_dir, v) for k, v in rel.items()}


def nodes(robot: str, recipes_dir: str, *, mux: bool = False, ekf: bool = False,
          slam: bool = True, map_file: str = '', use_sim_time: bool = False) -> list[NodeSpec]:
    """Return every node ``m4k_nav2.launch.py`` starts for ``robot`` ('' = the root namespace).

    Raise ValueError for a robot name that is no ROS name token, or for slam and a map both.
    """
    if robot and not (robot.replace('_', 'a').isalnum() and not robot[:1].isdigit()):
        raise ValueError('robot name must be a ROS name token ([A-Za-z_][A-Za-z0-9_]*), got '
                         '{!r}'.format(robot))
    if slam and map_file:
        raise ValueError('slam:=true maps, map:=FILE localizes on a map: give one')
    ns = '/' + robot if robot else '/'
    files = recipe_paths(recipes_dir, mux)
    sim = {'use_sim_time': use_sim_time}
    out = [NodeSpec(pkg, exe, name, ns, TF_REMAPS + extra, (files['nav2'],), sim)
           for pkg, exe, name, extra in NAV2_LIFECYCLE]
    out.append(NodeSpec('nav2_lifecycle_manager', 'lifecycle_manager',
                        'lifecycle_manager_navigation', ns, TF_REMAPS, (), {
                            **sim, 'autostart': True,
                            'node_names': [n for _, _, n, _ in NAV2_LIFECYCLE]}))
    if slam:
        # slam_toolbox (Jazzy) is a lifecycle node: with use_lifecycle_manager it waits for
        # the manager to configure and activate it, and keeps a bond with it
        # (slam_toolbox_common.cpp), so a dead mapper is noticed
        out.append(NodeSpec('slam_toolbox', 'async_slam_toolbox_node', 'slam_toolbox', ns,
                            TF_REMAPS, (files['slam'],),
                            {**sim, 'use_lifecycle_manager': True}))
        out.append(NodeSpec('nav2_lifecycle_manager', 'lifecycle_manager',
                            'lifecycle_manager_slam', ns, TF_REMAPS, (), {
                                **sim, 'autostart': True, 'node_names': ['slam_toolbox']}))
    elif map_file:
        out.append(NodeSpec('nav2_map_server', 'map_server', 'map_server', ns, TF_REMAPS, (),
                            {**sim, 'yaml_filename': map_file}))
        out.append(NodeSpec('nav2_amcl', 'amcl', 'amcl', ns, TF_REMAPS, (files['nav2'],), sim))
        out.append(NodeSpec('nav2_lifecycle_manager', 'lifecycle_manager',
                            'lifecycle_manager_localization', ns, TF_REMAPS, (), {
                                **sim, 'autostart': True,
                                'node_names': ['map_server', 'amcl']}))
    if ekf:
        out.append(NodeSpec('robot_localization', 'ekf_node', 'ekf_filter_node', ns, TF_REMAPS,
                            (files['ekf'],), sim))
    if mux:
        # twist_mux publishes cmd_vel_out, a name the bridge uses for its applied velocity
        out.append(NodeSpec('twist_mux', 'twist_mux', 'twist_mux', ns,
                            (('cmd_vel_out', 'cmd_vel'),), (files['twist_mux'],), sim))
    return out


def command(robot: str, recipes_dir: str, *, mux: bool = False, ekf: bool = False,
            slam: bool = True, map_file: str = '') -> str:
    """Return the exact shell command that starts :func:`nodes` with these arguments."""
    args = ['ros2 launch m4k_bringup m4k_nav2.launch.py']
    if robot:
        args.append('robot:=' + robot)
    args.append('recipes:=' + recipes_dir)
    if mux:
        args.append('twist_mux:=true')
    if ekf:
        args.append('ekf:=true')
    if not slam:
        args.append('slam:=false')
    if map_file:
        args.append('map:=' + map_file)
    return ' '.join(args)


def bridge_command(robot: str, recipes_dir: str, *, ekf: bool = False) -> str:
    """Return the command that starts the base for these recipes (m4k.launch.py)."""
    files = recipe_paths(recipes_dir, False)
    params = [files['nav2']] + ([files['ekf']] if ekf else [])
    return 'ros2 launch m4k_bringup m4k.launch.py {}bridge_params:={}'.format(
        'robot:={} '.format(robot) if robot else '', ','.join(params))
