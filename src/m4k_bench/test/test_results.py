"""benchlib.results, the one results writer: stamped folders, provenance, Markdown tables."""

import datetime
import json
import os

from m4k_bench.benchlib import results


def test_stamped_folders_are_new_every_time(tmp_path):
    when = results.stamp(datetime.datetime(2026, 11, 26, 13, 5, 1,
                                           tzinfo=datetime.timezone.utc))
    assert when == '20261126T130501Z'
    a = results.stamped_dir(str(tmp_path / 'r'), 'soak-', when=when)
    b = results.stamped_dir(str(tmp_path / 'r'), 'soak-', when=when)
    c = results.stamped_dir(str(tmp_path / 'r'), 'soak-', when=when)
    assert [os.path.basename(p) for p in (a, b, c)] == [
        'soak-20261126T130501Z', 'soak-20261126T130501Z-2', 'soak-20261126T130501Z-3']
    assert all(os.path.isdir(p) for p in (a, b, c))


def test_a_summary_carries_its_provenance_unless_it_has_one(tmp_path):
    path = str(tmp_path / 'x' / 'summary.json')
    out = results.write_json(path, {'n': 1})
    with open(path) as f:
        on_disk = json.load(f)
    assert on_disk == out and on_disk['n'] == 1
    assert set(on_disk['provenance']) == {'commit', 'dirty', 'machine', 'measured_utc'}
    results.write_json(path, {'n': 2, 'provenance': {'commit': 'abc'}})
    with open(path) as f:
        assert json.load(f)['provenance'] == {'commit': 'abc'}


def test_markdown_tables_and_pages(tmp_path):
    assert results.md_table(['a', 'b'], [[1, 'x'], [2, 'y']]) == [
        '| a | b |', '|---|---|', '| 1 | x |', '| 2 | y |']
    page = str(tmp_path / 'README.md')
    results.write_text(page, '# t')
    with open(page) as f:
        assert f.read() == '# t\n'
