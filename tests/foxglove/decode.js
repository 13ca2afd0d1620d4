// Decode the system's data the way the Foxglove app does, with Foxglove's own npm libraries, and print JSON lines.
//
//   node decode.js mcap FILE                     every message of every channel of an MCAP file
//   node decode.js ws URL [--subprotocol NAME]   every message of every channel of a live Foxglove WebSocket server,
//                                                until SIGTERM or the server closes; NAME defaults to what the
//                                                @foxglove/ws-protocol client names (FoxgloveClient.SUPPORTED_SUBPROTOCOL)
//
// Schemas: "omgidl" with @foxglove/omgidl-parser + @foxglove/omgidl-serialization, "ros2msg" with @foxglove/rosmsg +
// @foxglove/rosmsg2-serialization; MCAP with @mcap/core (chunk CRCs checked) and @mcap/support's decompressors;
// WebSocket with @foxglove/ws-protocol's FoxgloveClient over the `ws` package (Node 20 has no WebSocket of its own).
//
// Lines (one JSON object each, "kind" first):
//   {"kind": "channel", "topic", "schemaName", "schemaEncoding", "messageEncoding"[, "error"]}
//   {"kind": "message", "topic", "logTime", "raw": sha256 of the payload[, "rawBase64" up to 1 MiB], "value"|"error"}
//   {"kind": "mcap", "profile", "messages", "chunks", "chunksWithCrc", "compressions"}   once a file is read through
//   {"kind": "open", "protocol"} / {"kind": "close", "code"} / {"kind": "error", "error"}   WebSocket events
// Values: members by name as decoded; an enum member as the name of its enumerator, as the Foxglove app shows it;
// octet arrays as {"bytes": length, "sha256": hex}; other typed arrays as arrays; NaN and infinities as strings.
"use strict";

const crypto = require("crypto");
const fs = require("fs");
const { McapIndexedReader, McapStreamReader } = require("@mcap/core");
const { loadDecompressHandlers } = require("@mcap/support");
const { parseIDL } = require("@foxglove/omgidl-parser");
const { MessageReader: IdlMessageReader } = require("@foxglove/omgidl-serialization");
const { parse: parseRosMessageDefinition } = require("@foxglove/rosmsg");
const { MessageReader: Ros2MessageReader } = require("@foxglove/rosmsg2-serialization");

const RAW_BASE64_LIMIT = 1 << 20;

function emit(line) {
  process.stdout.write(JSON.stringify(line) + "\n");
}

// The last line, then exit once every line written has reached the pipe: process.exit() drops (or cuts in the
// middle) what a slow reader has not taken yet, and a line of a LiDAR cloud is a few hundred kB.
function emitAndExit(line, code) {
  process.stdout.write(JSON.stringify(line) + "\n", () => process.exit(code));
}

function sha256(bytes) {
  return crypto.createHash("sha256").update(bytes).digest("hex");
}

function plain(value) {
  if (value instanceof Uint8Array || value instanceof Int8Array) {
    return { bytes: value.length, sha256: sha256(value) };
  }
  if (ArrayBuffer.isView(value) || Array.isArray(value)) {
    return Array.from(value, plain);
  }
  if (typeof value === "bigint") {
    return Number.isSafeInteger(Number(value)) ? Number(value) : value.toString();
  }
  if (typeof value === "number" && !Number.isFinite(value)) {
    return String(value); // "NaN", "Infinity", "-Infinity"
  }
  if (value !== null && typeof value === "object") {
    return Object.fromEntries(Object.entries(value).map(([key, member]) => [key, plain(member)]));
  }
  return value;
}

// Replace each enum member's number by its enumerator's name, walking the parsed IDL definitions.
function nameEnums(value, typeName, definitionsByName) {
  const type = definitionsByName.get(typeName);
  if (!type || value === null || typeof value !== "object") {
    return value;
  }
  for (const field of type.definitions) {
    if (field.isConstant || !(field.name in value)) {
      continue;
    }
    const each = (member) => {
      if (field.enumType) {
        const enumerator = definitionsByName.get(field.enumType)?.definitions.find((e) => e.value === member);
        return enumerator ? enumerator.name : member;
      }
      return field.isComplex ? nameEnums(member, field.type, definitionsByName) : member;
    };
    const member = value[field.name];
    value[field.name] = Array.isArray(member) ? member.map(each) : each(member);
  }
  return value;
}

// A decoder for one channel, made as the Foxglove app makes it from the channel's schema; throws if it cannot.
function channelDecoder(schemaName, schemaEncoding, schemaText, messageEncoding) {
  if (messageEncoding !== "cdr") {
    throw new Error(`message encoding ${messageEncoding}: expected cdr`);
  }
  if (schemaEncoding === "omgidl") {
    const definitions = parseIDL(schemaText);
    const reader = new IdlMessageReader(schemaName, definitions);
    const byName = new Map(definitions.map((definition) => [definition.name, definition]));
    return (bytes) => nameEnums(plain(reader.readMessage(bytes)), schemaName, byName);
  }
  if (schemaEncoding === "ros2msg") {
    const reader = new Ros2MessageReader(parseRosMessageDefinition(schemaText, { ros2: true }));
    return (bytes) => plain(reader.readMessage(bytes));
  }
  throw new Error(`schema encoding ${schemaEncoding}: expected omgidl or ros2msg`);
}

function errorText(error) {
  return String(error && error.message ? error.message : error).split("\n")[0];
}

// Announce a channel; its decoder, or null when its schema does not parse.
function openChannel(topic, schemaName, schemaEncoding, schemaText, messageEncoding) {
  const line = { kind: "channel", topic, schemaName, schemaEncoding, messageEncoding };
  try {
    const decode = channelDecoder(schemaName, schemaEncoding, schemaText, messageEncoding);
    emit(line);
    return decode;
  } catch (error) {
    emit({ ...line, error: errorText(error) });
    return null;
  }
}

function decodeMessage(topic, decode, logTime, bytes) {
  const line = { kind: "message", topic, logTime: String(logTime), raw: sha256(bytes) };
  if (bytes.length <= RAW_BASE64_LIMIT) {
    line.rawBase64 = Buffer.from(bytes.buffer, bytes.byteOffset, bytes.byteLength).toString("base64");
  }
  if (!decode) {
    line.error = "no decoder: the channel's schema did not parse";
  } else {
    try {
      line.value = decode(bytes);
    } catch (error) {
      line.error = errorText(error);
    }
  }
  emit(line);
}

async function readMcap(path) {
  const handle = await fs.promises.open(path, "r");
  const size = (await handle.stat()).size;
  const readable = {
    size: async () => BigInt(size),
    read: async (offset, length) => {
      const buffer = new Uint8Array(Number(length));
      const { bytesRead } = await handle.read(buffer, 0, buffer.length, Number(offset));
      if (bytesRead !== buffer.length) {
        throw new Error(`short read at ${offset}`);
      }
      return buffer;
    },
  };
  // What the Foxglove app does with a complete file: the indexed reader, chunk CRCs validated. Compressed chunks go
  // through MCAP's own WebAssembly decompressors (@mcap/support: zstd, lz4, bz2).
  const decompressHandlers = await loadDecompressHandlers();
  const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
  const decoders = new Map();
  for (const [id, channel] of reader.channelsById) {
    const schema = reader.schemasById.get(channel.schemaId);
    const text = schema ? new TextDecoder().decode(schema.data) : "";
    decoders.set(id, openChannel(channel.topic, schema?.name, schema?.encoding, text, channel.messageEncoding));
  }
  let messages = 0;
  for await (const message of reader.readMessages({ validateCrcs: true })) {
    const channel = reader.channelsById.get(message.channelId);
    decodeMessage(channel.topic, decoders.get(message.channelId), message.logTime, message.data);
    messages += 1;
  }
  // The whole file once more, front to back, with the streaming reader: every record parses, every chunk CRC holds.
  const stream = new McapStreamReader({ includeChunks: true, validateCrcs: true, decompressHandlers });
  let chunks = 0;
  let chunksWithCrc = 0;
  const compressions = new Set();
  let streamed = 0;
  const piece = new Uint8Array(1 << 20);
  for (let offset = 0; offset < size; ) {
    const { bytesRead } = await handle.read(piece, 0, piece.length, offset);
    offset += bytesRead;
    stream.append(piece.subarray(0, bytesRead));
    for (let record; (record = stream.nextRecord()); ) {
      if (record.type === "Chunk") {
        chunks += 1;
        chunksWithCrc += record.uncompressedCrc !== 0 ? 1 : 0;
        compressions.add(record.compression);
      } else if (record.type === "Message") {
        streamed += 1;
      }
    }
  }
  await handle.close();
  if (!stream.done()) {
    throw new Error(`${path}: the streaming reader did not reach the footer`);
  }
  if (streamed !== messages) {
    throw new Error(`${path}: ${streamed} messages streamed, ${messages} read through the index`);
  }
  emit({ kind: "mcap", profile: reader.header.profile, messages, chunks, chunksWithCrc,
         compressions: [...compressions].sort() });
}

function readWebSocket(url, subprotocol) {
  const { FoxgloveClient } = require("@foxglove/ws-protocol");
  const WebSocket = require("ws");
  const ws = new WebSocket(url, [subprotocol ?? FoxgloveClient.SUPPORTED_SUBPROTOCOL], { maxPayload: 0 });
  ws.on("unexpected-response", (_request, response) => {
    emitAndExit({ kind: "error", error: `HTTP ${response.statusCode} ${response.statusMessage}` }, 1);
  });
  const client = new FoxgloveClient({ ws });
  const subscriptions = new Map(); // subscription id -> {topic, decode}
  client.on("open", () => emit({ kind: "open", protocol: ws.protocol }));
  client.on("error", (error) => emit({ kind: "error", error: errorText(error) }));
  client.on("close", (event) => {
    emitAndExit({ kind: "close", code: event.code }, 0);
  });
  client.on("advertise", (channels) => {
    for (const channel of channels) {
      const decode = openChannel(channel.topic, channel.schemaName, channel.schemaEncoding ?? "", channel.schema,
                                 channel.encoding);
      subscriptions.set(client.subscribe(channel.id), { topic: channel.topic, decode });
    }
  });
  client.on("message", ({ subscriptionId, timestamp, data }) => {
    const subscription = subscriptions.get(subscriptionId);
    const bytes = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
    decodeMessage(subscription ? subscription.topic : `subscription ${subscriptionId}`, subscription?.decode,
                  timestamp, bytes);
  });
  process.on("SIGTERM", () => client.close());
}

function main(argv) {
  const [mode, target, ...rest] = argv;
  if (mode === "mcap" && target && rest.length === 0) {
    readMcap(target).catch((error) => {
      emit({ kind: "error", error: errorText(error) });
      process.exitCode = 1;
    });
    return;
  }
  if (mode === "ws" && target && (rest.length === 0 || (rest.length === 2 && rest[0] === "--subprotocol"))) {
    readWebSocket(target, rest[1]);
    return;
  }
  process.stderr.write("usage: node decode.js mcap FILE | node decode.js ws URL [--subprotocol NAME]\n");
  process.exitCode = 2;
}

main(process.argv.slice(2));
