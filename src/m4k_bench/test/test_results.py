"""benchlib.results, the one results writer: stamped folders, provenance, Markdown tables."""

import ast
import datetime
import json
import os

import m4k_bench
from m4k_bench import recorder
from m4k_bench.benchlib import results

# json.dump calls allowed outside the writer, with why: the bench's rounds.json is a list
# of rounds (no mapping to carry a provenance), the floor probe prints to its parent's pipe.
_NOT_A_SUMMARY = {'bench.py': 1, 'benchlib/floor.py': 1}


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


def test_no_tool_writes_its_json_results_by_hand():
    # Seven tools (bench, core_bench, demo, fuzz, liveview, recorder, soak) wrote summary.json
    # with their own json.dump beside this writer; a new one would be a twin again.
    root = os.path.dirname(m4k_bench.__file__)
    found: dict[str, int] = {}
    for d, _, files in os.walk(root):
        for name in files:
            if not name.endswith('.py'):
                continue
            path = os.path.join(d, name)
            rel = os.path.relpath(path, root)
            with open(path, encoding='utf-8') as f:
                tree = ast.parse(f.read())
            n = sum(1 for c in ast.walk(tree) if isinstance(c, ast.Call)
                    and isinstance(c.func, ast.Attribute) and c.func.attr == 'dump'
                    and isinstance(c.func.value, ast.Name) and c.func.value.id == 'json')
            if n and rel != os.path.join('benchlib', 'results.py'):
                found[rel] = n
    assert found == _NOT_A_SUMMARY


def test_rt_stats_summary_comes_through_the_writer(tmp_path):
    # the recorder serialised its summary with json.dumps into its own file (no json.dump to
    # count above): what it writes now carries the writer's provenance
    paths = recorder.Recorder().write(str(tmp_path))
    with open(paths['json']) as f:
        doc = json.load(f)
    assert set(doc) == {'tasks', 'warmup_cycles_skipped', 'provenance'}
    assert set(doc['provenance']) == {'commit', 'dirty', 'machine', 'measured_utc'}
