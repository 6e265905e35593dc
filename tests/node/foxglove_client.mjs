// A Foxglove WebSocket client built on Foxglove's own @foxglove/ws-protocol, as the
// Foxglove app connects: it subscribes to skyfuse's live view and decodes the fused pose
// (foxglove.PoseInFrame, protobuf, with the schema the server advertises), a ROS 2 CDR
// input (with @foxglove/rosmsg2-serialization and the advertised ros2msg definition) and
// the health (JSON).
//
//   node foxglove_client.mjs ws://127.0.0.1:8765 SECONDS [--stall]
//
// --stall: subscribe to every channel, then stop reading from the socket (a client on a
// dead link); the server must drop for it, not wait. Prints a JSON report.
import { parse as parseMsgDef } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";
import wsProtocol from "@foxglove/ws-protocol";
import protobuf from "protobufjs";
import descriptor from "protobufjs/ext/descriptor/index.js";
import { WebSocket } from "ws";

const { FoxgloveClient } = wsProtocol;

const [url, secondsArg, flag] = process.argv.slice(2);
const seconds = Number(secondsArg ?? 5);
const stall = flag === "--stall";

// The Foxglove SDK's servers speak the protocol as `foxglove.sdk.v1` (the same messages
// ws-protocol names `foxglove.websocket.v1`); the Foxglove app offers both.
const ws = new WebSocket(url, ["foxglove.sdk.v1", FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
const client = new FoxgloveClient({ ws });
const decoders = new Map();
const report = { channels: [], counts: {}, pose: null, odom: null, health: null, errors: [] };

function protobufDecoder(channel) {
  const bytes = Buffer.from(channel.schema, "base64");
  const set = descriptor.FileDescriptorSet.decode(bytes);
  const root = protobuf.Root.fromDescriptor(set);
  const type = root.lookupType(channel.schemaName);
  return (data) => type.toObject(type.decode(data), { longs: Number });
}

client.on("advertise", (channels) => {
  for (const ch of channels) {
    report.channels.push({ topic: ch.topic, encoding: ch.encoding, schemaName: ch.schemaName });
    let decode = null;
    try {
      if (ch.encoding === "protobuf" && ch.topic === "/skyfuse/pose") {
        decode = protobufDecoder(ch);
      } else if (ch.encoding === "cdr" && ch.schemaName === "nav_msgs/msg/Odometry") {
        const reader = new MessageReader(parseMsgDef(ch.schema, { ros2: true }));
        decode = (data) => reader.readMessage(data);
      } else if (ch.encoding === "json" && ch.topic === "/skyfuse/health") {
        decode = (data) => JSON.parse(new TextDecoder().decode(data));
      }
    } catch (e) {
      report.errors.push(`${ch.topic}: ${e}`);
    }
    if (decode || stall) {
      const sub = client.subscribe(ch.id);
      decoders.set(sub, { topic: ch.topic, decode });
    }
  }
  if (stall) {
    // Stop reading: the kernel buffers fill, then the server's queue for us.
    setTimeout(() => ws._socket?.pause(), 200);
  }
});

client.on("message", ({ subscriptionId, data }) => {
  const d = decoders.get(subscriptionId);
  if (!d) return;
  report.counts[d.topic] = (report.counts[d.topic] ?? 0) + 1;
  if (!d.decode) return;
  try {
    const msg = d.decode(new Uint8Array(data.buffer, data.byteOffset, data.byteLength));
    if (d.topic === "/skyfuse/pose") report.pose = msg;
    else if (d.topic === "/skyfuse/health") report.health = msg;
    else report.odom = { frame_id: msg.header.frame_id, position: msg.pose.pose.position };
  } catch (e) {
    report.errors.push(`${d.topic}: ${e}`);
  }
});

client.on("error", (e) => report.errors.push(String(e)));

setTimeout(() => {
  console.log(JSON.stringify(report));
  ws.terminate();
  process.exit(0);
}, seconds * 1000);
