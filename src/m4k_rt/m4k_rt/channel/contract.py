"""The channel's contract: limits, modes, handshake bytes, errors and counters (pure).

Modelled on Xenomai's XDDP (docs/internals.md, "XDDP emulation"). What both sides of a port
agree on lives here, and only here: a port is a number ``0 .. max_ports - 1`` that may carry a
label; message mode keeps datagram boundaries, stream mode carries bytes; at most one NRT peer
is linked per port, told so by one handshake byte (linked, busy, or linked over shared
memory); the RT side never blocks: what it cannot deliver it drops and counts in
:class:`XddpCounters`. Errors form one small hierarchy under :class:`XddpError` (an
``OSError`` carrying the path and errno involved).
"""

from dataclasses import asdict, dataclass
import errno
import re
import socket
from typing import Any

DEFAULT_MAX_PORTS = 32
DEFAULT_POOLSZ = 65536
DEFAULT_MAX_DATAGRAM = 4096
DEFAULT_HANDSHAKE_TIMEOUT = 5.0  # the RT side accepts when its task polls: one period at most
HANDSHAKE_OK = b'\x01'
HANDSHAKE_BUSY = b'\x00'
HANDSHAKE_SHM = b'\x02'  # linked, datagrams go through the shared-memory rings passed along
MODES = {'message': socket.SOCK_SEQPACKET, 'stream': socket.SOCK_STREAM}
MIN_POOLSZ = 1024

SEND_FLAGS = socket.MSG_DONTWAIT | socket.MSG_NOSIGNAL
PEER_GONE = (errno.EPIPE, errno.ECONNRESET, errno.ENOTCONN, errno.ECONNREFUSED)
_LABEL_RE = re.compile(r'[A-Za-z0-9_][A-Za-z0-9_.-]{0,31}\Z')


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



def check_port(port: Any, max_ports: int) -> int:
    """Return ``port`` when it is an int in ``[0, max_ports)``, else raise XddpPortError."""
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port < max_ports:
        raise XddpPortError('port {!r} is not an integer in [0, {})'.format(port, max_ports),
                            None, errno.EINVAL)
    return port


def check_label(label: Any) -> str:
    """Return ``label`` when it is a valid XDDP_LABEL, else raise XddpPortError."""
    if not isinstance(label, str) or not _LABEL_RE.match(label):
        raise XddpPortError('label {!r} must be 1-32 characters of [A-Za-z0-9_.-] not starting '
                            'with . or -'.format(label), None, errno.EINVAL)
    return label


def check_mode(mode: Any) -> str:
    """Return ``mode`` when it is 'message' or 'stream', else raise XddpPortError."""
    if not isinstance(mode, str) or mode not in MODES:
        raise XddpPortError('mode {!r} is not one of {}'.format(mode, sorted(MODES)),
                            None, errno.EINVAL)
    return mode


def check_sizes(poolsz: Any, max_datagram: Any) -> None:
    """Raise XddpPortError unless every datagram fits half a kernel buffer (all-or-nothing)."""
    if isinstance(poolsz, bool) or not isinstance(poolsz, int) or poolsz < MIN_POOLSZ:
        raise XddpPortError('poolsz {!r} must be an int >= {}'.format(poolsz, MIN_POOLSZ),
                            None, errno.EINVAL)
    if (isinstance(max_datagram, bool) or not isinstance(max_datagram, int)
            or not 1 <= max_datagram <= poolsz // 2):
        raise XddpPortError('max_datagram {!r} must be in [1, poolsz // 2 = {}]'.format(
            max_datagram, poolsz // 2), None, errno.EINVAL)
