"""Make a crashed bag whole: an MCAP with its index and trailer, a metadata.yaml to match (no ROS).

``record --recover DIR`` calls :func:`recover`. A crash leaves the bag under its partial name
(``DIR.partial``, :data:`m4k_bridge.bag.writer.PARTIAL`): the last sync's file, without a
summary or chunk indexes (the last sync writes them), and after a power cut inside a sync's
append a torn last record with no footer; or the metadata one sync behind (a crash between the
MCAP's ``fsync`` and the metadata's rename). Recovery keeps every complete record, rewrites
what needs it, and gives the directory its final name.
"""

from __future__ import annotations

import dataclasses
import os
import struct
from typing import Any, Iterator

from mcap.exceptions import McapError
from mcap.records import Channel, ChunkIndex, Footer, Header, Message, Schema, Statistics
from mcap.stream_reader import StreamReader
import yaml

from m4k_bridge.bag.metadata import qos_entries_from_yaml
from m4k_bridge.bag.writer import (
    BagError,
    BagWriter,
    finish,
    fsync_dir,
    mcap_name,
    METADATA,
    PARTIAL,
    partial_directory,
)

__all__ = ['Recovery', 'recover']

_RECOVER_SYNC_BYTES = 4 << 20     # recovery writes out (and syncs) each 4 MiB it copies


@dataclasses.dataclass
class Recovery:
    """What :func:`recover` found and did."""

    messages: int
    counts: dict[str, int]
    complete: bool          # the MCAP ended with a valid footer
    rewritten: bool         # the MCAP and/or metadata.yaml were rewritten
    dropped_bytes: int      # bytes after the last complete record (a torn write)
    directory: str = ''     # where the bag is now (its final name once recovered)


def _records(path: str) -> Iterator[tuple[Any, int]]:
    """Yield (record, end offset) of the MCAP at ``path`` up to its first incomplete record."""
    with open(path, 'rb') as f:
        reader = StreamReader(f, skip_magic=False, emit_chunks=False)
        it = reader.records
        while True:
            try:
                rec = next(it)
            except StopIteration:
                return
            except (McapError, EOFError, struct.error, ValueError, UnicodeDecodeError):
                return
            yield rec, f.tell()


def _names(directory: str) -> tuple[str, str]:
    """Return (where the bag is, its final name) for ``DIR`` or ``DIR.partial``."""
    directory = os.path.normpath(directory)
    if directory.endswith(PARTIAL):
        return directory, directory[:-len(PARTIAL)]
    if not os.path.lexists(directory) and os.path.isdir(partial_directory(directory)):
        return partial_directory(directory), directory
    return directory, directory


def recover(directory: str) -> Recovery:
    """Recover the bag ``directory`` (``DIR`` or ``DIR.partial``) and name it ``DIR``."""
    work, final = _names(directory)
    r = _repair(work, mcap_name(final))
    if work != final:
        finish(work, final)
    return dataclasses.replace(r, directory=final)


def _repair(directory: str, file_name: str) -> Recovery:
    """Make a crashed bag directory whole: MCAP with a trailer, metadata.yaml that matches it.

    Every complete Schema, Channel and Message record is kept in file order; a torn last
    record is dropped. A bag that already agrees with its metadata is left as it is.
    Raise :class:`BagError` when ``directory`` holds no MCAP of this name or it cannot be read.

    The file is streamed, never held: a first pass counts (schemas and channels are kept, the
    messages are not), a second copies the messages into the new file, which is synced each
    :data:`_RECOVER_SYNC_BYTES`, so memory stays bounded whatever the bag's size.
    """
    path = os.path.join(directory, file_name)
    if not os.path.isfile(path):
        raise BagError('no {} in {!r}: not a bag written by m4k'.format(file_name, directory))
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    count = 0
    header = None
    complete = False
    end = 0
    chunks = indexed = 0                # Statistics' chunk count; chunk indexes in the summary
    by_id: dict[int, int] = {}
    for rec, pos in _records(path):
        if isinstance(rec, Header):
            header = rec
        elif isinstance(rec, Schema):
            schemas[rec.id] = rec
        elif isinstance(rec, Channel):
            channels[rec.id] = rec
        elif isinstance(rec, Message) and rec.channel_id in channels:
            count += 1
            by_id[rec.channel_id] = by_id.get(rec.channel_id, 0) + 1
        elif isinstance(rec, Statistics):
            chunks = rec.chunk_count
        elif isinstance(rec, ChunkIndex):
            indexed += 1
        elif isinstance(rec, Footer):
            complete = True
        if not complete:
            end = pos
    if header is None:
        raise BagError('{!r} has no MCAP header: nothing to recover'.format(path))
    size = os.path.getsize(path)
    by_topic: dict[str, int] = {c.topic: 0 for c in channels.values()}
    for cid, n in by_id.items():
        by_topic[channels[cid].topic] += n
    meta_path = os.path.join(directory, METADATA)
    old: dict[str, Any] = {}
    try:
        with open(meta_path, encoding='utf-8') as f:
            old = (yaml.safe_load(f) or {}).get('rosbag2_bagfile_information', {})
    except (OSError, yaml.YAMLError, AttributeError):
        old = {}
    listed = {t['topic_metadata']['name']: t.get('message_count')
              for t in old.get('topics_with_message_count', []) or []
              if isinstance(t, dict) and 'topic_metadata' in t}
    stale = meta_path + '.tmp'          # a sync's metadata that a crash kept from its rename
    if os.path.exists(stale):
        os.unlink(stale)
    # A partial file's syncs left the summary out (the last sync writes it, with the chunk
    # indexes): rewrite it so that it is indexed. Every message is in a chunk, so a file with
    # messages and no chunk index is a partial one.
    if complete and indexed == chunks and (indexed or not count) and listed == by_topic and \
            old.get('message_count') == count:
        return Recovery(count, by_topic, True, False, 0)
    # Rewrite into a sibling directory, then swap the files in (each rename is atomic).
    tmp_dir = os.path.join(directory, '.recover')
    if os.path.isdir(tmp_dir):
        for name in os.listdir(tmp_dir):
            os.unlink(os.path.join(tmp_dir, name))
        os.rmdir(tmp_dir)
    custom = {str(k): str(v) for k, v in (old.get('custom_data') or {}).items()}
    w = BagWriter(tmp_dir, library=header.library or 'm4k_bridge', custom_data=custom,
                  file_name=os.path.basename(path), atomic=False)
    ids: dict[int, int] = {}
    for cid, ch in channels.items():
        schema = schemas.get(ch.schema_id)
        qos_text = ch.metadata.get('offered_qos_profiles', '')
        ids[cid] = w.add_topic(ch.topic, schema.name if schema else '',
                               schema.data.decode() if schema else '',
                               ch.metadata.get('topic_type_hash', ''),
                               qos_entries_from_yaml(qos_text), qos_text)
    seen: set[int] = set()
    for rec, pos in _records(path):          # the second pass: copy, a bounded buffer
        if pos > end and not complete:
            break
        if isinstance(rec, Channel):
            seen.add(rec.id)
        elif isinstance(rec, Message) and rec.channel_id in seen:
            w.write(ids[rec.channel_id], rec.log_time, rec.data, rec.sequence,
                    rec.publish_time)
            if w.pending_bytes >= _RECOVER_SYNC_BYTES:
                w.sync()
        elif isinstance(rec, Footer):
            break
    w.close()
    os.replace(os.path.join(tmp_dir, w.file_name), path)
    os.replace(os.path.join(tmp_dir, METADATA), meta_path)
    os.rmdir(tmp_dir)
    fsync_dir(directory)
    return Recovery(count, by_topic, complete, True, 0 if complete else size - end)

