#!/usr/bin/env python3
"""An autopilot stand-in for TIMESYNC, written with pymavlink: it keeps its own clock
(time since its boot, optionally running at RATE times real time as SITL's --speedup
does), listens for skyfuse's frames on UDP, and behaves as PX4's and ArduPilot's
TIMESYNC do: it answers skyfuse's requests (tc1 = its clock, ts1 echoed) and sends its
own at 2 Hz to the address skyfuse sends from. It records every VISION_POSITION_ESTIMATE
with its own clock at arrival, so the caller can check that `usec` is in the autopilot's
time.

    python tests/py/timesync_standin.py --port P --seconds 12 [--rate 5] [--boot-s 1000]
        [--tcp] [--passphrase SECRET [--intruder]]

With --accept-setup-signing it starts without signing and takes a SETUP_SIGNING as
ArduPilot does: from then on its key is the one received, its frames are signed and
skyfuse's unsigned frames are refused; it reports what it received (target, whether
the key is --passphrase-check's SHA-256, the initial timestamp against its host's
clock) and the signature counts after it.

With --passphrase it requires MAVLink 2 signing as an autopilot with SETUP_SIGNING done
does: its key is the passphrase's SHA-256 (as MAVProxy's `signing setup`), its own frames
are signed, and unsigned frames from skyfuse are rejected (counted). With --intruder it
also sends unsigned TIMESYNC requests from its socket, as a sender without the key
would; skyfuse must refuse them (never answer them).

Prints one JSON object: requests answered for skyfuse, answers skyfuse gave to ours
(and their round trip by the stand-in's clock), and the VPEs' `usec` against the
stand-in's clock at arrival (age_ms: arrival minus usec, by its clock).
"""
import argparse
import json
import os
import statistics
import time

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--seconds", type=float, default=12.0)
    ap.add_argument("--rate", type=float, default=1.0, help="clock rate against real time")
    ap.add_argument("--boot-s", type=float, default=1000.0, help="the clock's reading at start, s")
    ap.add_argument("--passphrase", default=None, help="require signing with this passphrase's key")
    ap.add_argument("--intruder", action="store_true", help="also send unsigned TIMESYNC requests")
    ap.add_argument("--tcp", action="store_true",
                    help="listen on TCP (skyfuse's tcpout:, as SITL's serial ports) instead of UDP")
    ap.add_argument("--accept-setup-signing", action="store_true",
                    help="take a SETUP_SIGNING and require its key from then on")
    ap.add_argument("--passphrase-check", default=None,
                    help="with --accept-setup-signing: the passphrase the key should hash from")
    a = ap.parse_args()

    t0 = time.monotonic()

    def clock_ns():
        return int((a.boot_s + (time.monotonic() - t0) * a.rate) * 1e9)

    scheme = "tcpin" if a.tcp else "udpin"
    conn = mavutil.mavlink_connection(f"{scheme}:127.0.0.1:{a.port}", source_system=1, source_component=1)
    intruder = None
    if a.passphrase:
        import hashlib
        key = hashlib.sha256(a.passphrase.encode("utf-8")).digest()
        conn.setup_signing(key, sign_outgoing=True, allow_unsigned_callback=lambda mav, msg_id: False, link_id=3)
        if a.intruder:
            from pymavlink.dialects.v20 import common as dialect
            intruder = dialect.MAVLink(None, srcSystem=1, srcComponent=1)
    INTRUDER_TS1 = 777  # ts1 of the intruder's requests: an answer echoing it was accepted
    out = {"requests_from_skyfuse": 0, "answers_from_skyfuse": 0, "vpe": 0, "rtt_ms": [], "age_ms": [],
           "rate": a.rate}
    next_request = time.monotonic() + 0.5
    heard = False
    end = t0 + a.seconds
    while time.monotonic() < end:
        m = conn.recv_match(blocking=True, timeout=0.05)
        now = clock_ns()
        if m is not None:
            heard = True
            t = m.get_type()
            if t == "SETUP_SIGNING" and a.accept_setup_signing:
                import hashlib
                key = bytes(m.secret_key)
                want = hashlib.sha256(a.passphrase_check.encode("utf-8")).digest() if a.passphrase_check else None
                # The signing clock: 10 µs units since 2015-01-01 (pymavlink's).
                out["setup_signing"] = {
                    "received": out.get("setup_signing", {}).get("received", 0) + 1,
                    "target_system": m.target_system, "target_component": m.target_component,
                    "key_matches": key == want,
                    "initial_timestamp_vs_now_s": (m.initial_timestamp - (time.time() - 1420070400) * 1e5) / 1e5,
                    "at_s": round(time.monotonic() - t0, 3),
                }
                conn.setup_signing(key, sign_outgoing=True, allow_unsigned_callback=lambda mav, msg_id: False,
                                   link_id=3, initial_timestamp=m.initial_timestamp)
            if t == "TIMESYNC":
                if m.tc1 == 0:
                    out["requests_from_skyfuse"] += 1
                    conn.mav.timesync_send(clock_ns(), m.ts1)
                elif m.ts1 == INTRUDER_TS1:
                    out["intruder_answered"] = out.get("intruder_answered", 0) + 1
                else:
                    out["answers_from_skyfuse"] += 1
                    out["rtt_ms"].append((now - m.ts1) / 1e6 / a.rate)
            elif t == "VISION_POSITION_ESTIMATE":
                out["vpe"] += 1
                # Seconds into the run, so the caller can look at the end only.
                out["age_ms"].append((round(time.monotonic() - t0, 3), (now / 1e3 - m.usec) / 1e3))
        if heard and time.monotonic() >= next_request:
            next_request += 0.5
            conn.mav.timesync_send(0, clock_ns())
            # udpin: pymavlink keeps the senders it heard in `clients`.
            if intruder is not None and getattr(conn, "clients", None):
                frame = intruder.timesync_encode(0, INTRUDER_TS1).pack(intruder)
                for addr in list(conn.clients):
                    conn.port.sendto(frame, addr)
                out["intruder_sent"] = out.get("intruder_sent", 0) + 1
    late = [age for (t, age) in out["age_ms"] if t > a.seconds * 0.6]
    out["late_age_ms"] = {
        "n": len(late),
        "median": statistics.median(late) if late else None,
        "min": min(late) if late else None,
        "max": max(late) if late else None,
    }
    out["rtt_ms"] = {"n": len(out["rtt_ms"]), "median": statistics.median(out["rtt_ms"]) if out["rtt_ms"] else None}
    del out["age_ms"]
    sg = conn.mav.signing
    out["signing"] = {"good": sg.goodsig_count, "bad": sg.badsig_count, "unsigned_rejected": sg.reject_count}
    if a.accept_setup_signing:
        out["signing"]["enabled"] = bool(sg.sign_outgoing)
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
