"""The live view's service side: which services are served, who may call them, timeouts.

A mixin of :class:`m4k_bridge.foxglove.node.FoxgloveNode` (it uses the node's server, rights
and request queue). Served: the services matching ``service_whitelist`` (default the
bridge's own), each with the right it needs (:func:`.rights.service_right`); the server tells
each client only of those its right allows. A call is rate limited per client
(``max_service_rate``) and fails after ``service_timeout`` without a response. A call of the
bridge's ``~/e_stop`` with ``data`` true (engage) is never limited: the engage is published on
``e_stop`` at once from the server thread, and the call itself goes to the front of the
queue; with ``data`` false (release) it needs the safety right.
"""

from __future__ import annotations

import time
from typing import Any, Pattern

from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import Bool

from m4k_bridge.foxglove import protocol as fp
from m4k_bridge.foxglove.rights import at_least, service_right, TokenBucket
from m4k_bridge.interfaces import interface_class

__all__ = ['ServiceSide']

_SKIP_SERVICE_PACKAGES = ('rcl_interfaces', 'type_description_interfaces')


def allowed(name: str, namespace: str, patterns: list[Pattern[str]]) -> bool:
    """Return True when service ``name`` matches a pattern (relative ones: to ``namespace``)."""
    ns = namespace.rstrip('/') + '/'
    rel = name[len(ns):] if name.startswith(ns) else None
    for p in patterns:
        if p.pattern.startswith('/'):
            if p.fullmatch(name):
                return True
        elif rel is not None and p.fullmatch(rel):
            return True
    return False


class ServiceSide:
    """Serving and calling services for the live view (mixed into the node)."""

    server: Any
    service_whitelist: list[Pattern[str]]
    service_timeout: float
    max_service_rate: float
    _bridge_fqn: str
    _estop_pub: Any
    bad_client_messages: int

    def _init_services(self) -> None:
        self._service_ids: dict[str, int] = {}
        self._svc: dict[int, tuple[Any, Any, str, str]] = {}   # id -> (client, class, name, type)
        self._calls: dict[tuple[int, int], tuple[float, Any, Any, Any]] = {}
        self._call_buckets: dict[int, TokenBucket] = {}
        self.service_timeouts = 0
        self.calls_refused = 0

    def _poll_services(self) -> None:
        new = []
        for name, types in self.get_service_names_and_types():   # type: ignore[attr-defined]
            if name in self._service_ids or not types:
                continue
            tname = types[0]
            if tname.split('/')[0] in _SKIP_SERVICE_PACKAGES or not allowed(
                    name, self.get_namespace(), self.service_whitelist):  # type: ignore
                continue
            try:
                req, resp = fp.service_definitions(tname)
                cls = interface_class(tname)
            except (OSError, LookupError, ImportError, AttributeError, ValueError) as exc:
                self.get_logger().warning(  # type: ignore[attr-defined]
                    'not serving service {}: {}'.format(name, exc))
                self._service_ids[name] = 0
                continue
            sid = len(self._svc) + 1
            self._service_ids[name] = sid
            self._svc[sid] = (self.create_client(cls, name),  # type: ignore[attr-defined]
                              cls, name, tname)
            new.append((fp.service(sid, name, tname, req, resp),
                        service_right(name, self._bridge_fqn)))
        if new:
            self.server.set_services(new)

    def _is_e_stop_service(self, name: str, tname: str) -> bool:
        return name == self._bridge_fqn.rstrip('/') + '/e_stop' \
            and tname == 'std_srvs/srv/SetBool'

    def on_service_call(self, client: int, service_id: int, call_id: int, encoding: str,
                        payload: bytes) -> None:
        """Check the right and the rate, then call the ROS service (response as CDR)."""
        cli, cls, name, tname = self._svc[service_id]

        def fail(why: str) -> None:
            self.server.send_text(client, fp.service_call_failure(
                service_id, call_id, '{}: {}'.format(name, why)))

        if encoding != 'cdr':
            fail('encoding {!r} not supported, use cdr'.format(encoding))
            return
        try:
            request = deserialize_message(payload, cls.Request)
        except Exception as exc:  # noqa: BLE001 -- rclpy raises a private error type
            self.bad_client_messages += 1
            fail('bad request: {}'.format(exc))
            return
        def call() -> None:
            self._call(client, service_id, call_id, request)

        if self._is_e_stop_service(name, tname):
            if request.data:
                # Engage: latched now, whatever the queue holds; the answer follows.
                self._estop_pub.publish(Bool(data=True))
                self._post(call, critical=True, front=True)  # type: ignore[attr-defined]
                return
            if not at_least(self.server.client_right(client) or 'view', 'safety'):
                self.calls_refused += 1
                fail('releasing the e-stop needs the safety right (m4k_foxglove '
                     'safety_token_file)')
                return
        bucket = self._call_buckets.setdefault(client, TokenBucket(
            self.max_service_rate, max(1.0, self.max_service_rate)))
        if not bucket.take(time.monotonic()):
            self.calls_refused += 1
            fail('rate limited: at most {:g} calls/s per client (m4k_foxglove '
                 'max_service_rate)'.format(self.max_service_rate))
            return
        self._post(call, client=client)  # type: ignore[attr-defined]

    def _call(self, client: int, sid: int, call_id: int, request: Any) -> None:
        cli, _, name, _ = self._svc[sid]

        def fail(why: str) -> None:
            self.server.send_text(client, fp.service_call_failure(
                sid, call_id, '{}: {}'.format(name, why)))

        if not cli.service_is_ready():
            fail('no server')
            return
        fut = cli.call_async(request)
        key = (client, call_id)
        self._calls[key] = (time.monotonic() + self.service_timeout, fut, fail, cli)

        def done(f: Any) -> None:
            if self._calls.pop(key, None) is None or f.cancelled():
                return               # timed out: the failure was sent
            res = f.result()
            if res is None:
                fail('call failed')
                return
            self.server.send_binary(client, fp.service_call_response(
                sid, call_id, 'cdr', serialize_message(res)))

        fut.add_done_callback(done)

    def _expire_calls(self, now: float) -> None:
        """Fail the calls past ``service_timeout`` and forget them (ROS thread)."""
        for key, (deadline, fut, fail, cli) in list(self._calls.items()):
            if now >= deadline:
                self._calls.pop(key, None)
                self.service_timeouts += 1
                fail('no response within {:g} s (m4k_foxglove service_timeout)'.format(
                    self.service_timeout))
                cli.remove_pending_request(fut)
                fut.cancel()

    def _forget_client_calls(self, client: int) -> None:
        self._call_buckets.pop(client, None)
