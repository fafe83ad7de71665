// An independent client of sisa's live view: @foxglove/ws-protocol's FoxgloveClient over the
// `ws` package. It connects (retrying until the server is up), subscribes to every channel the
// server advertises, and checks every message against its channel's schema: JSON Schema with
// ajv, protobuf by decoding with the advertised FileDescriptorSet (protobufjs). It prints one
// JSON summary on stdout when the server closes or the time is up.
//
//   node live_client.mjs ws://127.0.0.1:PORT SECONDS
import wsProtocol from "@foxglove/ws-protocol";
import Ajv from "ajv";
import protobuf from "protobufjs";
import descriptor from "protobufjs/ext/descriptor/index.js";
import WebSocket from "ws";

const { FoxgloveClient } = wsProtocol; // a CommonJS package: its names come on the default

const [url, secondsText] = process.argv.slice(2);
const deadline = Date.now() + 1000 * Number(secondsText ?? "60");
const ajv = new Ajv({ strict: false, allErrors: true });
const decoder = new TextDecoder();
const channels = new Map(); // channel id -> its record in the summary
const bySubscription = new Map(); // subscription id -> channel id
const summary = { url, subprotocol: null, connected: false, channels: {}, errors: [] };

function checker(channel) {
  if (channel.encoding === "json" && channel.schemaEncoding === "jsonschema") {
    const validate = ajv.compile(JSON.parse(channel.schema));
    return (bytes) => {
      const value = JSON.parse(decoder.decode(bytes));
      return validate(value) ? null : ajv.errorsText(validate.errors);
    };
  }
  if (channel.encoding === "protobuf" && channel.schemaEncoding === "protobuf") {
    const set = descriptor.FileDescriptorSet.decode(Buffer.from(channel.schema, "base64"));
    const type = protobuf.Root.fromDescriptor(set).lookupType(channel.schemaName);
    return (bytes) => {
      const message = type.decode(bytes);
      const problem = type.verify(message);
      if (problem) return problem;
      if (channel.schemaName === "foxglove.GeoJSON") {
        const geo = JSON.parse(message.geojson);
        if (geo.type !== "FeatureCollection") return "geojson is no FeatureCollection";
      }
      return null;
    };
  }
  return () => `no check for encoding ${channel.encoding} / ${channel.schemaEncoding}`;
}

function finish() {
  process.stdout.write(JSON.stringify(summary) + "\n");
  process.exit(0);
}

function connect() {
  if (Date.now() > deadline) finish();
  const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL, "foxglove.sdk.v1"]);
  const client = new FoxgloveClient({ ws });
  let opened = false;
  client.on("open", () => {
    opened = true;
    summary.connected = true;
    summary.subprotocol = ws.protocol;
  });
  client.on("error", (error) => {
    if (opened) summary.errors.push(String(error?.message ?? error).slice(0, 300));
  });
  client.on("close", () => (opened ? finish() : setTimeout(connect, 20)));
  client.on("advertise", (advertised) => {
    for (const channel of advertised) {
      const record = {
        topic: channel.topic, encoding: channel.encoding, schemaName: channel.schemaName,
        schemaEncoding: channel.schemaEncoding, received: 0, invalid: 0, firstProblem: null,
        firstLogTime: null, // ns, as a string: JSON numbers cannot hold it
      };
      try {
        record.check = checker(channel);
      } catch (error) {
        record.check = () => `schema unusable: ${error.message}`;
      }
      channels.set(channel.id, record);
      summary.channels[channel.topic] = record;
      bySubscription.set(client.subscribe(channel.id), channel.id);
    }
  });
  client.on("message", ({ subscriptionId, timestamp, data }) => {
    const record = channels.get(bySubscription.get(subscriptionId));
    if (record === undefined) return;
    record.received += 1;
    record.firstLogTime ??= String(timestamp);
    const bytes = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
    let problem;
    try {
      problem = record.check(bytes);
    } catch (error) {
      problem = String(error.message);
    }
    if (problem) {
      record.invalid += 1;
      record.firstProblem ??= problem.slice(0, 300);
    }
  });
}

setTimeout(finish, Math.max(0, deadline - Date.now()));
connect();
