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
