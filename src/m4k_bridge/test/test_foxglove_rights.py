"""Rights, tokens, rate limits, the driver lock and TLS of the live view, without ROS.

The server-level tests connect with the plain ``websockets`` client and read the spec's JSON
ops by hand; a view client must not be offered any write capability, and a token is taken
from the query, an ``Authorization: Bearer`` header or an offered ``m4k-token.`` subprotocol.
"""

import asyncio
import json
import os
import ssl
import subprocess

import pytest
from test_foxglove_server import Handler
from websockets.asyncio.client import connect
from websockets.exceptions import InvalidMessage, InvalidStatus

from m4k_bridge.foxglove.access import AccessError, Credentials, presented_tokens
from m4k_bridge.foxglove.rights import (
    at_least,
    capabilities,
    DriverLock,
    service_right,
    TokenBucket,
)
from m4k_bridge.foxglove.server import Server

SUB = 'foxglove.websocket.v1'
DRIVE = 'd' * 20
SAFETY = 's' * 20
ALL = ('clientPublish', 'parameters', 'services')


def test_rights_are_ordered_and_view_is_offered_no_write_capability():
    assert at_least('safety', 'drive') and at_least('drive', 'drive')
    assert not at_least('view', 'drive') and not at_least('drive', 'safety')
    assert capabilities('view', ALL) == ('parameters',)
    assert capabilities('drive', ALL) == ALL == capabilities('safety', ALL)


def test_the_bridges_services_need_their_rights_and_any_other_needs_safety():
    assert service_right('/m4k_bridge/e_stop', '/m4k_bridge') == 'drive'
    assert service_right('/m4k_bridge/reset_odometry', '/m4k_bridge') == 'drive'
    assert service_right('/m4k_bridge/reset_motor_fault', '/m4k_bridge') == 'safety'
    assert service_right('/m4k_bridge/set_pose', '/m4k_bridge') == 'safety'
    assert service_right('/slam_toolbox/serialize_map', '/m4k_bridge') == 'safety'
    assert service_right('/r1/m4k_bridge/e_stop', '/r1/m4k_bridge') == 'drive'
    assert service_right('/m4k_bridge/e_stop', '/r1/m4k_bridge') == 'safety'


def test_a_token_bucket_passes_its_burst_then_its_rate():
    b = TokenBucket(rate=10.0, burst=10.0)
    assert sum(b.take(100.0) for _ in range(50)) == 10
    assert b.refused == 40
    assert sum(b.take(100.5) for _ in range(50)) == 5      # 0.5 s at 10/s
    assert not b.take(100.5)
    assert sum(b.take(1000.0) for _ in range(50)) == 10    # never more than the burst


def test_one_driver_at_a_time_idle_take_over_and_safety_take_over():
    lock = DriverLock(idle_s=2.0)
    assert lock.claim(1, 'a', 'drive', 0.0) == (True, True)
    assert lock.claim(1, 'a', 'drive', 1.0) == (True, False)
    assert lock.claim(2, 'b', 'drive', 2.5) == (False, False)      # 1.5 s since a's last
    assert lock.claim(2, 'b', 'drive', 3.1) == (True, True)        # a idle 2.1 s
    assert lock.owner == 2
    assert lock.claim(3, 'c', 'safety', 3.2) == (True, True)       # a supervisor takes it
    assert not lock.release(2) and lock.release(3) and lock.owner is None


def test_credentials_map_each_token_to_its_right_and_refuse_a_wrong_one():
    open_ = Credentials('view', None, DRIVE, SAFETY)
    assert open_.right([]) == 'view'
    assert open_.right([DRIVE]) == 'drive' and open_.right([SAFETY]) == 'safety'
    assert open_.right(['x' * 20]) is None                 # wrong: refused, not view
    assert open_.right([DRIVE, DRIVE]) is None             # two: ambiguous
    closed = Credentials('drive', 'a' * 20, None, SAFETY)
    assert closed.right([]) is None and closed.right(['a' * 20]) == 'drive'
    assert closed.right([SAFETY]) == 'safety'
    with pytest.raises(AccessError, match='different tokens'):
        Credentials('view', DRIVE, DRIVE)


def test_tokens_are_read_from_the_query_a_bearer_header_and_a_subprotocol():
    assert presented_tokens('/?token=abc', [], []) == ['abc']
    assert presented_tokens('/', ['Bearer abc'], []) == ['abc']
    assert presented_tokens('/', ['Basic abc'], []) == []
    assert presented_tokens('/', [], ['foxglove.websocket.v1, m4k-token.abc']) == ['abc']


def _server(**kw):
    srv = Server(Handler(), '127.0.0.1', 0, capabilities=ALL,
                 credentials=Credentials('view', None, DRIVE, SAFETY), **kw)
    srv.set_services([({'id': 1, 'name': '/m4k_bridge/e_stop'}, 'drive'),
                      ({'id': 2, 'name': '/m4k_bridge/set_pose'}, 'safety')])
    srv.start()
    return srv


async def _first(ws, n):
    return [json.loads(await ws.recv()) for _ in range(n)]


def test_each_client_is_offered_what_its_right_allows_wherever_it_puts_the_token():
    srv = _server()
    url = 'ws://127.0.0.1:{}/'.format(srv.port)

    async def main():
        async with connect(url, subprotocols=[SUB]) as ws:
            info, adv = await _first(ws, 2)
            assert info['capabilities'] == ['parameters'] and adv['op'] == 'advertise'
            await ws.send(json.dumps({'op': 'advertise', 'channels': [
                {'id': 1, 'topic': '/cmd_vel', 'encoding': 'cdr', 'schemaName': 'x/msg/T'}]}))
            status = json.loads(await ws.recv())
            assert status['op'] == 'status' and 'right view' in status['message']
        async with connect(url, subprotocols=[SUB],
                           additional_headers={'Authorization': 'Bearer ' + DRIVE}) as ws:
            info, _, svcs = await _first(ws, 3)
            assert info['capabilities'] == list(ALL)
            assert [s['name'] for s in svcs['services']] == ['/m4k_bridge/e_stop']
        async with connect(url, subprotocols=[SUB, 'm4k-token.' + SAFETY]) as ws:
            assert ws.subprotocol == SUB
            _, _, svcs = await _first(ws, 3)
            assert [s['name'] for s in svcs['services']] == ['/m4k_bridge/e_stop',
                                                              '/m4k_bridge/set_pose']
        with pytest.raises(InvalidStatus) as exc:
            async with connect(url + '?token=' + 'w' * 20, subprotocols=[SUB]):
                pass
        assert exc.value.response.status_code == 401

    try:
        asyncio.run(main())
        assert [s.right for s in srv.stats()] == []
    finally:
        srv.stop()


def test_tls_serves_wss_with_the_given_certificate(tmp_path):
    cert, key = tmp_path / 'cert.pem', tmp_path / 'key.pem'
    subprocess.run(['openssl', 'req', '-x509', '-newkey', 'rsa:2048', '-nodes', '-days', '1',
                    '-subj', '/CN=localhost', '-addext', 'subjectAltName=IP:127.0.0.1',
                    '-keyout', str(key), '-out', str(cert)], check=True, capture_output=True)
    os.chmod(key, 0o600)
    from m4k_bridge.foxglove.node import tls_context
    srv = _server(tls=tls_context(str(cert), str(key)))
    client_ctx = ssl.create_default_context(cafile=str(cert))

    async def main():
        async with connect('wss://127.0.0.1:{}/'.format(srv.port), subprotocols=[SUB],
                           ssl=client_ctx) as ws:
            info = json.loads(await ws.recv())
            assert info['op'] == 'serverInfo'
        with pytest.raises((OSError, InvalidMessage, TimeoutError)):   # plain ws:// to TLS
            async with connect('ws://127.0.0.1:{}/'.format(srv.port), subprotocols=[SUB],
                               open_timeout=10):
                pass

    try:
        asyncio.run(main())
    finally:
        srv.stop()
    os.chmod(key, 0o644)
    with pytest.raises(AccessError, match='chmod 600'):
        tls_context(str(cert), str(key))
    with pytest.raises(AccessError, match='go together'):
        tls_context(str(cert), '')
