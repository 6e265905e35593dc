#!/usr/bin/env python3
"""Two websocket clients of skyfuse's /ws, in the standard library only:
a slow one that connects, asks for 50 Hz ticks and never reads (small receive buffer,
so the server's queue for it fills), and a normal one that reads everything and counts
frames per second. Prints a JSON summary.

  ws_clients.py --port P --seconds S
"""
import argparse
import base64
import json
import os
import socket
import time


def connect(port, rcvbuf=None):
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    if rcvbuf:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    s.connect(("127.0.0.1", port))
    key = base64.b64encode(os.urandom(16)).decode()
    s.sendall((f"GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
               f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n").encode())
    head = b""
    while b"\r\n\r\n" not in head:
        head += s.recv(1)
    if b" 101 " not in head.split(b"\r\n")[0]:
        raise SystemExit(f"no websocket upgrade: {head[:200]!r}")
    return s


def send_text(s, text):
    data = text.encode()
    mask = os.urandom(4)
    hdr = bytes([0x81, 0x80 | len(data)]) if len(data) < 126 else bytes([0x81, 0xFE]) + len(data).to_bytes(2, "big")
    s.sendall(hdr + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(data)))


def recv_exact(s, n):
    buf = b""
    while len(buf) < n:
        chunk = s.recv(n - len(buf))
        if not chunk:
            raise EOFError
        buf += chunk
    return buf


def recv_frame(s):
    b0, b1 = recv_exact(s, 2)
    n = b1 & 0x7F
    if n == 126:
        n = int.from_bytes(recv_exact(s, 2), "big")
    elif n == 127:
        n = int.from_bytes(recv_exact(s, 8), "big")
    return b0 & 0x0F, recv_exact(s, n)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--seconds", type=float, required=True)
    a = ap.parse_args()
    slow = connect(a.port, rcvbuf=2048)
    send_text(slow, json.dumps({"type": "subscribe", "max_rate_hz": 50}))
    fast = connect(a.port)
    fast.settimeout(2.0)
    counts, per_second, types = {}, [], {}
    start = time.time()
    sec_start, sec_ticks = start, 0
    snapshot = None
    while time.time() - start < a.seconds:
        op, payload = recv_frame(fast)
        if op != 1:
            continue
        msg = json.loads(payload)
        t = msg.get("type")
        types[t] = types.get(t, 0) + 1
        if t == "snapshot":
            snapshot = {"ticks": len(msg.get("ticks", [])), "events": len(msg.get("events", [])),
                        "sensors": len(msg.get("status", {}).get("sensors", []))}
        if t == "tick":
            sec_ticks += 1
        now = time.time()
        if now - sec_start >= 1.0:
            per_second.append(sec_ticks / (now - sec_start))
            sec_start, sec_ticks = now, 0
    fast.close()
    slow.close()
    print(json.dumps({"types": types, "tick_rate_per_second": per_second, "snapshot": snapshot}))


if __name__ == "__main__":
    main()
