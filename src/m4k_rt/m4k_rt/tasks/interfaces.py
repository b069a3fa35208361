"""The typed interfaces a task body is written against (structural: ``typing.Protocol``).

A body never sees the XDDP socket class or the task class, only what it uses of them, so
strict mypy checks every body against these and a test double needs only these methods.
"""

from __future__ import annotations

from typing import Any, Callable, Mapping, Protocol, runtime_checkable, TypeAlias

from m4k_rt.config import TaskConfig

__all__ = ['Body', 'BodyFactory', 'CycleContext', 'RtPort']


@runtime_checkable
class RtPort(Protocol):
    """The RT side of one XDDP port, as a body uses it (:class:`m4k_rt.channel.RtXddpSocket`)."""

    def send(self, data: bytes | bytearray | memoryview, /) -> bool:
        """Send one datagram without blocking; False when dropped (the socket counts why)."""

    def recv_into(self, buf: bytearray | memoryview, /) -> int:
        """Receive one pending datagram into ``buf``; its size, or 0 when none is pending."""

    def count_malformed(self) -> None:
        """Count a datagram the body rejected (shown in the port's statistics)."""


@runtime_checkable
class CycleContext(Protocol):
    """What a body reads of its task each cycle (:class:`m4k_rt.task.RtTask`)."""

    @property
    def t_start(self) -> int:
        """Monotonic ns at which this cycle started, after the wait for its release."""

    @property
    def cycles(self) -> int:
        """Cycles completed before this one."""


Body: TypeAlias = Callable[[CycleContext], object]
# factory(task, ports by label, the RT process's shared object) -> the per-cycle body
BodyFactory: TypeAlias = Callable[[TaskConfig, Mapping[str, RtPort], Any], Body]
