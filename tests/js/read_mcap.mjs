// Read an MCAP file with the TypeScript reference libraries and print what they decode, as JSON.
//
//   node read_mcap.mjs FILE.mcap [TOPIC_PREFIX]
//
// @mcap/core reads the file twice: with McapIndexedReader (summary, chunk indexes; what
// Foxglove uses for a local file) and with McapStreamReader (record by record, no index).
// Messages on topics starting with TOPIC_PREFIX (default "/pcainterp/") are decoded with
// @foxglove/rosmsg (parses the ros2msg schema text) and @foxglove/rosmsg2-serialization
// (CDR), and their pixel and point values are decoded here from the raw bytes, honouring
// step, point_step, field offsets and is_bigendian. Non-finite floats are printed as the
// strings "NaN", "Infinity", "-Infinity" (JSON has no such numbers).
//
// Used by tests/test_interop.py; prints one JSON object on stdout, exits 1 on any error.

import { open } from "node:fs/promises";

import zstd from "@foxglove/wasm-zstd";
import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";
import { McapIndexedReader, McapStreamReader } from "@mcap/core";

const [path, prefix = "/pcainterp/"] = process.argv.slice(2);
if (!path) {
  process.stderr.write("usage: node read_mcap.mjs FILE.mcap [TOPIC_PREFIX]\n");
  process.exit(2);
}

await zstd.isLoaded;
const decompressHandlers = {
  zstd: (buffer, decompressedSize) => zstd.decompress(buffer, Number(decompressedSize)),
};

// PointField datatype code -> [DataView getter, byte size]
const POINT_FIELD_TYPES = {
  1: ["getInt8", 1],
  2: ["getUint8", 1],
  3: ["getInt16", 2],
  4: ["getUint16", 2],
  5: ["getInt32", 4],
  6: ["getUint32", 4],
  7: ["getFloat32", 4],
  8: ["getFloat64", 8],
};

// image encoding -> [DataView getter, bytes per channel, channels]
const IMAGE_ENCODINGS = {
  "32FC1": ["getFloat32", 4, 1],
  "16UC1": ["getUint16", 2, 1],
  mono16: ["getUint16", 2, 1],
  mono8: ["getUint8", 1, 1],
  "8UC1": ["getUint8", 1, 1],
};

function number(value) {
  return Number.isFinite(value) ? value : String(value);
}

function view(bytes) {
  return new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
}

function imageValues(image) {
  const type = IMAGE_ENCODINGS[image.encoding];
  if (!type) return null;
  const [getter, size, channels] = type;
  const data = view(image.data);
  const littleEndian = image.is_bigendian === 0;
  const values = [];
  for (let row = 0; row < image.height; row++) {
    for (let col = 0; col < image.width * channels; col++) {
      values.push(number(data[getter](row * image.step + col * size, littleEndian)));
    }
  }
  return values;
}

function imageSummary(image) {
  return {
    header: image.header,
    height: image.height,
    width: image.width,
    encoding: image.encoding,
    is_bigendian: image.is_bigendian,
    step: image.step,
    data_length: image.data.length,
    values: imageValues(image),
  };
}

function pointCloudSummary(cloud) {
  const data = view(cloud.data);
  const littleEndian = !cloud.is_bigendian;
  const n = cloud.height * cloud.width;
  const points = {};
  for (const field of cloud.fields) {
    const [getter] = POINT_FIELD_TYPES[field.datatype];
    const values = [];
    for (let i = 0; i < n; i++) {
      const row = Math.floor(i / cloud.width);
      const col = i % cloud.width;
      values.push(number(data[getter](row * cloud.row_step + col * cloud.point_step + field.offset, littleEndian)));
    }
    points[field.name] = values;
  }
  return {
    header: cloud.header,
    height: cloud.height,
    width: cloud.width,
    fields: cloud.fields.map(({ name, offset, datatype, count }) => ({ name, offset, datatype, count })),
    is_bigendian: cloud.is_bigendian,
    point_step: cloud.point_step,
    row_step: cloud.row_step,
    is_dense: cloud.is_dense,
    data_length: cloud.data.length,
    points,
  };
}

function summarize(schemaName, message) {
  switch (schemaName) {
    case "sensor_msgs/msg/Image":
      return imageSummary(message);
    case "stereo_msgs/msg/DisparityImage":
      return {
        header: message.header,
        image: imageSummary(message.image),
        f: number(message.f),
        t: number(message.t),
        valid_window: message.valid_window,
        min_disparity: number(message.min_disparity),
        max_disparity: number(message.max_disparity),
        delta_d: number(message.delta_d),
      };
    case "sensor_msgs/msg/PointCloud2":
      return pointCloudSummary(message);
    case "sensor_msgs/msg/CompressedImage":
      // compressedDepth: the caller decodes the bytes (header + PNG / RVL) independently
      return {
        header: message.header,
        format: message.format,
        data_base64: Buffer.from(message.data).toString("base64"),
      };
    case "sensor_msgs/msg/CameraInfo":
      return {
        ...message,
        d: Array.from(message.d, number),
        k: Array.from(message.k, number),
        r: Array.from(message.r, number),
        p: Array.from(message.p, number),
      };
    default:
      return { fields: Object.keys(message) };
  }
}

async function readIndexed(handle) {
  const { size } = await handle.stat();
  const readable = {
    size: async () => BigInt(size),
    read: async (offset, length) => {
      const buffer = new Uint8Array(Number(length));
      const { bytesRead } = await handle.read(buffer, 0, buffer.length, Number(offset));
      if (bytesRead !== buffer.length) throw new Error(`short read at ${offset}`);
      return buffer;
    },
  };
  const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
  const channels = {};
  const decoders = new Map();
  for (const [id, channel] of reader.channelsById) {
    const schema = reader.schemasById.get(channel.schemaId);
    channels[channel.topic] = {
      message_encoding: channel.messageEncoding,
      schema_name: schema?.name ?? null,
      schema_encoding: schema?.encoding ?? null,
      message_count: Number(reader.statistics?.channelMessageCounts.get(id) ?? -1),
    };
    if (channel.topic.startsWith(prefix)) {
      if (channel.messageEncoding !== "cdr" || schema?.encoding !== "ros2msg") {
        throw new Error(`${channel.topic}: ${channel.messageEncoding} / ${schema?.encoding}`);
      }
      const definitions = parse(new TextDecoder().decode(schema.data), { ros2: true });
      decoders.set(id, [schema.name, new MessageReader(definitions)]);
    }
  }
  const messages = [];
  for await (const record of reader.readMessages({ validateCrcs: true })) {
    const decoder = decoders.get(record.channelId);
    if (!decoder) continue;
    const [schemaName, messageReader] = decoder;
    const message = messageReader.readMessage(record.data);
    messages.push({
      topic: reader.channelsById.get(record.channelId).topic,
      log_time: record.logTime.toString(),
      publish_time: record.publishTime.toString(),
      trailing_bytes: messageReader.lastReadHadTrailingBytes(),
      message: summarize(schemaName, message),
    });
  }
  return {
    profile: reader.header.profile,
    library: reader.header.library,
    message_count: Number(reader.statistics?.messageCount ?? -1),
    chunk_compression: [...new Set(reader.chunkIndexes.map((chunk) => chunk.compression))],
    channels,
    messages,
  };
}

async function readStream(handle) {
  const reader = new McapStreamReader({ decompressHandlers, validateCrcs: true });
  const topics = new Map();
  const counts = {};
  for await (const chunk of handle.createReadStream({ highWaterMark: 1 << 20 })) {
    reader.append(new Uint8Array(chunk.buffer, chunk.byteOffset, chunk.byteLength));
    for (let record; (record = reader.nextRecord()); ) {
      if (record.type === "Channel") topics.set(record.id, record.topic);
      if (record.type === "Message") {
        const topic = topics.get(record.channelId);
        counts[topic] = (counts[topic] ?? 0) + 1;
      }
    }
  }
  return { done: reader.done(), message_counts: counts };
}

const indexedHandle = await open(path, "r");
let indexed;
try {
  indexed = await readIndexed(indexedHandle);
} finally {
  await indexedHandle.close();
}
const streamHandle = await open(path, "r");
const stream = await readStream(streamHandle); // the read stream closes the handle at its end

process.stdout.write(JSON.stringify({ indexed, stream }));
