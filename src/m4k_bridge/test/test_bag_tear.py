"""A power cut at any byte of a sync: what rosbags opens, and what ``--recover`` makes of it.

:mod:`bag_tears` cuts one sync of the writer at every byte of each of its writes (the retiring
of the old trailer, 9 bytes; the append of the new records and trailer) and keeps each cut as
a bag directory. Read here by rosbags (its own MCAP parser and CDR decoder, written from
rosbag2's format, not from ours); the same cuts are opened with Lichtblick's @mcap/core by
tools/mcap-check/tear.sh (needs npm; see docs/recording.md).
"""

from __future__ import annotations

import shutil
import struct

import bag_tears as bt
import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import get_typestore, Stores

from m4k_bridge.bag import recover as br

STORE = get_typestore(Stores.ROS2_JAZZY)


def _rosbags(directory):
    """Return [(topic, type, log time, text)] of the bag as rosbags reads and decodes it."""
    with Reader(directory) as r:
        return [(c.topic, c.msgtype, t, STORE.deserialize_cdr(raw, c.msgtype).data)
                for c, t, raw in r.messages()]


@pytest.fixture(scope='module')
def cuts(tmp_path_factory):
    return bt.tear_images(str(tmp_path_factory.mktemp('tears')))


def _where(m, im):
    """Name the moment of the cut: before, retire-torn, retired, append-torn, after."""
    ops = m['ops']
    retire, append = ops[0], ops[1]
    assert retire['kind'] == append['kind'] == 'pwrite' and retire['length'] == 9
    assert append['offset'] >= retire['offset'] + 9        # appended, never over the old
    if im['op'] < 0 or im['op'] == 0 and im['k'] == 0:
        return 'before'
    if im['op'] == 0 and im['k'] < 9:
        return 'retire-torn'
    if im['op'] == 0 or im['op'] == 1 and im['k'] == 0:
        return 'retired'
    if im['op'] == 1 and im['k'] < append['length']:
        return 'append-torn'
    return 'after'


def test_the_sync_retires_the_old_trailer_inside_one_sector_and_only_appends(cuts):
    retire, append, truncate = cuts['ops']
    # The only bytes ever rewritten: a record header that does not straddle a 512-byte sector.
    assert retire['offset'] // 512 == (retire['offset'] + 8) // 512
    assert truncate == {'kind': 'ftruncate', 'offset': append['offset'] + append['length'],
                        'length': 0}
    # Every byte offset of both writes was cut (identical files counted once).
    assert len(cuts['images']) >= append['length']


def test_rosbags_opens_the_partial_file_whenever_its_end_is_a_footer(cuts):
    texts = cuts['texts']
    seen = {}
    for im in cuts['images']:
        where = _where(cuts, im)
        try:
            got = _rosbags(im['dir'])
        except Exception as exc:                    # noqa: BLE001 -- what rosbags makes of it
            seen.setdefault(where, set()).add('fails')
            # Only an append cut short has no footer at its end. (The retiring, torn at any
            # byte, leaves the old DataEnd or an empty private record before the old footer.)
            assert where == 'append-torn', (im, exc)
            continue
        seen.setdefault(where, set()).add(len(got))
        if where == 'after':
            # The metadata.yaml of the sync before (a crash before the new one's rename):
            # rosbags shows the topics it names, so not /flag, new in the cut sync, yet.
            want = texts[:cuts['after'] - 1]
        else:
            want = texts[:cuts['before']]
        assert [g[3] for g in got] == want, im
        assert all((g[0], g[1]) == ('/chatter', 'std_msgs/msg/String') for g in got)
        assert [g[2] for g in got] == [bt.T0 + i * bt.S // 10 for i in range(len(want))]
    assert seen['before'] == seen['retired'] == {cuts['before']}
    assert seen['after'] == {cuts['after'] - 1}
    assert seen['append-torn'] == {'fails'}       # the limit: its end is a torn record


def _boundaries(m):
    """Return the offsets, inside the appended write, where each of its records begins."""
    append = m['ops'][1]
    data = open(m['images'][-1]['file'], 'rb').read()          # noqa: SIM115 -- the whole file
    at, out = append['offset'], []
    while at < append['offset'] + append['length'] - 8:          # then the closing magic
        out.append(at - append['offset'])
        at += 9 + struct.unpack_from('<Q', data, at + 1)[0]
    return out + [append['length'] - 8]


def _classes(m):
    """Return the cuts to recover: all but the torn append, and of it every offset class."""
    near = {b + d for b in _boundaries(m) for d in (-1, 0, 1, 2, 8, 9, 10)}
    length = m['ops'][1]['length']
    for im in m['images']:
        if _where(m, im) != 'append-torn' or im['k'] in near or im['k'] < 20 or \
                im['k'] > length - 20 or im['k'] % 97 == 0:
            yield im


def test_recover_makes_every_cut_a_whole_bag_of_the_synced_messages(cuts, tmp_path):
    texts = cuts['texts']
    results = set()
    # Every cut but those inside the append's record bodies, where one byte more or less is
    # the same torn record (each record's first and last bytes, and a byte every 97, are in).
    for im in _classes(cuts):
        d = tmp_path / 'b'
        shutil.copytree(im['dir'], d)
        (d / 'b_0.mcap').unlink(missing_ok=True)
        shutil.move(im['file'].replace(im['dir'], str(d)), d / 'b_0.mcap')
        r = br.recover(str(d))
        got = _rosbags(str(d))
        n = len(got)
        where = _where(cuts, im)
        # Everything synced before the cut, and the cut sync only when all of it is there.
        assert n == (cuts['after'] if where == 'after' else cuts['before']) or \
            where == 'append-torn' and n in (cuts['before'], cuts['after']), (im, n)
        assert [g[3] for g in got] == texts[:n] and r.messages == n
        results.add((where, n))
        shutil.rmtree(d)
    assert ('after', cuts['after']) in results and ('before', cuts['before']) in results


def test_a_disk_full_append_leaves_the_file_as_the_last_sync_did(tmp_path, monkeypatch):
    import errno
    import os

    from m4k_bridge.bag import writer as bw
    w = bw.BagWriter(str(tmp_path / 'full'))
    cid = bt.add_string_topic(w, '/chatter')
    for i in range(4):
        w.write(cid, bt.T0 + i, bt.cdr_string(bt.message_text(i)), i)
    w.sync()
    synced = open(w.path, 'rb').read()                 # noqa: SIM115
    real = os.pwrite

    def full(fd, data, offset):                       # the append gets half its bytes down
        if fd == w._fd and len(data) > 9:
            real(fd, data[:len(data) // 2], offset)
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(fd, data, offset)

    monkeypatch.setattr(os, 'pwrite', full)
    w.write(cid, bt.T0 + 10, bt.cdr_string('lost'), 10)
    with pytest.raises(bw.BagError, match='No space left'):
        w.sync()
    monkeypatch.setattr(os, 'pwrite', real)
    assert open(w.path, 'rb').read() == synced           # noqa: SIM115 -- byte for byte
    got = _rosbags(w.work_directory)
    assert [g[3] for g in got] == [bt.message_text(i) for i in range(4)]
