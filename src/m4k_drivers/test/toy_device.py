"""A device package written from outside m4k_drivers: what adding a device takes.

Kind ``toy``: a one-register output whose register is a file (the ``real`` backend's
``path``), standing in for a sysfs attribute.  The package registers, like every built-in
device, its backend and the service that answers the RT side -- nothing in the driver host
names it.  The service takes REQUEST(request_id, arg): it writes ``arg`` to the register
(arg 0: read only), reads it back and answers REQUEST(request_id, value read); each loop pass
while active counts a tick; when the RT side goes away the register goes to 0 at once
(outputs safe), and deactivate does the same.  ``driver_host --device-module toy_device``
loads it.
"""

from __future__ import annotations

from typing import Any, Callable, Mapping

from m4k_drivers.handler import DeviceHandler, DeviceIOError, State, wrap_os_error
from m4k_drivers.registry import (
    BuildContext,
    Param,
    register,
    register_service,
    Replier,
    ServiceSpec,
)
from m4k_rt.protocol import Kind

SAFE = 0


class Register:
    """The transport: one integer in a file."""

    def __init__(self, path: str) -> None:
        try:
            with open(path, encoding='ascii'):
                pass
        except OSError as exc:
            raise wrap_os_error(exc, path) from exc
        self.path = path

    def write(self, value: int) -> None:
        with open(self.path, 'w', encoding='ascii') as fh:
            fh.write(f'{value}\n')

    def read(self) -> int:
        with open(self.path, encoding='ascii') as fh:
            text = fh.read().strip()
        try:
            return int(text)
        except ValueError as exc:
            raise DeviceIOError(f'{self.path}: not a number: {text!r}') from exc


class ToyHandler(DeviceHandler):
    """Lifecycle handler around an opener, like the built-in ones."""

    kind = 'toy'

    def __init__(self, opener: Callable[[], Register], *, name: str = 'toy',
                 **kw: Any) -> None:
        super().__init__(name, **kw)
        self._opener = opener
        self.reg: Register | None = None
        self.ticks = 0

    def on_configure(self) -> None:
        self.reg = self._opener()
        self.reg.write(SAFE)

    def on_write(self, command: int) -> None:
        assert self.reg is not None
        self.reg.write(command)

    def on_read(self) -> int:
        assert self.reg is not None
        return self.reg.read()

    def on_deactivate(self) -> None:
        self.make_safe()

    def on_cleanup(self) -> None:
        self.reg = None

    def make_safe(self) -> None:
        if self.reg is not None:
            self.reg.write(SAFE)


@register('toy', 'real', params={'path': Param(str, doc='file holding the register'),
                                 'poll_s': Param(float, 0.05, 'loop tick, s')})
def _build(name: str, params: dict[str, Any], ctx: BuildContext) -> ToyHandler:
    return ToyHandler(lambda: Register(params['path']), name=name)


def serve(handler: ToyHandler, msg: Any, tx: Replier) -> None:
    if handler.state != State.ACTIVE:
        return
    if msg.arg:
        handler.write(msg.arg)
    r = handler.read()
    if r.error is None:
        tx.send(Kind.REQUEST, msg.request_id, r.value)


def _tick(handler: ToyHandler) -> None:
    handler.ticks += 1


def _poll(section: Mapping[str, Any]) -> float:
    return float(section['poll_s'])


register_service('toy', ServiceSpec(
    accepts=frozenset({Kind.REQUEST}), serve=serve, format=lambda v: f'toy value={v}',
    read_timeout=_poll, tick=_tick, on_link_lost=ToyHandler.make_safe, path_key='path'))
