"""Small helpers the long-running test scripts share: a free loopback port, skyfuse's
status, and a process's (or thread's) CPU time from /proc."""
import json
import os
import socket
import urllib.request

TICK = os.sysconf("SC_CLK_TCK")


_next_port = [None]


def free_port(kind=None):
    """A loopback port free for TCP and UDP, below the kernel's ephemeral range
    (32768-60999): a port bind(0) hands out could be taken by an outgoing connection
    before the child binds it. Each process walks its own stretch, seeded by its pid.
    `kind` is accepted for callers that name a socket type; both are checked anyway."""
    low, span = 20000, 12000
    if _next_port[0] is None:
        _next_port[0] = (os.getpid() * 131 + 7) % span
    for _ in range(span):
        port = low + _next_port[0] % span
        _next_port[0] += 1
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as t, \
                    socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u:
                t.bind(("127.0.0.1", port))
                u.bind(("127.0.0.1", port))
            return port
        except OSError:
            continue
    raise RuntimeError(f"no free loopback port in {low}..{low + span}")


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


def rss_mib(pid):
    """Resident memory of process `pid`, MiB."""
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return 0.0


def open_page(playwright, chromium, errors):
    """A headless Chromium page (Debian's browser) whose page errors and console errors
    are appended to `errors`."""
    browser = playwright.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
    page = browser.new_page(viewport={"width": 1400, "height": 800})
    page.on("pageerror", lambda e: errors.append(f"page error: {e}"))
    page.on("console", lambda m: m.type == "error" and errors.append(f"console: {m.text}"))
    return browser, page


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
