"""The hazard table of docs/safety.md is generated from config/hazards.yaml and cannot drift.

Stale table, a reference to a scenario, grid cell or test that does not exist, a row with
neither proof nor gap: each fails here.
"""

import os
import shutil

import pytest
from wsenv import ROOT
import yaml

from m4k_bench import hazards


def test_the_committed_hazard_table_is_the_generated_one(capsys):
    assert hazards.main(['--check', '--root', ROOT]) == 0, (
        capsys.readouterr().err + ' -- regenerate: python -m m4k_bench.hazards --write')


def test_every_reference_exists_and_every_row_is_proven_or_a_gap():
    rows = hazards.load(ROOT)        # raises on a missing scenario, cell or test
    assert len({r['id'] for r in rows}) == len(rows)
    section = hazards.render(ROOT)
    gaps = [r for r in rows if not r.get('proof')]
    assert section.count('**GAP**: ') == len(gaps)
    # the rows: every obstacle kind, faults at creep and at top, restarts, calibration
    text = ' '.join(str(r) for r in rows)
    for needed in ('leg', 'black', 'glass', 'below the laser plane', 'person', 'creep',
                   'top speed', 'restart', 'calibrate', 'sonar cone'):
        assert needed in text, needed


def _root_with(tmp_path, rows):
    root = tmp_path / 'ws'
    shutil.copytree(os.path.join(ROOT, 'config'), root / 'config')
    for d in ('test', 'src'):
        os.symlink(os.path.join(ROOT, d), root / d)
    (root / 'config' / 'hazards.yaml').write_text(yaml.safe_dump({'hazards': rows}))
    return str(root)


ROW = {'id': 'X1', 'situation': 's', 'harm': 'h', 'severity': 'S1', 'mitigation': 'm'}


@pytest.mark.parametrize('ref, message', [
    ({'scenario': 'no_such_world'}, 'no scenario config/scenarios/no_such_world.yaml'),
    ({'grid': 'wall.warp.straight'}, "no cell 'wall.warp.straight'"),
    ({'grid': 'leg.top.turning'}, 'is not promised'),
    ({'test': 'test/test_nothing.py::test_x'}, 'no test file test/test_nothing.py'),
    ({'test': 'test/test_hazards.py::test_not_there'}, 'no test test_not_there'),
    ({'test': 'test/test_scenarios.py::test_scenario[no_such_world]'}, 'no parameter'),
])
def test_a_reference_to_nothing_is_an_error(tmp_path, ref, message):
    root = _root_with(tmp_path, [dict(ROW, proof=[ref])])
    with pytest.raises(hazards.HazardError, match=message.replace('[', r'\[').replace('.', r'\.')):
        hazards.load(root)


def test_a_row_without_proof_is_a_gap_and_one_with_neither_is_refused(tmp_path):
    root = _root_with(tmp_path, [dict(ROW, gap='a scenario nobody wrote yet')])
    assert '**GAP**: a scenario nobody wrote yet' in hazards.render(root)
    root = _root_with(tmp_path / 'b', [dict(ROW)])
    with pytest.raises(hazards.HazardError, match='give proof'):
        hazards.load(root)
