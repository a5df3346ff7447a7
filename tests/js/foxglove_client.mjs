// The Foxglove WebSocket protocol's own client (@foxglove/ws-protocol) against the node's
// endpoint or `mps serve`: subscribes to every channel it is advertised, decodes every message
// with @foxglove/rosmsg2-serialization from the channel's ros2msg schema, and writes what it got.
//
//   node foxglove_client.mjs '{"url": "ws://127.0.0.1:PORT", "out": "DIR", ...}'
//
// Options: "expect" (end after this many messages), "endOnRunEnd" (end after the run-end event),
// "engageAfterNs" (call the endpoint's /press_twin/engage once a message stamped at or after
// this time has come), "lateAfterNs" (then connect a second client that subscribes to
// "lateTopics" only), "timeoutS" (give up: exit status 1). Writes DIR/messages.jsonl (topic,
// log time, sha256 of the bytes, decoded value), DIR/summary.json (channels, services, the
// service's answer, the parameters, the late client's messages).
import { createHash } from "node:crypto";
import { writeFileSync, appendFileSync } from "node:fs";
import { join } from "node:path";

import rosmsg from "@foxglove/rosmsg";
import serialization from "@foxglove/rosmsg2-serialization";
import wsProtocol from "@foxglove/ws-protocol";
import WebSocket from "ws";

// CommonJS packages: their exports through the default import
const { parse } = rosmsg;
const { MessageReader } = serialization;
const { FoxgloveClient } = wsProtocol;

const opts = JSON.parse(process.argv[2]);
const out = opts.out;
const messagesPath = join(out, "messages.jsonl");
writeFileSync(messagesPath, "");
// foxglove-sdk 0.30's server takes `foxglove.sdk.v1`; this client offers `foxglove.websocket.v1`:
// offered both, the server picks the one it speaks
const SUBPROTOCOLS = [FoxgloveClient.SUPPORTED_SUBPROTOCOL, "foxglove.sdk.v1"];

function plain(_key, value) {
  if (typeof value === "bigint") return Number(value);
  if (ArrayBuffer.isView(value)) return Array.from(value, (v) => (Number.isNaN(v) ? "NaN" : v));
  if (typeof value === "number" && !Number.isFinite(value)) return String(value);
  return value;
}

function reader(schemaName, schema) {
  return new MessageReader(parse(schema, { ros2: true }));
}

const summary = {
  subprotocol: null,
  channels: {},
  services: [],
  engage: null,
  parameters: null,
  late: { messages: [] },
  count: 0,
  errors: [],
};

function connect(label, topics, onMessage, onReady) {
  const ws = new WebSocket(opts.url, SUBPROTOCOLS);
  const client = new FoxgloveClient({ ws });
  const bySub = new Map();
  const subscribed = new Set();
  client.on("open", () => {
    if (label === "main") summary.subprotocol = ws.protocol;
  });
  client.on("error", (e) => summary.errors.push(`${label}: ${e.message ?? e}`));
  client.on("advertise", (channels) => {
    for (const ch of channels) {
      if (subscribed.has(ch.id) || (topics && !topics.includes(ch.topic))) continue;
      subscribed.add(ch.id);
      if (label === "main") {
        summary.channels[ch.topic] = { encoding: ch.encoding, schemaName: ch.schemaName, schemaEncoding: ch.schemaEncoding };
      }
      const sub = client.subscribe(ch.id);
      bySub.set(sub, { topic: ch.topic, reader: reader(ch.schemaName, ch.schema) });
    }
    if (onReady) onReady(client, ws);
  });
  client.on("message", ({ subscriptionId, timestamp, data }) => {
    const ch = bySub.get(subscriptionId);
    const bytes = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
    const value = ch.reader.readMessage(bytes);
    onMessage(ch.topic, timestamp, bytes, value);
  });
  return { client, ws };
}

let engageSent = false;
let mainDone = false;
let lateDone = false;

function end() {
  clearTimeout(timer);
  setTimeout(() => {
    mainClient.close();
    finish(0);
  }, 0);
}

let lateStarted = false;
let services = new Map();
let mainClient = null;
let finished = false;

function finish(code) {
  if (finished) return;
  finished = true;
  writeFileSync(join(out, "summary.json"), JSON.stringify(summary, plain, 1));
  process.exit(code);
}

const timer = setTimeout(() => {
  summary.errors.push(`timed out after ${opts.timeoutS} s with ${summary.count} messages`);
  finish(1);
}, (opts.timeoutS ?? 120) * 1000);

const main = connect(
  "main",
  null,
  (topic, timestamp, bytes, value) => {
    summary.count += 1;
    const sha = createHash("sha256").update(bytes).digest("hex");
    appendFileSync(messagesPath, JSON.stringify({ topic, t: timestamp, sha, value }, plain) + "\n");
    if (opts.engageAfterNs !== undefined && !engageSent && timestamp >= BigInt(opts.engageAfterNs)) {
      engageSent = true;
      const svc = services.get("/press_twin/engage");
      if (!svc) {
        summary.errors.push("no service /press_twin/engage advertised");
      } else {
        // std_srvs/srv/Trigger's request is empty: its CDR is the encapsulation header alone
        main.client.sendServiceCallRequest({
          serviceId: svc.id,
          callId: 1,
          encoding: "cdr",
          data: new DataView(new Uint8Array([0, 1, 0, 0]).buffer),
        });
      }
    }
    if (opts.lateAfterNs !== undefined && !lateStarted && timestamp >= BigInt(opts.lateAfterNs)) {
      lateStarted = true;
      summary.late.joinedAfterNs = Number(timestamp);
      const late = connect("late", opts.lateTopics, (t2, ts2, b2, v2) => {
        summary.late.messages.push({ topic: t2, t: Number(ts2), value: JSON.parse(JSON.stringify(v2, plain)) });
        if (new Set(summary.late.messages.map((m) => m.topic)).size >= opts.lateTopics.length) {
          late.client.close();
          lateDone = true;
          if (mainDone) end();
        }
      });
    }
    const ended = opts.endOnRunEnd && topic === "/press_twin/events" && String(value.data).includes('"run-end"');
    if (ended || (opts.expect !== undefined && summary.count >= opts.expect)) {
      mainDone = true;
      // the late client, where one was started, has its messages first (the endpoint stays
      // up while a client is subscribed)
      if (!lateStarted || lateDone) end();
    }
  },
  null,
);
mainClient = main.client;
main.client.on("serverInfo", (info) => {
  summary.serverInfo = { name: info.name, capabilities: info.capabilities };
  if (info.capabilities.includes("parameters")) main.client.getParameters([], "all");
});
main.client.on("parameterValues", (msg) => {
  summary.parameters = msg.parameters;
});
main.client.on("advertiseServices", (list) => {
  for (const s of list) {
    services.set(s.name, s);
    summary.services.push({ name: s.name, type: s.type, response: s.response?.schemaName ?? null });
  }
});
main.client.on("serviceCallResponse", (resp) => {
  const svc = [...services.values()].find((s) => s.id === resp.serviceId);
  const schema = svc.response?.schema ?? svc.responseSchema;
  const value = reader(null, schema).readMessage(new Uint8Array(resp.data.buffer, resp.data.byteOffset, resp.data.byteLength));
  summary.engage = { encoding: resp.encoding, value };
});
main.client.on("serviceCallFailure", (f) => summary.errors.push(`service call failed: ${f.message}`));
