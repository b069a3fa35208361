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


def test_the_messages_are_valid_cdr_strings_of_the_traffic_sizes_times_the_scale(tmp_path):
    from mcap.reader import make_reader
    from rosbags.typesys import get_typestore, Stores
    store = get_typestore(Stores.ROS2_JAZZY)
    path, _ = bag_seek.write(str(tmp_path / 'b'), 2, scale=3)
    sizes = {t: size * 3 for t, _, size in bag_seek.TRAFFIC}
    with open(path, 'rb') as f:
        for _, channel, m in make_reader(f).iter_messages():
            assert len(m.data) == sizes[channel.topic]
            text = store.deserialize_cdr(m.data, 'std_msgs/msg/String').data
            assert len(text) == sizes[channel.topic] - 9 and text.isalnum()


def test_a_scale_below_one_is_refused(tmp_path, capsys):
    assert bag_seek.main(['--seconds', '2', '--scale', '0', '--results', str(tmp_path)]) == 2
    assert '--scale must be >= 1' in capsys.readouterr().err
