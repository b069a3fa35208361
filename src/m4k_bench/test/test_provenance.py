"""The one helper that stamps every result file with the commit and the machine."""

import os
import subprocess

from m4k_bench.benchlib import provenance

HERE = os.path.dirname(os.path.abspath(__file__))


def test_provenance_names_the_checkout_commit_and_the_machine_without_its_name():
    head = subprocess.run(['git', 'rev-parse', 'HEAD'], cwd=HERE, capture_output=True,
                          text=True, check=True).stdout.strip()
    p = provenance.provenance(HERE)
    assert p['commit'] == head and isinstance(p['dirty'], bool)
    m = p['machine']
    assert m['cpus_online'] == os.cpu_count() and m['kernel'] == os.uname().release
    assert 'hostname' not in m and os.uname().nodename not in str(m.values())
    assert p['measured_utc'].endswith('Z')
    line = provenance.text(p)
    assert line.startswith('commit ' + head[:12]) and 'x{}'.format(os.cpu_count()) in line


def test_outside_a_checkout_the_commit_is_unknown_not_guessed(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(os.path, 'realpath', lambda p: str(tmp_path / 'x.py'))
    monkeypatch.setenv('GIT_CEILING_DIRECTORIES', str(tmp_path.parent))
    assert provenance.commit(str(tmp_path)) == {'commit': None, 'dirty': None}
    assert 'commit unknown on ' in provenance.text({**provenance.provenance(str(tmp_path)),
                                                   'commit': None})
