"""Small helpers the long-running test scripts share: a free loopback port, skyfuse's
status, and a process's (or thread's) CPU time from /proc."""
import json
import os
import socket
import urllib.request

TICK = os.sysconf("SC_CLK_TCK")


def free_port():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    p = s.getsockname()[1]
    s.close()
    return p


def status(port):
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/v1/status", timeout=5) as r:
        return json.loads(r.read())


def cpu_s(stat_path):
    """User + system CPU seconds of /proc/<pid>/stat or /proc/<pid>/task/<tid>/stat."""
    with open(stat_path) as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK


# Chromium as the browser tests start it: Debian's, headless, no background traffic.
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]


def run_with_sim(binary, extra=(), out=None, timeout=30.0):
    """`skyfuse run` on free loopback ports fed by `skyfuse sim` (the demo's sensors and
    rates over Zenoh), started and waited for until the estimate is valid. Returns
    (service, sim, http_port); the caller terminates both. `out`: where their output
    goes (default: nowhere)."""
    import subprocess
    import time
    zport, hport = free_port(), free_port()
    env = {**os.environ, "RUST_LOG": "warn"}
    sink = out if out is not None else subprocess.DEVNULL
    err = subprocess.STDOUT if out is not None else subprocess.DEVNULL
    svc = subprocess.Popen([binary, "run", "--no-multicast", "--listen", f"tcp/127.0.0.1:{zport}",
                            "--http", f"127.0.0.1:{hport}", *extra], stdout=sink, stderr=err, env=env)
    sim = subprocess.Popen([binary, "sim", "--no-multicast", "--connect", f"tcp/127.0.0.1:{zport}",
                            "--listen", f"tcp/127.0.0.1:{free_port()}"], stdout=sink, stderr=err, env=env)
    deadline = time.time() + timeout
    while time.time() < deadline:
        try:
            if status(hport)["estimator"]["valid"]:
                break
        except Exception:
            pass
        time.sleep(0.3)
    return svc, sim, hport
