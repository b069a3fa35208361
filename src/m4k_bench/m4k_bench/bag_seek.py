"""Seek in an hour-long recording: what the MCAP index saves a viewer (bench, not a test).

``python -m m4k_bench.bag_seek [--seconds 3600] [--out DIR] [--results DIR]`` writes a bag
with the recorder's writer (:class:`m4k_bridge.bag.writer.BagWriter`, one sync a second, as
``record`` does) carrying the stack's traffic at its rates and sizes (``/scan`` 10 Hz,
``/odom`` 20 Hz, ``/imu`` 100 Hz, ``/tf`` 20 Hz; each message a valid CDR ``std_msgs/String``
of that message's size, so a viewer can decode it; ``--scale N`` makes every message N times
larger, for a multi-GiB file), then
reads one second from its middle with the ``mcap`` package's seeking reader, which finds the
chunks through the summary's chunk indexes, and counts the bytes it read from the file and the
time it took; the same second read by a linear scan is the baseline a viewer without an index
pays. Results: ``summary.json`` and ``report.md`` in ``--results`` (a stamped folder under
docs/results/bagseek by default).
"""

from __future__ import annotations

import argparse
import io
import os
import shutil
import struct
import sys
import tempfile
import time
from typing import Any, Sequence

from mcap.reader import make_reader, NonSeekingReader

from m4k_bench.benchlib import provenance, results
from m4k_bridge.bag.writer import BagWriter

_NS = 1_000_000_000
# (topic, rate Hz, CDR bytes): the sizes the stack's messages have on the wire (a 720-ray
# LaserScan with intensities, Odometry with its covariances, Imu, a one-transform TFMessage).
TRAFFIC = (('/scan', 10, 5_860), ('/odom', 20, 724), ('/imu', 100, 324), ('/tf', 20, 148))
_T0 = 1_800_000_000 * _NS


class _Counting(io.RawIOBase):
    """A read-only file that counts the bytes read through it."""

    def __init__(self, path: str) -> None:
        self._f = open(path, 'rb')   # noqa: SIM115 -- closed by close()
        self.read_bytes = 0

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, offset: int, whence: int = 0) -> int:
        return self._f.seek(offset, whence)

    def tell(self) -> int:
        return self._f.tell()

    def readinto(self, b: Any) -> int:
        n = self._f.readinto(b)
        self.read_bytes += n or 0
        return n or 0

    def close(self) -> None:
        self._f.close()
        super().close()


def _payload(pool: bytes, off: int, size: int) -> bytes:
    """Return a ``size``-byte CDR ``std_msgs/String``: encapsulation, length, text, NUL."""
    text = pool[off:off + size - 9]
    return b'\x00\x01\x00\x00' + struct.pack('<I', len(text) + 1) + text + b'\x00'


def write(directory: str, seconds: int, scale: int = 1) -> tuple[str, float]:
    """Write ``seconds`` of the traffic as a bag; return its MCAP path and the wall time."""
    alphabet = b'abcdefghijklmnopqrstuvwxyz0123456789'
    pool = bytes(alphabet[b % len(alphabet)] for b in os.urandom(1 << 16)) * max(1, scale)
    w = BagWriter(directory, library='m4k_bench bag_seek')
    ids = {t: w.add_topic(t, 'std_msgs/msg/String', 'string data\n', '', [], '')
           for t, _, _ in TRAFFIC}
    start = time.monotonic()
    for s in range(seconds):
        for topic, hz, size in TRAFFIC:
            for k in range(hz):
                off = (s * 7919 + k * 104729) % (len(pool) - size * scale)
                w.write(ids[topic], _T0 + s * _NS + k * _NS // hz,
                        _payload(pool, off, size * scale))
        w.sync()
    w.close()
    return w.path, time.monotonic() - start


def read_window(path: str, lo: int, hi: int, seeking: bool) -> tuple[int, int, float]:
    """Return (messages in [lo, hi), bytes read, seconds) by the seeking or linear reader."""
    f = _Counting(path)
    start = time.monotonic()
    try:
        buf = io.BufferedReader(f, 64 * 1024)
        if seeking:
            n = sum(1 for _ in make_reader(buf).iter_messages(starting_at=lo, ending_before=hi))
        else:
            n = sum(1 for _, _, m in NonSeekingReader(buf).iter_messages(log_time_order=False)
                    if lo <= m.log_time < hi)
        return n, f.read_bytes, time.monotonic() - start
    finally:
        f.close()


def main(argv: Sequence[str] | None = None) -> int:
    """Write the bag, read a second from its middle both ways, report."""
    ap = argparse.ArgumentParser(prog='bag_seek', description=__doc__.split('\n\n')[0])
    ap.add_argument('--seconds', type=int, default=3600, help='length of the recording')
    ap.add_argument('--scale', type=int, default=1,
                    help='every message this many times its size (a bigger file, same rates)')
    ap.add_argument('--out', help='where to write the bag (default: a temporary directory, '
                    'removed afterwards)')
    ap.add_argument('--results', help='results folder (default: docs/results/bagseek/<UTC>)')
    args = ap.parse_args(argv)
    if args.scale < 1:
        print('bag_seek: --scale must be >= 1, got {}'.format(args.scale), file=sys.stderr)
        return 2
    if args.seconds < 2:
        print('bag_seek: --seconds must be >= 2, got {}'.format(args.seconds), file=sys.stderr)
        return 2
    tmp = tempfile.mkdtemp(prefix='bag_seek-')
    try:
        path, write_s = write(args.out or os.path.join(tmp, 'bag'), args.seconds, args.scale)
        size = os.path.getsize(path)
        with open(path, 'rb') as f:
            summary = make_reader(f).get_summary()
        if summary is None or summary.statistics is None:
            print('bag_seek: {} has no summary'.format(path), file=sys.stderr)
            return 1
        mid = _T0 + args.seconds // 2 * _NS
        rows = {}
        for name, seeking in (('seeking (index)', True), ('linear scan', False)):
            n, nbytes, secs = read_window(path, mid, mid + _NS, seeking)
            rows[name] = {'messages': n, 'bytes_read': nbytes, 'seconds': round(secs, 3)}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    doc = {'seconds': args.seconds, 'scale': args.scale, 'file_bytes': size,
           'write_seconds': round(write_s, 1),
           'chunks': len(summary.chunk_indexes), 'messages': summary.statistics.message_count,
           'one_second_window': rows, 'traffic': [list(t) for t in TRAFFIC]}
    out = args.results or results.stamped_dir(os.path.join('docs', 'results', 'bagseek'))
    written = results.write_json(os.path.join(out, 'summary.json'), doc)
    lines = ['# Seeking one second in a {} s recording'.format(args.seconds), '',
             '`python -m m4k_bench.bag_seek --seconds {}{}` at {}.'.format(
                 args.seconds, ' --scale {}'.format(args.scale) if args.scale > 1 else '',
                 provenance.text(written['provenance'])), '',
             'File: {:.1f} MiB, {} messages, {} chunks; written in {} s (one sync a '
             'second).'.format(size / 2**20, doc['messages'], doc['chunks'], doc['write_seconds']),
             '']
    lines += results.md_table(['reader', 'messages', 'bytes read', 'seconds'],
                              [[k, v['messages'], v['bytes_read'], v['seconds']]
                               for k, v in rows.items()])
    results.write_text(os.path.join(out, 'report.md'), '\n'.join(lines) + '\n')
    print('\n'.join(lines))
    return 0


if __name__ == '__main__':
    sys.exit(main())
