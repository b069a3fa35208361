"""The crash-safe bag writer: never overwrites, readable after every sync, recoverable.

The files are read back with the ``mcap`` package's own readers (seeking and streaming), not
with the writer's code; a "crash" is the process state the writer leaves between syncs, or a
file cut inside a record as a torn write leaves it.
"""

from __future__ import annotations

import os

from mcap.reader import make_reader, NonSeekingReader
import pytest
import yaml

from m4k_bridge.bag import recover as br
from m4k_bridge.bag import writer as bw

# std_msgs/msg/String 'hi' in CDR: encapsulation header, length 3, 'hi\0'.
HI = b'\x00\x01\x00\x00\x03\x00\x00\x00hi\x00'
QOS = [{'history': 'keep_last', 'depth': 10}]


def _bag(tmp_path, name='b', **kw):
    w = bw.BagWriter(str(tmp_path / name), **kw)
    cid = w.add_topic('/chatter', 'std_msgs/msg/String', 'string data\n', 'RIHS01_' + '1' * 64,
                      QOS, '- history: 1\n  depth: 10\n')
    return w, cid


def _meta(path):
    with open(os.path.join(path, 'metadata.yaml'), encoding='utf-8') as f:
        return yaml.safe_load(f)['rosbag2_bagfile_information']


def _read(path):
    with open(path, 'rb') as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        logs = [m.log_time for _, _, m in reader.iter_messages()]
    return summary, logs


def test_an_existing_directory_is_refused_and_left_untouched(tmp_path):
    target = tmp_path / 'b'
    target.mkdir()
    (target / 'keep.txt').write_text('earlier bag')
    with pytest.raises(bw.BagExistsError, match='never overwrites'):
        bw.BagWriter(str(target))
    assert sorted(os.listdir(target)) == ['keep.txt']


def test_a_partial_bag_of_that_name_is_refused_too(tmp_path):
    (tmp_path / 'b.partial').mkdir()                  # a crashed recording of the same name
    with pytest.raises(bw.BagExistsError, match='b.partial'):
        bw.BagWriter(str(tmp_path / 'b'))
    assert sorted(os.listdir(tmp_path)) == ['b.partial']


def test_a_failed_writer_keeps_its_partial_name(tmp_path):
    w, cid = _bag(tmp_path)
    w.write(cid, 7, HI)
    w.close(complete=False)
    assert sorted(os.listdir(tmp_path)) == ['b.partial']
    assert _read(w.path)[1] == [7]


def test_metadata_exists_from_the_start_and_lists_nothing(tmp_path):
    w, _ = _bag(tmp_path)
    meta = _meta(w.work_directory)
    assert w.work_directory == str(tmp_path / 'b.partial') and not os.path.exists(w.directory)
    assert meta['message_count'] == 0 and meta['relative_file_paths'] == ['b_0.mcap']
    summary, logs = _read(w.path)
    assert logs == [] and summary is None     # a partial file has no summary (the last sync's)
    w.close()


def test_between_syncs_the_file_is_the_last_synced_bag_and_metadata_matches(tmp_path):
    w, cid = _bag(tmp_path)
    for i in range(5):
        w.write(cid, 1_000 + i, HI, i)
    w.sync()
    for i in range(3):                       # written, never synced: what a crash loses
        w.write(cid, 2_000 + i, HI, 5 + i)
    summary, logs = _read(w.path)
    assert logs == [1_000, 1_001, 1_002, 1_003, 1_004] and summary is None
    meta = _meta(w.work_directory)
    assert meta['message_count'] == 5
    assert meta['topics_with_message_count'][0]['message_count'] == 5
    assert meta['starting_time']['nanoseconds_since_epoch'] == 1_000
    assert meta['duration']['nanoseconds'] == 4
    with open(w.path, 'rb') as f:             # a streaming reader ends at the footer cleanly
        assert sum(1 for _ in NonSeekingReader(f).iter_messages()) == 5
    w.close()
    summary, logs = _read(w.path)
    assert len(logs) == 8 and _meta(w.directory)['message_count'] == 8


def test_custom_data_reaches_the_metadata(tmp_path):
    w, _ = _bag(tmp_path, custom_data={'m4k.flight_recorder.trigger': 'e_stop'})
    w.close()
    assert _meta(w.directory)['custom_data'] == {'m4k.flight_recorder.trigger': 'e_stop'}


def test_recover_leaves_a_consistent_bag_alone(tmp_path):
    w, cid = _bag(tmp_path)
    w.write(cid, 5, HI)
    w.close()
    before = open(w.path, 'rb').read()
    r = br.recover(w.directory)
    assert (r.complete, r.rewritten, r.messages) == (True, False, 1)
    assert open(w.path, 'rb').read() == before


def test_recover_keeps_every_complete_record_of_a_torn_write(tmp_path):
    w, cid = _bag(tmp_path)
    for i in range(4):
        w.write(cid, 100 + i, HI, i)
    w.sync()
    synced = os.path.getsize(w.path)
    for i in range(6):
        w.write(cid, 200 + i, HI, 4 + i)
    w.sync()
    w.close()
    # A sync cut short: the new records over the old trailer, the last one incomplete.
    cut = synced + 30
    os.truncate(w.path, cut)
    with pytest.raises(Exception):           # noqa: B017 -- what a reader makes of it now
        _read(w.path)
    r = br.recover(w.directory)
    assert not r.complete and r.rewritten and r.dropped_bytes > 0
    summary, logs = _read(w.path)
    assert logs[:4] == [100, 101, 102, 103] and len(logs) == r.messages >= 4
    meta = _meta(w.directory)
    assert meta['message_count'] == r.messages == summary.statistics.message_count
    assert meta['relative_file_paths'] == ['b_0.mcap']
    assert meta['topics_with_message_count'][0]['topic_metadata']['offered_qos_profiles'] == \
        [{'history': 'keep_last', 'depth': 10}]
    assert sorted(os.listdir(w.directory)) == ['b_0.mcap', 'metadata.yaml']


def test_recover_refuses_a_directory_without_the_bag_file(tmp_path):
    (tmp_path / 'x').mkdir()
    with pytest.raises(bw.BagError, match='not a bag'):
        br.recover(str(tmp_path / 'x'))


def test_the_default_name_moves_on_when_taken(tmp_path, monkeypatch):
    import datetime

    from m4k_bridge.bag.record import default_output
    monkeypatch.chdir(tmp_path)
    when = datetime.datetime(2026, 11, 26, 6, 0, 0, tzinfo=datetime.timezone.utc)
    assert default_output(when) == 'm4k_2026_11_26-06_00_00'
    (tmp_path / 'm4k_2026_11_26-06_00_00').mkdir()
    (tmp_path / 'm4k_2026_11_26-06_00_00-2').mkdir()
    assert default_output(when) == 'm4k_2026_11_26-06_00_00-3'


def test_recover_streams_a_bag_much_larger_than_the_memory_it_uses(tmp_path):
    import tracemalloc
    w, cid = _bag(tmp_path)
    big = HI[:4] + os.urandom(64 * 1024)                 # 64 KiB payloads: 40 MiB in all
    for i in range(640):
        w.write(cid, 1000 + i, big, i)
        if i % 64 == 63:
            w.sync()
    w.close()
    os.truncate(w.path, os.path.getsize(w.path) - 10)  # no footer: recovery must rewrite
    tracemalloc.start()
    try:
        r = br.recover(w.directory)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert r.rewritten and r.messages == 640
    # Held whole, the messages alone would be 40 MiB; streamed, the 4 MiB copy buffer and a
    # record or two.
    assert peak < 12 << 20, peak
    summary, logs = _read(w.path)
    assert logs == list(range(1000, 1640)) and summary.statistics.message_count == 640
