"""LED handler: LED datagrams -> the strip; deactivate turns it off."""

from __future__ import annotations

from typing import Any, Callable, Protocol

from m4k_drivers.handler import DeviceHandler, DeviceProtocolError
from m4k_drivers.led import protocol as p

__all__ = ['LedHandler', 'LedOutput']


class LedOutput(Protocol):
    """LedClassOutput, LedClassRgbOutput, PwmOutput provide this (/sys or a sim tree)."""

    def show(self, color: p.LedColor) -> None:
        """Show one colour."""

    def close(self) -> None:
        """Release the output."""


class LedHandler(DeviceHandler):
    """Lifecycle handler for the NS-LED-02 strip; read() returns the colour last shown."""

    kind = 'led'

    def __init__(self, opener: Callable[[], LedOutput], *, name: str = 'led',
                 **kw: Any) -> None:
        super().__init__(name, **kw)
        self._opener = opener
        self.out: LedOutput | None = None
        self.shown = p.OFF

    def on_configure(self) -> None:
        """Open the output and turn it off."""
        self.out = self._opener()
        self.out.show(p.OFF)
        self.shown = p.OFF

    def on_write(self, command: p.LedColor) -> None:
        """Show a validated colour."""
        assert self.out is not None
        try:
            color = p.LedColor(*command).validated()
        except (TypeError, ValueError) as exc:
            raise DeviceProtocolError(f'{self.name}: bad colour {command!r}: {exc}') from exc
        self.out.show(color)
        self.shown = color

    def on_read(self) -> p.LedColor:
        """Return the colour last shown."""
        return self.shown

    def on_deactivate(self) -> None:
        """Turn the strip off."""
        if self.out is not None:
            self.out.show(p.OFF)
            self.shown = p.OFF

    def on_cleanup(self) -> None:
        """Release the output."""
        if self.out is not None:
            self.out.close()
            self.out = None
