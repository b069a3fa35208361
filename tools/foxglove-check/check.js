// The m4k live view seen by Foxglove's own code: @foxglove/ws-protocol's FoxgloveClient, the
// ros2msg parser (@foxglove/rosmsg) and the CDR reader/writer (@foxglove/rosmsg2-serialization)
// that Foxglove uses for ROS 2 data. Manual check (docs/live-view.md):
//   npm install && node check.js ws://127.0.0.1:8765
// Subscribes to the layout's main topics, decodes them, reads the parameters, calls
// reset_odometry and drives 3 s at 0.2 m/s on cmd_vel (watch `sim_truth`). Exit 0 when all came.
'use strict';
const { FoxgloveClient } = require('@foxglove/ws-protocol');
const WebSocket = require('ws');
const { parse } = require('@foxglove/rosmsg');
const { MessageReader, MessageWriter } = require('@foxglove/rosmsg2-serialization');

const url = process.argv[2] || 'ws://127.0.0.1:8765';
const want = ['/odom', '/scan', '/tf', '/tf_static', '/robot_description', '/diagnostics'];
const client = new FoxgloveClient({
  ws: new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]),
});
const readers = new Map();
const topicOf = new Map();
const counts = {};
const last = {};
let services = [];
let params = null;
let reset = null;

client.on('status', (s) => console.log('status', JSON.stringify(s)));
client.on('advertise', (channels) => {
  for (const c of channels) {
    if (!want.includes(c.topic) || readers.has(c.topic)) continue;
    readers.set(c.topic, new MessageReader(parse(c.schema, { ros2: true })));
    topicOf.set(client.subscribe(c.id), c.topic);
  }
});
client.on('message', ({ subscriptionId, data }) => {
  const topic = topicOf.get(subscriptionId);
  last[topic] = readers.get(topic).readMessage(data);
  counts[topic] = (counts[topic] || 0) + 1;
});
client.on('advertiseServices', (s) => { services = services.concat(s); });
client.on('parameterValues', (p) => { params = p.parameters; });
client.on('serviceCallResponse', (r) => {
  const svc = services.find((s) => s.id === r.serviceId);
  reset = new MessageReader(parse(svc.response.schema, { ros2: true })).readMessage(r.data);
});

client.on('open', () => {
  setTimeout(() => {
    client.getParameters([], 'all');
    const svc = services.find((s) => s.name.endsWith('/reset_odometry'));
    if (svc) {
      const req = new MessageWriter(parse(svc.request.schema, { ros2: true })).writeMessage({});
      client.sendServiceCallRequest({ serviceId: svc.id, callId: 1, encoding: 'cdr', data: req });
    }
    const twist = new MessageWriter(parse(
      'geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular\n' + '='.repeat(80) +
      '\nMSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n', { ros2: true }));
    const ch = client.advertise({ topic: '/cmd_vel', encoding: 'cdr',
                                  schemaName: 'geometry_msgs/msg/Twist' });
    const data = twist.writeMessage({ linear: { x: 0.2, y: 0, z: 0 },
                                      angular: { x: 0, y: 0, z: 0 } });
    let n = 0;
    const timer = setInterval(() => {  // 10 Hz for 3 s, as the teleop panel publishes
      client.sendMessage(ch, data);
      if (++n >= 30) { clearInterval(timer); client.unadvertise(ch); }
    }, 100);
  }, 3000);
  setTimeout(() => {
    console.log('messages', JSON.stringify(counts));
    const ok = want.every((t) => counts[t] > 0) && params && params.length > 0 && reset;
    if (last['/odom']) {
      const o = last['/odom'];
      console.log('odom', o.header.frame_id, '->', o.child_frame_id,
                  'x', o.pose.pose.position.x.toFixed(3));
    }
    if (last['/tf_static']) {
      console.log('tf_static', last['/tf_static'].transforms.map(
        (t) => t.header.frame_id + '->' + t.child_frame_id).join(' '));
    }
    console.log('parameters', params ? params.length : 0, 'reset_odometry', JSON.stringify(reset));
    client.close();
    process.exit(ok ? 0 : 1);
  }, 9000);
});
