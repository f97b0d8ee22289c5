// A Foxglove WebSocket viewer for the tests, built the way Foxglove and Lichtblick build theirs:
// FoxgloveClient from @foxglove/ws-protocol over the `ws` package, ROS 1 schemas parsed with
// @foxglove/rosmsg and messages read and written with @foxglove/rosmsg-serialization.
//
//   node client.mjs URL SUBPROTOCOL
//
// Commands come on stdin, one JSON object a line:
//   {"cmd": "subscribe", "topic": T}          subscribe once T is advertised
//   {"cmd": "advertise", "topic": T, "schemaName": N, "encoding": "ros1"|"json", "schema": S}
//   {"cmd": "publish", "topic": T, "message": {...}}   on a topic advertised before
//   {"cmd": "call", "service": NAME, "request": {...}, "encoding": "ros1"|"json"}
//   {"cmd": "close"}
// Events go to stdout, one JSON object a line, each with an "event" field.
import { createInterface } from "node:readline";

import rosmsg from "@foxglove/rosmsg";
import serialization from "@foxglove/rosmsg-serialization";
import wsProtocol from "@foxglove/ws-protocol";
import WebSocket from "ws";

// CommonJS packages: their exports come as one object.
const { parse } = rosmsg;
const { MessageReader, MessageWriter } = serialization;
const { FoxgloveClient } = wsProtocol;

const [url, subprotocol] = process.argv.slice(2);
if (!url || !subprotocol) {
  process.stderr.write("usage: node client.mjs URL SUBPROTOCOL\n");
  process.exit(2);
}

function plain(_key, value) {
  if (typeof value === "bigint") return value.toString();
  if (ArrayBuffer.isView(value)) return Array.from(value);
  return value;
}

function emit(event, fields = {}) {
  process.stdout.write(JSON.stringify({ event, ...fields }, plain) + "\n");
}

const ws = new WebSocket(url, [subprotocol]);
const client = new FoxgloveClient({ ws });

const channelsByTopic = new Map(); // topic -> {channel, reader}
const channelsById = new Map();
const wanted = new Set(); // topics to subscribe to once advertised
const subscriptions = new Map(); // subscription id -> topic
const ownChannels = new Map(); // topic -> {id, encoding, writer}
const services = new Map(); // name -> {service, writer, reader}
const calls = new Map(); // call id -> {name, encoding, reader}
let nextCall = 1;
let times = 0;

function subscribeIfWanted(topic) {
  const known = channelsByTopic.get(topic);
  if (known && wanted.has(topic)) {
    wanted.delete(topic);
    const id = client.subscribe(known.channel.id);
    subscriptions.set(id, topic);
    emit("subscribed", { topic, subscription: id });
  }
}

client.on("open", () => emit("open", { protocol: ws.protocol }));
client.on("error", (error) => emit("error", { message: String(error?.message ?? error) }));
client.on("close", (event) => {
  emit("close", { code: event.code, reason: String(event.reason ?? "") });
  process.exit(0);
});
client.on("serverInfo", (info) => emit("serverInfo", { info }));
client.on("status", (status) => emit("status", { level: status.level, message: status.message }));
client.on("advertise", (channels) => {
  for (const channel of channels) {
    let reader;
    let problem;
    try {
      if (channel.encoding !== "ros1" || channel.schemaEncoding !== "ros1msg") {
        throw new Error(`encoding ${channel.encoding}, schema ${channel.schemaEncoding}`);
      }
      reader = new MessageReader(parse(channel.schema, { ros2: false }));
    } catch (error) {
      problem = String(error?.message ?? error);
    }
    channelsByTopic.set(channel.topic, { channel, reader });
    channelsById.set(channel.id, channel.topic);
    emit("advertise", {
      id: channel.id,
      topic: channel.topic,
      encoding: channel.encoding,
      schemaName: channel.schemaName,
      schemaEncoding: channel.schemaEncoding,
      problem,
    });
    subscribeIfWanted(channel.topic);
  }
});
client.on("unadvertise", (ids) => emit("unadvertise", { ids }));
client.on("message", ({ subscriptionId, timestamp, data }) => {
  const topic = subscriptions.get(subscriptionId);
  const known = topic && channelsByTopic.get(topic);
  if (!known?.reader) {
    emit("message", { topic, subscription: subscriptionId, undecoded: data.byteLength });
    return;
  }
  try {
    const message = known.reader.readMessage(data);
    emit("message", { topic, timestamp, message });
  } catch (error) {
    emit("message", { topic, decodeError: String(error?.message ?? error) });
  }
});
client.on("time", ({ timestamp }) => {
  times += 1;
  if (times <= 3) emit("time", { timestamp, count: times });
});
client.on("advertiseServices", (list) => {
  for (const service of list) {
    const request = service.request?.schema ?? service.requestSchema;
    const response = service.response?.schema ?? service.responseSchema;
    services.set(service.name, {
      service,
      writer: new MessageWriter(parse(request, { ros2: false })),
      reader: new MessageReader(parse(response, { ros2: false })),
    });
    emit("advertiseServices", {
      id: service.id,
      name: service.name,
      type: service.type,
      request: service.request,
      response: service.response,
    });
  }
});
client.on("unadvertiseServices", (ids) => emit("unadvertiseServices", { ids }));
client.on("serviceCallResponse", (response) => {
  const pending = calls.get(response.callId);
  calls.delete(response.callId);
  let message;
  if (response.encoding === "json") {
    message = JSON.parse(new TextDecoder().decode(response.data));
  } else {
    message = pending.reader.readMessage(response.data);
  }
  emit("serviceCallResponse", {
    service: pending?.name,
    callId: response.callId,
    encoding: response.encoding,
    message,
  });
});
client.on("serviceCallFailure", (failure) =>
  emit("serviceCallFailure", {
    service: calls.get(failure.callId)?.name,
    callId: failure.callId,
    message: failure.message,
  }),
);

function encode(encoding, writer, message) {
  return encoding === "json"
    ? new TextEncoder().encode(JSON.stringify(message))
    : writer.writeMessage(message);
}

function handle(command) {
  switch (command.cmd) {
    case "subscribe":
      wanted.add(command.topic);
      subscribeIfWanted(command.topic);
      return;
    case "advertise": {
      const id = client.advertise({
        topic: command.topic,
        encoding: command.encoding,
        schemaName: command.schemaName,
        ...(command.schema ? { schema: command.schema, schemaEncoding: "ros1msg" } : {}),
      });
      const writer = command.schema ? new MessageWriter(parse(command.schema, { ros2: false })) : undefined;
      ownChannels.set(command.topic, { id, encoding: command.encoding, writer });
      emit("advertised", { topic: command.topic, id });
      return;
    }
    case "publish": {
      const own = ownChannels.get(command.topic);
      client.sendMessage(own.id, encode(own.encoding, own.writer, command.message));
      return;
    }
    case "call": {
      const known = services.get(command.service);
      if (!known) {
        emit("error", { message: `no service ${command.service} advertised` });
        return;
      }
      const callId = nextCall++;
      const encoding = command.encoding ?? "ros1";
      calls.set(callId, { name: command.service, encoding, reader: known.reader });
      client.sendServiceCallRequest({
        serviceId: known.service.id,
        callId,
        encoding,
        data: encode(encoding, known.writer, command.request),
      });
      return;
    }
    case "close":
      client.close();
      return;
    default:
      emit("error", { message: `unknown command ${command.cmd}` });
  }
}

createInterface({ input: process.stdin }).on("line", (line) => {
  if (!line.trim()) return;
  try {
    handle(JSON.parse(line));
  } catch (error) {
    emit("error", { message: String(error?.stack ?? error) });
  }
});
