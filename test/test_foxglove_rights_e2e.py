"""Rights in the live view, end to end: view, drive and safety clients on the running stack.

``bringup --foxglove`` with a parameter file giving rights by token (``rights``,
``drive_token_file``, ``safety_token_file``). The clients are written from the Foxglove
WebSocket protocol specification (``test_foxglove_e2e.Client``: JSON ops, ``struct`` frames,
CDR decoded by rclpy); they present their tokens in each of the places the server reads them
(URL query, ``Authorization: Bearer``, an offered ``m4k-token.`` subprotocol). What a client
could do is judged on the simulator's ground truth and on the bridge's own reports of the RT
latches (``e_stop_state``, ``motor_fault``), never on what the live view says it did.
"""

import asyncio
import json
import os
import signal
import struct
import time

from geometry_msgs.msg import Twist, Vector3
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import Bool
from std_srvs.srv import SetBool, Trigger
from test_bringup import start_bringup, write_overlay
from test_foxglove_e2e import _log_port, Client, START, SUBPROTOCOL, WAIT_S
from websockets.asyncio.client import connect
from wsenv import ground_truth
import yaml

pytestmark = pytest.mark.allow_leaks('fds')  # FastDDS keeps its sockets for the process

DRIVE = 'drive-token-0123456789abcdef'
SAFETY = 'safety-token-0123456789abcdef'
STILL = 0.005        # m/s: at rest
MOVED = 0.005        # m: the robot has not moved


@pytest.fixture
def rights_live(procs, tmp_path, m4k_runtime_dir, request):
    """The stack with a live view whose rights come from tokens; yield (port, runtime dir)."""
    opts = dict(getattr(request, 'param', {}))
    world = {'start': START}
    world.update(opts.pop('world', {}))
    files = {}
    for name, token in (('drive', DRIVE), ('safety', SAFETY)):
        path = tmp_path / (name + '.token')
        path.write_text(token + '\n')
        os.chmod(path, 0o600)
        files[name + '_token_file'] = str(path)
    params = tmp_path / 'foxglove.yaml'
    params.write_text(yaml.safe_dump({'m4k_foxglove': {'ros__parameters': dict(
        rights=opts.pop('rights', 'drive'), **files, **opts)}}))
    overlay = write_overlay(tmp_path, {'world': world})
    proc = start_bringup(procs, tmp_path, m4k_runtime_dir, overlay,
                         extra=['--no-status', '--foxglove', '--foxglove-port', '0',
                                '--foxglove-params', str(params)])
    try:
        yield _log_port(tmp_path / 'bringup.err', time.monotonic() + WAIT_S), m4k_runtime_dir
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            proc.wait(40)


def _open(port, token=None, how='query'):
    url = 'ws://127.0.0.1:{}/'.format(port)
    kw = {'subprotocols': [SUBPROTOCOL], 'max_size': None}
    if token is not None and how == 'query':
        url += '?token=' + token
    elif token is not None and how == 'bearer':
        kw['additional_headers'] = {'Authorization': 'Bearer ' + token}
    elif token is not None:
        kw['subprotocols'] = [SUBPROTOCOL, 'm4k-token.' + token]
    return connect(url, **kw)


def _frame(channel, msg):
    return b'\x01' + struct.pack('<I', channel) + serialize_message(msg)


def _call(service, call_id, request):
    return struct.pack('<BIII', 0x02, service['id'], call_id, 3) + b'cdr' \
        + serialize_message(request)


async def _advertise(ws, channels):
    await ws.send(json.dumps({'op': 'advertise', 'channels': [
        {'id': i, 'topic': t, 'encoding': 'cdr', 'schemaName': s} for i, t, s in channels]}))


async def _latest(c, got, what, value):
    """Wait for a fresh ``what`` message (the bridge republishes at 1 Hz) equal to value."""
    n = len(got)
    await c.until(lambda: len(got) > n + 1, 'two fresh ' + what + ' messages')
    await c.until(lambda: got[-1].data is value, '{} {}'.format(what, value))


@pytest.mark.parametrize('rights_live', [{'rights': 'view'}], indirect=True)
def test_a_view_only_client_cannot_release_the_e_stop_or_move_the_robot(rights_live):
    port, runtime_dir = rights_live

    async def main():
        async with _open(port, SAFETY, 'bearer') as sws, _open(port) as vws:
            boss, viewer = Client(sws), Client(vws)
            await boss.until(lambda: '/m4k_bridge/e_stop' in boss.services, 'the services')
            assert {'clientPublish', 'services'} <= set(boss.info['capabilities'])
            assert {'/m4k_bridge/reset_motor_fault', '/m4k_bridge/set_pose'} <= set(
                boss.services)
            e_stop = boss.services['/m4k_bridge/e_stop']
            await sws.send(_call(e_stop, 1, SetBool.Request(data=True)))
            await boss.until(lambda: boss.responses, 'the engage response')
            assert deserialize_message(boss.responses[0][3], SetBool.Response).success

            # The viewer: no write capability offered, no service advertised at all.
            state = (await viewer.subscribe(['/e_stop_state']))['/e_stop_state']
            await viewer.until(lambda: viewer.info is not None, 'serverInfo')
            assert 'clientPublish' not in viewer.info['capabilities']
            assert 'services' not in viewer.info['capabilities']
            await _latest(viewer, state, 'e_stop_state', True)
            assert viewer.services == {}
            assert not [t for t in viewer.texts if t['op'] == 'advertiseServices']
            # It tries anyway, as a hand-written client could: advertise, publish, call.
            await _advertise(vws, [(1, '/e_stop', 'std_msgs/msg/Bool'),
                                   (2, '/cmd_vel', 'geometry_msgs/msg/Twist')])
            await vws.send(_frame(1, Bool(data=False)))
            await vws.send(_call(e_stop, 7, SetBool.Request(data=False)))
            start = ground_truth(runtime_dir)
            for _ in range(20):
                await vws.send(_frame(2, Twist(linear=Vector3(x=0.3))))
                await viewer.pump(0.05)
            await viewer.until(lambda: len(viewer.statuses) >= 3, 'the refusals')
            texts = ' | '.join(s['message'] for s in viewer.statuses)
            assert 'clientPublish is not enabled for this client (right view)' in texts
            assert 'services are not enabled for this client (right view)' in texts
            assert viewer.responses == []
            # The latch holds (the bridge's report of the RT latch, fresh), the robot is put.
            await _latest(viewer, state, 'e_stop_state', True)

            # Released by the safety client, the latch opens; the viewer still cannot drive.
            await _advertise(sws, [(1, '/e_stop', 'std_msgs/msg/Bool')])
            await sws.send(_frame(1, Bool(data=False)))
            await _latest(viewer, state, 'e_stop_state', False)
            for _ in range(30):
                await vws.send(_frame(2, Twist(linear=Vector3(x=0.3))))
                await viewer.pump(0.05)
            end = ground_truth(runtime_dir)
            assert abs(end['pose'][0] - start['pose'][0]) < MOVED, (start, end)
            assert abs(end['v']) < STILL

    asyncio.run(main())


# Both wheels blocked: the robot cannot move, so no obstacle comes near and the guard never
# takes the setpoint away before the supervision latches (one stalled wheel pivots the robot,
# and under load the guard was seen to stop it first).
@pytest.mark.parametrize('rights_live', [{'world': {'faults': [
    {'at_s': 0.0, 'kind': 'wheel_stall', 'wheel': 'both'}]}}], indirect=True)
def test_a_driver_cannot_clear_a_motor_fault_or_release_the_e_stop(rights_live):
    port, _ = rights_live

    async def main():
        async with _open(port, DRIVE, 'subprotocol') as dws, _open(port, SAFETY) as sws:
            driver, boss = Client(dws), Client(sws)
            assert dws.subprotocol == SUBPROTOCOL       # the token's never selected
            fault = (await driver.subscribe(['/motor_fault']))['/motor_fault']
            await boss.until(lambda: '/m4k_bridge/reset_motor_fault' in boss.services,
                             'the safety client sees the reset')
            await driver.until(lambda: '/m4k_bridge/e_stop' in driver.services,
                               'the drive services')
            assert set(driver.services) == {'/m4k_bridge/e_stop', '/m4k_bridge/reset_odometry'}
            # Drive against the stalled wheel until the RT supervision latches the fault.
            await _advertise(dws, [(1, '/cmd_vel', 'geometry_msgs/msg/Twist'),
                                   (2, '/e_stop', 'std_msgs/msg/Bool')])
            deadline = time.monotonic() + WAIT_S
            while not (fault and fault[-1].data):
                assert time.monotonic() < deadline, 'no motor fault latched'
                await dws.send(_frame(1, Twist(linear=Vector3(x=0.2))))
                await driver.pump(0.1)
            # The driver calls the reset by the id the safety client was told: refused.
            reset = boss.services['/m4k_bridge/reset_motor_fault']
            await dws.send(_call(reset, 5, Trigger.Request()))
            await driver.until(lambda: any('no service {}'.format(reset['id']) in s['message']
                                           for s in driver.statuses), 'the refusal')
            await _latest(driver, fault, 'motor_fault', True)
            assert driver.responses == []
            # The safety client's reset clears it (the RT side answers: cleared).
            await sws.send(_call(reset, 6, Trigger.Request()))
            await boss.until(lambda: boss.responses, 'the reset response')
            res = deserialize_message(boss.responses[0][3], Trigger.Response)
            assert res.success and 'motor fault cleared' in res.message, res.message
            await _latest(driver, fault, 'motor_fault', False)
            # Nor may the driver release an e-stop it engaged (the engage is its right).
            await dws.send(_frame(2, Bool(data=True)))
            await dws.send(_frame(2, Bool(data=False)))
            await driver.until(lambda: any('needs the safety right' in s['message']
                                           for s in driver.statuses), 'the release refusal')
            state = (await boss.subscribe(['/e_stop_state'], first_id=50))['/e_stop_state']
            await _latest(boss, state, 'e_stop_state', True)

    asyncio.run(main())


def test_one_clients_flood_does_not_stop_another_clients_e_stop_from_latching(rights_live):
    port, runtime_dir = rights_live
    start = ground_truth(runtime_dir)
    forward = _frame(1, Twist(linear=Vector3(x=0.2)))

    async def main():
        async with _open(port) as aws, _open(port) as bws:
            a, b = Client(aws), Client(bws)
            state = (await b.subscribe(['/e_stop_state']))['/e_stop_state']
            await _advertise(aws, [(1, '/cmd_vel', 'geometry_msgs/msg/Twist')])
            await _advertise(bws, [(1, '/e_stop', 'std_msgs/msg/Bool')])

            async def flood(n):
                for _ in range(n):           # as fast as the socket takes them
                    await aws.send(forward)
                await a.pump(0.01)

            deadline = time.monotonic() + WAIT_S
            while ground_truth(runtime_dir)['pose'][0] - start['pose'][0] < 0.2:
                assert time.monotonic() < deadline, 'the flooding client did not drive'
                await flood(200)
            assert any(s['level'] == 1 and 'max_publish_rate' in s['message']
                       for s in a.statuses), a.statuses
            # B engages in the middle of A's flood, which goes on.
            await bws.send(_frame(1, Bool(data=True)))
            deadline = time.monotonic() + WAIT_S
            while not (state and state[-1].data is True
                       and abs(ground_truth(runtime_dir)['v']) < STILL):
                assert time.monotonic() < deadline, 'the e-stop did not latch under the flood'
                await flood(200)
                await b.pump(0.01)
            held = ground_truth(runtime_dir)['pose']
            for _ in range(10):
                await flood(200)
                await b.pump(0.05)
            after = ground_truth(runtime_dir)['pose']
            assert abs(after[0] - held[0]) < 0.01, (held, after)
            assert not [s for s in b.statuses if s['level'] >= 1], b.statuses

    asyncio.run(main())


def test_one_client_drives_at_a_time_and_the_lock_is_taken_over_when_idle(rights_live):
    port, runtime_dir = rights_live
    start = ground_truth(runtime_dir)

    async def main():
        async with _open(port) as aws, _open(port) as bws:
            a, b = Client(aws), Client(bws)
            await a.until(lambda: a.info is not None, 'serverInfo')
            await b.until(lambda: b.info is not None, 'serverInfo')
            for ws in (aws, bws):
                await _advertise(ws, [(1, '/cmd_vel', 'geometry_msgs/msg/Twist')])
            stop, forward = _frame(1, Twist()), _frame(1, Twist(linear=Vector3(x=0.3)))
            await aws.send(stop)          # A takes the lock, holding the robot still
            await b.until(lambda: any('drives now' in s['message'] for s in b.statuses),
                          'the owner announced')
            for _ in range(30):           # B's forward commands are not published
                await aws.send(stop)
                await bws.send(forward)
                await b.pump(0.1)
            assert any('drives; it may be taken over' in s['message'] for s in b.statuses)
            mid = ground_truth(runtime_dir)
            assert abs(mid['pose'][0] - start['pose'][0]) < MOVED, (start, mid)
            # A falls silent: after driver_idle_timeout B takes over and drives.
            deadline = time.monotonic() + WAIT_S
            while ground_truth(runtime_dir)['pose'][0] - start['pose'][0] < 0.1:
                assert time.monotonic() < deadline, 'B never took over'
                await bws.send(forward)
                await b.pump(0.1)
            await bws.send(stop)

    asyncio.run(main())
