"""The paper's names for the channel (Delgado et al. 2019, after Xenomai's XDDP API).

A thin layer over the classes: ``rt_xddp_bind`` binds the RT side of a port over the
configured transport, ``nrt_xddp_open`` opens the NRT side like ``open("/dev/rtpN")``, and the
rest call the objects' methods.
"""

from typing import Any

from m4k_rt.channel.endpoint import NrtXddpEndpoint
from m4k_rt.channel.nrt import nrt_xddp_open
from m4k_rt.channel.port import RtXddpSocket
from m4k_rt.channel.transports import rt_port_class

__all__ = ['nrt_xddp_close', 'nrt_xddp_open', 'nrt_xddp_read', 'nrt_xddp_write',
           'rt_xddp_bind', 'rt_xddp_close', 'rt_xddp_recv', 'rt_xddp_send']


def rt_xddp_bind(port: int, label: str | None = None, *, transport: str | None = None,
                 **kwargs: Any) -> RtXddpSocket:
    """Bind the RT side of a port over ``transport`` (None: the default transport)."""
    return rt_port_class(transport)(port, label, **kwargs)


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
