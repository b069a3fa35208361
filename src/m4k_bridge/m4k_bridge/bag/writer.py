"""A rosbag2 MCAP directory, indexed, readable after every sync, named only when whole (no ROS).

Used by the recorder (:mod:`m4k_bridge.bag.record`) and the flight recorder's dumps
(:mod:`m4k_bridge.flightrec`). Why it is written this way:

* A bag is the directory ``DIR/`` with ``DIR/<DIR name>_0.mcap`` and ``DIR/metadata.yaml``.
  It is written under the temporary name ``DIR.partial/`` (:data:`PARTIAL`) beside it and
  renamed to ``DIR`` by :meth:`BagWriter.close`, after the last sync: a reader never finds a
  bag under its final name that is still being written or was cut off, and a crash leaves a
  directory whose name says so (``record --recover`` finishes it). Neither name may exist
  beforehand: a writer never overwrites (:class:`BagExistsError`).
* Messages are buffered in memory and written by :meth:`BagWriter.sync` (the callers sync once
  a second). A sync never writes over data or a live trailer. It first *retires* the live
  trailer (``DataEnd``, the footer and the closing magic, 50 bytes): one 9-byte record
  header, inside one disk sector, turns its ``DataEnd`` into a private record (opcode
  :data:`RETIRED`, in the 0x80-0xFF range the MCAP specification leaves to applications)
  that spans the old trailer, so a stream reader skips it; a reader that starts from the end
  still finds the old footer there. ``fsync``. Then the new records and a new trailer are
  appended behind it, ``fsync``. Between syncs the partial file is a finished MCAP that
  every reader opens; at every byte of a sync it is readable by a stream reader up to the
  last sync (Lichtblick's path for these files; docs/recording.md has the evidence). A
  ``kill -9`` or a power cut loses what came after the last sync -- at most one sync
  period. The name changes only at the end, so a bag under its final name was closed.
* Messages go into uncompressed chunks of at most :data:`CHUNK_BYTES` (one per sync at least),
  each followed by a message index per channel, and the last sync's summary lists a chunk
  index per chunk (MCAP specification, "Chunk Index"): a seeking reader (Lichtblick, Foxglove,
  rosbag2's MCAP plugin, the ``mcap`` readers) goes straight to the chunks of a time range
  instead of reading the whole file, and Lichtblick opens files over 1 GiB only when they are
  indexed. The syncs before it write no summary (the chunk index list grows a chunk a
  second, and every trailer stays in the file): a reader reads such a partial file
  linearly, finding schemas and channels in the data section, and ``record --recover``
  indexes it.
* ``metadata.yaml`` (rosbag2 format 9) is written at the start and at each sync, with the
  counts and times of exactly the messages synced, atomically: the new text is fsynced under a
  temporary name before the MCAP grows and renamed over the old one after the MCAP's
  ``fsync``. It never lists a message the MCAP lacks.
* ``custom_data`` (the commit, a flight recorder's trigger) goes to ``metadata.yaml`` and to an
  MCAP Metadata record ``m4k`` (listed in the final summary's metadata index), so a viewer
  of the MCAP alone shows it too.
"""

from __future__ import annotations

import dataclasses
import os
import struct
from typing import Any, Mapping
import zlib

from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Message,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap.well_known import MessageEncoding, SchemaEncoding

from m4k_bridge.bag.metadata import metadata_yaml, TopicRecord

__all__ = ['BagError', 'BagExistsError', 'BagWriter', 'CHUNK_BYTES', 'METADATA', 'PARTIAL',
           'finish', 'fsync_dir', 'mcap_name', 'partial_directory', 'write_atomic']

MAGIC = b'\x89MCAP0\r\n'
METADATA = 'metadata.yaml'
PARTIAL = '.partial'             # suffix of a bag directory still being written (or cut off)
METADATA_NAME = 'm4k'            # the MCAP Metadata record that carries custom_data
# The opcode of a retired trailer (and of sector padding): a record in the range the MCAP
# specification reserves for application extensions (0x80-0xFF), which readers skip.
RETIRED = 0x80
SECTOR = 512                     # a retired trailer's 9-byte header never straddles one
# A chunk is closed past this many bytes of records (the mcap writers' default size): small
# enough that a seek reads little more than it needs, large enough that the index stays small.
CHUNK_BYTES = 1 << 20


class BagError(OSError):
    """A bag directory cannot be created, written or recovered."""


class BagExistsError(BagError, FileExistsError):
    """The output directory exists: a writer never overwrites a bag."""


def mcap_name(directory: str) -> str:
    """Return the MCAP file name rosbag2 uses in ``directory``: ``<name>_0.mcap``."""
    return os.path.basename(os.path.normpath(directory)) + '_0.mcap'


def partial_directory(directory: str) -> str:
    """Return the temporary name ``directory`` has while it is written: ``<directory>.partial``."""
    return os.path.normpath(directory) + PARTIAL


def fsync_dir(directory: str) -> None:
    """Make a rename or a new file in ``directory`` durable."""
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
    fsync_dir(os.path.dirname(path) or '.')


def _record_header(opcode: int, length: int) -> bytes:
    return struct.pack('<BQ', opcode, length)


def _sector_pad(offset: int) -> bytes:
    """Return a private record that moves a 9-byte header at ``offset`` off a sector boundary.

    The header of a trailer is later rewritten in place (retired); a write inside one sector
    is all-or-nothing on disks that write sectors atomically, a write across two is not.
    """
    if offset % SECTOR <= SECTOR - 9:
        return b''
    size = SECTOR - offset % SECTOR + SECTOR      # 513..520 bytes, the smallest pad that fits
    return _record_header(RETIRED, size - 9) + bytes(size - 9)


def _record(rec: Any) -> bytes:
    from mcap.data_stream import RecordBuilder
    b = RecordBuilder()
    rec.write(b)
    return bytes(b.end())


@dataclasses.dataclass
class _Topic:
    channel_id: int
    record: TopicRecord


class _OpenChunk:
    """The message records of the chunk being filled, and their index entries."""

    def __init__(self) -> None:
        self.records = bytearray()
        self.index: dict[int, list[tuple[int, int]]] = {}
        self.start = self.end = 0

    def add(self, channel_id: int, log_time: int, record: bytes) -> None:
        self.start = min(self.start, log_time) if self.records else log_time
        self.end = max(self.end, log_time)
        self.index.setdefault(channel_id, []).append((log_time, len(self.records)))
        self.records += record


def _chunk_bytes(chunk: _OpenChunk, offset: int) -> tuple[bytes, ChunkIndex]:
    """Return the Chunk record and its message indexes at file ``offset``, and its index."""
    data = bytes(chunk.records)
    rec = _record(Chunk(compression='', data=data, message_start_time=chunk.start,
                        message_end_time=chunk.end, uncompressed_crc=zlib.crc32(data),
                        uncompressed_size=len(data)))
    out = bytearray(rec)
    offsets: dict[int, int] = {}
    for cid in sorted(chunk.index):
        # Log-time order within a channel, as the specification asks of a message index.
        entries = sorted(chunk.index[cid])
        offsets[cid] = offset + len(out)
        out += _record(MessageIndex(channel_id=cid, records=entries))
    index = ChunkIndex(message_start_time=chunk.start, message_end_time=chunk.end,
                       chunk_start_offset=offset, chunk_length=len(rec),
                       message_index_offsets=offsets, message_index_length=len(out) - len(rec),
                       compression='', compressed_size=len(data), uncompressed_size=len(data))
    return bytes(out), index


class BagWriter:
    """Write one bag directory; :meth:`sync` makes everything so far durable and readable."""

    def __init__(self, directory: str, library: str = 'm4k_bridge',
                 custom_data: Mapping[str, str] | None = None,
                 file_name: str | None = None, atomic: bool = True) -> None:
        """Create ``directory`` (``<directory>.partial`` until closed) and its MCAP file.

        Raise :class:`BagExistsError` if either name exists. ``file_name``: the MCAP's name
        (default ``<directory name>_0.mcap``). ``atomic`` False: write under the final name
        (:func:`m4k_bridge.bag.recover.recover` does, inside a directory of its own).
        """
        self.directory = os.path.normpath(directory)
        self.work_directory = partial_directory(directory) if atomic else self.directory
        for name in {self.directory, self.work_directory}:
            if os.path.lexists(name):
                raise BagExistsError(
                    'output directory {!r} exists: a recording never overwrites one (choose '
                    'another name, or move it away)'.format(name))
        try:
            os.makedirs(os.path.dirname(os.path.abspath(directory)), exist_ok=True)
            os.mkdir(self.work_directory)
        except FileExistsError:
            raise BagExistsError('output directory {!r} exists: a recording never overwrites '
                                 'one'.format(self.work_directory)) from None
        except OSError as exc:
            raise BagError('cannot create {!r}: {} (errno {})'.format(
                self.work_directory, exc.strerror, exc.errno)) from None
        self.file_name = file_name or mcap_name(directory)
        self._fd = os.open(os.path.join(self.work_directory, self.file_name),
                           os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        self.custom_data = dict(custom_data or {})
        self._pending = bytearray(MAGIC + _record(Header(profile='ros2', library=library)))
        self._eof = 0                 # the file's size: everything is appended here
        self._trailer_at: int | None = None   # where the live trailer (its DataEnd) starts
        self._schemas: dict[str, Schema] = {}
        self._channels: dict[str, Channel] = {}
        self._topics: dict[str, _Topic] = {}
        self._counts: dict[int, int] = {}
        self._pending_counts: dict[int, int] = {}
        self._start_ns = self._end_ns = 0
        self._pending_start = self._pending_end = 0
        self._chunk = _OpenChunk()
        self._chunk_indexes: list[ChunkIndex] = []
        self._pending_chunk_indexes: list[ChunkIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._closed = False
        if self.custom_data:
            rec = _record(Metadata(name=METADATA_NAME, metadata=self.custom_data))
            self._metadata_indexes.append(MetadataIndex(
                offset=len(self._pending), length=len(rec), name=METADATA_NAME))
            self._pending += rec
        self.sync()

    @property
    def path(self) -> str:
        """Return where the MCAP file is now (under the partial name until closed)."""
        where = self.directory if self.renamed else self.work_directory
        return os.path.join(where, self.file_name)

    @property
    def renamed(self) -> bool:
        """Tell whether the bag is closed and under its final name."""
        return self._closed and not os.path.lexists(self.work_directory)

    @property
    def topics(self) -> list[TopicRecord]:
        """Return the topics with the message counts synced so far."""
        return [t.record for t in self._topics.values()]

    @property
    def pending_bytes(self) -> int:
        """Return the bytes buffered for the next :meth:`sync`."""
        return len(self._pending) + len(self._chunk.records)

    @property
    def message_count(self) -> int:
        """Return the number of messages synced so far."""
        return sum(self._counts.values())

    def add_topic(self, topic: str, type_name: str, msgdef: str, type_hash: str,
                  qos: list[dict[str, Any]], qos_text: str) -> int:
        """Register ``topic`` (once) and return its channel id.

        ``msgdef``: the ``ros2msg`` schema text; ``qos``: version-9 metadata entries;
        ``qos_text``: the same as rosbag2's MCAP channel metadata ``offered_qos_profiles``.
        The Schema and Channel records go to the data section outside the chunks, ahead of
        every chunk that holds a message of the channel.
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
        self._chunk.add(channel_id, log_time_ns, _record(Message(
            channel_id=channel_id, sequence=sequence & 0xFFFFFFFF, log_time=log_time_ns,
            publish_time=log_time_ns if publish_time_ns is None else publish_time_ns,
            data=data)))
        self._pending_counts[channel_id] = self._pending_counts.get(channel_id, 0) + 1
        if not self._pending_start or log_time_ns < self._pending_start:
            self._pending_start = log_time_ns
        self._pending_end = max(self._pending_end, log_time_ns)
        if len(self._chunk.records) >= CHUNK_BYTES:
            self._close_chunk()

    def _close_chunk(self) -> None:
        if not self._chunk.index:
            return
        # The chunk lands at the file offset where the pending bytes end after the next sync.
        blob, index = _chunk_bytes(self._chunk, self._eof + len(self._pending))
        self._pending += blob
        self._pending_chunk_indexes.append(index)
        self._chunk = _OpenChunk()

    def _trailer(self, data_end: int, indexed: bool) -> bytes:
        """Return DataEnd, the summary (the last sync's only), the footer and the magic.

        Without ``indexed`` there is no summary (footer ``summary_start`` 0, as the
        specification allows): a summary repeats every schema, about 30 KB a second for the
        stack's topics, and each sync leaves its trailer in the file when it retires it. A
        reader finds the schemas and channels in the data section instead.
        """
        head = _record(DataEnd(data_section_crc=0))
        if not indexed:
            return head + _record(Footer(summary_start=0, summary_offset_start=0,
                                         summary_crc=0)) + MAGIC
        stats = Statistics(
            message_count=sum(self._counts.values()), schema_count=len(self._schemas),
            channel_count=len(self._channels), attachment_count=0,
            metadata_count=len(self._metadata_indexes), chunk_count=len(self._chunk_indexes),
            message_start_time=self._start_ns, message_end_time=self._end_ns,
            channel_message_counts=dict(self._counts))
        summary_start = data_end + len(head)
        groups: list[tuple[int, bytes]] = [
            (Opcode.SCHEMA, b''.join(_record(s) for s in self._schemas.values())),
            (Opcode.CHANNEL, b''.join(_record(c) for c in self._channels.values())),
            (Opcode.STATISTICS, _record(stats)),
            (Opcode.CHUNK_INDEX, b''.join(_record(c) for c in self._chunk_indexes)),
            (Opcode.METADATA_INDEX, b''.join(_record(m) for m in self._metadata_indexes))]
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

    def sync(self, indexed: bool = False) -> None:
        """Retire the live trailer, append the buffered records and a new trailer, fsync each.

        ``indexed``: the trailer has the summary, with the chunk indexes (the last sync). The
        others have no summary: the chunk index list grows by one chunk a sync, and writing
        it every second would cost an hour's recording about 400 KiB a second by its end; the
        schemas alone are 30 KB (see :meth:`_trailer`). A sync with nothing new and no
        summary to write writes nothing.
        """
        if self._closed:
            return
        self._close_chunk()           # every sync ends the chunk: each sync is indexed
        if not self._pending and not indexed and self._trailer_at is not None:
            return
        for cid, n in self._pending_counts.items():
            self._counts[cid] = self._counts.get(cid, 0) + n
        if self._pending_counts:
            if not self._start_ns or self._pending_start < self._start_ns:
                self._start_ns = self._pending_start
            self._end_ns = max(self._end_ns, self._pending_end)
        self._pending_counts = {}
        self._pending_start = self._pending_end = 0
        self._chunk_indexes += self._pending_chunk_indexes
        self._pending_chunk_indexes = []
        data = bytes(self._pending) + _sector_pad(self._eof + len(self._pending))
        self._pending = bytearray()
        trailer_at = self._eof + len(data)
        blob = data + self._trailer(trailer_at, indexed)
        for t in self._topics.values():
            t.record.count = self._counts.get(t.channel_id, 0)
        meta = os.path.join(self.work_directory, METADATA)
        try:
            # The new metadata is durable under a temporary name before the MCAP grows and
            # renamed over the old one after: it never lists a message the file lacks.
            tmp = _write_durable(meta + '.tmp', metadata_yaml(
                self.file_name, self.topics, self._start_ns, self._end_ns,
                custom_data=self.custom_data))
            if self._trailer_at is not None:
                # Retire the live trailer: its DataEnd header (9 bytes, inside one sector)
                # becomes a private record spanning it, so a stream reader skips the old
                # footer. Its bytes stay: the file's last 37 are still that footer. Only the
                # first two bytes change (DataEnd 0x0F, length 4 -> 0x80, length 41): a cut
                # after either leaves a valid file.
                self._pwrite(_record_header(RETIRED, self._eof - self._trailer_at - 9),
                             self._trailer_at)
                os.fsync(self._fd)
            self._pwrite(blob, self._eof)      # only ever past the end: nothing is overwritten
            os.ftruncate(self._fd, self._eof + len(blob))   # a failed sync's tail, if retried
            os.fsync(self._fd)
            self._trailer_at, self._eof = trailer_at, self._eof + len(blob)
            os.replace(tmp, meta)
            fsync_dir(self.work_directory)
        except OSError as exc:
            if self._eof != trailer_at - len(data) + len(blob):   # the append did not finish
                self._restore()
            if isinstance(exc, BagError):
                raise
            raise BagError('cannot write {!r}: {} (errno {})'.format(
                self.path, exc.strerror, exc.errno)) from None

    def _restore(self) -> None:
        """After a failed append (a full disk): the file as the last sync left it, if possible.

        Cut the torn tail and give the retired trailer its DataEnd header back; neither needs
        a new block. Best effort: if this fails too, a stream reader and ``--recover`` still
        read everything synced.
        """
        if self._trailer_at is None:
            return
        try:
            os.ftruncate(self._fd, self._eof)
            self._pwrite(_record(DataEnd(data_section_crc=0))[:9], self._trailer_at)
            os.fsync(self._fd)
        except OSError:
            pass

    def _pwrite(self, data: bytes, offset: int) -> None:
        written = os.pwrite(self._fd, data, offset)
        if written != len(data):
            raise BagError('short write to {!r}: {} of {} bytes'.format(
                self.path, written, len(data)))

    def close(self, complete: bool = True) -> None:
        """Sync, close the file and give the directory its final name (idempotent).

        ``complete`` False (the caller failed half-way): the directory keeps its partial name.
        A sync that fails leaves it there too (the error is raised).
        """
        if self._closed:
            return
        try:
            self.sync(indexed=True)
        finally:
            self._closed = True
            os.close(self._fd)
        if complete and self.work_directory != self.directory:
            finish(self.work_directory, self.directory)


def finish(work_directory: str, directory: str) -> None:
    """Rename the synced bag ``work_directory`` to ``directory``, never over another bag."""
    if os.path.lexists(directory):
        raise BagExistsError('cannot name the bag {!r}: {!r} appeared meanwhile; it stays '
                             'under its partial name'.format(work_directory, directory))
    try:
        os.rename(work_directory, directory)
        fsync_dir(os.path.dirname(os.path.abspath(directory)))
    except OSError as exc:
        raise BagError('cannot rename {!r} to {!r}: {} (errno {})'.format(
            work_directory, directory, exc.strerror, exc.errno)) from None
