// Independent MCAP reader for the cross-check test (tests/converters/test_independent_reader.py).
//
// Reads each file given on the command line with the TypeScript reference implementation
// (@mcap/core, zstd from @mcap/support, file access from @mcap/nodejs) twice: through the
// summary and indexes (McapIndexedReader), and record by record with CRC checks
// (McapStreamReader). Prints one JSON object per file with what both readers found: per-topic
// counts, log-time range, metadata and a digest over every message, defined exactly as
// skyvln_eval.converters.reader.message_digest defines it.
import { createHash } from "node:crypto";
import { open, readFile } from "node:fs/promises";

import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { FileHandleReadable } from "@mcap/nodejs";
import { loadDecompressHandlers } from "@mcap/support";

function digestOf(messages, topicOf) {
  const sorted = [...messages].sort((a, b) => a.sequence - b.sequence);
  const hash = createHash("sha256");
  for (const m of sorted) {
    const head = `${topicOf(m.channelId)}\n${m.logTime}\n${m.publishTime}\n${m.sequence}\n${m.data.byteLength}\n`;
    hash.update(Buffer.from(head, "utf8"));
    hash.update(m.data);
  }
  return hash.digest("hex");
}

function summarise(messages, topicOf, metadata) {
  const counts = {};
  let start = null;
  let end = null;
  for (const m of messages) {
    const topic = topicOf(m.channelId);
    counts[topic] = (counts[topic] ?? 0) + 1;
    if (start === null || m.logTime < start) start = m.logTime;
    if (end === null || m.logTime > end) end = m.logTime;
  }
  const sortedCounts = Object.fromEntries(Object.entries(counts).sort());
  return {
    topic_counts: sortedCounts,
    start_time_ns: start === null ? null : start.toString(),
    end_time_ns: end === null ? null : end.toString(),
    metadata,
    digest: digestOf(messages, topicOf),
  };
}

function metadataObject(records) {
  const out = {};
  for (const record of [...records].sort((a, b) => (a.name < b.name ? -1 : 1))) {
    out[record.name] = Object.fromEntries([...record.metadata.entries()].sort());
  }
  return out;
}

async function readIndexed(path, decompressHandlers) {
  const handle = await open(path, "r");
  try {
    const reader = await McapIndexedReader.Initialize({
      readable: new FileHandleReadable(handle),
      decompressHandlers,
    });
    const messages = [];
    for await (const m of reader.readMessages({ validateCrcs: true })) messages.push(m);
    const metadata = [];
    for await (const m of reader.readMetadata()) metadata.push(m);
    const topicOf = (id) => reader.channelsById.get(id).topic;
    const schemas = {};
    for (const channel of reader.channelsById.values()) {
      schemas[channel.topic] = reader.schemasById.get(channel.schemaId).name;
    }
    return {
      ...summarise(messages, topicOf, metadataObject(metadata)),
      header: { profile: reader.header.profile, library: reader.header.library },
      schemas: Object.fromEntries(Object.entries(schemas).sort()),
      statistics_message_count: reader.statistics?.messageCount.toString() ?? null,
    };
  } finally {
    await handle.close();
  }
}

async function readStreamed(path, decompressHandlers) {
  const reader = new McapStreamReader({ decompressHandlers, validateCrcs: true });
  reader.append(await readFile(path));
  const channels = new Map();
  const messages = [];
  const metadata = [];
  let footer = false;
  for (let record; (record = reader.nextRecord()); ) {
    if (record.type === "Channel") channels.set(record.id, record);
    else if (record.type === "Message") messages.push(record);
    else if (record.type === "Metadata") metadata.push(record);
    else if (record.type === "Footer") footer = true;
  }
  if (!footer || !reader.done()) throw new Error(`${path}: stream ended before the footer`);
  return summarise(messages, (id) => channels.get(id).topic, metadataObject(metadata));
}

const decompressHandlers = await loadDecompressHandlers();
const results = {};
for (const path of process.argv.slice(2)) {
  try {
    results[path] = {
      indexed: await readIndexed(path, decompressHandlers),
      streamed: await readStreamed(path, decompressHandlers),
    };
  } catch (error) {
    results[path] = { error: String(error?.message ?? error) };
  }
}
process.stdout.write(JSON.stringify(results) + "\n");
