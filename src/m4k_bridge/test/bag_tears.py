"""Every state a power cut can leave a bag's MCAP in during one sync (test helper, not a test).

A recorder writes three syncs of ``std_msgs/String`` messages; the fourth sync's file writes
are captured as they are issued (``os.pwrite`` / ``os.ftruncate`` on the bag's descriptor).
A power cut keeps the writes before it and a prefix of the write in flight (the model a
disk with in-order writes gives; each write torn at *every* byte offset, not a sample).
:func:`tear_images` writes each distinct resulting file as a bag directory of its own, with
the metadata.yaml of the last completed sync, and a manifest of what was synced before and
after, so readers written by others (rosbags, the ``mcap`` package, ``@mcap/core`` in
tools/mcap-check/tear.mjs) can be run over all of them.

``writer_module`` lets tools/mcap-check/tear.sh run the same cut against another version of
the writer (the one before the append-only trailer) for comparison.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import struct
from types import ModuleType
from typing import Any, Iterator

S = 1_000_000_000
T0 = 1_800_000_000 * S
SYNCS = 3                      # syncs before the one that is cut
PER_SYNC = 2                   # messages per sync
FLAG = '/flag'                 # std_msgs/Bool, first published in the cut sync (data: true)


def cdr_string(text: str) -> bytes:
    """Return ``std_msgs/String`` ``text`` in CDR: encapsulation, length, text, NUL."""
    raw = text.encode()
    return b'\x00\x01\x00\x00' + struct.pack('<I', len(raw) + 1) + raw + b'\x00'


def message_text(i: int) -> str:
    """Return the text of message ``i`` (what a reader must decode)."""
    return 'm4k message {:03d}'.format(i)


def add_string_topic(w: Any, topic: str) -> int:
    """Register ``topic`` as ``record`` does for a ``std_msgs/String`` publisher."""
    return add_topic(w, topic, 'std_msgs/msg/String')


def add_topic(w: Any, topic: str, type_name: str) -> int:
    """Register ``topic`` of ``type_name`` as ``record`` does for a publisher of it."""
    from rclpy.qos import QoSProfile

    from m4k_bridge.bag.metadata import qos_entries
    from m4k_bridge.bag.msgdef import message_definition, type_hash
    from m4k_bridge.bag.record import qos_yaml
    profiles = [QoSProfile(depth=10)]
    return int(w.add_topic(topic, type_name, message_definition(type_name),
                           type_hash(type_name), qos_entries(profiles), qos_yaml(profiles)))


@contextlib.contextmanager
def _captured(fd_of: Any) -> Iterator[list[tuple[str, int, bytes]]]:
    """Record the pwrite/ftruncate calls made on the writer's descriptor, in order."""
    ops: list[tuple[str, int, bytes]] = []
    pwrite, ftruncate = os.pwrite, os.ftruncate

    def rec_pwrite(fd: int, data: bytes, offset: int) -> int:
        if fd == fd_of():
            ops.append(('pwrite', offset, bytes(data)))
        return pwrite(fd, data, offset)

    def rec_ftruncate(fd: int, length: int) -> None:
        if fd == fd_of():
            ops.append(('ftruncate', length, b''))
        ftruncate(fd, length)

    os.pwrite, os.ftruncate = rec_pwrite, rec_ftruncate   # type: ignore[assignment]
    try:
        yield ops
    finally:
        os.pwrite, os.ftruncate = pwrite, ftruncate       # type: ignore[assignment]


def _apply(image: bytearray, op: tuple[str, int, bytes], k: int) -> bytearray:
    kind, offset, data = op
    out = bytearray(image)
    if kind == 'ftruncate':
        del out[offset:]
        out.extend(bytes(max(0, offset - len(out))))
        return out
    part = data[:k]
    if offset > len(out):
        out.extend(bytes(offset - len(out)))
    out[offset:offset + len(part)] = part
    return out


def tear_images(out_dir: str, writer_module: ModuleType | None = None) -> dict[str, Any]:
    """Write every distinct cut of one sync under ``out_dir``; return the manifest.

    Manifest: ``before`` / ``after`` (messages synced before the cut sync / after it),
    ``texts`` (every message's decoded ``data``, in order: the last is the ``/flag`` Bool),
    and ``images``: for each cut, its bag
    directory, file, the write it tore (``op``, 0-based; ``-1``: before the first write),
    the kind of that write (``pwrite`` of ``length`` bytes at ``offset``) and the bytes of it
    that reached the disk (``k``), in the order the cuts happen.
    """
    if writer_module is None:
        from m4k_bridge.bag import writer as writer_module
    bw = writer_module
    os.makedirs(out_dir, exist_ok=True)
    w = bw.BagWriter(os.path.join(out_dir, 'src'))
    cid = add_string_topic(w, '/chatter')
    n = 0
    for s in range(SYNCS + 1):
        if s == SYNCS:
            before = bytes(open(w.path, 'rb').read())   # noqa: SIM115
            meta_before = open(os.path.join(w.work_directory, 'metadata.yaml')).read()  # noqa
        for k in range(PER_SYNC):
            if s == SYNCS and k == PER_SYNC - 1:
                # A topic that appears in the cut sync: its Schema and Channel records are in
                # the append too, ahead of the chunk.
                flag = add_topic(w, FLAG, 'std_msgs/msg/Bool')
                w.write(flag, T0 + n * S // 10, b'\x00\x01\x00\x00\x01', n)
            else:
                w.write(cid, T0 + n * S // 10, cdr_string(message_text(n)), n)
            n += 1
        if s < SYNCS:
            w.sync()
            continue
        with _captured(lambda: w._fd) as ops:
            w.sync()
    after = bytes(open(w.path, 'rb').read())   # noqa: SIM115
    w.close(complete=False)
    shutil.rmtree(w.work_directory)
    images = []
    seen: set[bytes] = set()
    state = bytearray(before)
    cuts: list[tuple[int, int, bytearray]] = [(-1, 0, bytearray(before))]
    whole = {bytes(before): (-1, 0)}       # the file after each write, whole
    for i, op in enumerate(ops):
        for k in range(len(op[2]) + 1 if op[0] == 'pwrite' else 1):
            cuts.append((i, k, _apply(state, op, k)))
        state = _apply(state, op, len(op[2]))
        whole.setdefault(bytes(state), (i, len(op[2])))
    assert bytes(state) == after, 'the captured writes do not rebuild the file'
    # A torn write that left the same bytes as a whole one (or none) is that state: name it so.
    cuts = [(*whole.get(bytes(im), (i, k)), im) for i, k, im in cuts]
    for i, k, image in cuts:
        if bytes(image) in seen:
            continue
        seen.add(bytes(image))
        name = 'cut{:04d}'.format(len(images))
        d = os.path.join(out_dir, name)
        os.mkdir(d)
        with open(os.path.join(d, name + '_0.mcap'), 'wb') as f:
            f.write(image)
        # The metadata of the last completed sync, renamed from its temporary name only after
        # the MCAP's fsync, with the file renamed to this directory's rosbag2 name.
        with open(os.path.join(d, 'metadata.yaml'), 'w') as f:
            f.write(meta_before.replace('src_0.mcap', name + '_0.mcap'))
        op = ops[i] if i >= 0 else ('none', 0, b'')
        images.append({'dir': d, 'file': os.path.join(d, name + '_0.mcap'), 'op': i,
                       'kind': op[0], 'offset': op[1], 'length': len(op[2]), 'k': k,
                       'size': len(image)})
    manifest = {'before': SYNCS * PER_SYNC, 'after': (SYNCS + 1) * PER_SYNC,
                'texts': [message_text(i) for i in range(n - 1)] + [True],
                'ops': [{'kind': o[0], 'offset': o[1], 'length': len(o[2])} for o in ops],
                'images': images}
    with open(os.path.join(out_dir, 'manifest.json'), 'w') as f:
        json.dump(manifest, f, indent=1)
    return manifest
