"""Every test module skips for missing root through the ``needs_root`` marker, never a skipif.

A plain ``skipif(os.geteuid() != 0)`` gives a reason the skip policy (m4k_testing) does
not know, so a non-root ``make test`` fails on it; ``needs_root`` is the one accepted form.
"""

import pathlib
import re

from wsenv import ROOT

# skipif(...) whose condition looks at the effective uid, on one line or across a few
SKIPIF_ROOT = re.compile(r'skipif\([^)]*geteuid', re.S)


def _test_modules():
    root = pathlib.Path(ROOT)
    yield from sorted((root / 'test').glob('test_*.py'))
    yield from sorted(root.glob('src/*/test/test_*.py'))


def test_no_test_module_skips_for_root_with_a_plain_skipif():
    offenders = [str(p) for p in _test_modules()
                 if p.name != 'test_skip_markers.py' and SKIPIF_ROOT.search(p.read_text())]
    assert offenders == [], 'use pytest.mark.needs_root(reason) instead: {}'.format(offenders)
