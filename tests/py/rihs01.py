#!/usr/bin/env python3
"""Print rosbags' REP 2011 type hashes (RIHS01) for the given ROS 2 types, as JSON.

  rihs01.py geometry_msgs/msg/PoseStamped ...
"""
import json
import sys

from rosbags.typesys import Stores, get_typestore

ts = get_typestore(Stores.ROS2_JAZZY)
print(json.dumps({t: ts.hash_rihs01(t) for t in sys.argv[1:]}))
