"""bag_seek's own arithmetic: it writes what it says and reads one second both ways."""

import json

from m4k_bench import bag_seek


def test_a_short_run_writes_the_traffic_and_reads_one_second_both_ways(tmp_path):
    assert bag_seek.main(['--seconds', '4', '--results', str(tmp_path / 'r')]) == 0
    doc = json.loads((tmp_path / 'r' / 'summary.json').read_text())
    per_second = sum(hz for _, hz, _ in bag_seek.TRAFFIC)
    assert doc['messages'] == 4 * per_second and doc['chunks'] == 4
    seek, scan = doc['one_second_window']['seeking (index)'], doc['one_second_window'][
        'linear scan']
    assert seek['messages'] == scan['messages'] == per_second
    assert scan['bytes_read'] == doc['file_bytes'] > seek['bytes_read']
    assert doc['provenance']['commit']
    report = (tmp_path / 'r' / 'report.md').read_text()
    assert '| seeking (index) | {} |'.format(per_second) in report


def test_fewer_than_two_seconds_is_refused(tmp_path, capsys):
    assert bag_seek.main(['--seconds', '1', '--results', str(tmp_path)]) == 2
    assert '--seconds must be >= 2' in capsys.readouterr().err
