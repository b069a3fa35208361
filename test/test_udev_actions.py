"""The shipped udev rules that set permissions run on add and on change.

docs/real-robot.md installs them with `udevadm trigger`, which sends "change": a rule limited
to "add" would never run for a device that existed before the rule was installed.
"""

import os
import re

from wsenv import ROOT

RULES = os.path.join(ROOT, 'config', 'udev', '99-m4k.rules')


def _rules():
    with open(RULES, encoding='utf-8') as f:
        return [line for line in f.read().splitlines() if line and not line.startswith('#')]


def test_every_subsystem_with_a_run_rule_is_handled_on_add_and_on_change():
    actions: dict[str, set[str]] = {}
    for line in _rules():
        sub = re.search(r'SUBSYSTEM=="([^"]+)"', line)
        if sub is None or 'RUN+=' not in line:
            continue
        act = re.search(r'ACTION=="([^"]+)"', line)
        names = set(act.group(1).split('|')) if act else {'add', 'change'}
        actions.setdefault(sub.group(1), set()).update(names)
    assert actions, 'no RUN rules found'
    for subsystem, acts in actions.items():
        assert {'add', 'change'} <= acts, f'{subsystem}: rules run only on {sorted(acts)}'
