"""The `make test` summary line keeps skipped tests apart from passed ones (tools/run-tests.sh)."""

import os
import subprocess

from wsenv import ROOT

SUMMARY = os.path.join(ROOT, 'tools', 'test-summary.sh')


def _junit(base, passed, failed, skipped):
    cases = ['<testcase classname="m" name="p{}" time="0"/>'.format(i) for i in range(passed)]
    cases += ['<testcase classname="m" name="f{}" time="0"><failure message="x">x</failure>'
              '</testcase>'.format(i) for i in range(failed)]
    cases += ['<testcase classname="m" name="s{}" time="0"><skipped message="s">s</skipped>'
              '</testcase>'.format(i) for i in range(skipped)]
    d = base / 'pkg' / 'test_results' / 'pkg'
    d.mkdir(parents=True)
    (d / 'pytest.xml').write_text(
        '<?xml version="1.0" encoding="utf-8"?><testsuites><testsuite name="pytest" '
        'errors="0" failures="{}" skipped="{}" tests="{}" time="0">{}</testsuite>'
        '</testsuites>'.format(failed, skipped, passed + failed + skipped, ''.join(cases)))


def _summary(base):
    return subprocess.run([SUMMARY, str(base)], capture_output=True, text=True, timeout=60)


def test_skipped_tests_are_reported_apart_from_passed(tmp_path):
    _junit(tmp_path, passed=7, failed=0, skipped=5)
    r = _summary(tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[-1] == (
        'm4k: 7 passed, 5 skipped, 0 failed, 0 errors (12 collected)')


def test_a_failure_fails_the_summary(tmp_path):
    _junit(tmp_path, passed=3, failed=1, skipped=2)
    r = _summary(tmp_path)
    assert r.returncode != 0
    assert r.stdout.splitlines()[-1] == (
        'm4k: 3 passed, 2 skipped, 1 failed, 0 errors (6 collected)')


def test_only_skips_is_no_pass(tmp_path):
    _junit(tmp_path, passed=0, failed=0, skipped=4)
    r = _summary(tmp_path)
    assert r.returncode != 0 and 'no test passed' in r.stderr
