"""A bag appears under its final name only whole: a writer killed with SIGKILL mid-dump.

The writer is a real process (the flight recorder's own Dumper, or ``BagWriter``), killed with
SIGKILL by this test; what is then on disk is read with the ``mcap`` package's readers, never
with the writer's code. Under the final name a reader finds either nothing or a complete,
indexed bag; the cut-off dump is a ``.partial`` directory that the disk-cap pruning counts and
removes, and that ``record --recover`` can finish.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

from mcap.reader import make_reader, NonSeekingReader
import yaml

from m4k_bridge.bag.recover import recover
from m4k_bridge.flightrec_store import dumps, prune

S = 1_000_000_000
_DUMPER = textwrap.dedent("""
    import os, sys, time
    from m4k_bridge import flightrec as fr
    out, share, mode = sys.argv[1], sys.argv[2], sys.argv[3]
    hi = b'\\x00\\x01\\x00\\x00\\x03\\x00\\x00\\x00hi\\x00'
    ring = fr.Ring(13.0, 8 << 20)
    spec = fr.TopicSpec('/chatter', 'std_msgs/msg/String', [], '')
    d = fr.Dumper(ring, {'chatter': spec}, out, 10.0, 0.0,
                  share=lambda pkg: os.path.join(share, pkg))
    real_close = fr.BagWriter.close
    def close(self, complete=True):
        self.sync()
        if mode == 'hold':                # every message written and synced: now hold
            print('synced', self.work_directory, flush=True)
            sys.stdin.read()
        real_close(self, complete)
    fr.BagWriter.close = close
    t0 = 1_800_000_000 * 10**9
    for k in range(100000):               # 'loop': dump after dump until killed
        t = t0 + k * 60 * 10**9
        for i in range(2000):
            ring.add(t - i * 10**9 // 200, 'chatter', hi)
        d.dump(fr.Trigger('guard_stop', 'x', t, 0))
        if mode == 'loop':
            print('dumped', flush=True)
""")


def _share(tmp_path):
    msg = tmp_path / 'share' / 'std_msgs' / 'msg'
    msg.mkdir(parents=True)
    (msg / 'String.msg').write_text('string data\n')
    return str(tmp_path / 'share')


def _start(tmp_path, out, mode):
    return subprocess.Popen([sys.executable, '-c', _DUMPER, str(out), _share(tmp_path), mode],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)


def _kill(p):
    p.send_signal(signal.SIGKILL)
    assert p.wait(30) == -signal.SIGKILL
    p.stdin.close()
    p.stdout.close()


def _whole(bag_dir, indexed=True):
    """Messages of the bag, read by the seeking reader (through its index) and linearly."""
    with open(os.path.join(bag_dir, 'metadata.yaml'), encoding='utf-8') as f:
        meta = yaml.safe_load(f)['rosbag2_bagfile_information']
    mcap = os.path.join(bag_dir, meta['relative_file_paths'][0])
    with open(mcap, 'rb') as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        n = sum(1 for _ in reader.iter_messages())
    with open(mcap, 'rb') as f:
        assert sum(1 for _ in NonSeekingReader(f).iter_messages()) == n
    # A partial file has no summary (the last sync writes it, with the chunk indexes).
    assert (summary is not None) == indexed
    assert summary is None or summary.chunk_indexes and summary.statistics.message_count == n
    assert meta['message_count'] == n
    return n


def test_a_dump_killed_before_its_rename_leaves_only_a_partial_that_pruning_removes(tmp_path):
    out = tmp_path / 'dumps'
    p = _start(tmp_path, out, 'hold')
    try:
        line = p.stdout.readline().split()
        assert line[0] == 'synced', line
    finally:
        _kill(p)
    partial = line[1]
    final = partial[:-len('.partial')]
    assert partial.endswith('.partial') and os.path.basename(final).startswith('flight_')
    # Under the final name there is nothing: no reader can take a cut-off dump for a whole one.
    assert sorted(os.listdir(out)) == [os.path.basename(partial)]
    assert not os.path.exists(final)
    # The partial is what the last sync left: itself readable (linearly: the chunk indexes
    # come with the rename's sync), all 2000 messages in it.
    assert _whole(partial, indexed=False) == 2000
    # It takes disk, so it counts towards the cap, and pruning removes it like any dump.
    found = dumps(str(out))
    assert [d.path for d in found] == [partial] and found[0].size > 2000 * 12
    removed, left = prune(str(out), 0, 0.0)
    assert removed == [partial] and left == 0 and os.listdir(out) == []


def test_a_partial_dump_is_finished_by_recover_under_its_final_name(tmp_path):
    out = tmp_path / 'dumps'
    p = _start(tmp_path, out, 'hold')
    try:
        partial = p.stdout.readline().split()[1]
    finally:
        _kill(p)
    r = recover(partial)
    final = partial[:-len('.partial')]
    assert r.directory == final and r.messages == 2000
    assert os.listdir(out) == [os.path.basename(final)] and _whole(final) == 2000


def test_dumps_killed_at_any_moment_are_whole_under_their_names(tmp_path):
    out = tmp_path / 'dumps'
    for wait_s in (0.0, 0.37, 1.1):
        p = _start(tmp_path / str(wait_s), out, 'loop')
        try:
            assert p.stdout.readline().strip() == 'dumped'
            time.sleep(wait_s)                   # wherever the next dump has got to
        finally:
            _kill(p)
    names = os.listdir(out)
    finals = [n for n in names if not n.endswith('.partial')]
    assert finals and len(names) - len(finals) <= 3
    for name in finals:
        assert _whole(str(out / name)) == 2000, name
