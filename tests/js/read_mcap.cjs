// Read an MCAP file the way the Foxglove app does: @mcap/core's indexed reader (summary,
// chunk indexes, zstd chunks), then decode every message with the schema the file carries
// (protobuf through protobufjs from the FileDescriptorSet, JSON by JSON.parse).
// Prints {"topic": {"schema": name, "count": n, "first": {...decoded fields}}} as JSON.
// Usage: node read_mcap.cjs FILE.mcap   (NODE_PATH must hold @mcap/core, protobufjs, fzstd)
"use strict";
const fs = require("fs");
const { McapIndexedReader } = require("@mcap/core");
const protobuf = require("protobufjs");
const descriptor = require("protobufjs/ext/descriptor");
const fzstd = require("fzstd");

class FileReadable {
  constructor(buf) { this.buf = buf; }
  async size() { return BigInt(this.buf.length); }
  async read(offset, size) { return this.buf.subarray(Number(offset), Number(offset + size)); }
}

async function main() {
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
