"""The flight recorder's dump directory stays bounded: a week of incidents, the age limit,
and a failed dump that the recorder reports.

Real dumps, written by the recorder's own Dumper into a temporary directory; the sizes are
read back here with ``du``'s rule (the blocks each file takes), not with the pruning code.
"""

from __future__ import annotations

import os
import time

from test_flightrec import _share

from m4k_bridge import flightrec as fr
from m4k_bridge.flightrec_store import dumps, prune

S = 1_000_000_000
HI = b'\x00\x01\x00\x00\x03\x00\x00\x00hi\x00'


def _du(directory):
    total = 0
    for root, _, files in os.walk(directory):
        total += sum(os.lstat(os.path.join(root, f)).st_blocks * 512 for f in files)
    return total


def _dumper(tmp_path, out, limits):
    ring = fr.Ring(13.0, 1 << 20)
    spec = fr.TopicSpec('/chatter', 'std_msgs/msg/String', [{'history': 'keep_last'}], '')
    return ring, fr.Dumper(ring, {'chatter': spec}, str(out), pre_s=10.0, post_s=0.0,
                           share=_share(tmp_path), limits=limits)


def test_a_week_of_repeating_incidents_stays_under_the_disk_cap(tmp_path):
    out = tmp_path / 'dumps'
    cap = 128 * 1024
    ring, d = _dumper(tmp_path, out, (cap, 30 * 86400.0))
    now = time.time_ns()
    t0 = now - 7 * 86400 * S
    try:
        for i in range(7 * 12):                         # a guard stop every 2 h, 7 days
            t = t0 + i * 7200 * S
            for k in range(20):
                ring.add(t - k * S // 10, 'chatter', HI)
            path = d.dump(fr.Trigger('guard_stop', 'repeating', t, 0))
            d._prune(keep=path)                          # as the dump thread does after each
            assert _du(out) <= cap, (i, _du(out))
            assert os.path.isdir(path)                   # the newest is always kept
    finally:
        d.close()
    left = sorted(os.listdir(out))
    assert 0 < len(left) < 7 * 12 and d.pruned == 7 * 12 - len(left)
    # What is left is the newest run of dumps, in order.
    times = [x.t_s for x in dumps(str(out))]
    assert times == sorted(times) and times[-1] >= (now - 7200 * S) / S - 1


def test_dumps_past_the_age_limit_go_and_other_files_stay(tmp_path):
    out = tmp_path / 'dumps'
    ring, d = _dumper(tmp_path, out, None)
    now = time.time()
    try:
        for age_days in (40, 31, 2, 0):
            ring.add(int((now - age_days * 86400) * S), 'chatter', HI)
            d.dump(fr.Trigger('e_stop', 'x', int((now - age_days * 86400) * S), 0))
    finally:
        d.close()
    (out / 'notes.txt').write_text('mine')
    (out / 'flight_not_a_dump').mkdir()
    removed, _ = prune(str(out), 1 << 30, 30 * 86400.0, now_s=now)
    assert len(removed) == 2
    assert len(dumps(str(out))) == 2
    assert (out / 'notes.txt').exists() and (out / 'flight_not_a_dump').is_dir()
    assert prune(str(out), 1 << 30, 0.0, now_s=now + 1e9)[0] == []      # 0: no age limit


def test_a_failed_dump_is_counted_and_reported_until_a_good_one(tmp_path):
    blocker = tmp_path / 'dumps'
    blocker.write_text('a file where the directory should be')
    ring, d = _dumper(tmp_path, blocker, (1 << 20, 0.0))
    try:
        ring.add(time.time_ns(), 'chatter', HI)
        d.submit(fr.Trigger('motor_fault', 'x', time.time_ns(), time.monotonic_ns()))
        deadline = time.monotonic() + 30
        while d.failed == 0:
            assert time.monotonic() < deadline
            time.sleep(0.05)
        assert d.failing and d.last_error.startswith('motor_fault: ')
        assert 'File exists' in d.last_error or 'Not a directory' in d.last_error, d.last_error
        blocker.unlink()
        d.submit(fr.Trigger('motor_fault', 'y', time.time_ns(), time.monotonic_ns()))
        while not d.written:
            assert time.monotonic() < deadline
            time.sleep(0.05)
        assert not d.failing and d.failed == 1
    finally:
        d.close()
