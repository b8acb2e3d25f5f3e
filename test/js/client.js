// A stock Foxglove WebSocket client for test/test_live_client.py: @foxglove/ws-protocol's
// FoxgloveClient over the `ws` package, offering only FoxgloveClient.SUPPORTED_SUBPROTOCOL
// (foxglove.websocket.v1), as Lichtblick and PlotJuggler do.
//
//   node client.js ws://HOST:PORT
//
// Prints what it receives as JSON lines on stdout ({"event": ...}) and takes commands as
// JSON lines on stdin:
//   {"cmd": "subscribe", "topic": "/joint_states"}
//   {"cmd": "advertise", "topic": "/goal_pose", "encoding": "json", "schemaName": "..."}
//     (any topic: the test advertises /goal_pose and /simulator/push; the reply
//     {"event": "advertised", "topic": ..., "channelId": N} names the channel to publish on)
//   {"cmd": "publish", "channelId": 1, "text": "{...}"}   (clientPublish, UTF-8 payload)
//   {"cmd": "getParameters", "names": ["/simulator.pause_at"], "id": "g1"}
//   {"cmd": "setParameters", "parameters": [{"name": ..., "value": ..., "type": ...}], "id": "s1"}
//   {"cmd": "subscribeParameters", "names": [...]}
//   {"cmd": "callService", "service": "/simulator/reset", "callId": 1, "encoding": "cdr",
//    "data": "<base64>"}   (the service id is looked up by name in advertiseServices)
//   {"cmd": "subscribeConnectionGraph"}
//   {"cmd": "close"}
"use strict";
const readline = require("readline");
const WebSocket = require("ws");
const { FoxgloveClient } = require("@foxglove/ws-protocol");

const url = process.argv[2];
const emit = (event) => process.stdout.write(JSON.stringify(event) + "\n");
const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
ws.on("unexpected-response", (_req, res) => {
  let body = "";
  res.on("data", (chunk) => (body += chunk));
  res.on("end", () => {
    emit({ event: "refused", status: res.statusCode, body });
    process.exit(3);
  });
});
const client = new FoxgloveClient({ ws });
const channels = new Map(); // topic -> channel
const topicOfSub = new Map();

client.on("open", () => emit({ event: "open", protocol: ws.protocol }));
client.on("error", (err) => emit({ event: "error", message: String(err && err.message) }));
client.on("close", (ev) => {
  emit({ event: "close", code: ev.code });
  process.exit(0);
});
client.on("serverInfo", (info) => emit({ event: "serverInfo", info }));
client.on("status", (status) => emit({ event: "status", status }));
client.on("advertise", (chans) => {
  for (const ch of chans) channels.set(ch.topic, ch);
  emit({ event: "advertise", channels: chans });
});
client.on("parameterValues", (m) =>
  emit({ event: "parameterValues", id: m.id ?? null, parameters: m.parameters }));
const services = new Map(); // name -> service
client.on("advertiseServices", (list) => {
  for (const sv of list) services.set(sv.name, sv);
  emit({ event: "advertiseServices", services: list });
});
client.on("connectionGraphUpdate", (g) => emit({ event: "connectionGraphUpdate", graph: g }));
client.on("serviceCallResponse", (r) => {
  const data = Buffer.from(r.data.buffer, r.data.byteOffset, r.data.byteLength);
  emit({ event: "serviceCallResponse", serviceId: r.serviceId, callId: r.callId,
         encoding: r.encoding, data: data.toString("base64") });
});
client.on("serviceCallFailure", (f) => emit({ event: "serviceCallFailure", failure: f }));
client.on("time", (t) => emit({ event: "time", timestamp: t.timestamp.toString() }));
client.on("message", (m) => {
  const data = Buffer.from(m.data.buffer, m.data.byteOffset, m.data.byteLength);
  emit({
    event: "message",
    topic: topicOfSub.get(m.subscriptionId),
    timestamp: m.timestamp.toString(),
    data: data.toString("base64"),
  });
});

readline.createInterface({ input: process.stdin }).on("line", (line) => {
  const c = JSON.parse(line);
  if (c.cmd === "subscribe") {
    const ch = channels.get(c.topic);
    if (!ch) return emit({ event: "error", message: `no channel ${c.topic}` });
    topicOfSub.set(client.subscribe(ch.id), c.topic);
    emit({ event: "subscribed", topic: c.topic });
  } else if (c.cmd === "advertise") {
    const id = client.advertise({ topic: c.topic, encoding: c.encoding, schemaName: c.schemaName });
    emit({ event: "advertised", topic: c.topic, channelId: id });
  } else if (c.cmd === "publish") {
    client.sendMessage(c.channelId, new TextEncoder().encode(c.text));
    emit({ event: "published", channelId: c.channelId });
  } else if (c.cmd === "getParameters") {
    client.getParameters(c.names, c.id);
  } else if (c.cmd === "setParameters") {
    client.setParameters(c.parameters, c.id);
  } else if (c.cmd === "subscribeParameters") {
    client.subscribeParameterUpdates(c.names);
  } else if (c.cmd === "callService") {
    const sv = services.get(c.service);
    if (!sv) return emit({ event: "error", message: `no service ${c.service}` });
    client.sendServiceCallRequest({ serviceId: sv.id, callId: c.callId, encoding: c.encoding,
                                    data: new Uint8Array(Buffer.from(c.data, "base64")) });
    emit({ event: "called", service: c.service, callId: c.callId });
  } else if (c.cmd === "subscribeConnectionGraph") {
    client.subscribeConnectionGraph();
  } else if (c.cmd === "close") {
    client.close();
  }
});
