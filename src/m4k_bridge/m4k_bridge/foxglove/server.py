"""The Foxglove WebSocket server: an asyncio ``websockets`` server on its own thread.

The ROS side (:mod:`m4k_bridge.foxglove.node`) calls :meth:`Server.publish` and friends from
its executor thread; they only append to per-client queues under a lock and wake the client's
writer task, so a slow or stalled client never blocks ROS. Each client has two bounded
queues: control messages (advertise, status, parameter values, service responses: never
dropped; a client that lets more than ``max_control`` of them pile up is not reading and is
disconnected) and message data, bounded by count and bytes, where the oldest frame is dropped
and counted when a new one does not fit (the newest data is what a live view wants). What a
client sends is handed to a :class:`Handler` on the server thread.

Who may connect, and with which right, is decided in the opening handshake, before anything
is sent or imported (:meth:`Server._admit`): a foreign ``Origin`` gets HTTP 403, a missing or
wrong token HTTP 401, one client more than ``max_clients`` HTTP 503 -- a refused browser page
never sees ``serverInfo``. Each client's ``serverInfo`` lists only the capabilities its right
allows (:func:`m4k_bridge.foxglove.rights.capabilities`: a view client gets no
``clientPublish`` and no ``services``), and it is told of, and may call, only the services
its right allows. A client may advertise at most ``max_client_channels`` channels.
"""

from __future__ import annotations

import asyncio
import collections
import dataclasses
from http import HTTPStatus
import itertools
import json
import ssl
import threading
import time
from typing import Any, Deque, Protocol
import weakref

from websockets.asyncio.server import serve, ServerConnection
from websockets.exceptions import ConnectionClosed
from websockets.http11 import Request, Response

from m4k_bridge.foxglove import protocol as fp
from m4k_bridge.foxglove.access import Credentials, DEFAULT_ORIGINS, OriginPolicy, presented_tokens
from m4k_bridge.foxglove.rights import at_least
from m4k_bridge.foxglove.rights import capabilities as right_capabilities

__all__ = ['ClientStats', 'Handler', 'Server']

LATCHED_DEPTH = 8      # distinct last messages kept per latched channel for late joiners
MAX_INCOMING = 1 << 20  # bytes of one client message (commands are tiny)


class Handler(Protocol):
    """What the server hands to the ROS side (called on the server thread)."""

    def on_client_advertise(self, client: int, channel: dict[str, Any]) -> str | None:
        """Accept a client channel; return an error text to refuse it."""

    def on_client_unadvertise(self, client: int, channel_id: int) -> None:
        """Forget a client channel (unadvertised, or its client disconnected)."""

    def on_client_message(self, client: int, channel_id: int, payload: bytes) -> None:
        """Publish what a client sent on one of its channels."""

    def on_get_parameters(self, client: int, names: list[str], request_id: str | None) -> None:
        """Answer with :meth:`Server.send_text` (``parameterValues``)."""

    def on_service_call(self, client: int, service_id: int, call_id: int, encoding: str,
                        payload: bytes) -> None:
        """Answer with :meth:`Server.send_binary` (a service call response)."""

    def on_client_gone(self, client: int) -> None:
        """Forget a client that disconnected (after its channels' unadvertise)."""


@dataclasses.dataclass
class ClientStats:
    """One client's counters (diagnostics)."""

    id: int
    address: str
    right: str
    subscriptions: int
    sent: int
    dropped: int
    queued: int
    queued_bytes: int


class _Client:
    def __init__(self, cid: int, ws: ServerConnection, loop: asyncio.AbstractEventLoop,
                 right: str) -> None:
        self.id = cid
        self.right = right
        self.ws = ws
        self.loop = loop
        self.address = '{}:{}'.format(*ws.remote_address[:2]) if ws.remote_address else '?'
        self.subs: dict[int, int] = {}          # subscription id -> channel id
        self.by_channel: dict[int, int] = {}    # channel id -> subscription id
        self.channels: set[int] = set()         # client-advertised channel ids
        self.control: Deque[str | bytes] = collections.deque()
        self.data: Deque[bytes] = collections.deque()
        self.data_bytes = 0
        self.sent = 0
        self.dropped = 0
        self.overrun = False
        self.event = asyncio.Event()
        self.wake_pending = False


class Server:
    """Serve channels to Foxglove clients; thread-safe entry points for the ROS side."""

    def __init__(self, handler: Handler, host: str = '127.0.0.1', port: int = 8765,
                 name: str = 'm4k', capabilities: tuple[str, ...] = (),
                 encodings: tuple[str, ...] = ('cdr',), max_queue_messages: int = 200,
                 max_queue_bytes: int = 8 << 20, max_control: int = 1000,
                 origins: OriginPolicy | None = None, credentials: Credentials | None = None,
                 max_clients: int = 4, max_client_channels: int = 16,
                 metadata: dict[str, str] | None = None,
                 tls: ssl.SSLContext | None = None) -> None:
        self.handler = handler
        self.metadata = dict(metadata or {})
        # Never unchecked: a server built without a policy gets the default allow-list.
        self.origins = origins if origins is not None else OriginPolicy(DEFAULT_ORIGINS)
        # Never unchecked either: no credentials is everyone admitted with the drive right.
        self.credentials = credentials if credentials is not None else Credentials('drive')
        self.tls = tls
        self._rights: weakref.WeakKeyDictionary[ServerConnection, str] = \
            weakref.WeakKeyDictionary()
        self.max_clients, self.max_client_channels = max_clients, max_client_channels
        self.refused: collections.Counter[str] = collections.Counter()   # why -> handshakes
        self.host, self.port, self.name = host, port, name
        self.capabilities, self.encodings = capabilities, encodings
        self.max_queue_messages, self.max_queue_bytes = max_queue_messages, max_queue_bytes
        self.max_control = max_control
        self.session_id = str(time.time_ns())
        self._lock = threading.Lock()
        self._clients: dict[int, _Client] = {}
        self._channels: dict[int, dict[str, Any]] = {}
        self._latched: dict[int, Deque[bytes]] = {}
        self._services: dict[int, dict[str, Any]] = {}
        self._service_rights: dict[int, str] = {}    # service id -> the right it needs
        self._ids = itertools.count(1)
        self._channel_ids = itertools.count(1)
        self.dropped_departed = 0      # drops of clients that have left
        self.clients_total = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._thread: threading.Thread | None = None
        self._started = threading.Event()
        self._error: BaseException | None = None

    # --- lifecycle -------------------------------------------------------------------------
    def start(self, timeout: float = 10.0) -> None:
        """Start listening (on a daemon thread); raise OSError when the port cannot be bound."""
        self._thread = threading.Thread(target=self._run, name='foxglove-ws', daemon=True)
        self._thread.start()
        if not self._started.wait(timeout):
            raise RuntimeError('the websocket server did not start within {} s'.format(timeout))
        if self._error is not None:
            raise self._error

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._serve())
        finally:
            loop.close()

    async def _serve(self) -> None:
        self._stop = asyncio.Event()
        try:
            server = await serve(self._handle, self.host, self.port,
                                 subprotocols=[fp.SUBPROTOCOL],  # type: ignore[list-item]
                                 process_request=self._admit, ssl=self.tls,
                                 max_size=MAX_INCOMING, compression=None)
        except OSError as exc:
            self._error = exc
            self._started.set()
            return
        self.port = server.sockets[0].getsockname()[1]   # the real one when asked for 0
        self._started.set()
        async with server:
            await self._stop.wait()
            server.close()

    def stop(self) -> None:
        """Close every connection and stop the thread."""
        loop, stop = self._loop, self._stop
        if loop is not None and stop is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(stop.set)
            except RuntimeError:
                pass
        if self._thread is not None:
            self._thread.join(5.0)

    # --- the ROS side: channels, data, services (any thread) --------------------------------
    def add_channel(self, topic: str, schema_name: str, schema: str) -> int:
        """Advertise a ``cdr``/``ros2msg`` channel to every client; return its id."""
        with self._lock:
            cid = next(self._channel_ids)
            chan = {'id': cid, 'topic': topic, 'encoding': 'cdr', 'schemaName': schema_name,
                    'schema': schema, 'schemaEncoding': 'ros2msg'}
            self._channels[cid] = chan
            text = fp.advertise([chan])
            for c in self._clients.values():
                self._control(c, text)
        return cid

    def remove_channel(self, channel_id: int) -> None:
        """Unadvertise a channel (its topic has gone) and end its subscriptions."""
        with self._lock:
            if self._channels.pop(channel_id, None) is None:
                return
            self._latched.pop(channel_id, None)
            text = fp.unadvertise([channel_id])
            for c in self._clients.values():
                sub = c.by_channel.pop(channel_id, None)
                if sub is not None:
                    c.subs.pop(sub, None)
                self._control(c, text)

    def set_services(self, services: list[tuple[dict[str, Any], str]]) -> None:
        """Advertise services: (dict with id, name, type, request, response; right needed).

        Each client is told of the services its right lets it call, and only those.
        """
        with self._lock:
            new = [(s, r) for s, r in services if s['id'] not in self._services]
            for s, r in new:
                self._services[s['id']] = s
                self._service_rights[s['id']] = r
            for c in self._clients.values():
                mine = [s for s, r in new if at_least(c.right, r)]
                if mine:
                    self._control(c, fp.advertise_services(mine))

    def _visible_services(self, c: _Client) -> list[dict[str, Any]]:
        return [s for sid, s in self._services.items()
                if at_least(c.right, self._service_rights[sid])]

    def client_right(self, client: int) -> str | None:
        """Return the right of a connected client (None: gone)."""
        with self._lock:
            c = self._clients.get(client)
            return None if c is None else c.right

    def client_name(self, client: int) -> str:
        """Return ``client N (address)`` for status texts and logs."""
        with self._lock:
            c = self._clients.get(client)
            return 'client {} ({})'.format(client, c.address if c is not None else 'gone')

    def publish(self, channel_id: int, payload: bytes, receive_ns: int = 0,
                latched: bool = False) -> None:
        """Queue one message to every client subscribed to ``channel_id`` (never blocks)."""
        now = receive_ns or time.time_ns()
        with self._lock:
            if latched:
                cache = self._latched.setdefault(channel_id,
                                                 collections.deque(maxlen=LATCHED_DEPTH))
                if payload not in cache:
                    cache.append(payload)
            for c in self._clients.values():
                sub = c.by_channel.get(channel_id)
                if sub is not None:
                    self._data(c, fp.message_data(sub, now, payload))

    def send_text(self, client: int, text: str) -> None:
        """Queue a JSON message to one client (a reply)."""
        with self._lock:
            c = self._clients.get(client)
            if c is not None:
                self._control(c, text)

    def send_binary(self, client: int, frame: bytes) -> None:
        """Queue a binary control frame (a service call response) to one client."""
        with self._lock:
            c = self._clients.get(client)
            if c is not None:
                self._control(c, frame)

    def broadcast_status(self, level: int, message: str) -> None:
        """Send a status message to every client."""
        text = fp.status(level, message)
        with self._lock:
            for c in self._clients.values():
                self._control(c, text)

    def stats(self) -> list[ClientStats]:
        """Return each connected client's counters."""
        with self._lock:
            return [ClientStats(c.id, c.address, c.right, len(c.subs), c.sent, c.dropped,
                                len(c.data), c.data_bytes) for c in self._clients.values()]

    # --- queues (caller holds the lock) -----------------------------------------------------
    def _control(self, c: _Client, item: str | bytes) -> None:
        if len(c.control) >= self.max_control:
            c.overrun = True      # not reading at all: the writer closes the connection
        else:
            c.control.append(item)
        self._wake(c)

    def _data(self, c: _Client, frame: bytes) -> None:
        while c.data and (len(c.data) >= self.max_queue_messages
                          or c.data_bytes + len(frame) > self.max_queue_bytes):
            c.data_bytes -= len(c.data.popleft())
            c.dropped += 1
        if len(frame) > self.max_queue_bytes:
            c.dropped += 1
            return
        c.data.append(frame)
        c.data_bytes += len(frame)
        self._wake(c)

    @staticmethod
    def _wake(c: _Client) -> None:
        if not c.wake_pending:
            c.wake_pending = True
            try:
                c.loop.call_soon_threadsafe(c.event.set)
            except RuntimeError:   # loop closed: the server is stopping
                pass

    # --- one connection (server thread) -----------------------------------------------------
    def _admit(self, conn: ServerConnection, request: Request) -> Response | None:
        """Refuse a handshake by Origin, token or client count (None: go on with it)."""
        origins = request.headers.get_all('Origin')
        origin = origins[0] if len(origins) == 1 else None
        if len(origins) > 1 or not self.origins.allows(origin):
            self.refused['origin'] += 1
            return conn.respond(HTTPStatus.FORBIDDEN, (
                'Origin {!r} may not open this live view (m4k_foxglove allowed_origins)\n'
                .format(origin if len(origins) == 1 else origins)[:300]))
        right = self.credentials.right(presented_tokens(
            request.path, request.headers.get_all('Authorization'),
            request.headers.get_all('Sec-WebSocket-Protocol')))
        if right is None:
            self.refused['token'] += 1
            return conn.respond(HTTPStatus.UNAUTHORIZED, (
                'this live view needs a valid token: ws://<host>:<port>/?token=<token>, '
                'Authorization: Bearer <token>, or subprotocol m4k-token.<token> (one)\n'))
        with self._lock:
            full = len(self._clients) >= self.max_clients
        if full:
            self.refused['clients'] += 1
            return conn.respond(HTTPStatus.SERVICE_UNAVAILABLE, (
                'this live view already serves {} clients (m4k_foxglove max_clients)\n'
                .format(self.max_clients)))
        self._rights[conn] = right
        return None

    async def _handle(self, ws: ServerConnection) -> None:
        if ws.subprotocol != fp.SUBPROTOCOL:
            await ws.close(1002, 'subprotocol {} required'.format(fp.SUBPROTOCOL))
            return
        c = _Client(next(self._ids), ws, asyncio.get_running_loop(),
                    self._rights.pop(ws, 'view'))
        with self._lock:
            # Handshakes admitted together may pass _admit together: this is the real count.
            full = len(self._clients) >= self.max_clients
            if not full:
                self._clients[c.id] = c
        if full:
            self.refused['clients'] += 1
            await ws.close(1013, 'too many clients (max_clients {})'.format(self.max_clients))
            return
        with self._lock:
            self.clients_total += 1
            self._control(c, fp.server_info(self.name, self._capabilities(c), self.encodings,
                                            self.session_id, self.metadata))
            self._control(c, fp.advertise(list(self._channels.values())))
            services = self._visible_services(c)
            if services and 'services' in self._capabilities(c):
                self._control(c, fp.advertise_services(services))
        writer = asyncio.create_task(self._writer(c))
        try:
            async for msg in ws:
                try:
                    if isinstance(msg, str):
                        self._on_text(c, msg)
                    else:
                        self._on_binary(c, msg)
                except fp.ProtocolError as exc:
                    self.send_text(c.id, fp.status(2, str(exc)))
        except ConnectionClosed:
            pass
        finally:
            writer.cancel()
            with self._lock:
                self._clients.pop(c.id, None)
                self.dropped_departed += c.dropped
                channels = sorted(c.channels)
            for ch in channels:
                self.handler.on_client_unadvertise(c.id, ch)
            self.handler.on_client_gone(c.id)

    def _capabilities(self, c: _Client) -> tuple[str, ...]:
        return right_capabilities(c.right, self.capabilities)

    async def _writer(self, c: _Client) -> None:
        try:
            while True:
                await c.event.wait()
                c.event.clear()
                with self._lock:
                    c.wake_pending = False
                while True:
                    with self._lock:
                        if c.overrun:
                            item: str | bytes | None = None
                        elif c.control:
                            item = c.control.popleft()
                        elif c.data:
                            item = c.data.popleft()
                            c.data_bytes -= len(item)
                        else:
                            break
                    if item is None:
                        await c.ws.close(1008, 'client not reading')
                        return
                    await c.ws.send(item)
                    c.sent += 1
        except ConnectionClosed:
            pass

    def _on_text(self, c: _Client, text: str) -> None:
        try:
            doc = json.loads(text)
        except ValueError:
            raise fp.ProtocolError('not JSON: {!r}'.format(text[:80])) from None
        if not isinstance(doc, dict):
            raise fp.ProtocolError('a JSON message must be an object')
        op = doc.get('op')
        try:
            if op == 'subscribe':
                self._subscribe(c, doc['subscriptions'])
            elif op == 'unsubscribe':
                with self._lock:
                    for sid in doc['subscriptionIds']:
                        ch = c.subs.pop(int(sid), None)
                        if ch is not None:
                            c.by_channel.pop(ch, None)
            elif op == 'advertise':
                self._client_advertise(c, doc['channels'])
            elif op == 'unadvertise':
                for ch in doc['channelIds']:
                    if int(ch) in c.channels:
                        c.channels.discard(int(ch))
                        self.handler.on_client_unadvertise(c.id, int(ch))
            elif op == 'getParameters':
                rid = doc.get('id')
                self.handler.on_get_parameters(c.id, [str(n) for n in doc['parameterNames']],
                                               None if rid is None else str(rid))
            elif op in ('setParameters', 'subscribeParameterUpdates',
                        'unsubscribeParameterUpdates'):
                raise fp.ProtocolError('{}: parameters are read-only here'.format(op))
            else:
                raise fp.ProtocolError('unsupported op {!r}'.format(op))
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, fp.ProtocolError):
                raise
            raise fp.ProtocolError('{}: malformed ({}: {})'.format(
                op, type(exc).__name__, exc)) from None

    def _subscribe(self, c: _Client, subs: list[dict[str, Any]]) -> None:
        errors = []
        with self._lock:
            for s in subs:
                sid, ch = int(s['id']), int(s['channelId'])
                if ch not in self._channels:
                    errors.append('no channel {}'.format(ch))
                elif sid in c.subs:
                    errors.append('subscription id {} already in use'.format(sid))
                elif ch in c.by_channel:
                    errors.append('channel {} already subscribed'.format(ch))
                else:
                    c.subs[sid] = ch
                    c.by_channel[ch] = sid
                    # Late joiners get the latched topics' last messages (tf_static, URDF).
                    for payload in self._latched.get(ch, ()):
                        self._data(c, fp.message_data(sid, time.time_ns(), payload))
        if errors:
            raise fp.ProtocolError('subscribe: ' + '; '.join(errors))

    def _client_advertise(self, c: _Client, channels: list[dict[str, Any]]) -> None:
        if 'clientPublish' not in self._capabilities(c):
            raise fp.ProtocolError('advertise: clientPublish is not enabled for this client '
                                   '(right {})'.format(c.right))
        errors = []
        for chan in channels:
            cid = int(chan['id'])
            if cid in c.channels:
                errors.append('client channel {} already advertised'.format(cid))
                continue
            if len(c.channels) >= self.max_client_channels:
                errors.append('{}: not advertised, this client already has {} channels '
                              '(m4k_foxglove max_client_channels)'.format(
                                  chan.get('topic'), self.max_client_channels))
                continue
            if chan.get('encoding') not in self.encodings:
                errors.append('{}: encoding {!r} not supported (use {})'.format(
                    chan.get('topic'), chan.get('encoding'), ', '.join(self.encodings)))
                continue
            refused = self.handler.on_client_advertise(c.id, dict(chan))
            if refused:
                errors.append(refused)
            else:
                c.channels.add(cid)
        if errors:
            raise fp.ProtocolError('advertise: ' + '; '.join(errors))

    def _on_binary(self, c: _Client, frame: bytes) -> None:
        if not frame:
            raise fp.ProtocolError('empty binary message')
        if frame[0] == fp.CLIENT_MESSAGE_DATA:
            ch, payload = fp.parse_client_message_data(frame)
            if ch not in c.channels:
                raise fp.ProtocolError('message on client channel {} that was not '
                                       'advertised'.format(ch))
            self.handler.on_client_message(c.id, ch, payload)
        elif frame[0] == fp.CLIENT_SERVICE_CALL_REQUEST:
            if 'services' not in self._capabilities(c):
                raise fp.ProtocolError('service call: services are not enabled for this '
                                       'client (right {})'.format(c.right))
            sid, call, enc, payload = fp.parse_service_call_request(frame)
            need = self._service_rights.get(sid)
            if need is None or not at_least(c.right, need):
                # Not told of it: the same answer whether it exists or not.
                raise fp.ProtocolError('service call: no service {}'.format(sid))
            self.handler.on_service_call(c.id, sid, call, enc, payload)
        else:
            raise fp.ProtocolError('unknown binary opcode 0x{:02x}'.format(frame[0]))
