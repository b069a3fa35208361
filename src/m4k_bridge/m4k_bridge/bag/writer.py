"""A rosbag2 MCAP directory that is a complete, readable bag after every sync (no ROS).

Used by the recorder (:mod:`m4k_bridge.bag.record`) and the flight recorder's dumps
(:mod:`m4k_bridge.flightrec`). Why it is written this way:

* A bag is the directory ``DIR/`` with ``DIR/<DIR name>_0.mcap`` and ``DIR/metadata.yaml``.
  The directory is created here and must not exist: a writer never overwrites
  (:class:`BagExistsError`).
* Messages are buffered in memory and written by :meth:`BagWriter.sync` (the callers sync once
  a second). Each sync writes the new records over the previous trailer and a new trailer
  behind them (``DataEnd``, a summary with schemas, channels and statistics, summary offsets,
  the footer and the closing magic) in one ``pwrite``, then ``fsync``: between syncs the file
  on disk is a finished MCAP that every reader opens, the seeking ones too. A ``kill -9`` or a
  power cut loses what came after the last sync -- at most one sync period.
* ``metadata.yaml`` (rosbag2 format 9) is written at the start and at each sync, with the
  counts and times of exactly the messages synced, atomically: the new text is fsynced under a
  temporary name before the MCAP grows and renamed over the old one after the MCAP's
  ``fsync``. It is always a whole file, and it never lists a message the MCAP lacks; a crash
  inside a sync leaves it one sync behind the MCAP.
* Messages are not chunked (rosbag2's ``fastwrite`` storage preset does the same:
  ``noChunking``): every record is final the moment it is written, at the price of no
  compression. Readers without a chunk index read such a file linearly (the ``mcap`` Python
  reader, rosbags and rosbag2's MCAP plugin all do).

If the process dies inside a sync's ``pwrite`` (a window of tens of microseconds a second; the
file then ends in a torn record, without a footer), or between the MCAP's ``pwrite`` and the
metadata's rename (the metadata lags), :func:`recover` rewrites the file and the metadata from
every complete record the file holds.
"""

from __future__ import annotations

import dataclasses
import os
import struct
from typing import Any, Iterator, Mapping
import zlib

from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    DataEnd,
    Footer,
    Header,
    Message,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap.stream_reader import StreamReader
from mcap.well_known import MessageEncoding, SchemaEncoding
import yaml

from m4k_bridge.bag.metadata import metadata_yaml, qos_entries_from_yaml, TopicRecord

__all__ = ['BagError', 'BagExistsError', 'BagWriter', 'Recovery', 'mcap_name', 'recover',
           'write_atomic']

MAGIC = b'\x89MCAP0\r\n'
_RECOVER_SYNC_BYTES = 4 << 20     # recovery writes out (and syncs) each 4 MiB it copies
METADATA = 'metadata.yaml'


class BagError(OSError):
    """A bag directory cannot be created, written or recovered."""


class BagExistsError(BagError, FileExistsError):
    """The output directory exists: a writer never overwrites a bag."""


def mcap_name(directory: str) -> str:
    """Return the MCAP file name rosbag2 uses in ``directory``: ``<name>_0.mcap``."""
    return os.path.basename(os.path.normpath(directory)) + '_0.mcap'


def _fsync_dir(directory: str) -> None:
    fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _write_durable(path: str, text: str) -> str:
    with open(path, 'w', encoding='utf-8') as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    return path


def write_atomic(path: str, text: str) -> None:
    """Replace ``path`` by ``text``: temporary file, fsync, rename, fsync of the directory."""
    os.replace(_write_durable(path + '.tmp', text), path)
    _fsync_dir(os.path.dirname(path) or '.')


def _record(rec: Any) -> bytes:
    from mcap.data_stream import RecordBuilder
    b = RecordBuilder()
    rec.write(b)
    return bytes(b.end())


@dataclasses.dataclass
class _Topic:
    channel_id: int
    record: TopicRecord


class BagWriter:
    """Write one bag directory; :meth:`sync` makes everything so far durable and readable."""

    def __init__(self, directory: str, library: str = 'm4k_bridge',
                 custom_data: Mapping[str, str] | None = None,
                 file_name: str | None = None) -> None:
        """Create ``directory`` and its MCAP file; raise :class:`BagExistsError` if it exists.

        ``file_name``: the MCAP's name (default ``<directory name>_0.mcap``).
        """
        self.directory = directory
        try:
            os.makedirs(os.path.dirname(os.path.abspath(directory)), exist_ok=True)
            os.mkdir(directory)
        except FileExistsError:
            raise BagExistsError(
                'output directory {!r} exists: a recording never overwrites one (choose '
                'another name, or move it away)'.format(directory)) from None
        except OSError as exc:
            raise BagError('cannot create {!r}: {} (errno {})'.format(
                directory, exc.strerror, exc.errno)) from None
        self.file_name = file_name or mcap_name(directory)
        self.path = os.path.join(directory, self.file_name)
        self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        self.custom_data = dict(custom_data or {})
        self._pending = bytearray(MAGIC + _record(Header(profile='ros2', library=library)))
        self._data_end = 0            # file offset where the trailer starts
        self._schemas: dict[str, Schema] = {}
        self._channels: dict[str, Channel] = {}
        self._topics: dict[str, _Topic] = {}
        self._counts: dict[int, int] = {}
        self._pending_counts: dict[int, int] = {}
        self._start_ns = self._end_ns = 0
        self._pending_start = self._pending_end = 0
        self._closed = False
        self.sync()

    @property
    def topics(self) -> list[TopicRecord]:
        """Return the topics with the message counts synced so far."""
        return [t.record for t in self._topics.values()]

    @property
    def pending_bytes(self) -> int:
        """Return the bytes buffered for the next :meth:`sync`."""
        return len(self._pending)

    @property
    def message_count(self) -> int:
        """Return the number of messages synced so far."""
        return sum(self._counts.values())

    def add_topic(self, topic: str, type_name: str, msgdef: str, type_hash: str,
                  qos: list[dict[str, Any]], qos_text: str) -> int:
        """Register ``topic`` (once) and return its channel id.

        ``msgdef``: the ``ros2msg`` schema text; ``qos``: version-9 metadata entries;
        ``qos_text``: the same as rosbag2's MCAP channel metadata ``offered_qos_profiles``.
        """
        if topic in self._topics:
            return self._topics[topic].channel_id
        schema = self._schemas.get(type_name)
        if schema is None:
            schema = Schema(id=len(self._schemas) + 1, name=type_name,
                            encoding=SchemaEncoding.ROS2, data=msgdef.encode())
            self._schemas[type_name] = schema
            self._pending += _record(schema)
        channel = Channel(id=len(self._channels) + 1, topic=topic,
                          message_encoding=MessageEncoding.CDR, schema_id=schema.id,
                          metadata={'offered_qos_profiles': qos_text,
                                    'topic_type_hash': type_hash})
        self._channels[topic] = channel
        self._pending += _record(channel)
        self._topics[topic] = _Topic(channel.id, TopicRecord(topic, type_name, type_hash, qos))
        self._counts[channel.id] = 0
        return channel.id

    def write(self, channel_id: int, log_time_ns: int, data: bytes, sequence: int = 0,
              publish_time_ns: int | None = None) -> None:
        """Buffer one serialized message (durable at the next :meth:`sync`)."""
        self._pending += _record(Message(
            channel_id=channel_id, sequence=sequence & 0xFFFFFFFF, log_time=log_time_ns,
            publish_time=log_time_ns if publish_time_ns is None else publish_time_ns,
            data=data))
        self._pending_counts[channel_id] = self._pending_counts.get(channel_id, 0) + 1
        if not self._pending_start or log_time_ns < self._pending_start:
            self._pending_start = log_time_ns
        self._pending_end = max(self._pending_end, log_time_ns)

    def _trailer(self, data_end: int) -> bytes:
        stats = Statistics(
            message_count=sum(self._counts.values()), schema_count=len(self._schemas),
            channel_count=len(self._channels), attachment_count=0, metadata_count=0,
            chunk_count=0, message_start_time=self._start_ns, message_end_time=self._end_ns,
            channel_message_counts=dict(self._counts))
        head = _record(DataEnd(data_section_crc=0))
        summary_start = data_end + len(head)
        groups: list[tuple[int, bytes]] = [
            (Opcode.SCHEMA, b''.join(_record(s) for s in self._schemas.values())),
            (Opcode.CHANNEL, b''.join(_record(c) for c in self._channels.values())),
            (Opcode.STATISTICS, _record(stats))]
        summary = bytearray()
        offsets = bytearray()
        for opcode, data in groups:
            if data:
                offsets += _record(SummaryOffset(group_opcode=opcode,
                                                 group_start=summary_start + len(summary),
                                                 group_length=len(data)))
                summary += data
        offset_start = summary_start + len(summary)
        summary += offsets
        crc = zlib.crc32(bytes(summary))
        crc = zlib.crc32(struct.pack('<BQQQ', Opcode.FOOTER, 20, summary_start, offset_start),
                         crc)
        footer = _record(Footer(summary_start=summary_start, summary_offset_start=offset_start,
                                summary_crc=crc))
        return head + bytes(summary) + footer + MAGIC

    def sync(self) -> None:
        """Write the buffered records and a new trailer, fsync, then update metadata.yaml."""
        if self._closed:
            return
        for cid, n in self._pending_counts.items():
            self._counts[cid] = self._counts.get(cid, 0) + n
        if self._pending_counts:
            if not self._start_ns or self._pending_start < self._start_ns:
                self._start_ns = self._pending_start
            self._end_ns = max(self._end_ns, self._pending_end)
        self._pending_counts = {}
        self._pending_start = self._pending_end = 0
        data = bytes(self._pending)
        self._pending = bytearray()
        blob = data + self._trailer(self._data_end + len(data))
        for t in self._topics.values():
            t.record.count = self._counts.get(t.channel_id, 0)
        meta = os.path.join(self.directory, METADATA)
        try:
            # The new metadata is durable under a temporary name before the MCAP grows and
            # renamed over the old one after: it never lists a message the file lacks.
            tmp = _write_durable(meta + '.tmp', metadata_yaml(
                self.file_name, self.topics, self._start_ns, self._end_ns,
                custom_data=self.custom_data))
            written = os.pwrite(self._fd, blob, self._data_end)
            if written != len(blob):
                raise BagError('short write to {!r}: {} of {} bytes'.format(
                    self.path, written, len(blob)))
            os.ftruncate(self._fd, self._data_end + len(blob))
            os.fsync(self._fd)
            self._data_end += len(data)
            os.replace(tmp, meta)
            _fsync_dir(self.directory)
        except OSError as exc:
            if isinstance(exc, BagError):
                raise
            raise BagError('cannot write {!r}: {} (errno {})'.format(
                self.path, exc.strerror, exc.errno)) from None

    def close(self) -> None:
        """Sync and close the file (idempotent)."""
        if self._closed:
            return
        try:
            self.sync()
        finally:
            self._closed = True
            os.close(self._fd)


# --- recovery ---------------------------------------------------------------------------------


@dataclasses.dataclass
class Recovery:
    """What :func:`recover` found and did."""

    messages: int
    counts: dict[str, int]
    complete: bool          # the MCAP ended with a valid footer
    rewritten: bool         # the MCAP and/or metadata.yaml were rewritten
    dropped_bytes: int      # bytes after the last complete record (a torn write)


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


def recover(directory: str) -> Recovery:
    """Make a crashed bag directory whole: MCAP with a trailer, metadata.yaml that matches it.

    Every complete Schema, Channel and Message record is kept in file order; a torn last
    record is dropped. A bag that already agrees with its metadata is left as it is.
    Raise :class:`BagError` when ``directory`` holds no MCAP of this name or it cannot be read.

    The file is streamed, never held: a first pass counts (schemas and channels are kept, the
    messages are not), a second copies the messages into the new file, which is synced each
    :data:`_RECOVER_SYNC_BYTES`, so memory stays bounded whatever the bag's size.
    """
    path = os.path.join(directory, mcap_name(directory))
    if not os.path.isfile(path):
        raise BagError('no {} in {!r}: not a bag written by m4k'.format(
            mcap_name(directory), directory))
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    count = 0
    header = None
    complete = False
    end = 0
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
    if complete and listed == by_topic and old.get('message_count') == count:
        return Recovery(count, by_topic, True, False, 0)
    # Rewrite into a sibling directory, then swap the files in (each rename is atomic).
    tmp_dir = os.path.join(directory, '.recover')
    if os.path.isdir(tmp_dir):
        for name in os.listdir(tmp_dir):
            os.unlink(os.path.join(tmp_dir, name))
        os.rmdir(tmp_dir)
    custom = {str(k): str(v) for k, v in (old.get('custom_data') or {}).items()}
    w = BagWriter(tmp_dir, library=header.library or 'm4k_bridge', custom_data=custom,
                  file_name=os.path.basename(path))
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
    _fsync_dir(directory)
    return Recovery(count, by_topic, complete, True, 0 if complete else size - end)

