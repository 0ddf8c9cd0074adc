// Foxglove's @foxglove/ws-protocol client (npm) on the `ws` package: connect to the
// URL in argv[2], subscribe to every advertised channel whose topic is in argv[3]
// (comma-separated), collect for argv[4] seconds, print what arrived as JSON.
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const WebSocket = require("ws");

const [url, topicList, seconds] = process.argv.slice(2);
const topics = new Set(topicList.split(","));
const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL, "foxglove.sdk.v1"]);
const client = new FoxgloveClient({ ws });
const subs = new Map();
const out = { protocol: null, serverInfo: null, channels: [], messages: [], times: [], errors: [] };
const decoder = new TextDecoder();

ws.on("open", () => { out.protocol = ws.protocol; });
client.on("serverInfo", (info) => { out.serverInfo = info; });
client.on("advertise", (channels) => {
  for (const ch of channels) {
    out.channels.push(ch);
    if (topics.has(ch.topic)) subs.set(client.subscribe(ch.id), ch.topic);
  }
});
client.on("message", ({ subscriptionId, timestamp, data }) => {
  const text = decoder.decode(new Uint8Array(data.buffer, data.byteOffset, data.byteLength));
  out.messages.push({ topic: subs.get(subscriptionId), timestamp: timestamp.toString(), payload: JSON.parse(text) });
});
client.on("time", ({ timestamp }) => { out.times.push(timestamp.toString()); });
client.on("error", (err) => { out.errors.push(String(err && err.message ? err.message : err)); });
setTimeout(() => {
  process.stdout.write(JSON.stringify(out));
  process.exit(0);
}, Number(seconds) * 1000);
