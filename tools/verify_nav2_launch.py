#!/usr/bin/env python3
"""Evaluate the real launch files with the documented arguments and compare them with the model.

For maintainers; no test needs it (the real ``launch`` / ``launch_ros`` are not on PyPI).
With them importable (docs/nav2.md, "Checked against the real launch files": the ``launch``
and ``launch_ros`` jazzy sources on PYTHONPATH, ``composition_interfaces`` built), this:

1. loads ``m4k_bringup/launch/m4k_nav2.launch.py`` with ``launch``'s own Python launch source,
   sets each documented argument set (robot r1..r3, twist_mux, ekf, slam or a map), runs the
   launch file's substitutions without starting a process, and compares every ``Node``
   action -- package, executable, fully qualified name, remaps in order, parameter files and
   inline values -- with ``m4k_bringup.fleet.nodes``, the list the tests consume;
2. with ``--nav2-src`` (a navigation2 jazzy checkout), evaluates upstream
   ``nav2_bringup/launch/navigation_launch.py namespace:=r1`` the same way and prints where
   its nodes land and what docking_server publishes on, the reasons m4k ships its own file.

Exit status 1 on any difference between the launch file and the model.

    export PYTHONPATH=<launch>/launch:<launch_ros>/launch_ros:$PYTHONPATH
    python tools/verify_nav2_launch.py [--nav2-src <navigation2>]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from typing import Any

import yaml

HERE = os.path.dirname(os.path.abspath(__file__))
M4K_LAUNCH = os.path.join(HERE, '..', 'src', 'm4k_bringup', 'launch', 'm4k_nav2.launch.py')
CASES = [
    {'robot': 'r1'},
    {'robot': 'r2', 'twist_mux': 'true', 'ekf': 'true'},
    {'robot': 'r3', 'slam': 'false', 'map': '/maps/m4k.yaml'},
    {},
]


def evaluate(path: str, args: dict[str, str]) -> list[Any]:
    """Return the launch file's Node actions for args, substitutions performed, none run."""
    import launch
    from launch.launch_description_sources import PythonLaunchDescriptionSource
    from launch_ros.actions import Node

    ctx = launch.LaunchContext()
    ld = PythonLaunchDescriptionSource(path).get_launch_description(ctx)
    ctx.launch_configurations.update(args)
    nodes: list[Any] = []

    def visit(entities: list[Any]) -> None:
        for e in entities:
            if isinstance(e, Node):
                e._perform_substitutions(ctx)
                nodes.append(e)
                continue
            if e.condition is not None and not e.condition.evaluate(ctx):
                continue
            if isinstance(e, launch.actions.DeclareLaunchArgument):
                e.execute(ctx)
            elif isinstance(e, launch.actions.OpaqueFunction):
                visit(list(e._OpaqueFunction__function(ctx)))
            elif isinstance(e, (launch.actions.GroupAction, launch.actions.SetEnvironmentVariable,
                                launch.actions.IncludeLaunchDescription)):
                visit(list(e.execute(ctx) or []))
            elif hasattr(e, 'execute') and type(e).__name__ in (
                    'SetParameter', 'PushROSNamespace', 'SetRemap'):
                e.execute(ctx)
            elif isinstance(e, launch.LaunchDescription):
                visit(e.entities)
    visit(ld.entities)
    return nodes


class _Loader(yaml.SafeLoader):
    """SafeLoader that reads the tuples launch_ros writes into its parameter files as lists."""


_Loader.add_constructor('tag:yaml.org,2002:python/tuple',
                        lambda loader, node: loader.construct_sequence(node))


def described(node: Any) -> dict[str, Any]:
    """Return what a Node action would start, as the model describes a node."""
    files, values = [], {}
    for arg, is_file in node._Node__expanded_parameter_arguments or []:
        if not is_file:
            continue
        with open(arg, encoding='utf-8') as f:
            doc = yaml.load(f, Loader=_Loader) or {}
        key = next(iter(doc)) if len(doc) == 1 else None
        if key and (key == '/**' or key == node.node_name) and 'ros__parameters' in doc[key] \
                and os.path.basename(arg).startswith('launch_params_'):
            values.update(doc[key]['ros__parameters'])
        else:
            files.append(arg)
    return {'package': node.node_package, 'executable': node.node_executable,
            'fqn': node.node_name, 'remaps': list(node.expanded_remapping_rules or []),
            'files': files, 'values': values}


def modelled(spec: Any) -> dict[str, Any]:
    """Return one fleet.NodeSpec in the same shape."""
    return {'package': spec.package, 'executable': spec.executable, 'fqn': spec.fqn,
            'remaps': [tuple(r) for r in spec.remaps], 'files': list(spec.params_files),
            'values': dict(spec.values)}


def check_m4k(recipes_dir: str) -> list[str]:
    """Return the differences between m4k_nav2.launch.py and fleet.nodes, every case."""
    from m4k_bringup import fleet
    out = []
    for case in CASES:
        args = {'recipes': recipes_dir if case.get('robot') else '', **case}
        real = sorted((described(n) for n in evaluate(M4K_LAUNCH, args)),
                      key=lambda d: d['fqn'])
        flag = {k: case.get(k, d) == 'true' for k, d in (('twist_mux', 'false'),
                                                         ('ekf', 'false'), ('slam', 'true'))}
        from m4k_rt import config
        model = sorted((modelled(s) for s in fleet.nodes(
            case.get('robot', ''), args['recipes'] or config.find_config_dir(),
            mux=flag['twist_mux'], ekf=flag['ekf'], slam=flag['slam'],
            map_file=case.get('map', ''))), key=lambda d: d['fqn'])
        label = ' '.join('{}:={}'.format(k, v) for k, v in case.items()) or '(no robot)'
        if [d['fqn'] for d in real] != [d['fqn'] for d in model]:
            out.append('{}: nodes {} != model {}'.format(
                label, [d['fqn'] for d in real], [d['fqn'] for d in model]))
            continue
        for r, m in zip(real, model, strict=True):
            for key in r:
                if r[key] != m[key]:
                    out.append('{}: {} {}: launch {!r} != model {!r}'.format(
                        label, r['fqn'], key, r[key], m[key]))
        print('{}: {} nodes match the model'.format(label, len(real)))
    return out


def show_upstream(nav2_src: str, params_file: str) -> None:
    """Print where upstream navigation_launch.py namespace:=r1 puts its nodes."""
    prefix = tempfile.mkdtemp(prefix='nav2-bringup-prefix-')
    index = os.path.join(prefix, 'share', 'ament_index', 'resource_index', 'packages')
    os.makedirs(index)
    open(os.path.join(index, 'nav2_bringup'), 'w').close()
    os.symlink(os.path.join(nav2_src, 'nav2_bringup'),
               os.path.join(prefix, 'share', 'nav2_bringup'))
    # launch's substitution grammar, under share/launch in a source checkout
    import launch
    open(os.path.join(index, 'launch'), 'w').close()
    os.symlink(os.path.join(os.path.dirname(os.path.dirname(launch.__file__)), 'share',
                            'launch'), os.path.join(prefix, 'share', 'launch'))
    os.environ['AMENT_PREFIX_PATH'] = prefix + os.pathsep + os.environ.get('AMENT_PREFIX_PATH',
                                                                          '')
    sys.path.insert(0, os.path.join(nav2_src, 'nav2_common'))
    path = os.path.join(nav2_src, 'nav2_bringup', 'launch', 'navigation_launch.py')
    for n in evaluate(path, {'namespace': 'r1', 'params_file': params_file,
                             'use_composition': 'False'}):
        d = described(n)
        fqn = d['fqn'].replace('<node_namespace_unspecified>', '(no namespace set)').replace(
            '<node_name_unspecified>', n.node_executable + ' (no name set)')
        print('upstream navigation_launch.py namespace:=r1: {} remaps {}'.format(
            fqn, d['remaps']))


def main(argv: list[str] | None = None) -> int:
    """Compare; print the differences; exit 1 when there is any."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--nav2-src', default='', help='a navigation2 (jazzy) checkout')
    a = ap.parse_args(argv)
    try:
        import launch  # noqa: F401
        import launch_ros  # noqa: F401
    except ImportError as exc:
        print('verify_nav2_launch: the real launch / launch_ros are needed ({}); see the '
              "script's docstring".format(exc), file=sys.stderr)
        return 2
    from m4k_bringup import recipes
    from m4k_rt import config
    with tempfile.TemporaryDirectory(prefix='m4k-recipes-') as d:
        layered = config.load_layered()
        for robot in ('r1', 'r2', 'r3'):
            # one directory for the check: the launch reads the files, the model names them
            for rel, text in recipes.generate(layered, robot, d).items():
                os.makedirs(os.path.dirname(os.path.join(d, rel)), exist_ok=True)
                with open(os.path.join(d, rel), 'w', encoding='utf-8') as f:
                    f.write(text)
        problems = check_m4k(d)
        if a.nav2_src:
            show_upstream(a.nav2_src, os.path.join(d, 'nav2', 'nav2_params.yaml'))
    for p in problems:
        print(p)
    print('verify_nav2_launch: {}'.format('{} difference(s)'.format(len(problems))
                                          if problems else 'the launch file is the model'),
          file=sys.stderr)
    return 1 if problems else 0


if __name__ == '__main__':
    sys.exit(main())
