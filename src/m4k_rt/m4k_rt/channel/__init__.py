"""The channel between RT tasks and NRT processes: Xenomai's XDDP, emulated over Unix sockets.

Read it as the paper's figure, one module per part:

* :mod:`~m4k_rt.channel.contract` -- limits, modes, handshake bytes, errors, counters;
* :mod:`~m4k_rt.channel.rundir` -- the runtime directory and who may reach a port;
* :mod:`~m4k_rt.channel.port` -- the RT side over the socket transport (:class:`RtXddpSocket`);
* :mod:`~m4k_rt.channel.shm`, :mod:`~m4k_rt.channel.shmring` -- the RT side over shared-memory
  rings (:class:`RtShmSocket`), opt-in;
* :mod:`~m4k_rt.channel.endpoint`, :mod:`~m4k_rt.channel.nrt` -- the NRT side: the endpoint of
  a linked port, :func:`nrt_xddp_open` and the self-re-linking :class:`NrtLink`;
* :mod:`~m4k_rt.channel.transports` -- the one place a transport is chosen;
* :mod:`~m4k_rt.channel.paper` -- the paper's names (``rt_xddp_bind``, ``nrt_xddp_open``, ...).

The names users need are importable from the package itself (``from m4k_rt import channel``).
"""

from m4k_rt.channel.contract import (
    DEFAULT_HANDSHAKE_TIMEOUT,
    DEFAULT_MAX_DATAGRAM,
    DEFAULT_MAX_PORTS,
    DEFAULT_POOLSZ,
    HANDSHAKE_BUSY,
    HANDSHAKE_OK,
    HANDSHAKE_SHM,
    MODES,
    XddpBusyError,
    XddpCounters,
    XddpError,
    XddpNotBoundError,
    XddpPortError,
)
from m4k_rt.channel.endpoint import NrtShmEndpoint, NrtXddpEndpoint
from m4k_rt.channel.nrt import NrtLink
from m4k_rt.channel.paper import (
    nrt_xddp_close,
    nrt_xddp_open,
    nrt_xddp_read,
    nrt_xddp_write,
    rt_xddp_bind,
    rt_xddp_close,
    rt_xddp_recv,
    rt_xddp_send,
)
from m4k_rt.channel.port import RtXddpSocket
from m4k_rt.channel.rundir import (
    check_runtime_dir,
    default_runtime_dir,
    ensure_runtime_dir,
    port_path,
)
from m4k_rt.channel.shm import RtShmSocket
from m4k_rt.channel.transports import DEFAULT_TRANSPORT, TRANSPORTS

__all__ = [
    'check_runtime_dir', 'default_runtime_dir', 'DEFAULT_HANDSHAKE_TIMEOUT',
    'DEFAULT_MAX_DATAGRAM', 'DEFAULT_MAX_PORTS', 'DEFAULT_POOLSZ', 'DEFAULT_TRANSPORT',
    'ensure_runtime_dir', 'HANDSHAKE_BUSY', 'HANDSHAKE_OK', 'HANDSHAKE_SHM', 'MODES',
    'nrt_xddp_close', 'nrt_xddp_open', 'nrt_xddp_read', 'nrt_xddp_write', 'NrtLink',
    'NrtShmEndpoint', 'NrtXddpEndpoint', 'port_path', 'rt_xddp_bind', 'rt_xddp_close',
    'rt_xddp_recv', 'rt_xddp_send', 'RtShmSocket', 'RtXddpSocket', 'TRANSPORTS',
    'XddpBusyError', 'XddpCounters', 'XddpError', 'XddpNotBoundError', 'XddpPortError',
]
