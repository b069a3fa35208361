"""m4k_bridge.foxglove.server without ROS: clients written from the protocol spec.

The reading client uses the plain ``websockets`` client; the stalled one is a raw socket that
does the RFC 6455 handshake, subscribes and never reads again. Frames are built and parsed
here with ``struct`` from the spec's tables, not with :mod:`m4k_bridge.foxglove.protocol`.
"""

import asyncio
import base64
import json
import os
import re
import socket
import struct
import threading
import time

import pytest
from websockets.asyncio.client import connect
from websockets.exceptions import InvalidStatus

from m4k_bridge.foxglove import protocol
from m4k_bridge.foxglove.server import Server

SUB = 'foxglove.websocket.v1'


class Handler:
    """Record what clients send."""

    def __init__(self):
        self.advertised = []
        self.messages = []
        self.gone = []

    def on_client_advertise(self, client, channel):
        if channel['topic'] != '/cmd_vel':
            return '{}: refused'.format(channel['topic'])
        self.advertised.append(channel)
        return None

    def on_client_unadvertise(self, client, channel_id):
        self.gone.append(channel_id)

    def on_client_message(self, client, channel_id, payload):
        self.messages.append((channel_id, payload))

    def on_get_parameters(self, client, names, request_id):
        pass

    def on_service_call(self, client, service_id, call_id, encoding, payload):
        pass

    def on_client_gone(self, client):
        pass


@pytest.fixture
def server():
    srv = Server(Handler(), '127.0.0.1', 0, capabilities=('clientPublish',),
                 max_queue_messages=50, max_queue_bytes=4 << 20)
    srv.start()
    try:
        yield srv
    finally:
        srv.stop()


def _stalled(port, channel_id):
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    s.connect(('127.0.0.1', port))
    key = base64.b64encode(os.urandom(16)).decode()
    s.sendall(('GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n'
               'Sec-WebSocket-Key: {}\r\nSec-WebSocket-Version: 13\r\n'
               'Sec-WebSocket-Protocol: {}\r\n\r\n'.format(key, SUB)).encode())
    head = b''
    while b'\r\n\r\n' not in head:
        head += s.recv(1)
    assert head.startswith(b'HTTP/1.1 101') and SUB.encode() in head
    text = json.dumps({'op': 'subscribe', 'subscriptions': [
        {'id': 9, 'channelId': channel_id}]}).encode()
    s.sendall(bytes([0x81, 0x80 | len(text)]) + b'\0\0\0\0' + text)
    return s


def _rss_kib():
    with open('/proc/self/status', encoding='ascii') as f:
        return int(re.search(r'VmRSS:\s+(\d+)', f.read()).group(1))


def _wait(predicate, what, timeout=30.0):
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, 'timed out waiting for ' + what
        time.sleep(0.02)


def test_a_late_joiner_gets_the_latched_message_and_live_data_in_order(server):
    ch = server.add_channel('/tf_static', 'tf2_msgs/msg/TFMessage', 'x')
    live = server.add_channel('/odom', 'nav_msgs/msg/Odometry', 'y')
    server.publish(ch, b'static-1', latched=True)
    server.publish(ch, b'static-1', latched=True)     # a repeat is kept once

    async def main():
        async with connect('ws://127.0.0.1:{}'.format(server.port), subprotocols=[SUB]) as ws:
            info = json.loads(await ws.recv())
            assert info['op'] == 'serverInfo' and info['capabilities'] == ['clientPublish']
            adv = json.loads(await ws.recv())
            assert {c['topic']: (c['encoding'], c['schemaEncoding']) for c in adv['channels']} \
                == {'/tf_static': ('cdr', 'ros2msg'), '/odom': ('cdr', 'ros2msg')}
            await ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
                {'id': 3, 'channelId': ch}, {'id': 4, 'channelId': live}]}))
            frame = await ws.recv()
            op, sub, ns = struct.unpack_from('<BIQ', frame)
            assert (op, sub, frame[13:]) == (1, 3, b'static-1') and ns > 0
            for i in range(5):
                server.publish(live, struct.pack('<I', i))
            got = [struct.unpack_from('<BIQI', await ws.recv()) for _ in range(5)]
            assert [(g[1], g[3]) for g in got] == [(4, i) for i in range(5)]

    asyncio.run(main())


def test_a_stalled_client_is_bounded_and_counted_and_the_reader_gets_everything(server):
    ch = server.add_channel('/big', 'std_msgs/msg/String', 'string data')
    stalled = _stalled(server.port, ch)
    got = []
    n, size = 300, 256 * 1024        # 75 MiB in all: a queue without a bound would hold it

    async def reader(ready):
        async with connect('ws://127.0.0.1:{}'.format(server.port), subprotocols=[SUB],
                           max_size=None) as ws:
            await ws.recv()
            await ws.recv()
            await ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
                {'id': 1, 'channelId': ch}]}))
            ready.set()
            while len(got) < n:
                frame = await ws.recv()
                got.append(struct.unpack_from('<I', frame, 13)[0])

    ready = threading.Event()
    t = threading.Thread(target=lambda: asyncio.run(reader(ready)), daemon=True)
    t.start()
    try:
        assert ready.wait(10)
        _wait(lambda: all(s.subscriptions == 1 for s in server.stats())
              and len(server.stats()) == 2, 'both subscriptions')
        rss0 = _rss_kib()
        blob = os.urandom(size - 4)
        for i in range(n):
            server.publish(ch, struct.pack('<I', i) + blob)
            # Paced so the reading client keeps up (its queue bound must not drop for it);
            # the stalled one cannot keep up at any pace.
            _wait(lambda i=i: len(got) > i - 8, 'the reader to keep up')
        t.join(60)
        assert got == list(range(n))
        slow = [s for s in server.stats() if s.dropped]
        assert len(slow) == 1 and slow[0].dropped > n // 2, server.stats()
        assert slow[0].queued <= 50 and slow[0].queued_bytes <= 4 << 20
        assert _rss_kib() - rss0 < 40 * 1024
    finally:
        stalled.close()


def test_client_publish_is_checked_and_handed_over(server):
    h = server.handler

    async def main():
        async with connect('ws://127.0.0.1:{}'.format(server.port), subprotocols=[SUB]) as ws:
            await ws.recv()
            await ws.recv()
            await ws.send(json.dumps({'op': 'advertise', 'channels': [
                {'id': 1, 'topic': '/cmd_vel', 'encoding': 'cdr',
                 'schemaName': 'geometry_msgs/msg/Twist'},
                {'id': 2, 'topic': '/x', 'encoding': 'json', 'schemaName': 'a/B'}]}))
            st = json.loads(await ws.recv())
            assert st['op'] == 'status' and st['level'] == 2
            assert "encoding 'json' not supported" in st['message']
            await ws.send(b'\x01' + struct.pack('<I', 1) + b'abc')
            await ws.send(b'\x01' + struct.pack('<I', 7) + b'abc')
            st = json.loads(await ws.recv())
            assert 'client channel 7 that was not advertised' in st['message']
            await ws.send(b'\x07')
            st = json.loads(await ws.recv())
            assert 'unknown binary opcode 0x07' in st['message']

    asyncio.run(main())
    assert h.messages == [(1, b'abc')]
    _wait(lambda: h.gone == [1], 'the channel to go with its client')


def test_a_client_without_the_subprotocol_is_refused_at_the_handshake(server):
    async def main():
        async with connect('ws://127.0.0.1:{}'.format(server.port)):
            pass

    with pytest.raises(InvalidStatus, match='HTTP 400'):
        asyncio.run(main())
    assert server.stats() == []


def test_frames_and_values_follow_the_spec_tables():
    assert protocol.message_data(7, 5, b'p') == b'\x01' + struct.pack('<IQ', 7, 5) + b'p'
    enc = protocol.service_call_response(2, 3, 'cdr', b'r')
    assert enc == b'\x03' + struct.pack('<III', 2, 3, 3) + b'cdr' + b'r'
    assert protocol.parse_service_call_request(
        b'\x02' + struct.pack('<III', 4, 5, 3) + b'cdrXY') == (4, 5, 'cdr', b'XY')
    with pytest.raises(protocol.ProtocolError, match='past the frame end'):
        protocol.parse_service_call_request(b'\x02' + struct.pack('<III', 4, 5, 99) + b'cdr')
    with pytest.raises(protocol.ProtocolError):
        protocol.parse_client_message_data(b'\x01\x00')
    assert protocol.parameter_value(1.0) == {'value': 1.0, 'type': 'float64'}
    assert protocol.parameter_value([1.0, 2.5]) == {'value': [1.0, 2.5],
                                                    'type': 'float64_array'}
    assert protocol.parameter_value(float('inf')) == {'value': 'inf'}
    assert protocol.parameter_value(b'AB') == {'value': 'QUI=', 'type': 'byte_array'}
    assert protocol.parameter_value(['a']) == {'value': ['a']}
    assert protocol.parameter_value(True) == {'value': True}


def test_service_definitions_split_the_srv_and_append_dependencies(tmp_path):
    (tmp_path / 'p' / 'srv').mkdir(parents=True)
    (tmp_path / 'p' / 'msg').mkdir(parents=True)
    (tmp_path / 'p' / 'srv' / 'S.srv').write_text('Point a  # in\n---\nbool ok\n')
    (tmp_path / 'p' / 'msg' / 'Point.msg').write_text('float64 x\n')
    req, resp = protocol.service_definitions('p/srv/S', lambda pkg: str(tmp_path / pkg))
    assert req == 'Point a  # in\n' + '=' * 80 + '\nMSG: p/Point\nfloat64 x\n'
    assert resp == 'bool ok\n'
    with pytest.raises(ValueError, match='not a service type'):
        protocol.service_definitions('p/msg/S')


def test_a_port_in_use_is_a_clear_error(server):
    other = Server(Handler(), '127.0.0.1', server.port)
    with pytest.raises(OSError, match='address already in use'):
        other.start()


# --- who may connect: Origin, token, caps ------------------------------------------------------

def _handshake(port, origin=None, path='/'):
    """Do a raw RFC 6455 handshake; return (status line, everything the server sent)."""
    s = socket.create_connection(('127.0.0.1', port))
    try:
        key = base64.b64encode(os.urandom(16)).decode()
        s.sendall(('GET {} HTTP/1.1\r\nHost: 127.0.0.1:{}\r\nUpgrade: websocket\r\n'
                   'Connection: Upgrade\r\nSec-WebSocket-Key: {}\r\n'
                   'Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: {}\r\n{}\r\n'.format(
                       path, port, key, SUB,
                       '' if origin is None else 'Origin: {}\r\n'.format(origin))).encode())
        s.settimeout(10.0)
        data = b''
        while b'\r\n\r\n' not in data:
            chunk = s.recv(4096)
            if not chunk:
                break
            data += chunk
        if data.startswith(b'HTTP/1.1 101'):
            # Accepted: serverInfo is the first frame (an unmasked text frame).
            while b'serverInfo' not in data:
                chunk = s.recv(4096)
                assert chunk, data
                data += chunk
        else:
            while True:     # refused: the server closes after its HTTP response
                chunk = s.recv(4096)
                if not chunk:
                    break
                data += chunk
        return data.split(b'\r\n', 1)[0].decode(), data
    finally:
        s.close()


@pytest.mark.parametrize('origin', ['http://evil.example', 'https://app.foxglove.dev.evil.io',
                                    'http://localhost.evil.io:8080', 'null',
                                    'https://app.foxglove.dev:8443'])
def test_a_foreign_origin_is_refused_with_403_before_server_info(server, origin):
    server.add_channel('/odom', 'nav_msgs/msg/Odometry', 'y')
    status, data = _handshake(server.port, origin)
    assert status.startswith('HTTP/1.1 403'), status
    assert b'allowed_origins' in data
    assert b'serverInfo' not in data and b'/odom' not in data
    assert server.stats() == [] and server.clients_total == 0
    assert server.refused['origin'] >= 1


@pytest.mark.parametrize('origin', [None, 'https://app.foxglove.dev', 'file://',
                                    'http://localhost:8080', 'http://127.0.0.1:3000',
                                    'http://[::1]:8080', 'HTTP://LOCALHOST:5173',
                                    'http://localhost'])
def test_native_clients_the_apps_and_localhost_pages_are_served(server, origin):
    status, data = _handshake(server.port, origin)
    assert status.startswith('HTTP/1.1 101'), (status, data)
    assert b'"op":"serverInfo"' in data


def test_the_allow_list_is_configurable():
    from m4k_bridge.foxglove.access import OriginPolicy
    srv = Server(Handler(), '127.0.0.1', 0, origins=OriginPolicy(['https://viz.example:8443']))
    srv.start()
    try:
        assert _handshake(srv.port, 'https://viz.example:8443')[0].startswith('HTTP/1.1 101')
        assert _handshake(srv.port, 'https://viz.example')[0].startswith('HTTP/1.1 403')
        assert _handshake(srv.port, 'http://localhost:8080')[0].startswith('HTTP/1.1 403')
        assert _handshake(srv.port, None)[0].startswith('HTTP/1.1 101')
    finally:
        srv.stop()


def test_the_websockets_client_sees_the_refusal_as_http_403(server):
    async def main():
        with pytest.raises(InvalidStatus) as exc:
            async with connect('ws://127.0.0.1:{}'.format(server.port), subprotocols=[SUB],
                               origin='http://evil.example'):
                pass
        assert exc.value.response.status_code == 403

    asyncio.run(main())


def test_with_a_token_only_a_client_that_gives_it_is_served():
    token = 'a' * 12 + 'Z-9_'
    from m4k_bridge.foxglove.access import Credentials
    srv = Server(Handler(), '127.0.0.1', 0, credentials=Credentials('drive', admit=token))
    srv.start()
    try:
        assert _handshake(srv.port, None, '/')[0].startswith('HTTP/1.1 401')
        assert _handshake(srv.port, None, '/?token=wrong')[0].startswith('HTTP/1.1 401')
        assert _handshake(srv.port, None, '/?token={}&token={}'.format(token, token))[0] \
            .startswith('HTTP/1.1 401')
        status, data = _handshake(srv.port, 'https://app.foxglove.dev', '/?token=' + token)
        assert status.startswith('HTTP/1.1 101') and b'serverInfo' in data
        # The token does not open the door to a foreign page.
        assert _handshake(srv.port, 'http://evil.example', '/?token=' + token)[0] \
            .startswith('HTTP/1.1 403')
        assert srv.refused['token'] == 3
    finally:
        srv.stop()


def test_one_client_more_than_max_clients_is_refused_and_a_freed_place_is_served():
    srv = Server(Handler(), '127.0.0.1', 0, max_clients=2)
    srv.start()

    async def main():
        url = 'ws://127.0.0.1:{}'.format(srv.port)
        async with connect(url, subprotocols=[SUB]) as a, connect(url, subprotocols=[SUB]):
            assert json.loads(await a.recv())['op'] == 'serverInfo'
            _wait(lambda: len(srv.stats()) == 2, 'two clients')
            with pytest.raises(InvalidStatus) as exc:
                async with connect(url, subprotocols=[SUB]):
                    pass
            assert exc.value.response.status_code == 503
            assert b'max_clients' in exc.value.response.body
        _wait(lambda: len(srv.stats()) == 0, 'the clients gone')
        async with connect(url, subprotocols=[SUB]) as c:
            assert json.loads(await c.recv())['op'] == 'serverInfo'

    try:
        asyncio.run(main())
        assert srv.refused['clients'] == 1
    finally:
        srv.stop()


def test_a_client_may_advertise_at_most_max_client_channels():
    handler = Handler()
    srv = Server(handler, '127.0.0.1', 0, capabilities=('clientPublish',),
                 max_client_channels=2)
    srv.start()

    async def main():
        async with connect('ws://127.0.0.1:{}'.format(srv.port), subprotocols=[SUB]) as ws:
            await ws.send(json.dumps({'op': 'advertise', 'channels': [
                {'id': i, 'topic': '/cmd_vel', 'encoding': 'cdr',
                 'schemaName': 'geometry_msgs/msg/Twist'} for i in (1, 2, 3)]}))
            while True:
                doc = json.loads(await ws.recv())
                if doc['op'] == 'status':
                    return doc

    try:
        status = asyncio.run(main())
        assert status['level'] == 2
        assert 'max_client_channels' in status['message'] and '2 channels' in status['message']
        assert [c['id'] for c in handler.advertised] == [1, 2]
    finally:
        srv.stop()


def test_origin_patterns_are_validated_and_matched_exactly():
    from m4k_bridge.foxglove.access import AccessError, OriginPolicy
    p = OriginPolicy(['https://app.foxglove.dev', 'http://localhost:*', 'file://'])
    assert p.allows(None) and p.allows('file://') and p.allows('http://localhost:1')
    assert not p.allows('https://app.foxglove.dev/') and not p.allows('http://localhost:x')
    assert not p.allows('http://localhost:8080@evil.io') and not p.allows('')
    for bad in ('app.foxglove.dev', 'https://app.foxglove.dev/', '*', 'http://*:80'):
        with pytest.raises(AccessError, match='allowed_origins'):
            OriginPolicy([bad])


def test_a_token_file_others_can_read_or_a_short_token_is_refused(tmp_path):
    from m4k_bridge.foxglove.access import AccessError, read_token_file
    f = tmp_path / 'token'
    f.write_text('0123456789abcdef0123\n')
    os.chmod(f, 0o644)
    with pytest.raises(AccessError, match='chmod 600'):
        read_token_file(str(f))
    os.chmod(f, 0o600)
    assert read_token_file(str(f)) == '0123456789abcdef0123'
    f.write_text('short\n')
    with pytest.raises(AccessError, match='at least 16'):
        read_token_file(str(f))
    link = tmp_path / 'link'
    link.symlink_to(f)
    with pytest.raises(AccessError, match='cannot open'):
        read_token_file(str(link))
