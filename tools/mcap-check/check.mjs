// An m4k bag's MCAP file opened the way Lichtblick opens a local file, with the libraries it pins
// (see package.json): @mcap/core's McapIndexedReader, Lichtblick's decompressors, and its ROS 2
// message parser and CDR reader. Written from Lichtblick's behaviour as read in its source
// (packages/suite-base/src/players/IterablePlayer/Mcap/McapIterableSource.ts and
// McapUnindexedIterableSource.ts), not copied from it:
//   * the indexed path is taken when McapIndexedReader.Initialize succeeds AND the summary lists
//     at least one chunk index and one channel;
//   * otherwise the whole file is streamed into memory, and a file over 1 GiB (1024^3 bytes) is
//     refused ("unindexed files are limited to 1GB").
//
//   npm ci && node check.mjs BAG_0.mcap [--window-s 1] [--json]
//
// Checks, then reports: which path Lichtblick would take; every chunk index points at a Chunk
// record whose times match and whose message indexes (read at the offsets the chunk index
// gives) count the messages the Statistics record claims; then a fresh reader (as a viewer
// opening the file and seeking) reads the window [middle, middle + window) through the index,
// decodes every message with its schema, and counts the bytes it read from the file and the
// time it took. Exit 0 when all holds, 1 when a check fails, 2 on bad arguments.
import { open } from 'node:fs/promises';
import mcap from '@mcap/core';
import rosmsg from '@lichtblick/rosmsg';
import cdr from '@lichtblick/rosmsg2-serialization';
import wasmZstd from '@lichtblick/wasm-zstd';
import wasmLz4 from '@lichtblick/wasm-lz4';
import wasmBz2 from '@lichtblick/wasm-bz2';

// CommonJS packages: their exports come through the default import.
export const { McapIndexedReader, McapStreamReader } = mcap;
const { parse } = rosmsg;
const { MessageReader } = cdr;

export const UNINDEXED_LIMIT = 1024 * 1024 * 1024;

export async function decompressHandlers() {
  await wasmZstd.isLoaded;
  const lz4 = wasmLz4.default ?? wasmLz4;
  await lz4.isLoaded;
  const bz2 = await (wasmBz2.default ?? wasmBz2).init();
  return {
    zstd: (buf, size) => new Uint8Array(wasmZstd.decompress(buf, Number(size))),
    lz4: (buf, size) => new Uint8Array(lz4(buf, Number(size))),
    bz2: (buf, size) => new Uint8Array(bz2.decompress(buf, Number(size), { small: false })),
  };
}

// A file opened for random reads that counts the bytes read through it (McapTypes.IReadable).
export class CountingFile {
  constructor(fh, size) {
    this.fh = fh;
    this.bytes = 0;
    this.reads = 0;
    this.fileSize = size;
  }

  static async open(path) {
    const fh = await open(path, 'r');
    return new CountingFile(fh, (await fh.stat()).size);
  }

  async size() {
    return BigInt(this.fileSize);
  }

  async read(offset, size) {
    const n = Number(size);
    const buf = new Uint8Array(n);
    let got = 0;
    while (got < n) {
      const { bytesRead } = await this.fh.read(buf, got, n - got, Number(offset) + got);
      if (bytesRead === 0) throw new Error(`read past the end at ${Number(offset) + got}`);
      got += bytesRead;
    }
    this.bytes += n;
    this.reads += 1;
    return buf;
  }

  close() {
    return this.fh.close();
  }
}

// Lichtblick's choice for a local file: the indexed reader, or why not.
export async function lichtblickPath(readable, handlers) {
  try {
    const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers: handlers });
    if (reader.chunkIndexes.length === 0 || reader.channelsById.size === 0) {
      return { path: 'unindexed', reader, why: 'the summary lists no chunk index or no channel' };
    }
    return { path: 'indexed', reader };
  } catch (err) {
    return { path: 'unindexed', reader: undefined, why: String(err.message ?? err) };
  }
}

function decoders(reader) {
  const out = new Map();
  for (const [id, ch] of reader.channelsById) {
    const schema = reader.schemasById.get(ch.schemaId);
    if (ch.messageEncoding !== 'cdr' || !schema || schema.encoding !== 'ros2msg') {
      throw new Error(`channel ${ch.topic}: not ROS 2 CDR with a ros2msg schema`);
    }
    const text = new TextDecoder().decode(schema.data);
    out.set(id, new MessageReader(parse(text, { ros2: true })));
  }
  return out;
}

// Every chunk index against the file: a Chunk record at its offset with its length and times,
// message indexes where it says, and the message count the Statistics record claims.
async function checkIndex(reader, readable) {
  const problems = [];
  let indexed = 0;
  for (const ci of reader.chunkIndexes) {
    const head = await readable.read(ci.chunkStartOffset, 9n + 16n);
    const view = new DataView(head.buffer);
    if (view.getUint8(0) !== 0x06) problems.push(`no Chunk at ${ci.chunkStartOffset}`);
    if (view.getBigUint64(1, true) + 9n !== ci.chunkLength) {
      problems.push(`chunk at ${ci.chunkStartOffset}: length differs from its index`);
    }
    if (view.getBigUint64(9, true) !== ci.messageStartTime ||
        view.getBigUint64(17, true) !== ci.messageEndTime) {
      problems.push(`chunk at ${ci.chunkStartOffset}: times differ from its index`);
    }
    const blob = await readable.read(ci.chunkStartOffset + ci.chunkLength, ci.messageIndexLength);
    const stream = new McapStreamReader({ noMagicPrefix: true });
    stream.append(blob);
    const seen = new Map();
    let pos = ci.chunkStartOffset + ci.chunkLength;
    for (let rec; (rec = stream.nextRecord()); ) {
      if (rec.type !== 'MessageIndex') {
        problems.push(`a ${rec.type} among the message indexes at ${pos}`);
        continue;
      }
      seen.set(rec.channelId, pos);
      indexed += rec.records.length;
      pos += 9n + 2n + 4n + 16n * BigInt(rec.records.length);
    }
    for (const [cid, off] of ci.messageIndexOffsets) {
      if (seen.get(cid) !== off) problems.push(`message index of channel ${cid} not at ${off}`);
    }
  }
  const claimed = reader.statistics ? reader.statistics.messageCount : undefined;
  if (claimed !== undefined && claimed !== BigInt(indexed)) {
    problems.push(`statistics: ${claimed} messages, the message indexes: ${indexed}`);
  }
  return { indexed, problems };
}

export async function check(path, windowS = 1) {
  const handlers = await decompressHandlers();
  const out = { file: path };
  // 1. The index, checked whole (not counted in the seek's bytes).
  {
    const f = await CountingFile.open(path);
    try {
      out.file_bytes = f.fileSize;
      const choice = await lichtblickPath(f, handlers);
      out.lichtblick_path = choice.path;
      if (choice.path !== 'indexed') {
        out.why = choice.why;
        out.lichtblick_opens = f.fileSize <= UNINDEXED_LIMIT;
        out.ok = false;
        return out;
      }
      out.lichtblick_opens = true;
      const r = choice.reader;
      out.chunks = r.chunkIndexes.length;
      out.channels = [...r.channelsById.values()].map((c) => c.topic);
      out.statistics_messages = r.statistics ? Number(r.statistics.messageCount) : null;
      const { indexed, problems } = await checkIndex(r, f);
      out.indexed_messages = indexed;
      out.index_problems = problems;
    } finally {
      await f.close();
    }
  }
  // 2. A viewer opening the file and seeking to its middle: a fresh reader, bytes counted.
  const f = await CountingFile.open(path);
  try {
    const t0 = process.hrtime.bigint();
    const r = await McapIndexedReader.Initialize({ readable: f, decompressHandlers: handlers });
    const openBytes = f.bytes;
    const t1 = process.hrtime.bigint();
    let start = undefined;
    let end = undefined;
    for (const ci of r.chunkIndexes) {
      if (start === undefined || ci.messageStartTime < start) start = ci.messageStartTime;
      if (end === undefined || ci.messageEndTime > end) end = ci.messageEndTime;
    }
    const lo = start + (end - start) / 2n;
    const hi = lo + BigInt(Math.round(windowS * 1e9)) - 1n;   // readMessages' end is inclusive
    const dec = decoders(r);
    let n = 0;
    let decoded = 0;
    let last = -1n;
    const topics = {};
    for await (const m of r.readMessages({ startTime: lo, endTime: hi })) {
      if (m.logTime < lo || m.logTime > hi) throw new Error(`message at ${m.logTime} outside the window`);
      if (m.logTime < last) throw new Error('messages out of log-time order');
      last = m.logTime;
      dec.get(m.channelId).readMessage(m.data);
      decoded += 1;
      n += 1;
      const topic = r.channelsById.get(m.channelId).topic;
      topics[topic] = (topics[topic] ?? 0) + 1;
    }
    const t2 = process.hrtime.bigint();
    out.seek = {
      window_s: windowS,
      messages: n,
      decoded,
      per_topic: topics,
      open_bytes: openBytes,
      bytes_read: f.bytes,
      reads: f.reads,
      open_ms: Number(t1 - t0) / 1e6,
      total_ms: Number(t2 - t0) / 1e6,
    };
  } finally {
    await f.close();
  }
  out.ok = out.index_problems.length === 0 && out.seek.messages > 0 &&
    out.indexed_messages === out.statistics_messages;
  return out;
}

async function main(argv) {
  const args = argv.slice(2);
  let windowS = 1;
  let json = false;
  const files = [];
  for (let i = 0; i < args.length; i++) {
    if (args[i] === '--window-s') windowS = Number(args[++i]);
    else if (args[i] === '--json') json = true;
    else files.push(args[i]);
  }
  if (files.length !== 1 || !(windowS > 0)) {
    console.error('usage: node check.mjs FILE.mcap [--window-s SECONDS] [--json]');
    return 2;
  }
  const out = await check(files[0], windowS);
  if (json) {
    console.log(JSON.stringify(out));
  } else {
    console.log(`${out.file}: ${out.file_bytes} bytes; Lichtblick: ${out.lichtblick_path} path` +
      (out.why ? ` (${out.why}); ${out.lichtblick_opens ? 'opens (<= 1 GiB)' : 'REFUSED (> 1 GiB, unindexed)'}` : ''));
    if (out.seek) {
      console.log(`  ${out.chunks} chunks, ${out.indexed_messages} messages in the message indexes ` +
        `(statistics: ${out.statistics_messages}); index problems: ${out.index_problems.length}`);
      for (const p of out.index_problems.slice(0, 10)) console.log(`    ${p}`);
      const s = out.seek;
      console.log(`  seek to the middle, ${s.window_s} s: ${s.messages} messages (${s.decoded} decoded), ` +
        `${s.bytes_read} bytes read in ${s.reads} reads (${s.open_bytes} to open), ` +
        `${s.total_ms.toFixed(1)} ms (open ${s.open_ms.toFixed(1)} ms)`);
    }
    console.log(out.ok ? 'OK' : 'FAILED');
  }
  return out.ok ? 0 : 1;
}

if (import.meta.url === `file://${process.argv[1]}`) {
  main(process.argv).then((rc) => process.exit(rc), (err) => {
    console.error(err);
    process.exit(1);
  });
}
