"""liveview: a picture of what the Foxglove live view carries, from a running stack.

``python -m m4k_bench.liveview [--results DIR] [--drive-s S]`` starts the stack with the live
view (``bringup --foxglove``, a free port), connects as a Foxglove WebSocket client (protocol
v1, written from the spec; the CDR payloads decoded by the advertised schema name with rclpy),
subscribes to what the shipped layout shows (``config/foxglove/m4k_layout.json``), drives the
simulated robot through the protocol's client publishing on ``cmd_vel`` as the teleop panel
does, and renders what it received with matplotlib: a top view of the 3D panel's content
(the laser scan and the TF frames placed through ``/tf`` and ``/tf_static``, the odometry
trail, the footprint from ``/robot_description``), the odometry speed plot and the
diagnostics summary. Foxglove itself cannot be run here (offline), so this is not a
screenshot of Foxglove: it shows the same data its panels draw. Writes ``liveview.png`` and
``summary.json`` (messages per topic, the server's counters) to DIR
(default ``docs/results/liveview``).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import random
import re
import shutil
import sys
import tempfile
import time
from typing import Any, Sequence

from m4k_bench.benchlib import results
from m4k_bridge.interfaces import interface_class
from m4k_bringup.bringup import bringup_argv
from m4k_bringup.child import Child, Output, Stopping
from m4k_rt import rosargs

SUB = 'foxglove.websocket.v1'
TOPICS = ('/scan', '/odom', '/tf', '/tf_static', '/robot_description', '/diagnostics', '/sonar',
          '/imu')


def _yaw(q: Any) -> float:
    return math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))


async def collect(port: int, drive_s: float) -> dict[str, list[tuple[float, Any]]]:
    """Subscribe, drive a curve through client publishing, return (time, message) per topic."""
    from geometry_msgs.msg import Twist, Vector3
    from rclpy.serialization import deserialize_message, serialize_message
    from websockets.asyncio.client import connect
    from websockets.typing import Subprotocol

    got: dict[str, list[tuple[float, Any]]] = {t: [] for t in TOPICS}
    async with connect('ws://127.0.0.1:{}'.format(port),
                       subprotocols=[Subprotocol(SUB)], max_size=None) as ws:
        channels: dict[str, dict[str, Any]] = {}
        subs: dict[int, tuple[str, Any]] = {}

        async def pump(timeout: float) -> None:
            end = time.monotonic() + timeout
            while (left := end - time.monotonic()) > 0:
                try:
                    msg = await asyncio.wait_for(ws.recv(), left)
                except asyncio.TimeoutError:
                    return
                if isinstance(msg, str):
                    doc = json.loads(msg)
                    if doc['op'] == 'advertise':
                        channels.update({c['topic']: c for c in doc['channels']})
                elif msg[0] == 1:
                    sid = int.from_bytes(msg[1:5], 'little')
                    topic, cls = subs[sid]
                    got[topic].append((time.monotonic(), deserialize_message(msg[13:], cls)))

        deadline = time.monotonic() + 60
        while not set(TOPICS) <= set(channels):
            if time.monotonic() > deadline:
                raise RuntimeError('not advertised: {}'.format(set(TOPICS) - set(channels)))
            await pump(0.2)
        for i, t in enumerate(TOPICS):
            subs[i] = (t, interface_class(channels[t]['schemaName']))
        await ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
            {'id': i, 'channelId': channels[t]['id']} for i, t in enumerate(TOPICS)]}))
        await ws.send(json.dumps({'op': 'advertise', 'channels': [
            {'id': 1, 'topic': '/cmd_vel', 'encoding': 'cdr',
             'schemaName': 'geometry_msgs/msg/Twist'}]}))
        await pump(1.0)
        twist = serialize_message(Twist(linear=Vector3(x=0.25), angular=Vector3(z=0.35)))
        end = time.monotonic() + drive_s
        while time.monotonic() < end:            # 10 Hz, as Foxglove's teleop panel
            await ws.send(b'\x01' + (1).to_bytes(4, 'little') + twist)
            await pump(0.1)
        await ws.send(json.dumps({'op': 'unadvertise', 'channelIds': [1]}))
        await pump(2.0)
    return got


def _frames(got: dict[str, list[tuple[float, Any]]]) -> dict[str, tuple[str, float, float,
                                                                         float]]:
    """Return child -> (parent, x, y, yaw): tf_static, then the newest dynamic transforms."""
    edges: dict[str, tuple[str, float, float, float]] = {}
    for topic in ('/tf_static', '/tf'):
        for _, m in got[topic]:
            for t in m.transforms:
                tr = t.transform.translation
                edges[t.child_frame_id] = (t.header.frame_id, tr.x, tr.y,
                                           _yaw(t.transform.rotation))
    return edges


def _in(frame: str, root: str, edges: dict[str, tuple[str, float, float, float]]
        ) -> tuple[float, float, float] | None:
    x = y = th = 0.0
    seen = 0
    while frame != root:
        if frame not in edges or seen > 32:
            return None
        parent, ex, ey, eth = edges[frame]
        x, y = ex + math.cos(eth) * x - math.sin(eth) * y, ey + math.sin(eth) * x \
            + math.cos(eth) * y
        th += eth
        frame, seen = parent, seen + 1
    return x, y, th


def render(got: dict[str, list[tuple[float, Any]]], path: str) -> None:
    """Draw the received data as the layout's panels would show it."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(13, 6.5))
    top = fig.add_axes((0.04, 0.08, 0.5, 0.82))
    speed = fig.add_axes((0.6, 0.56, 0.38, 0.34))
    diag = fig.add_axes((0.6, 0.02, 0.38, 0.4))
    edges = _frames(got)
    trail = [(m.pose.pose.position.x, m.pose.pose.position.y) for _, m in got['/odom']]
    top.plot(*zip(*trail, strict=True), color='#2a7ab9', lw=1.5, label='/odom trail')
    scan = got['/scan'][-1][1]
    pose = _in(scan.header.frame_id, 'odom', edges)
    if pose is not None:
        px, py, pth = pose
        pts = [(px + r * math.cos(pth + scan.angle_min + i * scan.angle_increment),
                py + r * math.sin(pth + scan.angle_min + i * scan.angle_increment))
               for i, r in enumerate(scan.ranges) if scan.range_min <= r <= scan.range_max]
        top.scatter([p[0] for p in pts], [p[1] for p in pts], s=3, color='#d62728',
                    label='/scan ({} points, frame {})'.format(len(pts), scan.header.frame_id))
    urdf = got['/robot_description'][-1][1].data
    base = _in('base_link', 'odom', edges)
    m = re.search(r'<cylinder[^>]*radius="([0-9.]+)"', urdf)
    if base is not None and m:
        top.add_patch(plt.Circle(base[:2], float(m.group(1)), fill=False, color='k',
                                 label='footprint (robot_description)'))
    for frame in sorted(edges):
        f = _in(frame, 'odom', edges)
        if f is None:
            continue
        fx, fy, fth = f
        top.arrow(fx, fy, 0.12 * math.cos(fth), 0.12 * math.sin(fth), width=0.004,
                  color='#2ca02c')
        if not frame.endswith('wheel_link'):
            top.annotate(frame, (fx, fy), fontsize=7, xytext=(3, -8),
                         textcoords='offset points')
    top.set_aspect('equal')
    top.grid(True, alpha=0.3)
    top.set_xlabel('x in odom [m]')
    top.set_ylabel('y in odom [m]')
    top.set_title('3D panel content, seen from above: scan, TF frames, model')
    top.legend(loc='upper left', fontsize=8)
    t0 = got['/odom'][0][0]
    speed.plot([t - t0 for t, _ in got['/odom']],
               [m.twist.twist.linear.x for _, m in got['/odom']], label='v (m/s)')
    speed.plot([t - t0 for t, _ in got['/odom']],
               [m.twist.twist.angular.z for _, m in got['/odom']], label='w (rad/s)')
    speed.set_title('Plot panel: /odom twist (driven from the protocol, teleop-style)')
    speed.set_xlabel('receive time [s]')
    speed.legend(fontsize=8)
    speed.grid(True, alpha=0.3)
    latest: dict[str, Any] = {}
    for _, arr in got['/diagnostics']:
        for st in arr.status:
            latest[st.name] = st
    diag.axis('off')
    diag.set_title('Diagnostics panel: latest status per name')
    colors = {0: '#2ca02c', 1: '#ff7f0e', 2: '#d62728', 3: '#7f7f7f'}
    rows = sorted(latest.values(), key=lambda s: (-s.level[0], s.name))[:18]
    for i, st in enumerate(rows):
        diag.text(0, 1 - i * 0.055, '{:<5} {}: {}'.format(
            ('OK', 'WARN', 'ERROR', 'STALE')[st.level[0]], st.name, st.message)[:80],
            color=colors[st.level[0]], fontsize=7.5, family='monospace',
            transform=diag.transAxes)
    fig.suptitle('What the live view carries: data a Foxglove-protocol client received from a '
                 'running m4k stack (drawn with matplotlib, not a Foxglove screenshot)',
                 fontsize=10)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the stack with the live view, collect, render; return the exit code."""
    ap = argparse.ArgumentParser(prog='liveview', description=__doc__.split('\n\n')[0])
    ap.add_argument('--results', default=os.path.join('docs', 'results', 'liveview'))
    ap.add_argument('--drive-s', type=float, default=8.0)
    args = rosargs.parse_args(ap, argv)   # launch_ros's --ros-args section accepted
    if not args.drive_s > 0:
        ap.error(f'--drive-s must be > 0 s, got {args.drive_s}')
    env = dict(os.environ)
    env.setdefault('ROS_DOMAIN_ID', str(random.randint(1, 200)))
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    os.environ.update(env)
    tmp = tempfile.mkdtemp(prefix='m4k-liveview-')
    env['M4K_RUNTIME_DIR'] = os.path.join(tmp, 'rt')
    log_path = os.path.join(tmp, 'bringup.log')
    # bringup stops its own children on SIGTERM: 40 s for that, then SIGKILL.
    proc = Child('bringup', bringup_argv(python_m=False) + [
        '--no-status', '--foxglove', '--foxglove-port', '0'], env,
                 output=Output(log_path=log_path),
                 stopping=Stopping(timeout=40.0, must_end=True)).start()
    try:
        port = None
        deadline = time.monotonic() + 60
        while port is None and time.monotonic() < deadline and proc.alive():
            m = re.search(r'WebSocket server on ws://127\.0\.0\.1:(\d+)',
                          open(log_path, errors='replace').read())
            port = int(m.group(1)) if m else None
            time.sleep(0.2)
        if port is None:
            print(open(log_path, errors='replace').read()[-3000:], file=sys.stderr)
            return 2
        got = asyncio.run(collect(port, args.drive_s))
    finally:
        proc.stop()
        shutil.rmtree(tmp, ignore_errors=True)
    os.makedirs(args.results, exist_ok=True)
    render(got, os.path.join(args.results, 'liveview.png'))
    server = [{kv.key: kv.value for kv in st.values} for _, a in got['/diagnostics']
              for st in a.status if st.name == 'm4k_foxglove: server']
    summary = results.write_json(os.path.join(args.results, 'summary.json'), {
        'messages': {t: len(v) for t, v in got.items()},
        'server': server[-1] if server else None})
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == '__main__':
    sys.exit(main())
