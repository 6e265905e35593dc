"""Child processes of the SITL harness: each started in its own session (so that its
own children go with it), its output in a log file, and every one of them stopped by
its id at the end, also on failure, timeout or a signal."""
import os
import signal
import socket
import subprocess
import time


class Procs:
    def __init__(self, logdir):
        self.logdir = logdir
        self.items = []  # (name, Popen, log file)

    def start(self, name, argv, cwd=None, env=None):
        log = open(os.path.join(self.logdir, f"{name}.log"), "wb")
        p = subprocess.Popen(argv, cwd=cwd, env=env, stdin=subprocess.DEVNULL, stdout=log,
                             stderr=subprocess.STDOUT, start_new_session=True)
        self.items.append((name, p, log))
        return p

    def get(self, name):
        for n, p, _ in self.items:
            if n == name:
                return p
        return None

    def dead(self):
        """Names and exit codes of the children that have ended."""
        return [(n, p.returncode) for n, p, _ in self.items if p.poll() is not None]

    def cpu_times(self):
        """user+system CPU seconds of each running child (itself, from /proc)."""
        out = {}
        tick = os.sysconf("SC_CLK_TCK")
        for n, p, _ in self.items:
            try:
                with open(f"/proc/{p.pid}/stat") as f:
                    fields = f.read().rsplit(")", 1)[1].split()
                out[n] = round((int(fields[11]) + int(fields[12])) / tick, 1)
            except (OSError, IndexError, ValueError):
                out[n] = None
        return out

    def stop_all(self, grace=3.0):
        """SIGTERM to each child's process group (its id: start_new_session made it the
        group leader), then SIGKILL to what is left after `grace` seconds."""
        codes = {}
        for _, p, _ in reversed(self.items):
            if p.poll() is None:
                try:
                    os.killpg(p.pid, signal.SIGTERM)
                except ProcessLookupError:
                    pass
        deadline = time.monotonic() + grace
        for n, p, log in reversed(self.items):
            try:
                p.wait(timeout=max(0.05, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                try:
                    os.killpg(p.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                try:
                    p.wait(timeout=2)
                except subprocess.TimeoutExpired:
                    pass
            codes[n] = p.returncode
            log.close()
        self.items = []
        return codes


def free_port(kind=socket.SOCK_STREAM):
    s = socket.socket(socket.AF_INET, kind)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def port_free(port, kind=socket.SOCK_STREAM):
    s = socket.socket(socket.AF_INET, kind)
    try:
        s.bind(("127.0.0.1", port))
        return True
    except OSError:
        return False
    finally:
        s.close()


def free_sitl_instance(first=1, last=60):
    """An instance number whose SITL ports (5760..5763 + 10·I, and the simulator's
    UDP ports 5501 + 10·I, 9002..9005 + 10·I) are all free on loopback."""
    for i in range(first, last + 1):
        tcp = [5760 + 10 * i + k for k in range(4)]
        udp = [5501 + 10 * i] + [9002 + 10 * i + k for k in range(4)]
        if all(port_free(p) for p in tcp) and all(port_free(p, socket.SOCK_DGRAM) for p in udp):
            return i
    raise RuntimeError("no free SITL instance")
