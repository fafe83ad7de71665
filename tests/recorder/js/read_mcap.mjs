// An independent MCAP reader for the recorder tests: Foxglove's @mcap/core (TypeScript), not the
// Python mcap package the recorder is built on. Prints one JSON object:
//   stream:  what McapStreamReader reads record by record (works on a file cut short):
//            per-topic message counts, whether the file ended cleanly (footer + magic),
//            bytes left unparsed at the end, messages whose payload is not valid JSON,
//            the largest log time, and the error that stopped it (null if none)
//   indexed: per-topic counts through McapIndexedReader (summary and chunk indexes), or null
//            when the file is not complete
// usage: node read_mcap.mjs FILE

import { open, readFile } from "node:fs/promises";
import { McapIndexedReader, McapStreamReader } from "@mcap/core";

function streamRead(bytes) {
  const reader = new McapStreamReader({ validateCrcs: true });
  const topics = new Map();
  const decoder = new TextDecoder("utf-8", { fatal: true });
  const out = { topics: {}, complete: false, bytes_remaining: 0, invalid_json: 0,
                last_log_time_ns: null, error: null };
  let last = null;
  try {
    reader.append(bytes);
    for (let rec; (rec = reader.nextRecord()); ) {
      if (rec.type === "Channel") {
        topics.set(rec.id, rec.topic);
      } else if (rec.type === "Message") {
        const topic = topics.get(rec.channelId);
        out.topics[topic] = (out.topics[topic] ?? 0) + 1;
        if (last === null || rec.logTime > last) last = rec.logTime;
        try {
          JSON.parse(decoder.decode(rec.data));
        } catch {
          out.invalid_json += 1;
        }
      }
    }
  } catch (err) {
    out.error = String(err.message ?? err);
  }
  out.complete = reader.done();
  out.bytes_remaining = reader.bytesRemaining();
  out.last_log_time_ns = last === null ? null : last.toString();
  return out;
}

async function indexedRead(path) {
  const fh = await open(path, "r");
  try {
    const readable = {
      size: async () => BigInt((await fh.stat()).size),
      read: async (offset, size) => {
        const buf = new Uint8Array(Number(size));
        await fh.read(buf, 0, buf.length, Number(offset));
        return buf;
      },
    };
    const reader = await McapIndexedReader.Initialize({ readable });
    const counts = {};
    for await (const msg of reader.readMessages()) {
      const topic = reader.channelsById.get(msg.channelId).topic;
      counts[topic] = (counts[topic] ?? 0) + 1;
    }
    return { topics: counts };
  } finally {
    await fh.close();
  }
}

const path = process.argv[2];
if (!path) {
  console.error("usage: node read_mcap.mjs FILE");
  process.exit(2);
}
const stream = streamRead(await readFile(path));
const indexed = stream.complete ? await indexedRead(path) : null;
console.log(JSON.stringify({ stream, indexed }));
