#!/usr/bin/env python3
"""skyfuse behind a real ground station and router: MAVProxy (PyPI) between skyfuse's
MAVLink output and an autopilot stand-in, over UDP and over TCP, killed and restarted.

skyfuse is already running (tests/e2e_mavproxy.rs starts `skyfuse demo` with the
endpoints below); this script starts three MAVProxy processes (headless:
`--daemon --non-interactive`), an autopilot stand-in for each, and two pymavlink readers.

MAVProxy routes what its --master link sends to every --out, and what an --out sends to
the master only. Two layouts use both directions:

  router/udp: skyfuse udpout:U --> MAVProxy --master=udpin:U --out=udpout:A1 --> stand-in
                                                             --out=udpout:R1 --> reader
  router/tcp: skyfuse tcpout:T --> MAVProxy --master=tcpin:T --out=tcp:A2 ---> stand-in (TCP server)
                                                             --out=udpout:R2 --> reader
  gcs/udp:    stand-in udpout:M --> MAVProxy --master=udpin:M (the autopilot, as a GCS sees it)
              skyfuse udpout:G  --> MAVProxy --out=udpin:G (a companion's link) --> the master

Each stand-in is an autopilot as far as MAVLink goes (HEARTBEAT at 1 Hz as a quadrotor
with ArduPilot, system 1 component 1, sent back through MAVProxy) and records what it
receives, decoded by pymavlink's parser. The two router instances are killed (SIGKILL),
left down, and started again; their stand-ins must get VPE again within a bound.

Checks (each failure listed, exit 1): at every stand-in, VISION_POSITION_ESTIMATE at the
configured rate, from system 1 component 197, MAVLink 2, finite, time_usec increasing,
skyfuse's HEARTBEAT (onboard controller) with it, no undecodable bytes; each reader
(MAVProxy's own --out) decodes the very frames its stand-in got (same bytes); after the
restart VPE reaches the stand-ins again within --restart-bound s, and keeps its rate.

Prints one JSON object with the figures (also when a check fails).

    mavproxy_check.py --router-udp U --router-tcp T --gcs-udp G [--rate-hz 30]
                      [--steady 6] [--down 2] [--after 3] [--restart-bound 15]
"""

import argparse
import json
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import common as mavlink2  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from probe import free_port  # noqa: E402

VPE_ID = mavlink2.MAVLINK_MSG_ID_VISION_POSITION_ESTIMATE
MAV_TYPE_ONBOARD_CONTROLLER = 18


class Fail(Exception):
    pass


def log(msg):
    print(f"[mavproxy_check {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)




def _die_with_parent():
    """In the child: SIGKILL when this script dies (even by SIGKILL)."""
    try:
        import ctypes
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except Exception:  # noqa: BLE001 - best effort
        pass


class Peer:
    """One MAVLink end on loopback, decoding with pymavlink's parser: 'udpin' (bound,
    answers the last sender), 'udpout' (sends to a fixed address, reads replies on the
    same socket) or 'tcpin' (a TCP server; the newest connection is the link, a new one
    replaces a dead one, as an autopilot's TCP port does). As an autopilot it sends
    HEARTBEAT at 1 Hz to whoever is on the other side."""

    def __init__(self, name, kind, port, t0, autopilot):
        self.name, self.kind, self.port, self.t0, self.autopilot = name, kind, port, t0, autopilot
        self.vpe = []          # dicts, in arrival order
        self.heartbeats = []   # (rx, sys, comp, type, autopilot)
        self.other = {}
        self.bad = 0
        self.frames = {}       # (usec, seq) -> frame bytes (hex)
        self.hb_sent = 0
        self.connections = 0
        self.stop = threading.Event()
        self.lock = threading.Lock()
        self.peer_addr = None
        self.conn = None
        self.mav = self._parser()
        if kind == "udpin":
            self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.sock.bind(("127.0.0.1", port))
        elif kind == "udpout":
            self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.sock.bind(("127.0.0.1", 0))
            self.peer_addr = ("127.0.0.1", port)
        elif kind == "tcpin":
            self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.sock.bind(("127.0.0.1", port))
            self.sock.listen(4)
        else:
            raise ValueError(kind)
        self.sock.settimeout(0.1)
        self.threads = [threading.Thread(target=self._run, daemon=True)]
        if autopilot:
            self.threads.append(threading.Thread(target=self._heartbeat, daemon=True))
        for t in self.threads:
            t.start()

    @staticmethod
    def _parser():
        m = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        m.robust_parsing = True  # undecodable bytes come out as BAD_DATA, counted
        return m

    def now(self):
        return time.monotonic() - self.t0

    def _send(self, buf):
        try:
            if self.kind == "tcpin":
                if self.conn is not None:
                    self.conn.sendall(buf)
            elif self.peer_addr is not None:
                self.sock.sendto(buf, self.peer_addr)
            else:
                return False
            return True
        except OSError:
            return False

    def _heartbeat(self):
        # An ArduCopter as MAVLink sees it: a quadrotor, ArduPilot, standby.
        tx = self._parser()
        while not self.stop.wait(1.0):
            msg = tx.heartbeat_encode(mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                      0, 0, mavlink2.MAV_STATE_STANDBY)
            buf = msg.pack(tx)
            tx.seq = (tx.seq + 1) % 256
            with self.lock:
                if self._send(buf):
                    self.hb_sent += 1

    def _take(self, data):
        try:
            msgs = self.mav.parse_buffer(data) or []
        except Exception:  # noqa: BLE001 - a parser error is undecodable data too
            self.bad += 1
            return
        rx = self.now()
        for m in msgs:
            t = m.get_type()
            if t == "BAD_DATA":
                self.bad += 1
            elif m.get_msgId() == VPE_ID:
                vals = [m.x, m.y, m.z, m.roll, m.pitch, m.yaw, *m.covariance]
                buf = bytes(m.get_msgbuf())
                self.vpe.append({"rx": rx, "usec": m.usec, "seq": m.get_seq(), "x": m.x, "y": m.y, "z": m.z,
                                 "sys": m.get_srcSystem(), "comp": m.get_srcComponent(),
                                 "finite": all(math.isfinite(v) for v in vals), "mavlink2": buf[0] == 0xFD})
                self.frames[(m.usec, m.get_seq())] = buf.hex()
            elif t == "HEARTBEAT":
                self.heartbeats.append((rx, m.get_srcSystem(), m.get_srcComponent(), m.type, m.autopilot))
            else:
                self.other[t] = self.other.get(t, 0) + 1

    def _run(self):
        while not self.stop.is_set():
            if self.kind == "tcpin":
                try:
                    c, _ = self.sock.accept()
                    c.settimeout(0.1)
                    with self.lock:
                        if self.conn is not None:
                            self.conn.close()
                        self.conn = c
                        self.connections += 1
                        self.mav = self._parser()  # a new byte stream
                except (socket.timeout, BlockingIOError):
                    pass
                except OSError:
                    break
                c = self.conn
                if c is None:
                    continue
                try:
                    data = c.recv(65536)
                except (socket.timeout, BlockingIOError):
                    continue
                except OSError:
                    data = b""
                if not data:
                    with self.lock:
                        if self.conn is c:
                            c.close()
                            self.conn = None
                    continue
                self._take(data)
            else:
                try:
                    data, addr = self.sock.recvfrom(65536)
                except (socket.timeout, BlockingIOError):
                    continue
                except OSError:
                    break
                if self.kind == "udpin":
                    self.peer_addr = addr
                self._take(data)

    def close(self):
        self.stop.set()
        for t in self.threads:
            t.join(2)
        with self.lock:
            if self.conn is not None:
                self.conn.close()
            self.sock.close()

    def vpe_between(self, a, b):
        return [v for v in self.vpe if a <= v["rx"] < b]


class MavProxy:
    """One mavproxy.py process (its own state dir, its own process group)."""

    def __init__(self, name, exe, master, outs, tmp):
        self.name, self.exe, self.master, self.outs = name, exe, master, outs
        self.dir = os.path.join(tmp, name)
        os.makedirs(self.dir, exist_ok=True)
        self.proc = None
        self.starts = 0

    def start(self):
        self.starts += 1
        argv = [sys.executable, self.exe, f"--master={self.master}", *[f"--out={o}" for o in self.outs],
                "--daemon", "--non-interactive", "--nowait", f"--state-basedir={self.dir}"]
        logf = open(os.path.join(self.dir, f"mavproxy-{self.starts}.log"), "wb")
        self.proc = subprocess.Popen(argv, cwd=self.dir, stdin=subprocess.DEVNULL, stdout=logf,
                                     stderr=subprocess.STDOUT, start_new_session=True,
                                     preexec_fn=_die_with_parent)
        logf.close()
        log(f"started MAVProxy {self.name} (pid {self.proc.pid}): {' '.join(argv[1:])}")

    def alive(self):
        return self.proc is not None and self.proc.poll() is None

    def kill(self):
        if self.proc is not None and self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            self.proc.wait(5)

    def log_tail(self):
        try:
            with open(os.path.join(self.dir, f"mavproxy-{self.starts}.log"), errors="replace") as f:
                return f.read()[-1500:]
        except OSError:
            return ""


def pct(xs, q):
    if not xs:
        return float("nan")
    s = sorted(xs)
    return s[min(len(s) - 1, int(q * (len(s) - 1) + 0.5))]


def r3(x):
    return None if x is None or (isinstance(x, float) and math.isnan(x)) else round(x, 3)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--router-udp", type=int, required=True, help="UDP port skyfuse sends to (udpout)")
    ap.add_argument("--router-tcp", type=int, required=True, help="TCP port skyfuse connects to (tcpout)")
    ap.add_argument("--gcs-udp", type=int, required=True, help="UDP port skyfuse sends to for the GCS layout")
    ap.add_argument("--mavproxy", default=os.path.join(os.path.dirname(sys.executable), "mavproxy.py"))
    ap.add_argument("--rate-hz", type=float, default=30.0, help="skyfuse's configured VPE rate")
    ap.add_argument("--steady", type=float, default=6.0, help="s of routing measured before the restart")
    ap.add_argument("--down", type=float, default=2.0, help="s the router MAVProxies stay killed")
    ap.add_argument("--after", type=float, default=3.0, help="s measured once VPE is back")
    ap.add_argument("--start-bound", type=float, default=30.0, help="s for the first VPE to arrive")
    ap.add_argument("--restart-bound", type=float, default=15.0,
                    help="s after the restart for VPE to reach the stand-ins again")
    ap.add_argument("--keep", action="store_true", help="keep MAVProxy's logs and tlogs")
    a = ap.parse_args()
    if not os.path.exists(a.mavproxy):
        print(f"FAIL: no MAVProxy at {a.mavproxy}", file=sys.stderr)
        return 1
    signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(Fail("terminated (SIGTERM)")))

    t0 = time.monotonic()
    tmp = tempfile.mkdtemp(prefix="skyfuse-mavproxy-")
    out = {"tmp": tmp, "rate_hz": a.rate_hz}
    try:
        from importlib.metadata import version
        out["mavproxy_version"] = version("MAVProxy")
        out["pymavlink_version"] = version("pymavlink")
    except Exception:  # noqa: BLE001 - only a figure
        pass
    failures = []
    peers, mps = [], []
    ok = False

    def expect(cond, msg):
        if not cond:
            failures.append(msg)

    try:
        # the stand-ins and readers first: MAVProxy's outputs connect to them
        ports = {k: free_port(socket.SOCK_STREAM if k == "a_tcp" else socket.SOCK_DGRAM)
                 for k in ("a_udp", "a_tcp", "r_udp", "r_tcp", "m_gcs")}
        standin = {
            "router_udp": Peer("stand-in router/udp", "udpin", ports["a_udp"], t0, autopilot=True),
            "router_tcp": Peer("stand-in router/tcp", "tcpin", ports["a_tcp"], t0, autopilot=True),
            "gcs_udp": Peer("stand-in gcs/udp", "udpout", ports["m_gcs"], t0, autopilot=True),
        }
        reader = {
            "router_udp": Peer("reader router/udp", "udpin", ports["r_udp"], t0, autopilot=False),
            "router_tcp": Peer("reader router/tcp", "udpin", ports["r_tcp"], t0, autopilot=False),
        }
        peers += list(standin.values()) + list(reader.values())
        mp = {
            "router_udp": MavProxy("router_udp", a.mavproxy, f"udpin:127.0.0.1:{a.router_udp}",
                                   [f"udpout:127.0.0.1:{ports['a_udp']}", f"udpout:127.0.0.1:{ports['r_udp']}"], tmp),
            "router_tcp": MavProxy("router_tcp", a.mavproxy, f"tcpin:127.0.0.1:{a.router_tcp}",
                                   [f"tcp:127.0.0.1:{ports['a_tcp']}", f"udpout:127.0.0.1:{ports['r_tcp']}"], tmp),
            "gcs_udp": MavProxy("gcs_udp", a.mavproxy, f"udpin:127.0.0.1:{ports['m_gcs']}",
                                [f"udpin:127.0.0.1:{a.gcs_udp}"], tmp),
        }
        mps += list(mp.values())
        for m in mps:
            m.start()
        out["layouts"] = {k: {"master": m.master, "outs": m.outs} for k, m in mp.items()}

        # -- first VPE at every stand-in
        first = {}
        end = time.monotonic() + a.start_bound
        while time.monotonic() < end and len(first) < len(standin):
            for k, s in standin.items():
                if k not in first and s.vpe:
                    first[k] = s.vpe[0]["rx"]
            for k, m in mp.items():
                if not m.alive():
                    raise Fail(f"MAVProxy {k} exited ({m.proc.returncode}):\n{m.log_tail()}")
            time.sleep(0.05)
        out["first_vpe_s"] = {k: r3(v) for k, v in first.items()}
        missing = [k for k in standin if k not in first]
        if missing:
            raise Fail(f"no VISION_POSITION_ESTIMATE reached the stand-in of {missing} within {a.start_bound} s "
                       f"(other messages there: {[standin[k].other for k in missing]}; "
                       f"heartbeats: {[len(standin[k].heartbeats) for k in missing]})")

        # -- steady routing
        s0 = max(first.values()) + 1.0
        while time.monotonic() - t0 < s0 + a.steady:
            time.sleep(0.05)
        s1 = time.monotonic() - t0

        # -- the router instances killed, left down, started again
        restarted = ("router_udp", "router_tcp")
        t_kill = time.monotonic() - t0
        for k in restarted:
            mp[k].kill()
        log(f"killed MAVProxy {restarted}; down {a.down} s")
        time.sleep(a.down)
        t_restart = time.monotonic() - t0
        for k in restarted:
            mp[k].start()
        back = {}
        end = time.monotonic() + a.restart_bound
        while time.monotonic() < end and len(back) < len(restarted):
            for k in restarted:
                after = [v for v in standin[k].vpe if v["rx"] > t_restart]
                if k not in back and after:
                    back[k] = after[0]["rx"]
            time.sleep(0.02)
        out["restart"] = {"killed_at_s": r3(t_kill), "down_s": a.down, "restarted_at_s": r3(t_restart)}
        for k in restarted:
            before = [v["rx"] for v in standin[k].vpe if v["rx"] <= t_kill]
            out["restart"][k] = {
                "vpe_back_after_restart_s": r3(back[k] - t_restart) if k in back else None,
                "gap_s": r3(back[k] - before[-1]) if k in back and before else None,
                "stand_in_tcp_connections": standin[k].connections if k == "router_tcp" else None,
            }
            expect(k in back, f"{k}: no VPE at the stand-in within {a.restart_bound} s of MAVProxy's restart "
                              f"(MAVProxy log: {mp[k].log_tail()!r})")
        # -- and after
        a0 = max(back.values()) + 0.5 if back else time.monotonic() - t0
        while time.monotonic() - t0 < a0 + a.after:
            time.sleep(0.05)
        a1 = time.monotonic() - t0
        for k, m in mp.items():
            expect(m.alive(), f"MAVProxy {k} died during the run ({m.proc.returncode}): {m.log_tail()!r}")
    except Fail as e:
        failures.append(str(e))
        s0 = s1 = a0 = a1 = None
    finally:
        for m in mps:
            m.kill()
        time.sleep(0.2)
        for p in peers:
            p.close()

    # ------------------------------------------------------------ analysis
    out["links"] = {}
    if s0 is not None:
        for k, s in standin.items():
            steady = s.vpe_between(s0, s1)
            rate = (len(steady) - 1) / (steady[-1]["rx"] - steady[0]["rx"]) if len(steady) > 2 else 0.0
            hb_sky = [h for h in s.heartbeats if (h[1], h[2]) == (1, 197)]
            hb_steady = [h for h in hb_sky if s0 <= h[0] < s1]
            usec = [v["usec"] for v in s.vpe]
            backwards = [(x, y) for x, y in zip(usec, usec[1:]) if y <= x]
            ids = sorted({(v["sys"], v["comp"]) for v in s.vpe})
            link = {"vpe": len(s.vpe), "vpe_steady": len(steady), "rate_hz_steady": r3(rate),
                    "ids": ids, "non_finite": sum(1 for v in s.vpe if not v["finite"]),
                    "mavlink1": sum(1 for v in s.vpe if not v["mavlink2"]),
                    "usec_not_increasing": len(backwards), "bad_data": s.bad,
                    "skyfuse_heartbeats": len(hb_sky),
                    "skyfuse_heartbeat_types": sorted({h[3] for h in hb_sky}),
                    "heartbeats_sent": s.hb_sent, "other": s.other,
                    "last": {kk: r3(s.vpe[-1][kk]) for kk in ("x", "y", "z")} if s.vpe else None}
            lo, hi = 0.8 * a.rate_hz, 1.2 * a.rate_hz
            expect(lo <= rate <= hi, f"{k}: VPE at the stand-in at {rate:.1f} Hz over {s1 - s0:.1f} s "
                                     f"({len(steady)} messages), skyfuse sends {a.rate_hz} Hz")
            expect(ids == [(1, 197)], f"{k}: VPE from system/component {ids}, want [(1, 197)]")
            expect(link["non_finite"] == 0, f"{k}: {link['non_finite']} VPE with non-finite values")
            expect(link["mavlink1"] == 0, f"{k}: {link['mavlink1']} VPE framed as MAVLink 1")
            expect(not backwards, f"{k}: time_usec not increasing {len(backwards)} times, first {backwards[:1]}")
            expect(s.bad == 0, f"{k}: {s.bad} undecodable chunks at the stand-in")
            expect(len(hb_steady) >= int(s1 - s0) - 1,
                   f"{k}: {len(hb_steady)} skyfuse HEARTBEATs in {s1 - s0:.1f} s at the stand-in")
            expect(link["skyfuse_heartbeat_types"] == [MAV_TYPE_ONBOARD_CONTROLLER],
                   f"{k}: skyfuse HEARTBEAT types {link['skyfuse_heartbeat_types']}")
            expect(s.hb_sent >= int(s1 - s0), f"{k}: the stand-in sent only {s.hb_sent} HEARTBEATs")
            if k == "gcs_udp":
                # MAVProxy took the stand-in for its vehicle: its own GCS HEARTBEAT
                # (system 255) and requests go there, next to skyfuse's VPE
                gcs_hb = [h for h in s.heartbeats if h[1] == 255 and h[3] == mavlink2.MAV_TYPE_GCS]
                link["mavproxy_gcs_heartbeats"] = len(gcs_hb)
                expect(len(gcs_hb) >= int(s1 - s0) - 1,
                       f"{k}: {len(gcs_hb)} GCS HEARTBEATs from MAVProxy at its master (the stand-in)")
            if k in ("router_udp", "router_tcp") and a1 is not None and a0 is not None:
                post = s.vpe_between(a0, a1)
                prate = (len(post) - 1) / (post[-1]["rx"] - post[0]["rx"]) if len(post) > 2 else 0.0
                link["rate_hz_after_restart"] = r3(prate)
                expect(lo <= prate <= hi, f"{k}: VPE at {prate:.1f} Hz after the restart")
            out["links"][k] = link

        # MAVProxy's own --out: the same frames as its stand-in, byte for byte
        out["readers"] = {}
        for k, r in reader.items():
            s = standin[k]
            want = {key: f for key, f in s.frames.items()
                    if any(v["usec"] == key[0] and s0 <= v["rx"] < s1 for v in s.vpe)}
            same = sum(1 for key, f in want.items() if r.frames.get(key) == f)
            differ = sum(1 for key, f in want.items() if key in r.frames and r.frames[key] != f)
            rd = {"vpe": len(r.vpe), "steady_frames_at_stand_in": len(want), "same_frame": same,
                  "different_bytes": differ, "bad_data": r.bad,
                  "ids": sorted({(v["sys"], v["comp"]) for v in r.vpe})}
            out["readers"][k] = rd
            expect(len(want) > 0 and same >= 0.98 * len(want),
                   f"{k}: MAVProxy's --out reader decoded {same} of the {len(want)} VPE frames its stand-in got")
            expect(differ == 0, f"{k}: {differ} VPE frames differ between the reader and the stand-in")
            expect(r.bad == 0, f"{k}: {r.bad} undecodable chunks at the reader")
            expect(rd["ids"] == [(1, 197)], f"{k}: the reader's VPE from {rd['ids']}")

    out["wall_s"] = r3(time.monotonic() - t0)
    out["failures"] = failures
    out["ok"] = ok = not failures
    if not ok:
        out["mavproxy_log_tail"] = {m.name: m.log_tail() for m in mps}
    print(json.dumps(out, indent=1))
    if a.keep or not ok:
        log(f"MAVProxy logs kept in {tmp}")
    else:
        shutil.rmtree(tmp, ignore_errors=True)
    if failures:
        print("FAIL: " + "; ".join(failures), file=sys.stderr, flush=True)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
