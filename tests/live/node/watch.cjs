// Foxglove's @foxglove/ws-protocol client (npm) on the `ws` package: connect to the
// URL in argv[2], subscribe to every advertised channel whose topic is in argv[3]
// (comma-separated; "*" for all) the moment its advertisement arrives, collect for
// argv[4] seconds, print what arrived as JSON. argv[5], if given: the subprotocols to
// offer (comma-separated); else the client's default, FoxgloveClient.SUPPORTED_SUBPROTOCOL.
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const WebSocket = require("ws");

const [url, topicList, seconds, protocolList] = process.argv.slice(2);
const topics = new Set(topicList.split(","));
const protocols = protocolList ? protocolList.split(",") : [FoxgloveClient.SUPPORTED_SUBPROTOCOL];
const ws = new WebSocket(url, protocols);
const client = new FoxgloveClient({ ws });
const subs = new Map();
const out = { offered: protocols, protocol: null, httpStatus: null, serverInfo: null, channels: [], messages: [], times: [], statuses: [], errors: [] };
const decoder = new TextDecoder();

ws.on("open", () => { out.protocol = ws.protocol; });
ws.on("unexpected-response", (_req, res) => {
  out.httpStatus = res.statusCode;
  ws.terminate();
});
client.on("serverInfo", (info) => { out.serverInfo = info; });
client.on("advertise", (channels) => {
  for (const ch of channels) {
    out.channels.push(ch);
    if (topics.has("*") || topics.has(ch.topic)) subs.set(client.subscribe(ch.id), ch.topic);
  }
});
client.on("message", ({ subscriptionId, timestamp, data }) => {
  const text = decoder.decode(new Uint8Array(data.buffer, data.byteOffset, data.byteLength));
  out.messages.push({ topic: subs.get(subscriptionId), timestamp: timestamp.toString(), payload: JSON.parse(text) });
});
client.on("time", ({ timestamp }) => { out.times.push(timestamp.toString()); });
client.on("status", (status) => { out.statuses.push(status); });
client.on("error", (err) => { out.errors.push(String(err && err.message ? err.message : err)); });
setTimeout(() => {
  ws.terminate();
  process.stdout.write(JSON.stringify(out), () => process.exit(0)); // a pipe is written asynchronously: exit once it is out
}, Number(seconds) * 1000);
