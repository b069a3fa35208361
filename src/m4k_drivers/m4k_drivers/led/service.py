"""How the driver host serves the LED strip: LED -> strip (no reply)."""

from __future__ import annotations

from m4k_drivers.handler import State
from m4k_drivers.led.handler import LedHandler
from m4k_drivers.led.protocol import LedColor, to_hex
from m4k_drivers.registry import Replier, ServiceSpec
from m4k_rt.protocol import Kind, Led

__all__ = ['SERVICE']


def serve(handler: LedHandler, msg: Led, tx: Replier) -> None:
    """Show the colour the RT side chose."""
    if handler.state == State.ACTIVE:
        handler.write((msg.r, msg.g, msg.b, msg.brightness))


def format_reading(value: LedColor) -> str:
    """Return the ``--print`` line: the colour shown."""
    return f'led shown={to_hex(value)}'


SERVICE: ServiceSpec[LedHandler] = ServiceSpec(
    accepts=frozenset({Kind.LED}), serve=serve, format=format_reading, path_key='name')
