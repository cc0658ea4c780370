// Independent reader of a recorder bag, with the npm libraries Foxglove itself uses.
// Usage: node read_bag.mjs <file.mcap>  -> JSON on stdout:
//   {profile, library, compression: [...], chunkCount, messageCount, counts: {topic: n},
//    metadataNames: [...], messages: [{topic, logTime, publishTime, schema, msg}]}
// Times are strings (nanoseconds, exact); 64-bit integers inside messages become strings.
import { open } from "node:fs/promises";
import { McapIndexedReader } from "@mcap/core";
import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";
import zstd from "@foxglove/wasm-zstd";

const path = process.argv[2];
if (!path) {
  console.error("usage: node read_bag.mjs <file.mcap>");
  process.exit(2);
}
await zstd.isLoaded;
const handle = await open(path, "r");
const readable = {
  size: async () => BigInt((await handle.stat()).size),
  read: async (offset, length) => {
    const buffer = new Uint8Array(Number(length));
    const { bytesRead } = await handle.read(buffer, 0, Number(length), Number(offset));
    if (bytesRead !== Number(length)) throw new Error(`short read at ${offset}`);
    return buffer;
  },
};
const reader = await McapIndexedReader.Initialize({
  readable,
  decompressHandlers: {
    zstd: (data, size) => zstd.decompress(data, Number(size)),
  },
});

const readers = new Map();  // schema id -> MessageReader
for (const [id, schema] of reader.schemasById) {
  if (schema.encoding !== "ros2msg") throw new Error(`schema ${schema.name}: ${schema.encoding}`);
  const text = new TextDecoder().decode(schema.data);
  readers.set(id, new MessageReader(parse(text, { ros2: true })));
}

const counts = {};
const messages = [];
for await (const message of reader.readMessages()) {
  const channel = reader.channelsById.get(message.channelId);
  const schema = reader.schemasById.get(channel.schemaId);
  counts[channel.topic] = (counts[channel.topic] ?? 0) + 1;
  messages.push({
    topic: channel.topic,
    logTime: message.logTime.toString(),
    publishTime: message.publishTime.toString(),
    schema: schema.name,
    msg: readers.get(channel.schemaId).readMessage(message.data),
  });
}
const metadataNames = [];
for await (const record of reader.readMetadata()) metadataNames.push(record.name);
await handle.close();

const replacer = (_key, value) => {
  if (typeof value === "bigint") return value.toString();
  if (ArrayBuffer.isView(value)) return Array.from(value);
  return value;
};
console.log(JSON.stringify({
  profile: reader.header.profile,
  library: reader.header.library,
  compression: [...new Set(reader.chunkIndexes.map((c) => c.compression))],
  chunkCount: reader.chunkIndexes.length,
  messageCount: reader.statistics?.messageCount?.toString(),
  counts,
  metadataNames,
  messages,
}, replacer));
