#!/usr/bin/env node
// Conformance check of a bench MCAP file with @mcap/core, the reader Foxglove uses
// (@mcap/nodejs for file access, @mcap/support for zstd/lz4 and protobuf descriptors).
//
// Usage: node check_mcap.mjs FILE.mcap            indexed read + stream read, all CRCs
//        node check_mcap.mjs --stream FILE.mcap   stream read only (unfinished files)
//
// Prints one JSON object on stdout: statistics, channels (topic, encodings, schema,
// message counts from the index, the stream and the Statistics record), metadata,
// attachments, CRC results and a list of errors. Exit status 1 if any error.
// Every message is decoded as Foxglove would: protobuf via protobufjs from the schema's
// FileDescriptorSet, JSON with JSON.parse after checking the jsonschema against the
// subset Foxglove's JSON-schema parser accepts.

import { open, readFile } from "node:fs/promises";
import { crc32 } from "node:zlib";

import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { FileHandleReadable } from "@mcap/nodejs";
import { loadDecompressHandlers, protobufFromBinaryDescriptor } from "@mcap/support";

const args = process.argv.slice(2);
const streamOnly = args.includes("--stream");
const file = args.find((a) => !a.startsWith("--"));
if (!file) {
  console.error("usage: check_mcap.mjs [--stream] FILE.mcap");
  process.exit(2);
}

const errors = [];
const textDecoder = new TextDecoder();

/** The checks of Foxglove's parseJsonSchema: root object, one scalar type per leaf. */
function checkJsonSchema(schema, path) {
  if (schema.type !== "object") {
    errors.push(`${path}: expected "type": "object", got ${JSON.stringify(schema.type)}`);
    return;
  }
  for (const [name, field] of Object.entries(schema.properties ?? {})) {
    const where = `${path}.${name}`;
    if (Array.isArray(field.oneOf)) {
      if (!field.oneOf.every((alt) => typeof alt.const === "number")) {
        errors.push(`${where}: oneOf alternatives must have number values`);
      }
      continue;
    }
    switch (field.type) {
      case "boolean":
      case "number":
      case "integer":
        break;
      case "string":
        if (field.contentEncoding !== undefined && field.contentEncoding !== "base64") {
          errors.push(`${where}: unsupported contentEncoding ${field.contentEncoding}`);
        }
        break;
      case "object":
        checkJsonSchema(field, where);
        break;
      case "array": {
        const item = field.items ?? {};
        if (item.type === "object") checkJsonSchema(item, `${where}[]`);
        else if (!["boolean", "string", "number", "integer"].includes(item.type)) {
          errors.push(`${where}: unsupported array item type ${JSON.stringify(item.type)}`);
        }
        break;
      }
      default:
        errors.push(`${where}: unsupported type ${JSON.stringify(field.type)}`);
    }
  }
}

/** A deserializer per channel, as Foxglove builds it; null if the channel cannot be decoded. */
function makeDecoder(channel, schema) {
  const where = `channel ${channel.topic}`;
  if (channel.messageEncoding === "protobuf") {
    if (schema?.encoding !== "protobuf") {
      errors.push(`${where}: protobuf messages need a protobuf schema`);
      return null;
    }
    try {
      const root = protobufFromBinaryDescriptor(schema.data);
      const type = root.lookupType(schema.name);
      return (data) => type.toObject(type.decode(data), { defaults: true, enums: String });
    } catch (err) {
      errors.push(`${where}: bad protobuf schema: ${err.message}`);
      return null;
    }
  }
  if (channel.messageEncoding === "json") {
    if (schema && schema.encoding !== "jsonschema") {
      errors.push(`${where}: json messages need a jsonschema schema`);
      return null;
    }
    if (schema) {
      try {
        checkJsonSchema(JSON.parse(textDecoder.decode(schema.data)), schema.name);
      } catch (err) {
        errors.push(`${where}: schema is not JSON: ${err.message}`);
      }
    }
    return (data) => JSON.parse(textDecoder.decode(data));
  }
  errors.push(`${where}: unsupported message encoding ${channel.messageEncoding}`);
  return null;
}

function plain(value) {
  return JSON.parse(
    JSON.stringify(value, (_k, v) => {
      if (typeof v === "bigint") return Number(v);
      if (v instanceof Uint8Array) return Array.from(v);
      if (v instanceof Map) return Object.fromEntries(v);
      return v;
    }),
  );
}

async function streamRead(bytes, decompressHandlers) {
  const reader = new McapStreamReader({ decompressHandlers, validateCrcs: true });
  reader.append(bytes);
  const channels = new Map();
  const schemas = new Map();
  const counts = new Map();
  let dataEnd;
  for (let rec; (rec = reader.nextRecord()); ) {
    if (rec.type === "Schema") schemas.set(rec.id, rec);
    else if (rec.type === "Channel") channels.set(rec.id, rec);
    else if (rec.type === "Message") counts.set(rec.channelId, (counts.get(rec.channelId) ?? 0) + 1);
    else if (rec.type === "DataEnd") dataEnd = rec;
  }
  return { channels, schemas, counts, done: reader.done(), dataEnd };
}

async function main() {
  const decompressHandlers = await loadDecompressHandlers();
  const bytes = new Uint8Array(await readFile(file));
  const out = { file, size: bytes.length, errors };

  let stream;
  try {
    stream = await streamRead(bytes, decompressHandlers);
  } catch (err) {
    errors.push(`stream read failed: ${err.message}`);
    stream = { channels: new Map(), schemas: new Map(), counts: new Map(), done: false };
  }
  out.stream = {
    done: stream.done,
    counts: Object.fromEntries(
      [...stream.channels.values()].map((c) => [c.topic, stream.counts.get(c.id) ?? 0]),
    ),
  };
  if (streamOnly) {
    console.log(JSON.stringify(out, null, 1));
    return;
  }

  const handle = await open(file, "r");
  try {
    const reader = await McapIndexedReader.Initialize({
      readable: new FileHandleReadable(handle),
      decompressHandlers,
    }); // validates the footer, the summary and its CRC
    out.header = plain(reader.header);
    out.statistics = plain(reader.statistics);
    out.chunkCount = reader.chunkIndexes.length;
    out.compression = [...new Set(reader.chunkIndexes.map((c) => c.compression))];

    // data section CRC: every byte before the DataEnd record (mcap spec)
    const dataCrc = reader.dataSectionCrc;
    if (dataCrc === undefined) out.dataSectionCrc = "absent";
    else {
      const calc = crc32(bytes.subarray(0, Number(reader.dataEndOffset)));
      out.dataSectionCrc = calc === dataCrc ? "ok" : "mismatch";
      if (calc !== dataCrc) errors.push(`data section CRC ${calc} != ${dataCrc}`);
    }
    if (!stream.done) errors.push("stream reader did not reach the footer");
    if (stream.dataEnd && stream.dataEnd.dataSectionCrc !== (dataCrc ?? 0)) {
      errors.push("DataEnd seen by the stream reader differs from the indexed reader's");
    }

    const decoders = new Map();
    const counts = new Map();
    const first = new Map();
    let previous = -1n;
    for await (const msg of reader.readMessages({ validateCrcs: true })) {
      if (msg.logTime < previous) errors.push("indexed reader returned messages out of log time order");
      previous = msg.logTime;
      const channel = reader.channelsById.get(msg.channelId);
      if (!channel) {
        errors.push(`message on unknown channel ${msg.channelId}`);
        continue;
      }
      if (!decoders.has(channel.id)) {
        decoders.set(channel.id, makeDecoder(channel, reader.schemasById.get(channel.schemaId)));
      }
      const decode = decoders.get(channel.id);
      counts.set(channel.id, (counts.get(channel.id) ?? 0) + 1);
      if (decode) {
        try {
          const value = decode(msg.data);
          if (!first.has(channel.id)) first.set(channel.id, { sequence: msg.sequence, logTime: msg.logTime, value });
        } catch (err) {
          if (errors.length < 50) errors.push(`${channel.topic}: cannot decode message: ${err.message}`);
        }
      }
    }

    const statsCounts = reader.statistics?.channelMessageCounts ?? new Map();
    out.channels = [...reader.channelsById.values()].map((c) => {
      const schema = reader.schemasById.get(c.schemaId);
      const indexed = counts.get(c.id) ?? 0;
      const streamed = stream.counts.get(c.id) ?? 0;
      const stats = Number(statsCounts.get(c.id) ?? 0n);
      if (indexed !== streamed || indexed !== stats) {
        errors.push(`${c.topic}: message counts differ (index ${indexed}, stream ${streamed}, statistics ${stats})`);
      }
      return {
        id: c.id,
        topic: c.topic,
        messageEncoding: c.messageEncoding,
        schemaName: schema?.name ?? "",
        schemaEncoding: schema?.encoding ?? "",
        metadata: Object.fromEntries(c.metadata),
        count: indexed,
        first: plain(first.get(c.id) ?? null),
      };
    });

    out.metadata = [];
    for await (const m of reader.readMetadata()) {
      out.metadata.push({ name: m.name, metadata: Object.fromEntries(m.metadata) });
    }
    out.attachments = [];
    for await (const a of reader.readAttachments({ validateCrcs: true })) {
      out.attachments.push({ name: a.name, mediaType: a.mediaType, size: a.data.length });
    }
  } catch (err) {
    errors.push(`indexed read failed: ${err.message}`);
  } finally {
    await handle.close();
  }
  console.log(JSON.stringify(out, null, 1));
}

main()
  .then(() => process.exit(errors.length ? 1 : 0))
  .catch((err) => {
    console.error(err);
    process.exit(1);
  });
