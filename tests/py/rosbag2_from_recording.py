"""Write a rosbag2 bag (MCAP storage) with rosbags, as a ROS 2 user's `ros2 bag record -a`
would have it, from a skyfuse recording: every CDR message (the inputs, and skyfuse's
own ROS 2 outputs, which a replay must not feed back in), its type, and its receive
time (the recording's arrival time) as the bag's timestamp.

    python rosbag2_from_recording.py RECORDING.mcap BAG_DIR [--rename OLD=NEW ...]

Topics are `/` + the Zenoh key (zenoh-bridge-ros2dds maps `/imu/data` to `imu/data`);
`--rename mavros/imu/data=/vehicle/imu` puts one under a topic no config names, which
skyfuse must then map by its type. Prints the topics and message counts as JSON.
"""
import json
import sys
from pathlib import Path

from mcap.reader import make_reader
from rosbags.rosbag2 import StoragePlugin, Writer

import ros2msg


def main():
    recording, bag = sys.argv[1], Path(sys.argv[2])
    renames = dict(a.split("=", 1) for a in sys.argv[3:] if "=" in a)
    store = ros2msg.typestore()
    counts = {}
    with open(recording, "rb") as f, Writer(bag, version=8, storage_plugin=StoragePlugin.MCAP) as w:
        connections = {}
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.message_encoding != "cdr" or schema is None:
                continue
            topic = renames.get(channel.topic, "/" + channel.topic)
            if topic not in connections:
                connections[topic] = w.add_connection(topic, schema.name, typestore=store)
            w.write(connections[topic], message.log_time, message.data)
            counts[topic] = counts.get(topic, 0) + 1
    print(json.dumps(counts))


if __name__ == "__main__":
    main()
