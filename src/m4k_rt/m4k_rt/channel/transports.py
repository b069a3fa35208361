"""The one place a transport is chosen: by name on the RT side, by the answer on the NRT side.

A transport is a pair of classes: the RT side's port (:class:`RtXddpSocket` over the socket,
:class:`RtShmSocket` over shared-memory rings) and the NRT side's endpoint. Each class names its
transport and the RT class the handshake byte it links with, so the names below are derived,
never restated (``runtime.transport`` in the configuration schema takes its choices and
default from here).
"""

import errno

from m4k_rt.channel.contract import XddpPortError
from m4k_rt.channel.endpoint import NrtShmEndpoint, NrtXddpEndpoint
from m4k_rt.channel.port import RtXddpSocket
from m4k_rt.channel.shm import RtShmSocket

_RT: dict[str, type[RtXddpSocket]] = {c.transport: c for c in (RtXddpSocket, RtShmSocket)}
_NRT: dict[str, type[NrtXddpEndpoint]] = {
    c.transport: c for c in (NrtXddpEndpoint, NrtShmEndpoint)}
_BY_ANSWER: dict[bytes, str] = {c.handshake: name for name, c in _RT.items()}

TRANSPORTS: tuple[str, ...] = tuple(_RT)
DEFAULT_TRANSPORT = 'socket'  # measured against shm and kept (docs/design-notes.md, 9c)
ANSWER_SIZE = max(c.answer_size for c in _NRT.values())  # the longest handshake answer
ANSWER_FDS = max(c.answer_fds for c in _NRT.values())


def check_transport(name: object) -> str:
    """Return ``name`` when it names a transport, else raise XddpPortError."""
    if not isinstance(name, str) or name not in _RT:
        raise XddpPortError('transport {!r} is not one of {}'.format(name, list(TRANSPORTS)),
                            None, errno.EINVAL)
    return name


def rt_port_class(name: str | None = None) -> type[RtXddpSocket]:
    """Return the RT port class of transport ``name`` (None: the default)."""
    return _RT[check_transport(DEFAULT_TRANSPORT if name is None else name)]


def answered(answer: bytes) -> str | None:
    """Return the transport an RT side's handshake answer links over; None: not linked."""
    return _BY_ANSWER.get(answer)


def nrt_endpoint_class(name: str) -> type[NrtXddpEndpoint]:
    """Return the NRT endpoint class of transport ``name``."""
    return _NRT[name]
