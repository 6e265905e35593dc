"""Read a skyfuse recording with the MCAP project's own Python readers and check it.

    python mcap_check.py FILE.mcap            # a finished recording: summary, every channel
    python mcap_check.py FILE.mcap --killed   # a recorder killed mid-write: read to the cut

Decodes the ROS 2 CDR channels with mcap-ros2-support (from the schema skyfuse wrote,
which must equal rosbags' definition of the type), the Foxglove pose, transform and
location with mcap-protobuf-support, the VISION_POSITION_ESTIMATE frames with pymavlink,
and every JSON channel with json. Prints a JSON report; exits non-zero on the first
check that fails.
"""
import json
import math
import sys
from collections import Counter

from mcap.reader import NonSeekingReader, make_reader
from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoders
from mcap_ros2.decoder import DecoderFactory as Ros2Decoders
from pymavlink.dialects.v20 import common as mavlink2

import ros2msg


def fail(msg):
    print(f"FAIL: {msg}", file=sys.stderr)
    sys.exit(1)


def finite(*values):
    return all(math.isfinite(v) for v in values)


def main():
    path = sys.argv[1]
    killed = "--killed" in sys.argv
    definitions = ros2msg.definitions()
    counts = Counter()
    channels = {}
    ros2 = Ros2Decoders()
    proto = ProtobufDecoders()
    decoders = {}
    mav = mavlink2.MAVLink(None)
    mav.robust_parsing = True
    vpe = 0
    poses = {}
    pose_json = {}
    cut = None
    with open(path, "rb") as f:
        if killed:
            reader = NonSeekingReader(f)
        else:
            reader = make_reader(f)
            summary = reader.get_summary()
            if summary is None or summary.statistics is None:
                fail("a finished recording has a summary with statistics")
        it = reader.iter_messages(log_time_order=False)
        while True:
            try:
                schema, channel, message = next(it)
            except StopIteration:
                break
            except Exception as e:  # the cut of a killed recorder
                if not killed:
                    fail(f"reading stopped: {e}")
                cut = str(e) or type(e).__name__
                break
            topic = channel.topic
            counts[topic] += 1
            enc = channel.message_encoding
            channels.setdefault(
                topic,
                {
                    "encoding": enc,
                    "schema": schema.name if schema else None,
                    "schema_encoding": schema.encoding if schema else None,
                    "metadata": dict(channel.metadata),
                },
            )
            if enc == "cdr":
                if schema is None or schema.encoding != "ros2msg":
                    fail(f"{topic}: CDR without a ros2msg schema")
                want = definitions.get(schema.name)
                if want is None or schema.data.decode() != want:
                    fail(f"{topic}: the {schema.name} definition differs from rosbags'")
                key = (schema.id, enc)
                if key not in decoders:
                    decoders[key] = ros2.decoder_for(enc, schema)
                msg = decoders[key](message.data)
                stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
                if not stamp > 0:
                    fail(f"{topic}: header stamp {stamp}")
                if schema.name == "nav_msgs/msg/Odometry":
                    p = msg.pose.pose.position
                    if not finite(p.x, p.y, p.z):
                        fail(f"{topic}: position not finite")
            elif enc == "protobuf":
                key = (schema.id, enc)
                if key not in decoders:
                    decoders[key] = proto.decoder_for(enc, schema)
                msg = decoders[key](message.data)
                if schema.name == "foxglove.PoseInFrame":
                    p = msg.pose.position
                    if msg.frame_id != "map" or not finite(p.x, p.y, p.z):
                        fail(f"{topic}: pose {msg}")
                    poses[message.log_time] = (p.x, p.y, p.z)
                elif schema.name == "foxglove.FrameTransform":
                    if (msg.parent_frame_id, msg.child_frame_id) != ("map", "base_link"):
                        fail(f"{topic}: frames {msg.parent_frame_id} -> {msg.child_frame_id}")
                elif schema.name == "foxglove.LocationFix":
                    if not (-90 <= msg.latitude <= 90 and -180 <= msg.longitude <= 180):
                        fail(f"{topic}: location {msg.latitude}, {msg.longitude}")
            elif enc == "json":
                value = json.loads(message.data)
                if topic == "/skyfuse/pose_json":
                    pose_json[message.log_time] = tuple(value["position"])
            elif enc == "mavlink2":
                for m in mav.parse_buffer(message.data) or []:
                    if m.get_type() == "VISION_POSITION_ESTIMATE":
                        if not finite(m.x, m.y, m.z, m.roll, m.pitch, m.yaw):
                            fail(f"VPE not finite: {m}")
                        vpe += 1
            else:
                fail(f"{topic}: unexpected encoding {enc!r}")
    # The pose in Foxglove's schema and as skyfuse publishes it on Zenoh agree, the
    # latter to the millimetre (half of one on each axis).
    same = [t for t in poses if t in pose_json]
    worst = max(
        (math.dist(poses[t], pose_json[t]) for t in same),
        default=0.0,
    )
    if worst > 0.0005 * math.sqrt(3) + 1e-9:
        fail(f"PoseInFrame and pose_json differ by {worst} m")
    print(
        json.dumps(
            {
                "messages": sum(counts.values()),
                "counts": counts,
                "channels": channels,
                "vpe": vpe,
                "poses_compared": len(same),
                "cut": cut,
            }
        )
    )


if __name__ == "__main__":
    main()
