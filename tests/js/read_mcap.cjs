// Read an MCAP file the way the Foxglove app does: @mcap/core's indexed reader (summary,
// chunk indexes, zstd chunks), then decode every message with the schema the file carries
// (protobuf through protobufjs from the FileDescriptorSet, JSON by JSON.parse).
// Prints {"topic": {"schema": name, "count": n, "first": {...decoded fields}}} as JSON.
// Usage: node read_mcap.cjs FILE.mcap   (NODE_PATH must hold @mcap/core, protobufjs, fzstd)
//        node read_mcap.cjs --stream FILE.mcap   streamed, as Foxglove reads a file without an
//        index (cut short by a kill): prints {"messages": n, "complete": bool}
"use strict";
const fs = require("fs");
const { McapIndexedReader, McapStreamReader } = require("@mcap/core");
const protobuf = require("protobufjs");
const descriptor = require("protobufjs/ext/descriptor");
const fzstd = require("fzstd");

class FileReadable {
  constructor(buf) { this.buf = buf; }
  async size() { return BigInt(this.buf.length); }
  async read(offset, size) { return this.buf.subarray(Number(offset), Number(offset + size)); }
}

function stream(buf) {
  const reader = new McapStreamReader({
    decompressHandlers: { zstd: (data, size) => fzstd.decompress(data, new Uint8Array(Number(size))) },
    validateCrcs: true,
  });
  reader.append(buf);
  let messages = 0, complete = false, rec;
  while ((rec = reader.nextRecord()) !== undefined) {
    if (rec.type === "Message") messages += 1;
    if (rec.type === "Footer") complete = true;
  }
  process.stdout.write(JSON.stringify({ messages, complete }));
}

async function main() {
  if (process.argv[2] === "--stream") return stream(fs.readFileSync(process.argv[3]));
  const buf = fs.readFileSync(process.argv[2]);
  const reader = await McapIndexedReader.Initialize({
    readable: new FileReadable(buf),
    decompressHandlers: { zstd: (data, size) => fzstd.decompress(data, new Uint8Array(Number(size))) },
  });
  const decoders = new Map();
  for (const [id, ch] of reader.channelsById) {
    const schema = reader.schemasById.get(ch.schemaId);
    if (ch.messageEncoding === "protobuf") {
      const fds = descriptor.FileDescriptorSet.decode(schema.data);
      const root = protobuf.Root.fromDescriptor(fds);
      const type = root.lookupType(schema.name);
      decoders.set(id, { schema: schema.name, decode: (d) => type.toObject(type.decode(d), { longs: Number, bytes: String }) });
    } else if (ch.messageEncoding === "json") {
      JSON.parse(new TextDecoder().decode(schema.data)); // the JSON schema itself must parse
      decoders.set(id, { schema: schema.name, decode: (d) => JSON.parse(new TextDecoder().decode(d)) });
    } else {
      throw new Error(`unknown encoding ${ch.messageEncoding} on ${ch.topic}`);
    }
  }
  const out = {};
  for await (const msg of reader.readMessages()) {
    const ch = reader.channelsById.get(msg.channelId);
    const dec = decoders.get(msg.channelId);
    const obj = dec.decode(msg.data);
    const t = (out[ch.topic] ??= { schema: dec.schema, count: 0, first: obj, log_time_ns: [] });
    t.count += 1;
    if (t.log_time_ns.length < 3) t.log_time_ns.push(Number(msg.logTime));
  }
  for (const t of Object.values(out)) {
    if (t.first && typeof t.first.data === "string" && t.first.data.length > 64) t.first.data = t.first.data.slice(0, 16);
  }
  process.stdout.write(JSON.stringify(out));
}
main().catch((e) => { console.error(String(e && e.stack || e)); process.exit(1); });
