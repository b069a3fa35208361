// Every message of an MCAP file decoded as Lichtblick decodes ROS 2 data: the ros2msg schema in
// the file parsed by @lichtblick/rosmsg, the CDR by @lichtblick/rosmsg2-serialization. Prints
// one JSON line per message ({topic, schema, log_time, message}; bigints and typed arrays as
// plain numbers and lists), so a caller can compare them with what was written.
//   node decode.mjs FILE.mcap
import { readFile } from 'node:fs/promises';
import rosmsg from '@lichtblick/rosmsg';
import cdr from '@lichtblick/rosmsg2-serialization';
import { decompressHandlers, McapStreamReader } from './check.mjs';

const plain = (_k, v) => (typeof v === 'bigint' ? Number(v)
  : ArrayBuffer.isView(v) ? Array.from(v) : v);

const reader = new McapStreamReader({ decompressHandlers: await decompressHandlers() });
reader.append(await readFile(process.argv[2]));
const schemas = new Map();
const channels = new Map();
for (let rec; (rec = reader.nextRecord()); ) {
  if (rec.type === 'Schema') schemas.set(rec.id, rec);
  else if (rec.type === 'Channel' && !channels.has(rec.id)) {
    const s = schemas.get(rec.schemaId);
    const def = rosmsg.parse(new TextDecoder().decode(s.data), { ros2: true });
    channels.set(rec.id, { topic: rec.topic, schema: s.name, reader: new cdr.MessageReader(def) });
  } else if (rec.type === 'Message') {
    const c = channels.get(rec.channelId);
    const message = c.reader.readMessage(rec.data);
    console.log(JSON.stringify({ topic: c.topic, schema: c.schema, log_time: rec.logTime, message }, plain));
  }
}
if (!reader.done()) {
  console.error('decode.mjs: the file ended before its footer');
  process.exit(1);
}
