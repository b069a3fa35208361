"""Xenomai XDDP emulation over Unix-domain sockets: RT side and NRT side.

The RT side binds port N (a listening socket ``<runtime_dir>/xddp<N>``, optionally labelled by
a symlink ``label.<label>``) and never blocks: accept, send and receive are non-blocking, and a
datagram that cannot be delivered (no peer, full queue, oversize) is dropped and counted. The
NRT side opens a port by number or label, like ``open("/dev/rtpN")``, and gets blocking reads
and writes with timeouts. At most one NRT peer is linked per port: on connect the RT side
answers one handshake byte, 1 (linked) or 0 (busy, then closed). Either
side may restart; the other one notices (EOF, EPIPE, ECONNRESET), counts it and re-links.

Access control is the file system's, as for ``/dev/rtpN``: the runtime directory is 0700 (0770
with a group) and refuses to be used when it is owned by someone else or is more open than
configured; sockets are 0600 (0660).

Message mode (``SOCK_SEQPACKET``) keeps datagram boundaries; stream mode (``SOCK_STREAM``)
carries bytes. ``max_datagram`` is kept at most ``poolsz // 2`` so every send fits a single
kernel buffer and is all-or-nothing in both modes.

Two transports carry the datagrams of a linked port (message mode only for ``shm``):

* ``socket``: every datagram is a ``send``/``recv`` on the linked Unix socket.
* ``shm``: the socket only does the rendezvous, access control, handshake and liveness. At link
  time the RT side creates two single-producer single-consumer datagram rings in one sealed
  memfd region and two eventfds, and passes the fds to the peer with the handshake
  (SCM_RIGHTS). The RT side then sends by copying into the ring (plus one ``eventfd_write``
  to wake the NRT reader) and receives by reading the ring: no other system call per
  datagram. It looks at the socket (peer gone, second opener) every :data:`SHM_LIVENESS_NS`.
  A datagram's first slot carries ``seq, length, crc32``: the writer publishes ``seq`` last,
  the reader accepts it only when ``seq`` is the one it expects and the CRC32 of the bytes it
  copied, seeded with ``seq`` and ``length``, matches, then acknowledges its slots in an ack
  array only it writes (:class:`_ShmRing`). See docs/design-notes.md, 9c, for why that is
  safe without memory barriers.
"""

from dataclasses import asdict, dataclass
import errno
import fcntl
import grp
import mmap
import os
import re
import select
import socket
import stat
import struct
import time
from typing import Any
import zlib

DEFAULT_MAX_PORTS = 32
DEFAULT_POOLSZ = 65536
DEFAULT_MAX_DATAGRAM = 4096
DEFAULT_HANDSHAKE_TIMEOUT = 5.0  # the RT side accepts when its task polls: one period at most
HANDSHAKE_OK = b'\x01'
HANDSHAKE_BUSY = b'\x00'
HANDSHAKE_SHM = b'\x02'  # linked, datagrams go through the shared-memory rings passed along
MODES = {'message': socket.SOCK_SEQPACKET, 'stream': socket.SOCK_STREAM}
TRANSPORTS = ('socket', 'shm')
DEFAULT_TRANSPORT = 'socket'
SHM_LIVENESS_NS = 100_000_000  # the RT side looks at its socket (peer gone? opener?) this often
SHM_TORN_GIVEUP_NS = 50_000_000  # a published slot failing its CRC this long is malformed
SHM_MIN_SLOTS = 4
DEFAULT_SHM_SOCKET_JUNK = 8  # datagrams a peer wrongly sent on an shm link's socket, per look

_SEND_FLAGS = socket.MSG_DONTWAIT | socket.MSG_NOSIGNAL
_LABEL_RE = re.compile(r'[A-Za-z0-9_][A-Za-z0-9_.-]{0,31}\Z')
_PEER_GONE = (errno.EPIPE, errno.ECONNRESET, errno.ENOTCONN, errno.ECONNREFUSED)
_OPEN_RETRY_S = 0.02
_NRT_BUFSZ = 65536


class XddpError(OSError):
    """Base error of the XDDP emulation; ``path`` names the socket or directory involved."""

    def __init__(self, message: str, path: str | None = None, err: int | None = None) -> None:
        super().__init__(message)
        self.path = path
        self.filename = path
        self.errno = err

    def __str__(self) -> str:
        return str(self.args[0])


class XddpBusyError(XddpError):
    """The port is bound by another live process, or already has an NRT peer."""


class XddpNotBoundError(XddpError):
    """No RT socket is bound at the port (yet)."""


class XddpPortError(XddpError):
    """The port number, label or mode is invalid."""


@dataclass(slots=True)
class XddpCounters:
    """Per-port event counters of the RT side."""

    sent: int = 0
    received: int = 0
    dropped_no_peer: int = 0
    dropped_full: int = 0
    dropped_oversize: int = 0  # sends empty/above max_datagram, receives above the buffer
    malformed: int = 0  # counted by the receiver via count_malformed(); corrupt shm slots
    torn: int = 0  # shm: a published slot failing its CRC when first read (retried)
    peer_restarts: int = 0  # peers linked after the first one
    peer_lost: int = 0  # peer EOF / EPIPE / ECONNRESET
    busy_rejects: int = 0  # openers refused because a peer was linked

    def as_dict(self) -> dict[str, int]:
        """Return the counters as a plain dict."""
        return asdict(self)


def default_runtime_dir() -> str:
    """Return the runtime directory: $M4K_RUNTIME_DIR, $XDG_RUNTIME_DIR/m4k, /run/m4k, /tmp."""
    path = os.environ.get('M4K_RUNTIME_DIR')
    if path:
        return path
    xdg = os.environ.get('XDG_RUNTIME_DIR')
    if xdg:
        return os.path.join(xdg, 'm4k')
    if os.geteuid() == 0:
        return '/run/m4k'
    return '/tmp/m4k-{}'.format(os.getuid())


def _gid(group: str | int | None) -> int | None:
    if group is None:
        return None
    if isinstance(group, int) and not isinstance(group, bool):
        return group
    if isinstance(group, str):
        try:
            return grp.getgrnam(group).gr_gid
        except KeyError:
            pass
    raise XddpError('unknown group {!r}'.format(group), None, errno.EINVAL)


def ensure_runtime_dir(path: str | None = None, group: str | int | None = None) -> str:
    """Create (0700, or 0770 + chgrp) or check the runtime directory and return its path.

    Like ssh with ``~/.ssh``, refuse a directory that is a symlink, is owned by another user,
    has another group than configured, or grants more than the configured permissions.
    """
    path = os.path.abspath(path or default_runtime_dir())
    gid = _gid(group)
    mode = 0o770 if gid is not None else 0o700
    try:
        try:
            os.mkdir(path, mode)
            created = True
        except FileNotFoundError:
            os.makedirs(os.path.dirname(path), 0o755, exist_ok=True)
            os.mkdir(path, mode)
            created = True
        except FileExistsError:
            created = False
        if created:
            if gid is not None:
                os.chown(path, -1, gid)
            os.chmod(path, mode)  # mkdir's mode went through the umask
        st = os.lstat(path)
    except OSError as exc:
        raise XddpError('cannot create runtime directory {!r}: {}'.format(
            path, exc.strerror), path, exc.errno) from exc
    if not stat.S_ISDIR(st.st_mode):
        raise XddpError('runtime directory {!r} is not a directory (symlinks are refused)'.format(
            path), path, errno.ENOTDIR)
    if st.st_uid != os.geteuid():
        raise XddpError('runtime directory {!r} is owned by uid {}, not by uid {}: refusing to '
                        'use it'.format(path, st.st_uid, os.geteuid()), path, errno.EPERM)
    perm = st.st_mode & 0o777
    if perm & ~mode:
        raise XddpError('runtime directory {!r} has mode {:04o}, wider than {:04o}: refusing to '
                        'use it (chmod {:o} it or remove it)'.format(path, perm, mode, mode),
                        path, errno.EPERM)
    if gid is not None and st.st_gid != gid:
        raise XddpError('runtime directory {!r} has group {}, expected {}'.format(
            path, st.st_gid, gid), path, errno.EPERM)
    if perm != mode:
        os.chmod(path, mode)  # narrower than configured (e.g. 0700 with a group): ours, widen
    return path


def check_runtime_dir(path: str | None = None, group: str | int | None = None) -> str:
    """Check, as the NRT side, the runtime directory the RT side made; return its path.

    The NRT side neither creates nor changes it (a missing directory is only "nothing bound
    yet"), but before it links it refuses what :func:`ensure_runtime_dir` refuses: a symlink
    or non-directory, an owner it cannot trust, permissions wider than 0700 (0770 with a
    group), another group than the configured one. Trusted owners: this user, root, and with
    a group its members (the RT process may run as another member). Else whoever made the
    directory could have planted the sockets: a fake RT side that reads the commands or feeds
    odometry. A peer of a stack configured with a group must be given that group.
    """
    path = os.path.abspath(path or default_runtime_dir())
    gid = _gid(group)
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return path
    except OSError as exc:
        raise XddpError('cannot check runtime directory {!r}: {}'.format(
            path, exc.strerror), path, exc.errno) from exc
    if not stat.S_ISDIR(st.st_mode):
        raise XddpError('runtime directory {!r} is not a directory (symlinks are refused)'.format(
            path), path, errno.ENOTDIR)
    euid = os.geteuid()
    if st.st_uid not in (euid, 0) and not (gid is not None and _member(st.st_uid, gid)):
        raise XddpError('runtime directory {!r} is owned by uid {}, not by uid {}{}: refusing '
                        'to link to it'.format(path, st.st_uid, euid, '' if gid is None else
                                               ' or a member of group {}'.format(gid)),
                        path, errno.EPERM)
    perm = st.st_mode & 0o777
    mode = 0o770 if gid is not None else 0o700
    if perm & ~mode:
        raise XddpError('runtime directory {!r} has mode {:04o}, wider than {:04o}: refusing to '
                        'link to it'.format(path, perm, mode), path, errno.EPERM)
    if gid is not None and st.st_gid != gid:
        raise XddpError('runtime directory {!r} has group {}, expected {}'.format(
            path, st.st_gid, gid), path, errno.EPERM)
    return path


def _member(uid: int, gid: int) -> bool:
    import pwd
    try:
        user = pwd.getpwuid(uid)
        return user.pw_gid == gid or user.pw_name in grp.getgrgid(gid).gr_mem
    except KeyError:
        return False


def _check_port(port: Any, max_ports: int) -> int:
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port < max_ports:
        raise XddpPortError('port {!r} is not an integer in [0, {})'.format(port, max_ports),
                            None, errno.EINVAL)
    return port


def _check_label(label: Any) -> str:
    if not isinstance(label, str) or not _LABEL_RE.match(label):
        raise XddpPortError('label {!r} must be 1-32 characters of [A-Za-z0-9_.-] not starting '
                            'with . or -'.format(label), None, errno.EINVAL)
    return label


def port_path(port_or_label: int | str, runtime_dir: str | None = None,
              max_ports: int = DEFAULT_MAX_PORTS) -> str:
    """Return the socket path of a port number or the symlink path of a label."""
    rd = runtime_dir or default_runtime_dir()
    if isinstance(port_or_label, str):
        return os.path.join(rd, 'label.' + _check_label(port_or_label))
    return os.path.join(rd, 'xddp{}'.format(_check_port(port_or_label, max_ports)))


def _socket_alive(path: str) -> bool:
    # A datagram socket cannot connect to a stream/seqpacket listener (EPROTOTYPE) but finds
    # out whether one is bound without creating a connection the live process would see.
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
    try:
        probe.connect(path)
    except OSError as exc:
        return exc.errno not in (errno.ECONNREFUSED, errno.ENOENT)
    finally:
        probe.close()
    return True


# A datagram takes ceil((16 + length) / 128) consecutive slots. The hot paths of _ShmRing
# write these two as literals (``(n + 143) >> 7``, ``i << 7``, ``slot + 16``).
_SLOT = 128  # bytes per slot
_HDR = 16  # seq u32, length u32, crc32 u32, reserved u32: at a datagram's first slot
_LINE = 64  # cache line: the consumer's ack array and the producer's slots never share one
_U32 = struct.Struct('<I')
_SEQ_LEN_CRC = struct.Struct('<III')
_LEN_CRC = struct.Struct('<II')
_SHM_OFFER = struct.Struct('<4sHHIII')  # magic, version, reserved, slots per ring, slot, region
_SHM_MAGIC = b'M4KS'
_SHM_VERSION = 1
_SHM_SEALS = fcntl.F_SEAL_SHRINK | fcntl.F_SEAL_GROW | fcntl.F_SEAL_SEAL
_M32 = 0xFFFFFFFF
_SKIP = 0xFFFFFFFF  # length of a wrap marker: the rest of the ring is skipped
_GOLDEN = 0x9E3779B1  # spreads seq over the CRC seed
_clock = time.monotonic_ns

# _ShmRing.get_into results besides a length > 0 and 0 (nothing published)
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


class _ShmRing:
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
        self._dst = self._dstbuf = None
        self.mv = memoryview(b'')


class _ShmRegion:
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
        self.to_nrt = _ShmRing(self.mv, 0, nslots)
        self.to_rt = _ShmRing(self.mv, _ring_bytes(nslots), nslots)

    def close(self) -> None:
        self.to_nrt.release()
        self.to_rt.release()
        self.mv.release()
        self.mm.close()
        for fd in (self.efd, self.efd_rt):
            if fd >= 0:
                os.close(fd)
        self.efd = self.efd_rt = -1


def _shm_create(port: int, nslots: int) -> tuple[_ShmRegion, int, bytes]:
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
    offer = HANDSHAKE_SHM + _SHM_OFFER.pack(_SHM_MAGIC, _SHM_VERSION, 0, nslots, _SLOT, size)
    region = _ShmRegion(mm, efd, efd_rt, nslots)
    region.to_nrt.init_acks()
    region.to_rt.init_acks()
    return region, fd, offer


def _shm_accept_offer(msg: bytes, fds: list[int], path: str) -> _ShmRegion:
    """Map the region an RT side offered (NRT side); closes ``fds`` on failure."""
    try:
        if len(msg) != 1 + _SHM_OFFER.size or len(fds) != 3:
            raise XddpError('RT side of {} sent a malformed shm offer ({} bytes, {} fds)'.format(
                path, len(msg), len(fds)), path, errno.EPROTO)
        magic, version, _, nslots, slot, size = _SHM_OFFER.unpack_from(msg, 1)
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
    return _ShmRegion(mm, efd, efd_rt, nslots)


class RtXddpSocket:
    """RT side of one port: a non-blocking listener with at most one linked NRT peer.

    Not thread-safe: one RT task owns a port. After close() it stays harmless (sends are
    dropped and counted, receives return 0).
    """

    def __init__(self, port: int, label: str | None = None, *, mode: str = 'message',
                 poolsz: int = DEFAULT_POOLSZ, max_datagram: int = DEFAULT_MAX_DATAGRAM,
                 runtime_dir: str | None = None, max_ports: int = DEFAULT_MAX_PORTS,
                 group: str | int | None = None, transport: str | None = None) -> None:
        if transport is None:
            transport = DEFAULT_TRANSPORT
        if mode not in MODES:
            raise XddpPortError('mode {!r} is not one of {}'.format(mode, sorted(MODES)),
                                None, errno.EINVAL)
        if transport not in TRANSPORTS:
            raise XddpPortError('transport {!r} is not one of {}'.format(
                transport, list(TRANSPORTS)), None, errno.EINVAL)
        if transport == 'shm' and mode != 'message':
            raise XddpPortError('the shm transport carries datagrams: it needs message mode, '
                                'not {}'.format(mode), None, errno.EINVAL)
        if isinstance(poolsz, bool) or not isinstance(poolsz, int) or poolsz < 1024:
            raise XddpPortError('poolsz {!r} must be an int >= 1024'.format(poolsz),
                                None, errno.EINVAL)
        if (isinstance(max_datagram, bool) or not isinstance(max_datagram, int)
                or not 1 <= max_datagram <= poolsz // 2):
            raise XddpPortError('max_datagram {!r} must be in [1, poolsz // 2 = {}]'.format(
                max_datagram, poolsz // 2), None, errno.EINVAL)
        self.port = _check_port(port, max_ports)
        self.label = None if label is None else _check_label(label)
        self.mode = mode
        self.transport = transport
        self.poolsz = poolsz
        self.max_datagram = max_datagram
        self.counters = XddpCounters()
        self._shm_slots = shm_geometry(poolsz, max_datagram)[0]
        self._region: _ShmRegion | None = None
        self._tx: _ShmRing | None = None  # shm: RT -> NRT ring while linked
        self._rx: _ShmRing | None = None  # shm: NRT -> RT ring while linked
        self._efd = -1
        self._next_check = 0
        self._gid = _gid(group)
        self.runtime_dir = ensure_runtime_dir(runtime_dir, group)
        self.path = port_path(port, self.runtime_dir, max_ports)
        self.label_path = None if label is None else port_path(label, self.runtime_dir)
        self._recv_flags = socket.MSG_DONTWAIT | (
            socket.MSG_TRUNC if mode == 'message' else 0)
        self._rbuf = bytearray(max_datagram)
        self._peer: socket.socket | None = None
        self._ever_linked = False
        self._inode: tuple[int, int] | None = None
        self._listener = self._bind()
        self._lfd = self._listener.fileno()
        self._lpoll = select.poll()  # listener only: is an opener waiting?
        self._lpoll.register(self._lfd, select.POLLIN)
        self._poll = select.poll()  # listener + peer: anything to do at all?
        self._poll.register(self._lfd, select.POLLIN)
        self._ppoll = select.poll()  # peer only: hung up?
        try:
            self._link_label()
        except BaseException:
            self.close()
            raise

    def _bind(self) -> socket.socket:
        path = self.path
        try:
            st = os.lstat(path)
        except FileNotFoundError:
            st = None
        if st is not None:
            if not stat.S_ISSOCK(st.st_mode):
                raise XddpError('{!r} exists and is not a socket: refusing to replace it'.format(
                    path), path, errno.EEXIST)
            if _socket_alive(path):
                raise XddpBusyError('port {} is already bound by a live process: {}'.format(
                    self.port, path), path, errno.EADDRINUSE)
            try:
                os.unlink(path)  # stale: its RT process died without closing
            except FileNotFoundError:
                pass
        sock = socket.socket(socket.AF_UNIX,
                             MODES[self.mode] | socket.SOCK_NONBLOCK | socket.SOCK_CLOEXEC)
        try:
            self._set_buffers(sock)
            sock.bind(path)
            if self._gid is not None:
                os.chown(path, -1, self._gid)
            os.chmod(path, 0o660 if self._gid is not None else 0o600)
            st = os.stat(path)
            self._inode = (st.st_dev, st.st_ino)
            sock.listen(8)
        except OSError as exc:
            sock.close()
            if self._inode is not None:
                os.unlink(path)
            raise XddpError('cannot bind port {} at {!r}: {}'.format(
                self.port, path, exc.strerror or exc), path, exc.errno) from exc
        return sock

    def _link_label(self) -> None:
        lpath = self.label_path
        if lpath is None:
            return
        target = os.path.basename(self.path)
        try:
            current: str | None = os.readlink(lpath)
        except FileNotFoundError:
            current = None
        except OSError as exc:
            raise XddpError('label path {!r} exists and is not a symlink'.format(lpath),
                            lpath, exc.errno) from exc
        if current is not None and current != target and _socket_alive(
                os.path.join(self.runtime_dir, current)):
            raise XddpBusyError('label {!r} is used by live port {!r}: {}'.format(
                self.label, current, lpath), lpath, errno.EADDRINUSE)
        tmp = '{}.tmp{}'.format(lpath, os.getpid())
        try:
            os.symlink(target, tmp)
            os.replace(tmp, lpath)  # atomic: openers never see a missing label
        except OSError as exc:
            raise XddpError('cannot create label {!r}: {}'.format(lpath, exc.strerror),
                            lpath, exc.errno) from exc

    def _set_buffers(self, sock: socket.socket) -> None:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, self.poolsz)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, self.poolsz)

    @property
    def closed(self) -> bool:
        """Return True once closed."""
        return self._lfd < 0

    @property
    def connected(self) -> bool:
        """Return True while an NRT peer is linked."""
        return self._peer is not None

    def fileno(self) -> int:
        """Return the linked peer's fd, else the listener's (for bounded waits).

        With the shm transport, a linked port returns the eventfd the peer writes per
        datagram: readable once it wrote; whoever waits on it resets it (os.eventfd_read).
        """
        region = self._region
        if region is not None:
            return region.efd_rt
        peer = self._peer
        return peer.fileno() if peer is not None else self._lfd

    def poll_peer(self) -> bool:
        """Accept a waiting opener (or refuse it when busy); return True when linked."""
        if self._lpoll.poll(0):
            self._accept_pending()
        return self._peer is not None

    def _accept_pending(self) -> None:
        while True:
            try:
                conn, _ = self._listener.accept()
            except OSError:  # nothing pending (EAGAIN), or EMFILE & co: retried next call
                return
            if self._peer is not None and self._ppoll.poll(0):
                self._drop_peer()  # hung up: let the new opener replace it right away
            if self._peer is not None:
                # Counted before the opener is told: whoever sees XddpBusyError sees the count.
                self.counters.busy_rejects += 1
                try:
                    conn.send(HANDSHAKE_BUSY, _SEND_FLAGS)
                except OSError:
                    pass
                conn.close()
                continue
            region = None
            try:
                conn.setblocking(False)
                self._set_buffers(conn)
                if self.transport == 'shm':
                    region, mfd, offer = _shm_create(self.port, self._shm_slots)
                    try:
                        socket.send_fds(conn, [offer], [mfd, region.efd, region.efd_rt],
                                        _SEND_FLAGS)
                    finally:
                        os.close(mfd)
                else:
                    conn.send(HANDSHAKE_OK, _SEND_FLAGS)
            except OSError:  # the opener is already gone (or no memory for the region)
                if region is not None:
                    region.close()
                conn.close()
                continue
            if region is not None:
                self._region = region
                self._tx = region.to_nrt
                self._rx = region.to_rt
                self._efd = region.efd
                self._next_check = _clock() + SHM_LIVENESS_NS
            self._peer = conn
            fd = conn.fileno()
            self._poll.register(fd, select.POLLIN)
            self._ppoll.register(fd, select.POLLHUP)
            if self._ever_linked:
                self.counters.peer_restarts += 1
            self._ever_linked = True

    def _drop_peer(self, count: bool = True) -> None:
        peer = self._peer
        if peer is None:
            return
        self._peer = None
        region = self._region
        if region is not None:
            # Fresh rings for the next peer: a restarted peer never sees this one's data.
            self._region = self._tx = self._rx = None
            self._efd = -1
            region.close()
        fd = peer.fileno()
        self._poll.unregister(fd)
        self._ppoll.unregister(fd)
        peer.close()
        if count:
            self.counters.peer_lost += 1

    def send(self, data: bytes | bytearray | memoryview) -> bool:
        """Send one datagram without blocking; return False when it was dropped (counted)."""
        n = len(data)
        c = self.counters
        if not 0 < n <= self.max_datagram:
            c.dropped_oversize += 1
            return False
        tx = self._tx
        if tx is not None:  # shm, linked: no system call but the wake of the NRT reader
            if _clock() >= self._next_check:
                return self._send_shm_slow(data)
            if tx.put(data):
                try:
                    os.eventfd_write(self._efd, 1)
                except OSError:
                    pass  # only at 2**64 - 2 pending wakes; the datagram is in anyway
                c.sent += 1
                return True
            c.dropped_full += 1
            return False
        peer = self._peer
        if peer is None:
            if self._lpoll.poll(0):
                self._accept_pending()
            peer = self._peer
            if peer is None:
                c.dropped_no_peer += 1
                return False
            if self._tx is not None:
                return self._send_shm_slow(data)
        try:
            sent = peer.send(data, _SEND_FLAGS)
        except BlockingIOError:
            c.dropped_full += 1
            return False
        except OSError as exc:
            if exc.errno == errno.EMSGSIZE:
                c.dropped_oversize += 1
                return False
            self._drop_peer()
            c.dropped_no_peer += 1
            return False
        if sent != n:  # cannot happen while max_datagram <= poolsz // 2; never count it sent
            c.dropped_full += 1
            return False
        c.sent += 1
        return True

    def _send_shm_slow(self, data: bytes | bytearray | memoryview) -> bool:
        """Shm: look at the socket first (peer gone? opener?), then send if still linked."""
        c = self.counters
        self._shm_check()
        tx = self._tx
        if tx is None:
            if self._lpoll.poll(0):
                self._accept_pending()
            tx = self._tx
            if tx is None:
                c.dropped_no_peer += 1
                return False
        if not tx.put(data):
            c.dropped_full += 1
            return False
        try:
            os.eventfd_write(self._efd, 1)
        except OSError:
            pass
        c.sent += 1
        return True

    def recv_into(self, buf: bytearray | memoryview) -> int:
        """Receive one pending datagram into ``buf`` without blocking; return 0 if none.

        Accepts a waiting opener first. A message-mode datagram larger than ``buf`` is
        discarded and counted ``dropped_oversize``; in stream mode up to ``len(buf)`` bytes
        are returned. With the shm transport, a linked port reads its ring (no system call)
        and looks at its socket every SHM_LIVENESS_NS.
        """
        rx = self._rx
        if rx is not None:  # shm, linked: no system call
            if _clock() >= self._next_check:
                self._shm_check()
                return 0 if self._rx is None else self._recv_shm(buf, 0)
            n = rx.get_into(buf)
            if n > 0:
                self.counters.received += 1
                return n
            if n == 0:
                return 0
            return self._recv_shm(buf, n)
        if self.transport == 'shm':
            if self._lpoll.poll(0):
                self._accept_pending()  # the new peer has nothing in its ring yet
            return 0
        poll = self._poll.poll
        lfd = self._lfd
        while True:
            events = poll(0)  # one syscall and no exception when idle
            if not events:
                return 0
            if len(events) > 1 or events[0][0] == lfd:
                self._accept_pending()  # an opener waits (alone or next to peer data)
            peer = self._peer
            if peer is None:
                return 0
            try:
                n = peer.recv_into(buf, 0, self._recv_flags)
            except BlockingIOError:
                return 0
            except OSError:  # ECONNRESET
                self._drop_peer()
                return 0
            if n == 0:  # EOF (empty datagrams are never sent by our endpoints)
                self._drop_peer()
                return 0
            if n > len(buf):  # discarded: look again
                self.counters.dropped_oversize += 1
                continue
            self.counters.received += 1
            return n

    def _recv_shm(self, buf: bytearray | memoryview, n: int) -> int:
        """Count what the ring's reader reported (``n`` < 0) and read on, or read (``n`` 0)."""
        c = self.counters
        rx = self._rx
        assert rx is not None
        while True:
            if n > 0:
                c.received += 1
                return n
            if n == SHM_DROPPED:
                c.dropped_oversize += 1
            elif n == SHM_TORN:
                c.torn += 1
                return 0
            elif n == SHM_CORRUPT:
                c.malformed += 1
            elif n < 0:  # SHM_TORN_WAIT: the same slot, already counted
                return 0
            n = rx.get_into(buf)
            if n == 0:
                return 0

    def _shm_check(self) -> None:
        """Shm transport: accept or refuse an opener, notice a peer gone (system calls)."""
        self._next_check = _clock() + SHM_LIVENESS_NS
        for fd, _ in self._poll.poll(0):
            if fd == self._lfd:
                self._accept_pending()  # a second opener is refused; a hung-up peer replaced
                continue
            peer = self._peer
            if peer is None or fd != peer.fileno():
                continue
            for _ in range(DEFAULT_SHM_SOCKET_JUNK):
                try:
                    junk = peer.recv(64, socket.MSG_DONTWAIT)
                except BlockingIOError:
                    break
                except OSError:  # ECONNRESET
                    junk = b''
                if not junk:
                    self._drop_peer()  # EOF: the peer is gone; its rings go with it
                    break
                self.counters.malformed += 1  # a peer writing the socket, not its ring

    def recv(self) -> bytes | None:
        """Receive one pending datagram as bytes, or None (allocates: not for RT loops)."""
        n = self.recv_into(self._rbuf)
        return bytes(self._rbuf[:n]) if n else None

    def count_malformed(self) -> None:
        """Count a received datagram that failed to decode."""
        self.counters.malformed += 1

    def close(self) -> None:
        """Close the peer and the listener; remove our socket file and label."""
        self._drop_peer(count=False)
        listener = self.__dict__.pop('_listener', None)
        if listener is None:
            return
        # Afterwards the pollers are empty: send() drops (no peer), recv_into() returns 0.
        self._lpoll.unregister(self._lfd)
        self._poll.unregister(self._lfd)
        self._lfd = -1
        listener.close()
        ours = False
        try:
            st = os.lstat(self.path)
            if (st.st_dev, st.st_ino) == self._inode:
                os.unlink(self.path)
                ours = True
        except OSError:
            pass
        if ours and self.label_path is not None:
            try:
                if os.readlink(self.label_path) == os.path.basename(self.path):
                    os.unlink(self.label_path)
            except OSError:
                pass

    def __enter__(self) -> 'RtXddpSocket':
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return '<RtXddpSocket port={} label={!r} mode={} connected={}>'.format(
            self.port, self.label, self.mode, self.connected)


class NrtXddpEndpoint:
    """NRT side of one port: blocking reads and writes with timeouts.

    With the shm transport (``region`` given) datagrams go through the link's rings; the
    socket only tells that the RT side is gone (EOF), and :meth:`fileno` is an epoll fd that
    is readable when a datagram was published or the RT side went away.
    """

    def __init__(self, sock: socket.socket, path: str, mode: str,
                 region: _ShmRegion | None = None) -> None:
        self._sock: socket.socket | None = sock
        self.path = path
        self.mode = mode
        self.transport = 'socket' if region is None else 'shm'
        self._buf = bytearray(_NRT_BUFSZ)
        self._flags = socket.MSG_TRUNC if mode == 'message' else 0
        self._region = region
        self._gone = False
        self._epoll: select.epoll | None = None
        self._spoll: select.poll | None = None
        if region is not None:
            try:
                self._epoll = select.epoll(2, select.EPOLL_CLOEXEC)
                self._epoll.register(region.efd, select.EPOLLIN)
                self._epoll.register(sock.fileno(), select.EPOLLIN | select.EPOLLRDHUP)
            except BaseException:
                region.close()
                if self._epoll is not None:
                    self._epoll.close()
                raise
            self._spoll = select.poll()
            self._spoll.register(sock.fileno(), select.POLLIN | select.POLLRDHUP)

    def _live(self) -> socket.socket:
        if self._sock is None:
            raise XddpError('endpoint {!r} is closed'.format(self.path), self.path, errno.EBADF)
        return self._sock

    def read(self, timeout: float | None = None) -> bytes:
        """Return the next datagram (message mode) or available bytes (stream mode).

        Raise TimeoutError when nothing arrives within ``timeout`` seconds (None waits
        forever) and BrokenPipeError when the RT side closed or died; never return b''.
        """
        sock = self._live()
        if self._region is not None:
            return self._shm_read(timeout)
        sock.settimeout(timeout)
        try:
            n = sock.recv_into(self._buf, 0, self._flags)
        except (TimeoutError, BlockingIOError):
            raise TimeoutError(errno.ETIMEDOUT, 'nothing received on {} within {}s'.format(
                self.path, timeout)) from None
        except OSError as exc:
            if exc.errno in _PEER_GONE:
                raise BrokenPipeError(errno.EPIPE, 'RT side of {} is gone'.format(
                    self.path)) from exc
            raise
        if n == 0:
            raise BrokenPipeError(errno.EPIPE, 'RT side of {} closed'.format(self.path))
        if n > len(self._buf):
            raise XddpError('datagram of {} bytes on {} exceeds the {}-byte read buffer'.format(
                n, self.path, len(self._buf)), self.path, errno.EMSGSIZE)
        return bytes(self._buf[:n])

    def write(self, data: bytes | bytearray | memoryview, timeout: float | None = None) -> None:
        """Write one datagram; raise BrokenPipeError when the RT side is gone."""
        if not len(data):
            raise ValueError('cannot write an empty datagram to {}'.format(self.path))
        sock = self._live()
        if self._region is not None:
            self._shm_write(data, timeout)
            return
        sock.settimeout(timeout)
        try:
            sock.sendall(data, socket.MSG_NOSIGNAL)
        except TimeoutError:
            raise TimeoutError(errno.ETIMEDOUT, 'write to {} blocked for {}s'.format(
                self.path, timeout)) from None
        except OSError as exc:
            if exc.errno in _PEER_GONE:
                raise BrokenPipeError(errno.EPIPE, 'RT side of {} is gone'.format(
                    self.path)) from exc
            raise XddpError('cannot write {} bytes to {}: {}'.format(
                len(data), self.path, exc.strerror), self.path, exc.errno) from exc

    def _shm_gone(self) -> None:
        """Look at the socket: EOF or reset means the RT side is gone (sets ``_gone``)."""
        sock = self._live()
        try:
            junk = sock.recv(64, socket.MSG_DONTWAIT)
        except BlockingIOError:
            return
        except OSError:  # ECONNRESET
            junk = b''
        if junk:
            raise XddpError('RT side of {} wrote {} bytes on the socket of an shm link'.format(
                self.path, len(junk)), self.path, errno.EPROTO)
        self._gone = True

    def _shm_read(self, timeout: float | None) -> bytes:
        assert self._region is not None and self._epoll is not None
        ring = self._region.to_nrt
        efd = self._region.efd
        buf = self._buf
        wait = self._epoll.poll
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            n = ring.get_into(buf)
            if n > 0:
                return bytes(buf[:n])
            if n == SHM_DROPPED or n == SHM_CORRUPT:
                continue  # cannot come from our RT side; skipped, look at the next one
            if self._gone:  # what was published before the RT side went is delivered first
                raise BrokenPipeError(errno.EPIPE, 'RT side of {} is gone'.format(self.path))
            pause = -1.0 if deadline is None else max(0.0, deadline - time.monotonic())
            if n < 0:  # a slot not complete yet (weakly ordered stores): look again soon
                pause = 0.0002 if pause < 0 else min(pause, 0.0002)
            events = wait(pause)
            for fd, _ in events:
                if fd == efd:
                    try:
                        os.eventfd_read(efd)  # consumed before the ring is read again
                    except BlockingIOError:
                        pass
                else:
                    self._shm_gone()
            if not events and n == 0 and deadline is not None and time.monotonic() >= deadline:
                raise TimeoutError(errno.ETIMEDOUT, 'nothing received on {} within {}s'.format(
                    self.path, timeout))

    def _shm_write(self, data: bytes | bytearray | memoryview, timeout: float | None) -> None:
        assert self._region is not None and self._spoll is not None
        ring = self._region.to_rt
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            if not self._gone and self._spoll.poll(0):
                self._shm_gone()
            if self._gone:
                raise BrokenPipeError(errno.EPIPE, 'RT side of {} is gone'.format(self.path))
            if ring.put(data):
                # The RT tasks read it at their next cycle; a waiting RT-side user wakes.
                os.eventfd_write(self._region.efd_rt, 1)
                return
            if deadline is not None and time.monotonic() >= deadline:
                raise TimeoutError(errno.ETIMEDOUT, 'write to {} blocked for {}s'.format(
                    self.path, timeout))
            time.sleep(0.0005)  # full: the RT side frees slots as it runs

    def fileno(self) -> int:
        """Return the fd for selectors / poll: the socket's, or with shm an epoll fd."""
        sock = self._live()
        return sock.fileno() if self._epoll is None else self._epoll.fileno()

    @property
    def closed(self) -> bool:
        """Return True once closed."""
        return self._sock is None

    def close(self) -> None:
        """Close the endpoint (the RT side sees EOF and counts a lost peer)."""
        sock, self._sock = self._sock, None
        if sock is not None:
            if self._epoll is not None:
                self._epoll.close()
            if self._region is not None:
                self._region.close()
            sock.close()

    def __enter__(self) -> 'NrtXddpEndpoint':
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return '<NrtXddpEndpoint {} mode={}{}>'.format(
            self.path, self.mode, ' closed' if self.closed else '')


class _NotBoundYet(Exception):
    def __init__(self, err: int, why: str) -> None:
        super().__init__(why)
        self.err = err


def _connect(path: str, mode: str | None, timeout: float) -> tuple[socket.socket, str]:
    for name in (mode,) if mode else ('message', 'stream'):
        sock = socket.socket(socket.AF_UNIX, MODES[name] | socket.SOCK_CLOEXEC)
        try:
            sock.settimeout(timeout)
            sock.connect(path)
        except OSError as exc:
            sock.close()
            if exc.errno == errno.EPROTOTYPE and mode is None:
                continue  # the RT side is in the other mode
            if exc.errno in (errno.ENOENT, errno.ECONNREFUSED):
                raise _NotBoundYet(exc.errno, exc.strerror or '') from None
            if exc.errno == errno.EPROTOTYPE:
                raise XddpPortError('{} is not bound in {} mode'.format(path, mode),
                                    path, exc.errno) from None
            raise XddpError('cannot connect to {}: {}'.format(path, exc.strerror or exc),
                            path, exc.errno) from exc
        return sock, name
    raise XddpError('{} is neither a message nor a stream socket'.format(path), path,
                    errno.EPROTOTYPE)


def nrt_xddp_open(port_or_label: int | str, *, wait: float | None = 0.0,
                  runtime_dir: str | None = None, max_ports: int = DEFAULT_MAX_PORTS,
                  mode: str | None = None,
                  handshake_timeout: float = DEFAULT_HANDSHAKE_TIMEOUT,
                  group: str | int | None = None,
                  transport: str | None = None) -> NrtXddpEndpoint:
    """Open the NRT side of a port by number or label (like ``open('/dev/rtpN')``).

    ``wait=0`` fails fast with XddpNotBoundError, ``None`` waits forever, a float waits that
    many seconds for the RT side to bind. ``mode=None`` detects message or stream mode.
    ``transport=None`` takes the transport the RT side offers; ``'socket'`` or ``'shm'``
    refuses the other one with XddpPortError.
    Raise XddpBusyError when another NRT peer is linked, XddpError when the runtime
    directory fails :func:`check_runtime_dir` (with the configured ``group``).
    """
    if mode is not None and mode not in MODES:
        raise XddpPortError('mode {!r} is not one of {}'.format(mode, sorted(MODES)),
                            None, errno.EINVAL)
    if transport is not None and transport not in TRANSPORTS:
        raise XddpPortError('transport {!r} is not one of {}'.format(
            transport, list(TRANSPORTS)), None, errno.EINVAL)
    path = port_path(port_or_label, runtime_dir, max_ports)
    check_runtime_dir(os.path.dirname(path), group)
    deadline = None if wait is None else time.monotonic() + wait
    while True:
        try:
            sock, found_mode = _connect(path, mode, handshake_timeout)
            try:
                sock.settimeout(handshake_timeout)
                # Message mode: the whole answer (one byte, or the shm offer with its two
                # fds). Stream mode: one byte, the RT side's data may follow right behind it.
                msg, fds, flags, _ = socket.recv_fds(
                    sock, 1 + _SHM_OFFER.size if found_mode == 'message' else 1, 3)
            except TimeoutError:
                sock.close()
                raise XddpError('RT side of {} did not accept within {}s'.format(
                    path, handshake_timeout), path, errno.ETIMEDOUT) from None
            except OSError as exc:
                sock.close()
                raise _NotBoundYet(exc.errno or errno.ECONNRESET,
                                   'reset during handshake') from None
            answer = msg[:1]
            if answer == HANDSHAKE_SHM and transport != 'socket':
                try:
                    if flags & (socket.MSG_CTRUNC | socket.MSG_TRUNC):
                        for fd in fds:
                            os.close(fd)
                        raise XddpError('shm offer of {} truncated'.format(path), path,
                                        errno.EPROTO)
                    region = _shm_accept_offer(msg, fds, path)
                except BaseException:
                    sock.close()
                    raise
                return NrtXddpEndpoint(sock, path, found_mode, region)
            for fd in fds:
                os.close(fd)
            if answer == HANDSHAKE_OK and transport != 'shm':
                return NrtXddpEndpoint(sock, path, found_mode)
            sock.close()
            if answer in (HANDSHAKE_OK, HANDSHAKE_SHM):
                raise XddpPortError('port {!r} ({}) is served over the {} transport; this peer '
                                    'was opened for {}'.format(
                                        port_or_label, path,
                                        'shm' if answer == HANDSHAKE_SHM else 'socket',
                                        transport), path, errno.EPROTONOSUPPORT)
            if answer == HANDSHAKE_BUSY:
                raise XddpBusyError('port {!r} already has an NRT peer: {}'.format(
                    port_or_label, path), path, errno.EBUSY)
            raise _NotBoundYet(errno.ECONNRESET, 'closed during handshake')
        except _NotBoundYet as exc:
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                raise XddpNotBoundError('nothing bound at port {!r} ({}): {}'.format(
                    port_or_label, path, exc), path, exc.err) from None
            pause = _OPEN_RETRY_S if deadline is None else min(_OPEN_RETRY_S, deadline - now)
            time.sleep(pause)


class NrtLink:
    """Auto re-linking NRT endpoint: reads/writes never raise on a missing or lost RT side."""

    def __init__(self, port_or_label: int | str, runtime_dir: str | None = None, *,
                 retry_interval: float = 0.5, max_ports: int = DEFAULT_MAX_PORTS,
                 mode: str | None = None, write_timeout: float | None = 1.0,
                 handshake_timeout: float = DEFAULT_HANDSHAKE_TIMEOUT,
                 group: str | int | None = None, transport: str | None = None) -> None:
        port_path(port_or_label, runtime_dir, max_ports)  # validate now, not on first use
        self.transport = transport
        self.port_or_label = port_or_label
        self.runtime_dir = runtime_dir
        self.group = group
        self.retry_interval = retry_interval
        self.max_ports = max_ports
        self.mode = mode
        self.write_timeout = write_timeout
        self.handshake_timeout = handshake_timeout
        self.links = 0  # successful opens
        self.relinks = 0  # opens after the first
        self.lost = 0  # links that broke
        self.last_error: Exception | None = None
        self._ep: NrtXddpEndpoint | None = None
        self._next_try = 0.0

    @property
    def linked(self) -> bool:
        """Return True while linked to the RT side."""
        return self._ep is not None

    def _link(self) -> NrtXddpEndpoint | None:
        ep = self._ep
        if ep is not None:
            return ep
        now = time.monotonic()
        if now < self._next_try:
            return None
        self._next_try = now + self.retry_interval
        try:
            ep = nrt_xddp_open(self.port_or_label, wait=0.0, runtime_dir=self.runtime_dir,
                               max_ports=self.max_ports, mode=self.mode,
                               handshake_timeout=self.handshake_timeout, group=self.group,
                               transport=self.transport)
        except OSError as exc:  # not bound, busy, permission: keep trying, keep the reason
            self.last_error = exc
            return None
        self._ep = ep
        if self.links:
            self.relinks += 1
        self.links += 1
        return ep

    def _unlink(self, exc: Exception) -> None:
        self.last_error = exc
        self.lost += 1
        if self._ep is not None:
            self._ep.close()
        self._ep = None
        self._next_try = 0.0  # the RT side may already be back: retry at once

    def read(self, timeout: float | None = None) -> bytes | None:
        """Return the next datagram, or None if none arrived (or no link) within ``timeout``."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            ep = self._link()
            now = time.monotonic()
            remaining = None if deadline is None else max(0.0, deadline - now)
            if ep is not None:
                try:
                    return ep.read(remaining)
                except TimeoutError:
                    return None
                except OSError as exc:  # BrokenPipeError and anything else: relink
                    self._unlink(exc)
                    continue
            if remaining is not None and remaining <= 0.0:
                return None
            pause = max(0.0, self._next_try - now)
            time.sleep(pause if remaining is None else min(pause, remaining))

    def write(self, data: bytes | bytearray | memoryview) -> bool:
        """Write one datagram; return False when not linked, lost or timed out."""
        ep = self._link()
        if ep is None:
            return False
        try:
            ep.write(data, self.write_timeout)
        except TimeoutError:
            return False
        except OSError as exc:
            self._unlink(exc)
            return False
        return True

    def fileno(self) -> int:
        """Return the current endpoint's fd, or -1 when unlinked."""
        return self._ep.fileno() if self._ep is not None else -1

    def close(self) -> None:
        """Close the current link."""
        if self._ep is not None:
            self._ep.close()
            self._ep = None

    def __enter__(self) -> 'NrtLink':
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def rt_xddp_bind(port: int, label: str | None = None, **kwargs: Any) -> RtXddpSocket:
    """Bind the RT side of a port (paper-style alias of RtXddpSocket)."""
    return RtXddpSocket(port, label, **kwargs)


def rt_xddp_send(sock: RtXddpSocket, data: bytes | bytearray | memoryview) -> bool:
    """Send one datagram without blocking (paper-style alias)."""
    return sock.send(data)


def rt_xddp_recv(sock: RtXddpSocket, buf: bytearray | memoryview) -> int:
    """Receive one pending datagram into ``buf``; 0 if none (paper-style alias)."""
    return sock.recv_into(buf)


def rt_xddp_close(sock: RtXddpSocket) -> None:
    """Close the RT side of a port (paper-style alias)."""
    sock.close()


def nrt_xddp_read(ep: NrtXddpEndpoint, timeout: float | None = None) -> bytes:
    """Read one datagram (paper-style alias)."""
    return ep.read(timeout)


def nrt_xddp_write(ep: NrtXddpEndpoint, data: bytes | bytearray | memoryview) -> None:
    """Write one datagram (paper-style alias)."""
    ep.write(data)


def nrt_xddp_close(ep: NrtXddpEndpoint) -> None:
    """Close the NRT side (paper-style alias)."""
    ep.close()
