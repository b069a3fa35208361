"""A live-view viewer for the bench: a Foxglove WebSocket client subscribed to everything.

The ``m4k_live`` condition runs the full stack with the live view (``m4k_bridge.foxglove``)
and this client reading every channel the server advertises, as a Foxglove window would, so
the RT tasks' timing is measured with the live view busy. It counts what it receives; it
decodes nothing (the cost under test is the server's, not the viewer's).
"""

from __future__ import annotations

import asyncio
import json
import socket
import threading
import time
from typing import Any

__all__ = ['LiveClient', 'free_port']

SUB = 'foxglove.websocket.v1'


def free_port() -> int:
    """Return a TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return int(s.getsockname()[1])


class LiveClient:
    """Connect (retrying while the server starts), subscribe to every channel, count."""

    def __init__(self, port: int, connect_timeout_s: float = 30.0) -> None:
        self.port = port
        self.connect_timeout_s = connect_timeout_s
        self.messages = 0
        self.bytes = 0
        self.channels = 0
        self.error: str | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name='liveclient', daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            asyncio.run(self._main())
        except Exception as exc:  # noqa: BLE001 -- reported with the run, never raised
            self.error = '{}: {}'.format(type(exc).__name__, exc)

    async def _main(self) -> None:
        from websockets.asyncio.client import connect
        from websockets.typing import Subprotocol

        deadline = time.monotonic() + self.connect_timeout_s
        while True:
            try:
                ws = await connect('ws://127.0.0.1:{}'.format(self.port),
                                   subprotocols=[Subprotocol(SUB)], max_size=None)
                break
            except OSError:
                if time.monotonic() > deadline or self._stop.is_set():
                    raise
                await asyncio.sleep(0.2)
        async with ws:
            next_id = 0
            while not self._stop.is_set():
                try:
                    msg: Any = await asyncio.wait_for(ws.recv(), 0.2)
                except asyncio.TimeoutError:
                    continue
                if isinstance(msg, str):
                    doc = json.loads(msg)
                    if doc.get('op') == 'advertise':
                        subs = []
                        for ch in doc['channels']:
                            subs.append({'id': next_id, 'channelId': ch['id']})
                            next_id += 1
                        self.channels += len(subs)
                        await ws.send(json.dumps({'op': 'subscribe', 'subscriptions': subs}))
                else:
                    self.messages += 1
                    self.bytes += len(msg)

    def stop(self) -> dict[str, Any]:
        """Stop reading; return what was received (and the error, if any)."""
        self._stop.set()
        self._thread.join(10.0)
        return {'messages': self.messages, 'bytes': self.bytes, 'channels': self.channels,
                'error': self.error}
