// Every cut of a sync (src/m4k_bridge/test/bag_tears.py wrote them, with manifest.json) opened
// as Lichtblick opens a local file (check.mjs: the indexed path when the summary has chunk
// indexes, else @mcap/core's McapStreamReader over the whole file, <= 1 GiB), each message
// decoded with Lichtblick's CDR reader and compared with what was written.
//
//   node tear.mjs DIR [--report-only]      (tear.sh makes DIR and runs this)
//
// Prints, per kind of cut, what Lichtblick shows; exit 1 if any cut does not open with exactly
// the messages synced before the cut sync or after it (unless --report-only).
import { readFile } from 'node:fs/promises';
import rosmsg from '@lichtblick/rosmsg';
import cdr from '@lichtblick/rosmsg2-serialization';
import { CountingFile, decompressHandlers, lichtblickPath, McapStreamReader,
  UNINDEXED_LIMIT } from './check.mjs';

const PIECE = 64 * 1024;    // a Blob stream's pieces; Lichtblick appends them one by one

function decoderFor(schemas, channel) {
  const schema = schemas.get(channel.schemaId);
  return new cdr.MessageReader(rosmsg.parse(new TextDecoder().decode(schema.data), { ros2: true }));
}

// Lichtblick's unindexed path: append the file piece by piece, take every record, decode.
async function streamed(path, handlers) {
  const bytes = await readFile(path);
  const reader = new McapStreamReader({ decompressHandlers: handlers });
  const schemas = new Map();
  const decoders = new Map();
  const texts = [];
  try {
    for (let at = 0; at < bytes.length; at += PIECE) {
      reader.append(bytes.subarray(at, at + PIECE));
      for (let rec; (rec = reader.nextRecord()); ) {
        if (rec.type === 'Schema') schemas.set(rec.id, rec);
        else if (rec.type === 'Channel' && !decoders.has(rec.id)) decoders.set(rec.id, decoderFor(schemas, rec));
        else if (rec.type === 'Message') texts.push(decoders.get(rec.channelId).readMessage(rec.data).data);
      }
    }
  } catch (err) {
    return { texts, error: String(err.message ?? err), footer: reader.done() };
  }
  return { texts, error: null, footer: reader.done() };
}

async function indexed(path, handlers) {
  const f = await CountingFile.open(path);
  try {
    const choice = await lichtblickPath(f, handlers);
    if (choice.path !== 'indexed') return { path: 'unindexed', why: choice.why, size: f.fileSize };
    const texts = [];
    const decoders = new Map();
    for await (const m of choice.reader.readMessages()) {
      if (!decoders.has(m.channelId)) {
        decoders.set(m.channelId, decoderFor(choice.reader.schemasById,
          choice.reader.channelsById.get(m.channelId)));
      }
      texts.push(decoders.get(m.channelId).readMessage(m.data).data);
    }
    return { path: 'indexed', texts };
  } catch (err) {
    return { path: 'indexed', error: String(err.message ?? err) };
  } finally {
    await f.close();
  }
}

function same(a, b) {
  return a.length === b.length && a.every((x, i) => x === b[i]);
}

async function main(argv) {
  const dir = argv[2];
  const reportOnly = argv.includes('--report-only');
  if (!dir) {
    console.error('usage: node tear.mjs DIR [--report-only]');
    return 2;
  }
  const manifest = JSON.parse(await readFile(`${dir}/manifest.json`, 'utf8'));
  const handlers = await decompressHandlers();
  const before = manifest.texts.slice(0, manifest.before);
  const after = manifest.texts.slice(0, manifest.after);
  const classes = new Map();
  let bad = 0;
  for (const im of manifest.images) {
    const ix = await indexed(im.file, handlers);
    let shown;
    if (ix.path === 'indexed') {
      shown = ix.error ? { error: ix.error, texts: [] } : { error: null, texts: ix.texts };
    } else if (ix.size > UNINDEXED_LIMIT) {
      shown = { error: 'unindexed file over 1 GiB', texts: [] };
    } else {
      shown = await streamed(im.file, handlers);
    }
    const opens = !shown.error && (same(shown.texts, before) || same(shown.texts, after));
    if (!opens) bad += 1;
    const where = im.op < 0 ? 'before the sync'
      : `${im.kind} ${im.op} (${im.length} B at ${im.offset}) ` +
        (im.k === 0 ? 'not started' : im.k === im.length ? 'whole' : 'torn');
    const verdict = `${ix.path} path: ` + (opens ? `opens, ${shown.texts.length} messages`
      : `FAILS (${shown.error?.replace(/\d+/g, 'N') ?? `${shown.texts.length} messages, expected ${before.length} or ${after.length}`})`);
    const key = `${where} -> ${verdict}`;
    classes.set(key, (classes.get(key) ?? 0) + 1);
  }
  for (const [k, n] of classes) console.log(`${String(n).padStart(5)} cut(s): ${k}`);
  console.log(`${manifest.images.length} distinct cuts, ${bad} that Lichtblick cannot open ` +
    'with the messages of a completed sync');
  return bad && !reportOnly ? 1 : 0;
}

main(process.argv).then((rc) => process.exit(rc), (err) => {
  console.error(err);
  process.exit(1);
});
