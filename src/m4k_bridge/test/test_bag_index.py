"""Recordings are indexed: a reader seeks by time through the summary, not through the file.

Two readers that are not the writer's code check it. ``_SpecReader`` below follows the MCAP
specification (https://mcap.dev/spec) with ``struct`` alone: footer, summary offsets, chunk
indexes, message indexes; every offset the index gives must land on the record it names. The
``mcap`` package's seeking reader answers a time-range query from the summary's chunk
indexes, and must agree with a plain filter over a linear read of the same file.
"""

from __future__ import annotations

import os
import struct

from mcap.reader import make_reader, NonSeekingReader
import pytest

from m4k_bridge.bag import writer as bw

HI = b'\x00\x01\x00\x00\x03\x00\x00\x00hi\x00'
MAGIC = b'\x89MCAP0\r\n'


class _SpecReader:
    """The index of an MCAP file, read by the specification's byte layout."""

    def __init__(self, path: str) -> None:
        with open(path, 'rb') as f:
            self.data = f.read()
        d = self.data
        assert d[:8] == MAGIC and d[-8:] == MAGIC
        op, length = struct.unpack_from('<BQ', d, len(d) - 8 - 29)
        assert (op, length) == (0x02, 20), 'no footer where the specification puts it'
        self.summary_start, self.offset_start, _ = struct.unpack_from('<QQI', d, len(d) - 28)
        self.chunk_indexes: list[dict] = []
        self.metadata_indexes: list[tuple[int, int, str]] = []
        self.groups: dict[int, tuple[int, int]] = {}
        # summary_start 0: no summary (a partial file); summary_offset_start 0: no offsets.
        pos = self.summary_start or len(d)
        while pos < (self.offset_start or len(d) - 8 - 29):
            op, length = struct.unpack_from('<BQ', d, pos)
            body = pos + 9
            if op == 0x08:
                self.chunk_indexes.append(self._chunk_index(body))
            elif op == 0x0D:
                off, ln, nlen = struct.unpack_from('<QQI', d, body)
                self.metadata_indexes.append(
                    (off, ln, d[body + 20:body + 20 + nlen].decode()))
            pos = body + length
        while pos < len(d) - 8 - 29:                  # the summary offset section
            op, length = struct.unpack_from('<BQ', d, pos)
            assert op == 0x0E
            group, start, glen = struct.unpack_from('<BQQ', d, pos + 9)
            self.groups[group] = (start, glen)
            pos += 9 + length

    def _chunk_index(self, p: int) -> dict:
        d = self.data
        start, end, offset, length, map_len = struct.unpack_from('<QQQQI', d, p)
        p += 36
        offsets = {}
        for q in range(p, p + map_len, 10):
            cid, off = struct.unpack_from('<HQ', d, q)
            offsets[cid] = off
        p += map_len
        index_len, clen = struct.unpack_from('<QI', d, p)
        compression = d[p + 12:p + 12 + clen].decode()
        p += 12 + clen
        compressed, uncompressed = struct.unpack_from('<QQ', d, p)
        return {'start': start, 'end': end, 'offset': offset, 'length': length,
                'index_offsets': offsets, 'index_length': index_len,
                'compression': compression, 'compressed': compressed,
                'uncompressed': uncompressed}

    def messages(self, ci: dict) -> list[tuple[int, int, int]]:
        """Return (channel, log time, sequence) of every message the chunk's indexes point at."""
        d = self.data
        op, length = struct.unpack_from('<BQ', d, ci['offset'])
        assert op == 0x06 and 9 + length == ci['length'], 'the chunk index misses its chunk'
        p = ci['offset'] + 9
        _, _, usize, _, clen = struct.unpack_from('<QQQII', d, p)
        p += 32 + clen
        rlen, = struct.unpack_from('<Q', d, p)
        records = p + 8
        assert ci['compression'] == '' and rlen == usize == ci['uncompressed']
        out = []
        total = 0
        for cid, off in ci['index_offsets'].items():
            op, length = struct.unpack_from('<BQ', d, off)
            assert op == 0x07, 'a message index offset lands on opcode {:#x}'.format(op)
            total += 9 + length
            mcid, alen = struct.unpack_from('<HI', d, off + 9)
            assert mcid == cid
            for q in range(off + 15, off + 15 + alen, 16):
                t, rel = struct.unpack_from('<QQ', d, q)
                mop, _, chan, seq, log_time = struct.unpack_from('<BQHIQ', d, records + rel)
                assert (mop, chan, log_time) == (0x05, cid, t), 'index entry misses its message'
                out.append((cid, t, seq))
        assert total == ci['index_length']
        return out


def _bag(tmp_path, n, payload, every):
    w = bw.BagWriter(str(tmp_path / 'b'), custom_data={'m4k.commit': 'abc123'})
    a = w.add_topic('/a', 'std_msgs/msg/String', 'string data\n', '', [], '')
    b = w.add_topic('/b', 'std_msgs/msg/String', 'string data\n', '', [], '')
    for i in range(n):
        w.write(a if i % 3 else b, 1_000_000 + i * 1000, HI + payload, i)
        if i % every == every - 1:
            w.sync()
    w.close()
    return w.path


def _linear(path):
    with open(path, 'rb') as f:
        return [(ch.id, m.log_time, m.sequence)
                for _, ch, m in NonSeekingReader(f).iter_messages(log_time_order=False)]


@pytest.mark.parametrize('n,payload,every', [(3000, b'', 1000), (900, bytes(8000), 10_000)])
def test_every_message_is_reached_through_the_chunk_and_message_indexes(tmp_path, n, payload,
                                                                       every):
    # One chunk per sync (small messages), or chunks closed by size within one sync.
    path = _bag(tmp_path, n, payload, every)
    spec = _SpecReader(path)
    assert {0x08, 0x0D} <= set(spec.groups)          # the summary offsets name both indexes
    indexed = [m for ci in spec.chunk_indexes for m in spec.messages(ci)]
    assert sorted(indexed) == sorted(_linear(path))
    assert len(indexed) == n
    for ci in spec.chunk_indexes:
        times = [t for cid, t, _ in spec.messages(ci)]
        assert (min(times), max(times)) == (ci['start'], ci['end'])
        assert ci['length'] > ci['compressed'] and ci['compressed'] <= bw.CHUNK_BYTES + 9000
    with open(path, 'rb') as f:
        assert make_reader(f).get_summary().statistics.chunk_count == len(spec.chunk_indexes)
    if every < n:
        assert len(spec.chunk_indexes) == n // every
    else:
        assert len(spec.chunk_indexes) >= (n * 8000) // bw.CHUNK_BYTES


def test_a_time_range_is_read_through_the_summary_and_matches_a_linear_filter(tmp_path):
    path = _bag(tmp_path, 5000, bytes(200), 500)
    lo, hi = 1_000_000 + 3210 * 1000, 1_000_000 + 3987 * 1000
    want = [(c, t, s) for c, t, s in _linear(path) if lo <= t < hi]
    with open(path, 'rb') as f:
        reader = make_reader(f)
        assert reader.get_summary().chunk_indexes            # seeking, not scanning
        got = [(ch.id, m.log_time, m.sequence)
               for _, ch, m in reader.iter_messages(starting_at=lo, ending_before=hi)]
    assert got == want and len(got) == 3987 - 3210
    # The chunks a seek must read are the few that overlap the range, not the file.
    spec = _SpecReader(path)
    overlapping = [ci for ci in spec.chunk_indexes if ci['end'] >= lo and ci['start'] < hi]
    assert len(overlapping) == 2 < len(spec.chunk_indexes) == 10


def test_the_commit_is_an_mcap_metadata_record_listed_in_the_summary(tmp_path):
    path = _bag(tmp_path, 3, b'', 10)
    spec = _SpecReader(path)
    assert [name for _, _, name in spec.metadata_indexes] == ['m4k']
    off, length, _ = spec.metadata_indexes[0]
    assert spec.data[off] == 0x0C and struct.unpack_from('<Q', spec.data, off + 1)[0] + 9 \
        == length
    with open(path, 'rb') as f:
        meta = list(make_reader(f).iter_metadata())
    assert [(m.name, m.metadata) for m in meta] == [('m4k', {'m4k.commit': 'abc123'})]


def test_the_summary_is_written_by_the_last_sync_and_partial_files_read_linearly(
        tmp_path):
    w = bw.BagWriter(str(tmp_path / 'p'))
    cid = w.add_topic('/a', 'std_msgs/msg/String', 'string data\n', '', [], '')
    for i in range(30):
        w.write(cid, 1000 + i, HI, i)
        if i % 10 == 9:
            w.sync()
    spec = _SpecReader(w.path)                    # the running (or crashed) partial file
    assert spec.chunk_indexes == [] and spec.summary_start == 0 and not spec.groups
    with open(w.path, 'rb') as f:
        reader = make_reader(f)
        assert reader.get_summary() is None       # no summary: read linearly
        assert [m.log_time for _, _, m in reader.iter_messages()] == list(range(1000, 1030))
    w.close()
    spec = _SpecReader(w.path)
    assert len(spec.chunk_indexes) == 3
    assert sorted(t for ci in spec.chunk_indexes for _, t, _ in spec.messages(ci)) == \
        list(range(1000, 1030))


def test_an_empty_bag_has_no_chunk_and_stays_readable(tmp_path):
    w = bw.BagWriter(str(tmp_path / 'e'))
    w.close()
    spec = _SpecReader(w.path)
    assert spec.chunk_indexes == [] and 0x08 not in spec.groups
    assert os.path.basename(os.path.dirname(w.path)) == 'e'
