#!/usr/bin/env python3
"""Zenoh with mutual TLS and access control in front of skyfuse.

  zenoh_tls.py setup DIR PORT      certificates (openssl) and skyfuse's Zenoh config
  zenoh_tls.py publish DIR PORT WHO SECONDS
                                   put sensor_msgs/NavSatFix on gps/fix at 10 Hz as WHO:
                                   bridge (certificate CN sensor-bridge, allowed),
                                   intruder (a certificate of the same CA, CN intruder:
                                   denied by the access control), stranger (a certificate
                                   of another CA: the TLS handshake fails), plain (TCP to
                                   the TLS port: no session)

`setup` writes DIR/skyfuse-zenoh.json5 from the shipped example config/zenoh-secure.json5
(its placeholders filled in): listen on tls/127.0.0.1:PORT only, mTLS, and an access
control list that denies by default, lets the certificate named `sensor-bridge` put on
the input keys, and any authenticated peer watch skyfuse's outputs. `publish` prints
JSON: whether the session opened and linked, how many were put, and how many of
skyfuse's health messages (`skyfuse/vehicle1/health`, 1 Hz) it received meanwhile.
"""
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)


def openssl(*args, cwd):
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True)


def make_ca(d, name):
    openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2", "-subj", f"/CN={name}",
            "-keyout", f"{name}.key", "-out", f"{name}.pem", cwd=d)


def make_cert(d, ca, name, cn, san=None):
    openssl("req", "-newkey", "rsa:2048", "-nodes", "-subj", f"/CN={cn}", "-keyout", f"{name}.key",
            "-out", f"{name}.csr", cwd=d)
    ext = os.path.join(d, f"{name}.ext")
    with open(ext, "w") as f:
        f.write(f"subjectAltName={san}\n" if san else "basicConstraints=CA:FALSE\n")
    openssl("x509", "-req", "-in", f"{name}.csr", "-CA", f"{ca}.pem", "-CAkey", f"{ca}.key",
            "-CAcreateserial", "-days", "2", "-extfile", ext, "-out", f"{name}.pem", cwd=d)


def setup(d, port):
    os.makedirs(d, exist_ok=True)
    make_ca(d, "ca")
    make_ca(d, "other-ca")
    make_cert(d, "ca", "skyfuse", "skyfuse", san="DNS:localhost,IP:127.0.0.1")
    make_cert(d, "ca", "bridge", "sensor-bridge")
    make_cert(d, "ca", "intruder", "intruder")
    make_cert(d, "other-ca", "stranger", "sensor-bridge")
    p = lambda n: os.path.join(d, n)  # noqa: E731
    with open(os.path.join(HERE, "..", "..", "config", "zenoh-secure.json5")) as f:
        text = f.read()
    for k, v in {"@HOST@": "127.0.0.1", "@PORT@": str(port), "@CERTS@": d,
                 "@BRIDGE_CN@": "sensor-bridge"}.items():
        text = text.replace(k, v)
    with open(p("skyfuse-zenoh.json5"), "w") as f:
        f.write(text)
    print(json.dumps({"config": p("skyfuse-zenoh.json5")}))


def publish(d, port, who, seconds):
    import numpy as np
    import zenoh
    from rosbags.typesys import Stores, get_typestore

    p = lambda n: os.path.join(d, n)  # noqa: E731
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", "[]")
    proto = "tcp" if who == "plain" else "tls"
    conf.insert_json5("connect/endpoints", json.dumps([f"{proto}/127.0.0.1:{port}"]))
    if who != "plain":
        cert = {"bridge": "bridge", "intruder": "intruder", "stranger": "stranger"}[who]
        tls = {"root_ca_certificate": p("ca.pem"), "connect_private_key": p(f"{cert}.key"),
               "connect_certificate": p(f"{cert}.pem"), "enable_mtls": True}
        conf.insert_json5("transport/link/tls", json.dumps(tls))
    try:
        session = zenoh.open(conf)
    except Exception as e:  # noqa: BLE001 - a refused handshake
        print(json.dumps({"who": who, "opened": False, "error": str(e), "put": 0}))
        return
    time.sleep(1.0)
    linked = len(list(session.info.peers_zid()))
    ts = get_typestore(Stores.ROS2_HUMBLE)
    t = ts.types
    health = []
    session.declare_subscriber("skyfuse/vehicle1/health", lambda s: health.append(1))
    pub = session.declare_publisher("gps/fix")
    n = 0
    start = time.time()
    while time.time() - start < seconds:
        now = time.time()
        msg = t["sensor_msgs/msg/NavSatFix"](
            header=t["std_msgs/msg/Header"](
                stamp=t["builtin_interfaces/msg/Time"](sec=int(now), nanosec=int(now % 1 * 1e9)),
                frame_id=who),
            status=t["sensor_msgs/msg/NavSatStatus"](status=0, service=1),
            latitude=47.0, longitude=8.0, altitude=500.0,
            position_covariance=np.eye(3).flatten(), position_covariance_type=2)
        pub.put(bytes(ts.serialize_cdr(msg, "sensor_msgs/msg/NavSatFix")))
        n += 1
        time.sleep(0.1)
    session.close()
    print(json.dumps({"who": who, "opened": True, "linked_peers": linked, "put": n, "health": len(health)}))


if __name__ == "__main__":
    if sys.argv[1] == "setup":
        setup(sys.argv[2], int(sys.argv[3]))
    else:
        publish(sys.argv[2], int(sys.argv[3]), sys.argv[4], float(sys.argv[5]))
