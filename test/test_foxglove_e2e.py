"""The live view end to end: ``bringup --foxglove`` seen by a Foxglove WebSocket client.

The client here is not the server's code: it is written from the published protocol
specification (foxglove/ws-protocol ``docs/spec.md``, subprotocol ``foxglove.websocket.v1``)
with the plain ``websockets`` library -- JSON ops, binary frames unpacked with ``struct`` --
and it decodes the CDR payloads by the advertised schema name with rclpy's
``deserialize_message``. Motion is judged on the simulator's ground truth
(``wsenv.ground_truth``), never on the odometry it streams. The stalled client is a raw TCP
socket that completes the WebSocket handshake (RFC 6455), subscribes, and never reads again.
"""

import asyncio
import base64
import importlib
import json
import os
import re
import signal
import socket
import struct
import time

from geometry_msgs.msg import Twist, Vector3
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import Bool
from test_bringup import cmdline, start_bringup, write_overlay
from websockets.asyncio.client import connect
from websockets.exceptions import InvalidStatus
from wsenv import ground_truth, ROOT

from m4k_testing import child_pids

pytestmark = pytest.mark.allow_leaks('fds')  # FastDDS keeps its sockets for the process

SUBPROTOCOL = 'foxglove.websocket.v1'
START = [0.0, 0.9, 0.0]     # the straight path ahead is free up to the wall at x = 4.2 m
WAIT_S = 60.0               # bound of every wait: a healthy run never comes near it


def _message_class(schema_name):
    pkg, kind, name = schema_name.split('/')
    return getattr(importlib.import_module('{}.{}'.format(pkg, kind)), name)


def _log_port(path, deadline):
    while time.monotonic() < deadline:
        m = re.search(r'Foxglove WebSocket server on ws://127\.0\.0\.1:(\d+)',
                      open(path, encoding='utf-8', errors='replace').read())
        if m:
            return int(m.group(1))
        time.sleep(0.1)
    raise AssertionError('no live view port in the bringup log')


@pytest.fixture
def live(procs, tmp_path, m4k_runtime_dir, request):
    """The stack with the live view on a free port; yield (port, runtime dir, bringup)."""
    extra = {'world': {'start': START}}
    extra.update(getattr(request, 'param', {}))
    overlay = write_overlay(tmp_path, extra)
    proc = start_bringup(procs, tmp_path, m4k_runtime_dir, overlay,
                         extra=['--no-status', '--foxglove', '--foxglove-port', '0'])
    try:
        port = _log_port(tmp_path / 'bringup.err', time.monotonic() + WAIT_S)
        yield port, m4k_runtime_dir, proc
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            proc.wait(40)


class Client:
    """A Foxglove protocol client: channels by topic, messages by subscription."""

    def __init__(self, ws):
        self.ws = ws
        self.info = None
        self.channels = {}          # topic -> advertised channel
        self.services = {}          # name -> advertised service
        self.by_sub = {}            # subscription id -> decoded messages
        self.sub_class = {}
        self.statuses = []
        self.texts = []
        self.responses = []

    async def pump(self, timeout=0.2):
        """Read what arrives within ``timeout`` seconds."""
        try:
            msg = await asyncio.wait_for(self.ws.recv(), timeout)
        except asyncio.TimeoutError:
            return
        if isinstance(msg, str):
            doc = json.loads(msg)
            self.texts.append(doc)
            if doc['op'] == 'serverInfo':
                self.info = doc
            elif doc['op'] == 'advertise':
                for ch in doc['channels']:
                    self.channels[ch['topic']] = ch
            elif doc['op'] == 'advertiseServices':
                for s in doc['services']:
                    self.services[s['name']] = s
            elif doc['op'] == 'status':
                self.statuses.append(doc)
        elif msg[0] == 0x01:        # Message Data: opcode, u32 subscription, u64 time, payload
            _, sub, _ns = struct.unpack_from('<BIQ', msg)
            self.by_sub[sub].append(deserialize_message(msg[13:], self.sub_class[sub]))
        elif msg[0] == 0x03:        # Service Call Response
            _, sid, call, n = struct.unpack_from('<BIII', msg)
            self.responses.append((sid, call, msg[13:13 + n].decode(), msg[13 + n:]))

    async def until(self, predicate, what):
        deadline = time.monotonic() + WAIT_S
        while not predicate():
            assert time.monotonic() < deadline, 'timed out waiting for ' + what
            await self.pump()

    async def subscribe(self, topics, first_id=1):
        await self.until(lambda: all(t in self.channels for t in topics),
                         'channels ' + ', '.join(topics))
        subs = []
        for i, topic in enumerate(topics):
            ch = self.channels[topic]
            assert ch['encoding'] == 'cdr' and ch.get('schemaEncoding') == 'ros2msg'
            self.by_sub[first_id + i] = []
            self.sub_class[first_id + i] = _message_class(ch['schemaName'])
            subs.append({'id': first_id + i, 'channelId': ch['id']})
        await self.ws.send(json.dumps({'op': 'subscribe', 'subscriptions': subs}))
        return {t: self.by_sub[first_id + i] for i, t in enumerate(topics)}


def _run(coro):
    return asyncio.run(coro)


def test_a_late_joiner_gets_odom_scan_and_the_latched_tf_tree_and_model(live):
    port, _, _ = live

    async def main():
        async with connect('ws://127.0.0.1:{}'.format(port), subprotocols=[SUBPROTOCOL],
                           max_size=None) as ws:
            assert ws.subprotocol == SUBPROTOCOL
            c = Client(ws)
            await c.until(lambda: c.info is not None, 'serverInfo')
            assert {'clientPublish', 'services'} <= set(c.info['capabilities'])
            assert 'cdr' in c.info['supportedEncodings']
            assert c.info['metadata']['ROS_DISTRO'] == (os.environ.get('ROS_DISTRO') or 'jazzy')
            # Every topic the shipped layout shows is served (what it publishes, the teleop
            # test publishes as its panels do).
            reads, _ = _layout_topics(_layout())
            await c.until(lambda: reads <= set(c.channels), 'the layout topics')
            got = await c.subscribe(['/odom', '/scan', '/tf_static', '/robot_description'])
            await c.until(lambda: len(got['/odom']) >= 5 and len(got['/scan']) >= 2
                          and got['/tf_static'] and got['/robot_description'], 'messages')
            schema = c.channels['/odom']['schema']
            assert schema.startswith(open(os.path.join(
                _share('nav_msgs'), 'msg', 'Odometry.msg'), encoding='utf-8').read().rstrip())
            assert '\nMSG: geometry_msgs/PoseWithCovariance\n' in schema
            return got, c

    got, c = _run(main())
    odom = got['/odom'][-1]
    assert (odom.header.frame_id, odom.child_frame_id) == ('odom', 'base_footprint')
    scan = got['/scan'][-1]
    assert len(scan.ranges) > 100 and scan.angle_max > scan.angle_min
    # The static tree and the URDF were published long before this client connected.
    children = {t.child_frame_id for m in got['/tf_static'] for t in m.transforms}
    assert scan.header.frame_id in children
    assert '<robot' in got['/robot_description'][-1].data
    assert not [s for s in c.statuses if s['level'] == 2], c.statuses


LAYOUT = os.path.join(ROOT, 'config', 'foxglove', 'm4k_layout.json')


def _layout():
    with open(LAYOUT, encoding='utf-8') as f:
        return json.load(f)


def _layout_topics(doc):
    """Return the topics the layout's panels read, and {topic: type} of what they publish."""
    cfg = doc['configById']
    reads = {cfg['3D!m4k']['layers']['urdf']['topic'], *cfg['3D!m4k']['topics']}
    for key, panel in cfg.items():
        if key.startswith('Plot!'):
            reads |= {p['value'].split('.', 1)[0] for p in panel['paths']}
        elif key.startswith('DiagnosticSummary!'):
            reads.add(panel['topicToRender'])
    writes = {cfg['Teleop!m4k']['topic']: 'geometry_msgs/msg/Twist'}
    writes.update({p['topicName']: p['datatype'] for k, p in cfg.items()
                   if k.startswith('Publish!')})
    return reads, writes


def _panel_3d_publishes(doc):
    """Return {topic: type} the 3D panel advertises on load (Foxglove and Lichtblick's
    ThreeDeeRender advertise all three of its publish tool's topics, whatever the click type)."""
    pub = doc['configById']['3D!m4k']['publish']
    return {pub['poseTopic']: 'geometry_msgs/msg/PoseStamped',
            pub['pointTopic']: 'geometry_msgs/msg/PointStamped',
            pub['poseEstimateTopic']: 'geometry_msgs/msg/PoseWithCovarianceStamped'}


def test_the_layout_names_every_panel_it_places():
    doc = _layout()

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node['first']) + leaves(
            node['second'])

    assert sorted(leaves(doc['layout'])) == sorted(doc['configById'])
    reads, writes = _layout_topics(doc)
    assert {'/scan', '/odom', '/robot_description', '/diagnostics', '/sonar'} <= reads
    assert writes == {'/cmd_vel': 'geometry_msgs/msg/Twist', '/e_stop': 'std_msgs/msg/Bool'}
    # The 3D panel draws only what both Foxglove and Lichtblick render there: the scan, the
    # URDF placed by /tf (the robot's pose), the grid. Odometry and Range have no 3D renderer
    # in Lichtblick; odometry's speed and the sonar's range are plotted instead.
    assert set(doc['configById']['3D!m4k']['topics']) == {'/scan'}
    # Its publish tool names the nav topics the server knows (nav_goals).
    assert set(_panel_3d_publishes(doc)) == {'/goal_pose', '/clicked_point', '/initialpose'}


def _share(pkg):
    from ament_index_python.packages import get_package_share_directory
    return get_package_share_directory(pkg)


def test_teleop_on_cmd_vel_drives_the_robot_and_e_stop_stops_it(live):
    port, runtime_dir, _ = live
    start = ground_truth(runtime_dir)
    assert start is not None

    async def main():
        async with connect('ws://127.0.0.1:{}'.format(port), subprotocols=[SUBPROTOCOL]) as ws:
            c = Client(ws)
            await c.until(lambda: '/odom' in c.channels, 'the graph')
            # As the layout's teleop and e-stop panels advertise.
            _, writes = _layout_topics(_layout())
            await ws.send(json.dumps({'op': 'advertise', 'channels': [
                {'id': i, 'topic': t, 'encoding': 'cdr', 'schemaName': writes[t]}
                for i, t in ((1, '/cmd_vel'), (2, '/e_stop'))]}))
            forward = b'\x01' + struct.pack('<I', 1) + serialize_message(
                Twist(linear=Vector3(x=0.2)))

            async def drive_until(predicate, what):
                deadline = time.monotonic() + WAIT_S
                while not predicate(ground_truth(runtime_dir)):
                    assert time.monotonic() < deadline, 'timed out: ' + what
                    await ws.send(forward)       # 10 Hz, as the teleop panel publishes
                    await c.pump(0.1)

            await drive_until(lambda t: t['pose'][0] - start['pose'][0] > 0.3,
                              'the robot to drive 0.3 m forward')
            assert abs(ground_truth(runtime_dir)['pose'][1] - START[1]) < 0.05
            stop = b'\x01' + struct.pack('<I', 2) + serialize_message(Bool(data=True))
            await ws.send(stop)
            # Still commanding forward: the latched stop holds the robot.
            await drive_until(lambda t: abs(t['v']) < 0.005, 'the e-stop to stop the robot')
            held = ground_truth(runtime_dir)['pose']
            for _ in range(10):
                await ws.send(forward)
                await c.pump(0.1)
            after = ground_truth(runtime_dir)['pose']
            assert abs(after[0] - held[0]) < 0.01, (held, after)
            assert not [s for s in c.statuses if s['level'] == 2], c.statuses
            # Releasing needs the safety right, which the default (drive) does not give
            # (test_foxglove_rights_e2e has the clients that do and do not hold it).
            await ws.send(b'\x01' + struct.pack('<I', 2) + serialize_message(Bool(data=False)))
            await c.until(lambda: c.statuses and c.statuses[-1]['level'] == 2, 'the refusal')
            assert 'needs the safety right' in c.statuses[-1]['message']

    _run(main())


EVIL = 'http://evil.example'


def _raw_handshake(port, origin):
    """Open a WebSocket by hand with ``origin``; return everything the server sent."""
    s = socket.create_connection(('127.0.0.1', port))
    s.settimeout(WAIT_S)
    try:
        key = base64.b64encode(os.urandom(16)).decode()
        s.sendall(('GET / HTTP/1.1\r\nHost: localhost:{}\r\nUpgrade: websocket\r\n'
                   'Connection: Upgrade\r\nSec-WebSocket-Key: {}\r\n'
                   'Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: {}\r\n'
                   'Origin: {}\r\n\r\n'.format(port, key, SUBPROTOCOL, origin)).encode())
        data = b''
        while True:             # a refused handshake ends with the server closing
            chunk = s.recv(4096)
            if not chunk:
                return data
            data += chunk
    finally:
        s.close()


def test_a_foreign_origin_is_refused_before_server_info_and_the_robot_stays_put(live):
    # A web page open in the operator's browser reaches ws://localhost:8765 through the SSH
    # tunnel as well as the Foxglove app does; the browser stamps the page's Origin on the
    # handshake. It would advertise cmd_vel and drive -- if it got in.
    port, runtime_dir, _ = live
    start = ground_truth(runtime_dir)
    forward = b'\x01' + struct.pack('<I', 1) + serialize_message(Twist(linear=Vector3(x=0.3)))

    async def attack():
        try:
            async with connect('ws://127.0.0.1:{}'.format(port), subprotocols=[SUBPROTOCOL],
                               origin=EVIL) as ws:
                await ws.send(json.dumps({'op': 'advertise', 'channels': [
                    {'id': 1, 'topic': '/cmd_vel', 'encoding': 'cdr',
                     'schemaName': 'geometry_msgs/msg/Twist'}]}))
                for _ in range(30):
                    await ws.send(forward)
                    await asyncio.sleep(0.1)
                return 'served'
        except InvalidStatus as exc:
            return exc.response.status_code

    for _ in range(3):
        assert _run(attack()) == 403
    data = _raw_handshake(port, EVIL)
    assert data.startswith(b'HTTP/1.1 403'), data[:200]
    assert b'serverInfo' not in data and b'/odom' not in data
    after = ground_truth(runtime_dir)
    assert abs(after['pose'][0] - start['pose'][0]) < 0.005, (start, after)
    assert abs(after['v']) < 0.005

    # The Foxglove web app's origin is served and drives the robot.
    async def drive():
        async with connect('ws://127.0.0.1:{}'.format(port), subprotocols=[SUBPROTOCOL],
                           origin='https://app.foxglove.dev') as ws:
            c = Client(ws)
            await c.until(lambda: c.info is not None, 'serverInfo')
            await ws.send(json.dumps({'op': 'advertise', 'channels': [
                {'id': 1, 'topic': '/cmd_vel', 'encoding': 'cdr',
                 'schemaName': 'geometry_msgs/msg/Twist'}]}))
            deadline = time.monotonic() + WAIT_S
            while ground_truth(runtime_dir)['pose'][0] - start['pose'][0] < 0.1:
                assert time.monotonic() < deadline, 'the allowed client did not drive'
                await ws.send(forward)
                await c.pump(0.1)
            # Only the driver lock's notice (info): no warning, no error.
            assert [s['level'] for s in c.statuses] in ([], [0]), c.statuses

    _run(drive())


def test_the_layouts_publishers_as_the_app_advertises_them_raise_no_alert(live):
    # On connect the app advertises what the layout's panels publish: the teleop panel,
    # the e-stop buttons and the 3D panel's publish tool (goal, point, initial pose). Each
    # refusal would be a red alert; there must be none, nor any warning.
    port, _, _ = live
    doc = _layout()
    _, writes = _layout_topics(doc)
    writes.update(_panel_3d_publishes(doc))

    async def main():
        async with connect('ws://127.0.0.1:{}'.format(port), subprotocols=[SUBPROTOCOL],
                           origin='file://') as ws:          # the desktop app
            c = Client(ws)
            await c.until(lambda: '/m4k_bridge/reset_odometry' in c.services
                          and '/odom' in c.channels, 'the graph')
            chans = {t: i for i, t in enumerate(sorted(writes), start=1)}
            await ws.send(json.dumps({'op': 'advertise', 'channels': [
                {'id': i, 'topic': t, 'encoding': 'cdr', 'schemaName': writes[t]}
                for t, i in chans.items()]}))
            end = time.monotonic() + 3.0
            while time.monotonic() < end:
                await c.pump(0.2)
            assert c.statuses == []
            # A click of the publish tool while no nav stack is configured: one error naming
            # the parameter, and nothing reaches the graph.
            from geometry_msgs.msg import PoseStamped
            await ws.send(b'\x01' + struct.pack('<I', chans['/goal_pose'])
                          + serialize_message(PoseStamped()))
            await c.until(lambda: c.statuses, 'the status of the click')
            assert c.statuses[0]['level'] == 2 and 'nav_goals' in c.statuses[0]['message']
            end = time.monotonic() + 3.0           # more than two graph polls
            while time.monotonic() < end:
                await c.pump(0.2)
            assert '/goal_pose' not in c.channels

    _run(main())


@pytest.mark.parametrize('live', [{'control': {'cmd_vel_timeout': 0.0}}], indirect=True)
def test_a_teleop_client_that_disconnects_leaves_the_robot_stopped(live):
    # With the RT command timeout off the robot would keep its last command forever (up to
    # the collision guard at the wall, metres ahead): only the zero Twist the server publishes
    # when the client's cmd_vel channel goes away stops it. Without it the robot would stop
    # only at the guard, about 3 m on (the wall is 3.5 m away); with it, after the braking
    # distance plus the delivery delay. The bound tells the two apart without timing the
    # machine: 1.5 m at 0.2 m/s is 7 s of delay (a loaded VM has shown more than 2 s).
    port, runtime_dir, _ = live
    start = ground_truth(runtime_dir)

    async def main():
        ws = await connect('ws://127.0.0.1:{}'.format(port), subprotocols=[SUBPROTOCOL])
        c = Client(ws)
        await c.until(lambda: c.info is not None, 'serverInfo')
        await ws.send(json.dumps({'op': 'advertise', 'channels': [
            {'id': 1, 'topic': '/cmd_vel', 'encoding': 'cdr',
             'schemaName': 'geometry_msgs/msg/Twist'}]}))
        forward = b'\x01' + struct.pack('<I', 1) + serialize_message(
            Twist(linear=Vector3(x=0.2)))
        deadline = time.monotonic() + WAIT_S
        while ground_truth(runtime_dir)['pose'][0] - start['pose'][0] < 0.2:
            assert time.monotonic() < deadline, 'the robot did not drive'
            await ws.send(forward)
            await c.pump(0.1)
        await ws.send(forward)
        ws.transport.abort()          # the connection drops: no close, no unadvertise
        return ground_truth(runtime_dir)

    gone = asyncio.run(main())
    deadline = time.monotonic() + WAIT_S
    while abs(ground_truth(runtime_dir)['v']) > 0.005:
        assert time.monotonic() < deadline, 'the robot did not stop'
        time.sleep(0.1)
    rest = ground_truth(runtime_dir)
    assert rest['pose'][0] - gone['pose'][0] < 1.5, (gone['pose'], rest['pose'])
    assert rest['collisions'] == 0


def test_refuses_a_topic_outside_client_topics_and_unknown_channels(live):
    port, _, _ = live

    async def main():
        async with connect('ws://127.0.0.1:{}'.format(port), subprotocols=[SUBPROTOCOL]) as ws:
            c = Client(ws)
            await c.until(lambda: c.info is not None, 'serverInfo')
            await ws.send(json.dumps({'op': 'advertise', 'channels': [
                {'id': 5, 'topic': '/odom', 'encoding': 'cdr',
                 'schemaName': 'nav_msgs/msg/Odometry'}]}))
            await c.until(lambda: c.statuses, 'a status')
            assert c.statuses[-1]['level'] == 2
            assert 'clients may publish only on' in c.statuses[-1]['message']
            await ws.send(b'\x01' + struct.pack('<I', 5) + b'\x00\x01\x00\x00')
            await c.until(lambda: len(c.statuses) >= 2, 'a second status')
            assert 'not advertised' in c.statuses[-1]['message']

    _run(main())


def test_reset_odometry_is_callable_and_the_bridge_parameters_readable(live):
    port, _, _ = live
    from std_srvs.srv import Trigger

    async def main():
        async with connect('ws://127.0.0.1:{}'.format(port), subprotocols=[SUBPROTOCOL]) as ws:
            c = Client(ws)
            await c.until(lambda: '/m4k_bridge/reset_odometry' in c.services, 'the service')
            svc = c.services['/m4k_bridge/reset_odometry']
            assert svc['type'] == 'std_srvs/srv/Trigger'
            # The spec's current form (request/response objects), not the deprecated
            # requestSchema/responseSchema strings Lichtblick warns about.
            assert 'requestSchema' not in svc and 'responseSchema' not in svc
            assert svc['request'] == {'encoding': 'cdr', 'schemaEncoding': 'ros2msg',
                                      'schemaName': 'std_srvs/srv/Trigger_Request',
                                      'schema': ''}
            assert svc['response']['schemaName'] == 'std_srvs/srv/Trigger_Response'
            assert (svc['response']['encoding'], svc['response']['schemaEncoding']) == (
                'cdr', 'ros2msg')
            fields = [ln.split('#')[0].split() for ln in svc['response']['schema'].splitlines()]
            assert [f for f in fields if f] == [['bool', 'success'], ['string', 'message']]
            enc = b'cdr'
            await ws.send(struct.pack('<BIII', 0x02, svc['id'], 42, len(enc)) + enc
                          + serialize_message(Trigger.Request()))
            await c.until(lambda: c.responses, 'the response')
            sid, call, encoding, payload = c.responses[0]
            assert (sid, call, encoding) == (svc['id'], 42, 'cdr')
            assert deserialize_message(payload, Trigger.Response).success is True
            # A request in an encoding the server did not offer fails with the reason.
            await ws.send(struct.pack('<BIII', 0x02, svc['id'], 43, 4) + b'json' + b'{}')
            await c.until(lambda: c.texts[-1]['op'] == 'serviceCallFailure', 'the failure')
            failure = c.texts[-1]
            assert (failure['serviceId'], failure['callId']) == (svc['id'], 43)
            assert "encoding 'json' not supported" in failure['message']
            # The bridge's parameters, read through the parameters capability.
            values = {}
            deadline = time.monotonic() + WAIT_S
            while '/m4k_bridge.odom_frame' not in values:
                assert time.monotonic() < deadline, 'no bridge parameters'
                await ws.send(json.dumps({'op': 'getParameters', 'parameterNames': [],
                                          'id': 'q'}))
                await c.until(lambda: c.texts[-1]['op'] == 'parameterValues', 'the values')
                reply = c.texts[-1]
                assert reply['id'] == 'q'
                values = {p['name']: p for p in reply['parameters']}
            assert values['/m4k_bridge.odom_frame']['value'] == 'odom'
            assert values['/m4k_bridge.topics.cmd_vel']['value'] == 'cmd_vel'
            assert values['/m4k_bridge.rt_status_period'] == {
                'name': '/m4k_bridge.rt_status_period', 'value': 1.0, 'type': 'float64'}
            assert values['/m4k_foxglove.address']['value'] == '127.0.0.1'

    _run(main())


def _stalled_client(port, topics_channels):
    """Open a WebSocket by hand, subscribe, and never read again (a frozen viewer)."""
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    s.connect(('127.0.0.1', port))
    key = base64.b64encode(os.urandom(16)).decode()
    s.sendall(('GET / HTTP/1.1\r\nHost: 127.0.0.1:{}\r\nUpgrade: websocket\r\n'
               'Connection: Upgrade\r\nSec-WebSocket-Key: {}\r\nSec-WebSocket-Version: 13\r\n'
               'Sec-WebSocket-Protocol: {}\r\n\r\n'.format(port, key, SUBPROTOCOL)).encode())
    head = b''
    while b'\r\n\r\n' not in head:
        head += s.recv(1)
    assert head.startswith(b'HTTP/1.1 101'), head
    text = json.dumps({'op': 'subscribe', 'subscriptions': [
        {'id': i, 'channelId': ch} for i, ch in enumerate(topics_channels)]}).encode()
    assert len(text) < 1 << 16
    # A masked text frame (client frames must be masked; a zero mask leaves the bytes as they
    # are), its length in the 16-bit extended field.
    s.sendall(bytes([0x81, 0x80 | 126]) + struct.pack('>H', len(text)) + b'\x00\x00\x00\x00'
              + text)
    return s


def _rss_kib(pid):
    with open('/proc/{}/status'.format(pid), encoding='ascii') as f:
        return int(re.search(r'VmRSS:\s+(\d+)', f.read()).group(1))


def _server_values(diag_msgs):
    for d in reversed(diag_msgs):
        for st in d.status:
            if st.name == 'm4k_foxglove: server':
                return {kv.key: kv.value for kv in st.values}, st.level[0]
    return None, None


def test_a_stalled_client_is_dropped_for_and_never_slows_the_others(live):
    port, _, proc = live
    fox = [p for p in child_pids(proc.pid) if 'm4k_bridge.foxglove.node' in cmdline(p)]
    assert len(fox) == 1

    async def main():
        async with connect('ws://127.0.0.1:{}'.format(port), subprotocols=[SUBPROTOCOL]) as ws:
            c = Client(ws)
            got = await c.subscribe(['/odom', '/diagnostics'])
            heavy = ('/scan', '/odom', '/tf', '/imu')
            await c.until(lambda: all(t in c.channels for t in heavy), 'the sensor channels')
            ids = [c.channels[t]['id'] for t in heavy]
            stalled = _stalled_client(port, ids)
            try:
                def values():
                    return _server_values(got['/diagnostics'])[0] or {}

                await c.until(lambda: int(values().get('dropped_total', 0)) > 0,
                              'drops for the stalled client')
                rss0, dropped0 = _rss_kib(fox[0]), int(values()['dropped_total'])
                odom0 = len(got['/odom'])
                await c.until(lambda: int(values()['dropped_total']) > dropped0 + 300,
                              '300 more drops')
                v, level = _server_values(got['/diagnostics'])
                assert level == 1
                rows = {int(re.search(r':(\d+)\)$', key).group(1)): val
                        for key, val in v.items() if key.startswith('client ')}
                assert ' dropped 0 ' in rows[ws.local_address[1]], v    # this one reads
                # The stalled one, unless the server's keepalive (no pong for 20 s) has
                # already closed it: its queue within the bounds.
                stalled_row = rows.get(stalled.getsockname()[1])
                if stalled_row is not None:
                    queued = [int(x) for x in re.findall(r'queued (\d+) \((\d+) bytes',
                                                         stalled_row)[0]]
                    assert queued[0] <= int(v['max_queue_messages'])
                    assert queued[1] <= int(v['max_queue_bytes'])
                # A sanity bound on the process (the strict memory test is the server's own,
                # src/m4k_bridge/test/test_foxglove_server.py, with megabyte frames).
                assert _rss_kib(fox[0]) - rss0 < 16 * 1024
                # The reading client kept getting odometry all along, in order.
                new = got['/odom'][odom0:]
                assert len(new) > 50
                stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in new]
                assert stamps == sorted(stamps)
            finally:
                stalled.close()

    _run(main())
