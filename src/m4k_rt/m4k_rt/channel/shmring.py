"""The shm transport's rings: two single-producer single-consumer datagram rings per link.

At link time the RT side creates two rings in one sealed memfd region and two eventfds, and
passes the fds to the peer with the handshake (SCM_RIGHTS). A datagram's first slot carries
``seq, length, crc32``: the writer publishes ``seq`` last, the reader accepts it only when
``seq`` is the one it expects and the CRC32 of the bytes it copied, seeded with ``seq`` and
``length``, matches, then acknowledges its slots in an ack array only it writes
(:class:`ShmRing`). See docs/design-notes.md, 9c, for why that is safe without memory
barriers. The transports that use them: :mod:`m4k_rt.channel.shm`.
"""

import errno
import fcntl
import mmap
import os
import struct
import time
import zlib

from m4k_rt.channel.contract import HANDSHAKE_SHM, XddpError

SHM_TORN_GIVEUP_NS = 50_000_000  # a published slot failing its CRC this long is malformed
SHM_MIN_SLOTS = 4

# A datagram takes ceil((16 + length) / 128) consecutive slots. The hot paths of ShmRing
# write these two as literals (``(n + 143) >> 7``, ``i << 7``, ``slot + 16``).
_SLOT = 128  # bytes per slot
_HDR = 16  # seq u32, length u32, crc32 u32, reserved u32: at a datagram's first slot
_LINE = 64  # cache line: the consumer's ack array and the producer's slots never share one
_U32 = struct.Struct('<I')
_SEQ_LEN_CRC = struct.Struct('<III')
_LEN_CRC = struct.Struct('<II')
SHM_OFFER = struct.Struct('<4sHHIII')  # magic, version, reserved, slots per ring, slot, region
_SHM_MAGIC = b'M4KS'
_SHM_VERSION = 1
_SHM_SEALS = fcntl.F_SEAL_SHRINK | fcntl.F_SEAL_GROW | fcntl.F_SEAL_SEAL
_M32 = 0xFFFFFFFF
_SKIP = 0xFFFFFFFF  # length of a wrap marker: the rest of the ring is skipped
_GOLDEN = 0x9E3779B1  # spreads seq over the CRC seed
_clock = time.monotonic_ns

# ShmRing.get_into results besides a length > 0 and 0 (nothing published)
SHM_DROPPED = -1  # larger than the reader's buffer or the ring, or empty: dropped (oversize)
SHM_TORN = -2  # published seq, failing check: first seen now (counted torn), retried
SHM_TORN_WAIT = -4  # the same slot still failing: retried, not counted again
SHM_CORRUPT = -3  # still failing after SHM_TORN_GIVEUP_NS: skipped, counted malformed


def shm_geometry(poolsz: int, max_datagram: int) -> tuple[int, int]:
    """Return (slots per ring, ring bytes) of a port: about poolsz per direction.

    A power of two (slot numbers wrap at 2**32 without a gap), at least enough slots for two
    datagrams of ``max_datagram`` bytes, so one always fits.
    """
    need = -(-(_HDR + max_datagram) // _SLOT)
    n = max(poolsz // _SLOT, 2 * need, SHM_MIN_SLOTS)
    nslots = 1 << (n - 1).bit_length()
    return nslots, _ring_bytes(nslots)


def _ring_bytes(nslots: int) -> int:
    return -(-4 * nslots // _LINE) * _LINE + nslots * _SLOT


_pack_u32 = _U32.pack_into
_unpack_u32 = _U32.unpack_from
_pack_len_crc = _LEN_CRC.pack_into
_unpack_seq_len_crc = _SEQ_LEN_CRC.unpack_from
_crc32 = zlib.crc32


class ShmRing:
    """One single-producer single-consumer datagram ring in a shared mapping.

    Layout: ``nslots`` (a power of two) u32 acks, written by the consumer only, then
    ``nslots`` slots of 128 bytes, written by the producer only. Slots have 32-bit absolute
    numbers that only grow (wrapping at 2**32); slot ``x`` lives at index ``x % nslots``.
    A datagram of ``n`` bytes takes ``k`` consecutive slots from its first slot ``x``: the
    producer copies the payload behind a 16-byte header, writes length and CRC32 (seeded
    with ``x`` and ``n``), then ``seq = x`` last. One that does not fit before the end of the
    ring leaves a wrap marker (length ``_SKIP``) and starts at index 0. The consumer accepts
    the datagram at ``x`` when ``seq`` is exactly ``x`` and the CRC of the bytes it copied
    matches, then writes ``ack = x + j`` into the ack of each of its slots. The producer
    reuses slot ``y`` once its ack is ``y - nslots``: the consumer finished the previous lap
    there; it checks the furthest slot it needs, as the consumer goes in order. The region's
    creator makes the first lap free (ack ``i`` at index ``i``; numbering starts at
    ``nslots``, so zeroed slots are never "published"). Equality on 32-bit values makes a
    torn read of ``seq`` or ``ack`` (stored byte by byte) look "not yet", never "done".
    """

    __slots__ = ('mv', 'acks', 'slots', 'nslots', 'mask', 'cap', 'wseq', 'rseq', 'torn_seq',
                 'torn_since', '_dst', '_dstbuf')

    def __init__(self, mv: memoryview, base: int, nslots: int) -> None:
        self.mv = mv
        self.nslots = nslots
        self.mask = nslots - 1
        self.acks = base
        self.slots = base + -(-4 * nslots // _LINE) * _LINE
        self.cap = nslots * _SLOT - _HDR  # the largest datagram the ring can carry
        self.wseq = nslots  # producer: absolute number of its next slot
        self.rseq = nslots  # consumer: absolute number of the next slot to look at
        self.torn_seq = -1
        self.torn_since = 0
        self._dst: memoryview | None = None  # a view of the last receive buffer (CRC of the copy)
        self._dstbuf: object = None

    def init_acks(self) -> None:
        """Make the first lap free (by the region's creator, before the peer has it)."""
        for i in range(self.nslots):
            _pack_u32(self.mv, self.acks + 4 * i, i)

    def put(self, data: bytes | bytearray | memoryview) -> bool:
        """Publish one datagram; False when the ring is full (counted by the caller).

        A datagram longer than the ring is published as a one-slot marker (length, no
        payload) that the consumer counts as dropped oversize, as a socket receiver counts a
        truncated one.
        """
        n = len(data)
        w = self.wseq
        i = w & self.mask
        k = (n + 143) >> 7  # slots: (16 + n) / 128, rounded up
        if i + k > self.nslots or n > self.cap:
            return self._put_wrapped(data, n, w, i)
        mv = self.mv
        last = i + k - 1
        if _unpack_u32(mv, self.acks + 4 * last)[0] != (w + last - i - self.nslots) & _M32:
            return False  # full: the consumer is still on the previous lap there
        slot = self.slots + (i << 7)
        mv[slot + 16:slot + 16 + n] = data
        _pack_len_crc(mv, slot + 4, n, _crc32(data, (w * _GOLDEN + n) & _M32))
        _pack_u32(mv, slot, w)  # published: last
        self.wseq = (w + k) & _M32
        return True

    def _put_wrapped(self, data: bytes | bytearray | memoryview, n: int, w: int,
                     i: int) -> bool:
        nslots = self.nslots
        mv = self.mv
        k = 1 if n > self.cap else (n + 143) >> 7
        skip = nslots - i if i + k > nslots else 0
        last = (w + skip + k - 1) & _M32  # the furthest slot needed; all before it are older
        if _unpack_u32(mv, self.acks + 4 * (last & self.mask))[0] != (last - nslots) & _M32:
            return False
        if skip:
            slot = self.slots + (i << 7)
            _pack_len_crc(mv, slot + 4, _SKIP, (w * _GOLDEN + _SKIP) & _M32)
            _pack_u32(mv, slot, w)
            w = (w + skip) & _M32
            i = 0
        slot = self.slots + (i << 7)
        seed = (w * _GOLDEN + n) & _M32
        if n > self.cap:
            crc = seed  # == zlib.crc32(b'', seed): the marker has no payload
        else:
            mv[slot + 16:slot + 16 + n] = data
            crc = _crc32(data, seed)
        _pack_len_crc(mv, slot + 4, n, crc)
        _pack_u32(mv, slot, w)
        self.wseq = (w + k) & _M32
        return True

    def get_into(self, buf: bytearray | memoryview) -> int:
        """Copy the next published datagram into ``buf``; return its length, 0 if none yet.

        Negative: SHM_DROPPED, SHM_TORN, SHM_TORN_WAIT or SHM_CORRUPT (see there).
        """
        r = self.rseq
        i = r & self.mask
        mv = self.mv
        slot = self.slots + (i << 7)
        got: int
        n: int
        crc: int
        got, n, crc = _unpack_seq_len_crc(mv, slot)
        if got != r:
            return 0
        k = (n + 143) >> 7
        if n > self.cap or not 0 < n <= len(buf) or i + k > self.nslots:
            return self._get_special(buf, r, i, n, crc)
        # Copy, then check the copy: what is delivered is what was checked, and the ack
        # below depends on the check, so on the copy's loads.
        buf[:n] = mv[slot + 16:slot + 16 + n]
        dst = self._dst
        if buf is not self._dstbuf or dst is None:
            dst = self._view(buf)
        if _crc32(dst[:n], (r * _GOLDEN + n) & _M32) != crc:
            return self._torn(r)
        if k == 1:
            _pack_u32(mv, self.acks + 4 * i, r)
        else:
            self._ack(r, i, k)
        self.rseq = (r + k) & _M32
        return n

    def _get_special(self, buf: bytearray | memoryview, r: int, i: int, n: int,
                     crc: int) -> int:
        """Handle a wrap marker, an oversize marker, a datagram larger than ``buf``, garbage."""
        mv = self.mv
        seed = (r * _GOLDEN + n) & _M32
        if n == _SKIP or n > self.cap:
            if crc != seed:
                return self._torn(r)
            k = self.nslots - i if n == _SKIP else 1
        else:
            k = (n + 143) >> 7
            slot = self.slots + (i << 7)
            if i + k > self.nslots or _crc32(mv[slot + 16:slot + 16 + n], seed) != crc:
                return self._torn(r)
        self._ack(r, i, k)
        self.rseq = (r + k) & _M32
        if n == _SKIP:
            return self.get_into(buf)  # the datagram after the marker is at index 0
        return SHM_DROPPED  # larger than buf or the ring, or empty

    def _ack(self, r: int, i: int, k: int) -> None:
        mv = self.mv
        a = self.acks + 4 * i
        for j in range(k):
            _pack_u32(mv, a + 4 * j, (r + j) & _M32)

    def _view(self, buf: bytearray | memoryview) -> memoryview:
        self._dstbuf = buf
        self._dst = view = memoryview(buf)
        return view

    def _torn(self, r: int) -> int:
        now = _clock()
        if self.torn_seq != r:
            self.torn_seq = r
            self.torn_since = now
            return SHM_TORN
        if now - self.torn_since < SHM_TORN_GIVEUP_NS:
            return SHM_TORN_WAIT
        # Not a late store: a corrupt slot. Skip it (one slot: the length is not trusted).
        _pack_u32(self.mv, self.acks + 4 * (r & self.mask), r)
        self.rseq = (r + 1) & _M32
        return SHM_CORRUPT

    def release(self) -> None:
        """Drop the views into the mapping, so it can be closed."""
        self._dst = self._dstbuf = None
        self.mv = memoryview(b'')


class ShmRegion:
    """The shared mapping of one link: ring 0 carries RT -> NRT, ring 1 NRT -> RT.

    ``efd`` wakes the NRT side (the RT side writes it per datagram sent); ``efd_rt`` is
    written by the NRT side per datagram it writes, for RT-side users that wait instead of
    running periodically (the round-trip bench); the RT tasks never read it.
    """

    __slots__ = ('mm', 'mv', 'efd', 'efd_rt', 'to_nrt', 'to_rt')

    def __init__(self, mm: mmap.mmap, efd: int, efd_rt: int, nslots: int) -> None:
        self.mm = mm
        self.mv = memoryview(mm)
        self.efd = efd
        self.efd_rt = efd_rt
        self.to_nrt = ShmRing(self.mv, 0, nslots)
        self.to_rt = ShmRing(self.mv, _ring_bytes(nslots), nslots)

    def close(self) -> None:
        """Unmap the region and close both eventfds."""
        self.to_nrt.release()
        self.to_rt.release()
        self.mv.release()
        self.mm.close()
        for fd in (self.efd, self.efd_rt):
            if fd >= 0:
                os.close(fd)
        self.efd = self.efd_rt = -1


def shm_create(port: int, nslots: int) -> tuple[ShmRegion, int, bytes]:
    """Create a link's region: (region, memfd to pass, offer bytes). The caller closes memfd."""
    size = 2 * _ring_bytes(nslots)
    size = -(-size // mmap.PAGESIZE) * mmap.PAGESIZE
    fd = os.memfd_create('m4k-xddp{}'.format(port), os.MFD_CLOEXEC | os.MFD_ALLOW_SEALING)
    try:
        os.fchmod(fd, 0o600)
        os.ftruncate(fd, size)
        # The peer gets this fd: sealed, it can neither shrink the region under our mapping
        # (SIGBUS in the RT process) nor grow it.
        fcntl.fcntl(fd, fcntl.F_ADD_SEALS, _SHM_SEALS)
        mm = mmap.mmap(fd, size)
        efd = os.eventfd(0, os.EFD_CLOEXEC | os.EFD_NONBLOCK)
        efd_rt = os.eventfd(0, os.EFD_CLOEXEC | os.EFD_NONBLOCK)
    except BaseException:
        os.close(fd)
        raise
    offer = HANDSHAKE_SHM + SHM_OFFER.pack(_SHM_MAGIC, _SHM_VERSION, 0, nslots, _SLOT, size)
    region = ShmRegion(mm, efd, efd_rt, nslots)
    region.to_nrt.init_acks()
    region.to_rt.init_acks()
    return region, fd, offer


def shm_accept_offer(msg: bytes, fds: list[int], path: str) -> ShmRegion:
    """Map the region an RT side offered (NRT side); closes ``fds`` on failure."""
    try:
        if len(msg) != 1 + SHM_OFFER.size or len(fds) != 3:
            raise XddpError('RT side of {} sent a malformed shm offer ({} bytes, {} fds)'.format(
                path, len(msg), len(fds)), path, errno.EPROTO)
        magic, version, _, nslots, slot, size = SHM_OFFER.unpack_from(msg, 1)
        if magic != _SHM_MAGIC or version != _SHM_VERSION or slot != _SLOT:
            raise XddpError('RT side of {} offers shm version {!r}/{} with {}-byte slots, this '
                            'peer speaks {} with {}'.format(path, magic, version, slot,
                                                            _SHM_VERSION, _SLOT),
                            path, errno.EPROTO)
        mfd, efd, efd_rt = fds
        if (nslots < SHM_MIN_SLOTS or nslots & (nslots - 1) or 2 * _ring_bytes(nslots) > size
                or os.fstat(mfd).st_size != size):
            raise XddpError('RT side of {} offers an inconsistent shm region'.format(path),
                            path, errno.EPROTO)
        mm = mmap.mmap(mfd, size)
    except BaseException:
        for fd in fds:
            os.close(fd)
        raise
    os.close(mfd)
    os.set_blocking(efd, False)
    os.set_blocking(efd_rt, False)
    return ShmRegion(mm, efd, efd_rt, nslots)

