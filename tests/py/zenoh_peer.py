"""The Zenoh session every Python peer of the tests opens: a peer that connects to one
endpoint (the service under test), with no multicast scouting and no listener."""
import json


def open_peer(connect):
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("connect/endpoints", json.dumps([connect]))
    return zenoh.open(conf)
