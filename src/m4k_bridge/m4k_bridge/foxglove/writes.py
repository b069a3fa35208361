"""What a live view client publishes: e-stop first, then the rate limit, then the driver lock.

A mixin of :class:`m4k_bridge.foxglove.node.FoxgloveNode`, called on the server thread for
every Client Message Data frame. An ``e_stop`` true is published here and now on the node's
own e-stop publisher (made at start): never behind the request queue, the rate limit or the
driver lock, never dropped. An ``e_stop`` false needs the safety right. Everything else passes
the client channel's token bucket (``max_publish_rate``; at the cap the client is told once
with a warning status, and the drops are counted) and, for motion (``cmd_vel``, ``led``,
goals), the single-driver lock (:class:`.rights.DriverLock`; each change of driver is
broadcast to every client as an info status), then goes to the ROS thread's queue.
"""

from __future__ import annotations

import time
from typing import Any

from rclpy.serialization import deserialize_message
from std_msgs.msg import Bool

from m4k_bridge.foxglove import protocol as fp
from m4k_bridge.foxglove.rights import at_least, DriverLock, TokenBucket

__all__ = ['ClientWrites']

_BOOL = 'std_msgs/msg/Bool'


class ClientWrites:
    """The gate between a client's message and the graph (mixed into the node)."""

    server: Any
    lock: DriverLock
    max_publish_rate: float
    _inert: set[tuple[int, int]]
    _estop_keys: set[tuple[int, int]]
    _buckets: dict[tuple[int, int], TokenBucket]
    _lock_refused: set[tuple[int, int]]
    _estop_pub: Any
    inert_messages: int
    bad_client_messages: int
    refused_rights: int
    throttled: int
    e_stop_engages: int

    def on_client_message(self, client: int, channel_id: int, payload: bytes) -> None:
        """Publish a client's CDR message after the rights, the rate and the driver lock.

        On the server thread. An e-stop engage is published here and now; everything else is
        queued for the ROS thread (decoded there to check it, then published by rclpy).
        """
        key = (client, channel_id)
        if key in self._inert:
            self.inert_messages += 1
            self.server.send_text(client, fp.status(2, (
                'not published: publishing goals and poses from the 3D panel is off '
                '(m4k_foxglove nav_goals:=false; set it true when a nav stack uses them)')))
            return
        right = self.server.client_right(client) or 'view'
        motion = True
        if key in self._estop_keys:
            try:
                engage = bool(deserialize_message(payload, Bool).data)
            except Exception as exc:  # noqa: BLE001 -- rclpy raises a private error type
                self.bad_client_messages += 1
                self.server.send_text(client, fp.status(2, 'not a CDR {}: {}'.format(
                    _BOOL, exc)))
                return
            if engage:
                self.e_stop_engages += 1
                self._estop_pub.publish(Bool(data=True))
                return
            if not at_least(right, 'safety'):
                self.refused_rights += 1
                self.server.send_text(client, fp.status(2, (
                    'e-stop not released: releasing it needs the safety right (m4k_foxglove '
                    'safety_token_file)')))
                return
            motion = False
        now = time.monotonic()
        bucket = self._buckets.setdefault(key, TokenBucket(self.max_publish_rate,
                                                           self.max_publish_rate))
        if not bucket.take(now):
            self.throttled += 1
            if not bucket.throttled:
                bucket.throttled = True
                self.server.send_text(client, fp.status(1, (
                    'channel {}: over {:g} messages/s, dropping (m4k_foxglove '
                    'max_publish_rate)'.format(channel_id, self.max_publish_rate))))
            return
        if motion and not self._drive(key, right, now):
            return
        self._post(lambda: self._publish(key, payload),  # type: ignore[attr-defined]
                   client=client)

    def _drive(self, key: tuple[int, int], right: str, now: float) -> bool:
        name = self.server.client_name(key[0])
        ok, changed = self.lock.claim(key[0], name, right, now)
        if changed:
            self.server.broadcast_status(0, '{} drives now'.format(name))
        if ok:
            self._lock_refused.discard(key)
            return True
        self.refused_rights += 1
        if key not in self._lock_refused:
            self._lock_refused.add(key)
            self.server.send_text(key[0], fp.status(1, (
                'not published: {} drives; it may be taken over after {:g} s without its '
                'commands, or by a client with the safety right (m4k_foxglove '
                'driver_idle_timeout)'.format(self.lock.owner_name, self.lock.idle_s))))
        return False

