// Receive a live `pcainterp densify --foxglove` stream with the protocol's reference client.
//
//   node live_client.mjs ws://127.0.0.1:PORT TOPIC[,TOPIC...] COUNT
//
// @foxglove/ws-protocol's FoxgloveClient (over the `ws` package, with the subprotocol
// foxglove-sdk 0.30 speaks, "foxglove.sdk.v1") connects, retrying while the server is not
// yet accepting clients, subscribes to TOPICs as they are advertised, and stops once COUNT
// messages of every TOPIC arrived. Each message is decoded with @foxglove/rosmsg (the
// advertised ros2msg schema) and @foxglove/rosmsg2-serialization (CDR).
//
// Prints one JSON object: topic -> {schemaName, encoding, schemaEncoding, messages: [{
// timestamp, size, sha256 (payload), header, width, height, encoding, step, point_step,
// fields, data_sha256 (the image's or cloud's data bytes)}]}. Exits 1 on any error or after
// 120 s without all messages.
//
// Used by tests/io/test_foxglove.py.

import { createHash } from "node:crypto";

import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";
import wsProtocol from "@foxglove/ws-protocol"; // CommonJS: no named exports for node
import WebSocket from "ws";

const { FoxgloveClient } = wsProtocol;

const SUBPROTOCOL = "foxglove.sdk.v1";
const [url, topicList, countText] = process.argv.slice(2);
if (!url || !topicList || !countText) {
  process.stderr.write("usage: node live_client.mjs URL TOPIC[,TOPIC...] COUNT\n");
  process.exit(2);
}
const wanted = new Set(topicList.split(","));
const count = Number(countText);

const sha256 = (bytes) => createHash("sha256").update(bytes).digest("hex");
const result = {};
const bySubscription = new Map(); // subscription id -> {topic, reader}

function done() {
  return [...wanted].every((topic) => (result[topic]?.messages.length ?? 0) >= count);
}

function summarize(message, payload) {
  const summary = { size: payload.byteLength, sha256: sha256(payload) };
  if (message.header) {
    summary.header = {
      stamp: { sec: message.header.stamp.sec, nanosec: message.header.stamp.nanosec },
      frame_id: message.header.frame_id,
    };
  }
  for (const key of ["width", "height", "encoding", "step", "point_step", "is_bigendian"]) {
    if (key in message) summary[key] = message[key];
  }
  if (message.fields) summary.fields = message.fields.map((field) => field.name);
  if (message.data) summary.data_sha256 = sha256(message.data);
  return summary;
}

const timeout = setTimeout(() => {
  const got = Object.fromEntries(Object.entries(result).map(([t, r]) => [t, r.messages.length]));
  process.stderr.write(`timed out; received ${JSON.stringify(got)}\n`);
  process.exit(1);
}, 120_000);

function connect() {
  const client = new FoxgloveClient({ ws: new WebSocket(url, [SUBPROTOCOL]) });
  let opened = false;
  client.on("open", () => {
    opened = true;
  });
  client.on("error", (error) => {
    if (!opened) return; // refused: the server accepts clients from its first message
    process.stderr.write(`client error: ${error?.message ?? error}\n`);
    process.exit(1);
  });
  client.on("close", () => {
    if (!opened) {
      setTimeout(connect, 100);
    } else if (!done()) {
      process.stderr.write("the server closed the connection before every message arrived\n");
      process.exit(1);
    }
  });
  client.on("advertise", (channels) => {
    for (const channel of channels) {
      if (!wanted.has(channel.topic)) continue;
      const reader = new MessageReader(parse(channel.schema, { ros2: true }));
      result[channel.topic] = {
        schemaName: channel.schemaName,
        encoding: channel.encoding,
        schemaEncoding: channel.schemaEncoding,
        messages: [],
      };
      bySubscription.set(client.subscribe(channel.id), { topic: channel.topic, reader });
    }
  });
  client.on("message", ({ subscriptionId, timestamp, data }) => {
    const subscription = bySubscription.get(subscriptionId);
    if (!subscription) return;
    const payload = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
    const message = subscription.reader.readMessage(payload);
    const summary = summarize(message, payload);
    summary.timestamp = timestamp.toString();
    result[subscription.topic].messages.push(summary);
    if (done()) {
      clearTimeout(timeout);
      process.stdout.write(JSON.stringify(result));
      client.close();
      process.exit(0);
    }
  });
}

connect();
