"""The bench's tools start the stack with bringup's one command recipe (bringup_argv)."""

import ast
import os

import m4k_bench
from m4k_bringup.bringup import bringup_argv


def _sources():
    root = os.path.dirname(m4k_bench.__file__)
    for d, _, files in os.walk(root):
        for name in sorted(files):
            if name.endswith('.py'):
                path = os.path.join(d, name)
                with open(path, encoding='utf-8') as f:
                    yield os.path.relpath(path, root), ast.parse(f.read())


def test_no_tool_writes_the_bringup_command_out_itself():
    # soak, flightrec_bench and liveview each wrote `python -m m4k_bringup.bringup ...` inline
    # beside bringup_argv; a flag bringup needs from every tool (--python-m) drifted that way.
    inline = [f'{rel}:{n.lineno}' for rel, tree in _sources() for n in ast.walk(tree)
              if isinstance(n, ast.Constant) and n.value == 'm4k_bringup.bringup']
    assert inline == []
    users = {rel for rel, tree in _sources() for n in ast.walk(tree)
             if isinstance(n, ast.Name) and n.id == 'bringup_argv'}
    assert {'soak.py', 'flightrec_bench.py', 'liveview.py', 'demo.py'} <= users


def test_the_recipe_runs_bringup_from_source_with_its_overlay():
    argv = bringup_argv('/tmp/overlay.yaml')
    assert argv[-3:] == ['--python-m', '--config', '/tmp/overlay.yaml']
    assert argv[1:3] == ['-m', 'm4k_bringup.bringup']
    assert '--config' not in bringup_argv()
