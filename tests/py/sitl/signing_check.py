#!/usr/bin/env python3
"""MAVLink 2 signing against a real ArduCopter SITL (issue 36).

    signing_check.py --skyfuse target/debug/skyfuse [--instance 7] --out result.json

ArduCopter 4.6.3 SITL from $SKYFUSE_PEERS (bin/arducopter, ardupilot/copter.parm) starts
without signing. `skyfuse demo` sends its pose, HEARTBEAT and TIMESYNC to SITL's SERIAL1
(`tcpout:`) signed with a passphrase's key. Before: an unsigned pymavlink sender on
SERIAL2 gets its TIMESYNC answered. Then `POST /api/v1/control/setup-signing` gives
SITL the key (SETUP_SIGNING, as MAVProxy's `signing setup` does). After: SITL answers
skyfuse's signed TIMESYNC (skyfuse's answered count keeps growing), answers a pymavlink
sender that signs with the key, and ignores the unsigned one.

Prints one JSON object; exit 0 when every check holds, 1 when one fails, 2 on a harness
error (a missing peer).
"""
import argparse
import hashlib
import json
import os
import shutil
import sys
import tempfile
import time
import urllib.request

os.environ.setdefault("MAVLINK20", "1")
HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", "..", ".."))
sys.path.insert(0, HERE)
import procs as procs_mod  # noqa: E402

PASSPHRASE = "skyfuse signing check"
TOKEN = "signing-check-token"


def http(method, url, token=None):
    req = urllib.request.Request(url, method=method, data=b"" if method == "POST" else None)
    if token:
        req.add_header("Authorization", f"Bearer {token}")
    with urllib.request.urlopen(req, timeout=5) as r:
        return r.status, json.loads(r.read() or b"null")


def timesync_answered(conn, seconds):
    """Send TIMESYNC requests for `seconds`; how many SITL answered (echoing our ts1)."""
    sent, answered = set(), 0
    end = time.monotonic() + seconds
    next_req = 0.0
    while time.monotonic() < end:
        if time.monotonic() >= next_req:
            ts1 = time.time_ns()
            sent.add(ts1)
            conn.mav.timesync_send(0, ts1)
            next_req = time.monotonic() + 0.25
        m = conn.recv_match(type="TIMESYNC", blocking=True, timeout=0.05)
        if m is not None and m.tc1 != 0 and m.ts1 in sent:
            answered += 1
    return {"sent": len(sent), "answered": answered}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--skyfuse", required=True)
    ap.add_argument("--instance", type=int, default=7)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    from pymavlink import mavutil
    peers = os.environ.get("SKYFUSE_PEERS", os.path.join(ROOT, "..", "shared", "peers"))
    arducopter = os.path.join(peers, "bin", "arducopter")
    parm = os.path.join(peers, "ardupilot", "copter.parm")
    result = {"pass": False, "fails": []}
    for f in (arducopter, parm):
        if not os.path.exists(f):
            result["fails"].append(f"harness: missing {f}")
            print(json.dumps(result))
            sys.exit(2)
    work = tempfile.mkdtemp(prefix="signing-check-")
    procs = procs_mod.Procs(work)
    code = 1
    serial0 = None
    try:
        n = a.instance
        s1, s2 = 5762 + 10 * n, 5763 + 10 * n
        procs.start("arducopter", [arducopter, "--model", "quad", "--speedup", "1", "-I", str(n), "-w",
                                   "--home", "-35.363261,149.16523,584,353", "--defaults", parm], cwd=work)
        # SITL waits for SERIAL0 before it runs; SERIAL0 is also the channel ArduPilot
        # trusts unsigned (USB on a board), so the checks use SERIAL1 and SERIAL2.
        s0 = 5760 + 10 * n
        deadline = time.monotonic() + 20
        while True:
            try:
                serial0 = mavutil.mavlink_connection(f"tcp:127.0.0.1:{s0}", source_system=249)
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise RuntimeError(f"SITL SERIAL0 {s0} not listening")
                time.sleep(0.3)
        serial0.wait_heartbeat(timeout=20)
        key_file = os.path.join(work, "mavlink.key")
        with open(key_file, "w") as f:
            f.write(PASSPHRASE)
        hport = procs_mod.free_port()
        env = dict(os.environ, SKYFUSE__HTTP__TOKEN=TOKEN, SKYFUSE__MAVLINK__SIGNING_KEY_FILE=key_file,
                   RUST_LOG="info,zenoh=warn")
        procs.start("skyfuse", [a.skyfuse, "demo", "--no-browser", "--http", f"127.0.0.1:{hport}",
                                "--listen", f"tcp/127.0.0.1:{procs_mod.free_port()}", "--no-multicast",
                                "--mavlink", f"tcpout:127.0.0.1:{s1}"], cwd=work, env=env)
        base = f"http://127.0.0.1:{hport}"

        def timesync():
            return http("GET", f"{base}/api/v1/status")[1]["outputs"][0]["timesync"]
        deadline = time.monotonic() + 40
        while True:
            try:
                if timesync().get("converged"):
                    break
            except OSError:
                pass
            if time.monotonic() > deadline:
                raise RuntimeError("skyfuse never converged on SITL's clock over tcpout")
            time.sleep(0.5)
        result["timesync_before"] = timesync()
        plain = mavutil.mavlink_connection(f"tcp:127.0.0.1:{s2}", source_system=250, source_component=1)
        result["unsigned_before"] = timesync_answered(plain, 3)
        code_, body = http("POST", f"{base}/api/v1/control/setup-signing", TOKEN)
        result["setup_signing"] = {"status": code_, "body": body}
        time.sleep(1.0)
        used_at_setup = timesync()["used"]
        result["unsigned_after"] = timesync_answered(plain, 4)
        # The same sender (SITL's TCP port takes one client), now signing with the key.
        plain.setup_signing(hashlib.sha256(PASSPHRASE.encode()).digest(), sign_outgoing=True,
                            link_id=9)
        result["signed_after"] = timesync_answered(plain, 4)
        result["timesync_after"] = timesync()
        checks = {
            "unsigned sender answered before": result["unsigned_before"]["answered"] > 3,
            "setup-signing accepted": code_ == 200,
            "unsigned sender ignored after": result["unsigned_after"]["answered"] == 0,
            "signed pymavlink answered after": result["signed_after"]["answered"] > 3,
            # SITL answers skyfuse's signed TIMESYNC requests: their answers keep coming.
            "skyfuse's signed frames answered after": result["timesync_after"]["used"] > used_at_setup,
        }
        result["checks"] = checks
        result["fails"] = [k for k, ok in checks.items() if not ok]
        result["pass"] = not result["fails"]
        code = 0 if result["pass"] else 1
    except (RuntimeError, OSError, KeyError) as e:
        result["fails"].append(f"harness: {e}")
        code = 2
    finally:
        procs.stop_all()
        shutil.rmtree(work, ignore_errors=True)
        with open(a.out, "w") as f:
            json.dump(result, f, indent=1)
    print(json.dumps(result))
    sys.exit(code)


if __name__ == "__main__":
    main()
