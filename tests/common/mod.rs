//! Shared helpers of the end-to-end tests: free ports, the service as a child
//! process, a minimal HTTP GET, and the Python peers (eclipse-zenoh, rosbags,
//! pymavlink) from the venv `tests/run` prepares.
#![allow(dead_code)]

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A port free for both TCP and UDP on loopback, chosen below the kernel's
/// ephemeral range (32768-60999 on Linux). A port the kernel hands out for `bind(0)`
/// lies in that range, so an outgoing connection (Zenoh's, a browser's) could take it
/// between our choice and the child's bind ("Address already in use", seen on a fresh
/// clone). Each test process walks its own stretch (seeded by its pid), so parallel
/// tests in one binary never choose the same port twice.
pub fn free_port() -> u16 {
    use std::net::UdpSocket;
    use std::sync::atomic::{AtomicU32, Ordering};
    const LOW: u32 = 20_000;
    const SPAN: u32 = 12_000; // 20000..32000, clear of the ephemeral range
    static NEXT: AtomicU32 = AtomicU32::new(u32::MAX);
    let _ = NEXT.compare_exchange(
        u32::MAX,
        (std::process::id() * 97) % SPAN,
        Ordering::SeqCst,
        Ordering::SeqCst,
    );
    for _ in 0..SPAN {
        let port = (LOW + NEXT.fetch_add(1, Ordering::SeqCst) % SPAN) as u16;
        let tcp = TcpListener::bind(("127.0.0.1", port));
        let udp = UdpSocket::bind(("127.0.0.1", port));
        if tcp.is_ok() && udp.is_ok() {
            return port;
        }
    }
    panic!("no free loopback port in {LOW}..{}", LOW + SPAN)
}

pub fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Whether the developer asked to skip the slow tests of `what` with
/// `SKYFUSE_SKIP=containers,browser,peers,routers` (the fast path in the README); prints
/// why.
pub fn skip_requested(what: &str, test: &str) -> bool {
    let asked = std::env::var("SKYFUSE_SKIP").unwrap_or_default();
    let skip = asked
        .split(',')
        .any(|w| w.trim() == what || w.trim() == "all");
    if skip {
        skipped(
            test,
            &format!("SKYFUSE_SKIP={asked} asks to skip the {what} tests"),
        );
    }
    skip
}

/// Say that `test` is skipped and why: on stderr, and in `$SKYFUSE_SKIP_LOG`, which
/// `tests/run` lists at the end of the run.
pub fn skipped(test: &str, why: &str) {
    skyfuse_core::shared_data::skipped(test, why);
}

/// The real third-party programs (ArduCopter SITL, mavlink-server,
/// zenoh-bridge-ros2dds): $SKYFUSE_PEERS, default ../shared/peers beside the project.
pub fn peers_dir() -> PathBuf {
    std::env::var_os("SKYFUSE_PEERS")
        .map(PathBuf::from)
        .unwrap_or_else(|| repo_root().join("../shared/peers"))
}

/// The Python with the test peers installed: $SKYFUSE_PYTHON, else the venv that
/// `tests/run` makes, else python3.
pub fn python() -> PathBuf {
    if let Some(p) = std::env::var_os("SKYFUSE_PYTHON") {
        return PathBuf::from(p);
    }
    if let Some(home) = std::env::var_os("HOME") {
        let venv = Path::new(&home).join(".cache/skyfuse-venv/bin/python");
        if venv.exists() {
            return venv;
        }
    }
    PathBuf::from("python3")
}

/// Run a Python script from tests/py with arguments; returns stdout, panics with
/// stderr on failure.
pub fn run_py(script: &str, args: &[&str]) -> String {
    let out = Command::new(python())
        .arg(repo_root().join("tests/py").join(script))
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", python().display()));
    assert!(
        out.status.success(),
        "{script} {args:?} failed ({}):\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// A fresh directory under the system's temp dir for one test: removed when dropped,
/// unless the test is failing (then kept, and named on stderr, to look into).
pub struct TempDir(PathBuf);

impl TempDir {
    /// `skyfuse-<name>-<pid>-<n>`, not created: some writers want to make it
    /// themselves (a rosbag2 bag directory must not exist yet).
    pub fn new(name: &str) -> TempDir {
        static NEXT: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
        let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let d = std::env::temp_dir().join(format!("skyfuse-{name}-{}-{n}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        TempDir(d)
    }
}

impl std::ops::Deref for TempDir {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for TempDir {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<std::ffi::OsStr> for TempDir {
    fn as_ref(&self) -> &std::ffi::OsStr {
        self.0.as_os_str()
    }
}

/// Remove `path` unless the thread is panicking: then keep it and say where it is.
fn remove_unless_failing(path: &Path) {
    if std::thread::panicking() {
        eprintln!("kept for the failed test: {}", path.display());
    } else if path.is_dir() {
        let _ = std::fs::remove_dir_all(path);
    } else {
        let _ = std::fs::remove_file(path);
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        remove_unless_failing(&self.0);
    }
}

/// The service binary as a child process, killed on drop.
pub struct Service {
    pub child: Child,
    pub http_port: u16,
    pub zenoh_port: u16,
    pub log: PathBuf,
    /// The controls token the service was started with (SKYFUSE__HTTP__TOKEN).
    pub token: String,
}

impl Service {
    /// Start `skyfuse <args>` with Zenoh on a free loopback port (no multicast) and
    /// HTTP on another; waits for /healthz.
    pub fn start(args: &[&str], env: &[(&str, &str)]) -> Service {
        let mut s = Service::spawn(args, env);
        s.wait_healthy(Duration::from_secs(30));
        s
    }

    /// As `start`, without waiting for anything.
    pub fn spawn(args: &[&str], env: &[(&str, &str)]) -> Service {
        let http_port = free_port();
        let zenoh_port = free_port();
        let log = std::env::temp_dir().join(format!("skyfuse-test-{http_port}.log"));
        let token = format!("test-token-{http_port}");
        let logf = std::fs::File::create(&log).expect("log file");
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_skyfuse"));
        cmd.args(args)
            .args([
                "--listen",
                &format!("tcp/127.0.0.1:{zenoh_port}"),
                "--no-multicast",
                "--http",
                &format!("127.0.0.1:{http_port}"),
            ])
            .env("RUST_LOG", "info,zenoh=warn")
            .env("SKYFUSE__HTTP__TOKEN", &token)
            .stdin(Stdio::null())
            .stdout(logf.try_clone().expect("log"))
            .stderr(logf);
        for (k, v) in env {
            cmd.env(k, v);
        }
        let child = cmd.spawn().expect("spawn skyfuse");
        Service {
            child,
            http_port,
            zenoh_port,
            log,
            token,
        }
    }

    /// Whether the process is still running.
    pub fn running(&mut self) -> bool {
        matches!(self.child.try_wait(), Ok(None))
    }

    pub fn zenoh_endpoint(&self) -> String {
        format!("tcp/127.0.0.1:{}", self.zenoh_port)
    }

    pub fn log_text(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    pub fn wait_healthy(&mut self, timeout: Duration) {
        let start = Instant::now();
        while start.elapsed() < timeout {
            if let Ok(Some(status)) = self.child.try_wait() {
                panic!("skyfuse exited with {status}:\n{}", self.log_text());
            }
            if let Ok((200, _)) = http_get(self.http_port, "/healthz") {
                return;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        panic!(
            "skyfuse not healthy after {timeout:?}:\n{}",
            self.log_text()
        );
    }

    pub fn get_json(&self, path: &str) -> serde_json::Value {
        let (code, body) = http_get(self.http_port, path).expect("GET");
        assert_eq!(code, 200, "GET {path}: {body}");
        serde_json::from_str(&body).unwrap_or_else(|e| panic!("GET {path}: {e}: {body}"))
    }

    /// Poll /api/v1/status until `done` holds or the timeout passes; returns the last status.
    pub fn wait_status(
        &self,
        timeout: Duration,
        done: impl Fn(&serde_json::Value) -> bool,
    ) -> serde_json::Value {
        self.wait_json("/api/v1/status", timeout, done)
    }

    /// Poll a JSON endpoint until `done` holds or the timeout passes; returns the last
    /// answer.
    pub fn wait_json(
        &self,
        path: &str,
        timeout: Duration,
        done: impl Fn(&serde_json::Value) -> bool,
    ) -> serde_json::Value {
        let start = Instant::now();
        loop {
            let s = self.get_json(path);
            if done(&s) || start.elapsed() > timeout {
                return s;
            }
            std::thread::sleep(Duration::from_millis(200));
        }
    }

    /// SIGTERM, then wait; returns the exit status and how long it took.
    pub fn terminate(&mut self) -> (std::process::ExitStatus, Duration) {
        let start = Instant::now();
        let _ = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status();
        loop {
            if let Ok(Some(st)) = self.child.try_wait() {
                return (st, start.elapsed());
            }
            if start.elapsed() > Duration::from_secs(10) {
                let _ = self.child.kill();
                panic!("skyfuse did not exit within 10 s of SIGTERM");
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for Service {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        remove_unless_failing(&self.log);
    }
}

/// Minimal HTTP/1.1 GET on loopback: (status code, body).
pub fn http_get(port: u16, path: &str) -> std::io::Result<(u16, String)> {
    request(port, "GET", path, "", None)
}

/// POST a JSON body, with `Authorization: Bearer <token>` if given.
pub fn http_post(
    port: u16,
    path: &str,
    body: &str,
    token: Option<&str>,
) -> std::io::Result<(u16, String)> {
    request(port, "POST", path, body, token)
}

fn request(
    port: u16,
    method: &str,
    path: &str,
    body: &str,
    token: Option<&str>,
) -> std::io::Result<(u16, String)> {
    let mut s = TcpStream::connect(("127.0.0.1", port))?;
    s.set_read_timeout(Some(Duration::from_secs(10)))?;
    let auth = token
        .map(|t| format!("Authorization: Bearer {t}\r\n"))
        .unwrap_or_default();
    write!(
        s,
        "{method} {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n{auth}Content-Type: application/json\r\nContent-Length: {}\r\n\r\n{body}",
        body.len()
    )?;
    let mut buf = Vec::new();
    s.read_to_end(&mut buf)?;
    let text = String::from_utf8_lossy(&buf).into_owned();
    let code = text
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    let (head, body) = text.split_once("\r\n\r\n").unwrap_or((&text, ""));
    let body = if head
        .to_ascii_lowercase()
        .contains("transfer-encoding: chunked")
    {
        dechunk(body)
    } else {
        body.to_string()
    };
    Ok((code, body))
}

fn dechunk(mut body: &str) -> String {
    let mut out = String::new();
    while let Some((size, rest)) = body.split_once("\r\n") {
        let n = usize::from_str_radix(size.trim(), 16).unwrap_or(0);
        if n == 0 || rest.len() < n {
            break;
        }
        out.push_str(&rest[..n]);
        body = rest[n..].trim_start_matches("\r\n");
    }
    out
}

/// Find a sensor's status object by id.
pub fn sensor<'a>(status: &'a serde_json::Value, id: &str) -> &'a serde_json::Value {
    status["sensors"]
        .as_array()
        .and_then(|a| a.iter().find(|s| s["id"] == id))
        .unwrap_or_else(|| panic!("no sensor {id} in status: {status}"))
}

/// The zenohd binary for router meshes on the host: $SKYFUSE_ZENOHD (tests/run sets it
/// to the one tests/containers/prepare builds), else that build's place in the cache,
/// else `zenohd` on the PATH.
pub fn zenohd() -> PathBuf {
    if let Some(p) = std::env::var_os("SKYFUSE_ZENOHD") {
        return PathBuf::from(p);
    }
    let cache = std::env::var_os("SKYFUSE_CONTAINER_CACHE")
        .map(PathBuf::from)
        .or_else(|| {
            std::env::var_os("HOME").map(|h| Path::new(&h).join(".cache/skyfuse-containers"))
        });
    if let Some(found) = cache
        .and_then(|c| std::fs::read_dir(c).ok())
        .into_iter()
        .flatten()
        .filter_map(Result::ok)
        .map(|e| e.path().join("bin/zenohd"))
        .find(|p| p.is_file())
    {
        return found;
    }
    PathBuf::from("zenohd")
}

/// A zenohd router on loopback, killed on drop; `restart` stops it and starts it again
/// on the same port (a router reboot in the mesh).
pub struct Router {
    child: Option<Child>,
    pub port: u16,
    args: Vec<String>,
    pub log: PathBuf,
}

impl Router {
    /// `zenohd -l tcp/127.0.0.1:<free port>` plus `args` (`-e` links, `-c` config).
    pub fn start(args: &[&str]) -> Router {
        let port = free_port();
        let log = std::env::temp_dir().join(format!("skyfuse-zenohd-{port}.log"));
        let mut r = Router {
            child: None,
            port,
            args: args.iter().map(|s| s.to_string()).collect(),
            log,
        };
        r.spawn();
        r
    }

    fn spawn(&mut self) {
        let logf = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&self.log)
            .expect("router log");
        let bin = zenohd();
        let child = Command::new(&bin)
            .args(["-l", &self.endpoint(), "--no-multicast-scouting"])
            .args(&self.args)
            .env("RUST_LOG", "warn")
            .stdin(Stdio::null())
            .stdout(logf.try_clone().expect("log"))
            .stderr(logf)
            .spawn()
            .unwrap_or_else(|e| {
                panic!(
                    "cannot run zenohd ({}): {e}; tests/containers/prepare builds it, or set SKYFUSE_ZENOHD",
                    bin.display()
                )
            });
        self.child = Some(child);
        // Listening once the port answers.
        let start = Instant::now();
        while TcpStream::connect(("127.0.0.1", self.port)).is_err() {
            assert!(
                start.elapsed() < Duration::from_secs(20),
                "zenohd not listening on {} after 20 s:\n{}",
                self.port,
                std::fs::read_to_string(&self.log).unwrap_or_default()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    pub fn endpoint(&self) -> String {
        format!("tcp/127.0.0.1:{}", self.port)
    }

    pub fn stop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }

    pub fn restart(&mut self) {
        self.stop();
        self.spawn();
    }
}

impl Drop for Router {
    fn drop(&mut self) {
        self.stop();
        remove_unless_failing(&self.log);
    }
}

/// Bytes the process `pid` has received on its established TCP connections to local
/// port `peer_port`, from the kernel's tcp_info (`ss -ti`: bytes_received): what crossed
/// the wire into it, whatever the process itself counts.
pub fn tcp_bytes_received(pid: u32, peer_port: u16) -> u64 {
    let out = Command::new("ss")
        .args([
            "-tinpH",
            "state",
            "established",
            &format!("( dport = :{peer_port} )"),
        ])
        .output()
        .expect("ss (iproute2)");
    let text = String::from_utf8_lossy(&out.stdout);
    let owner = format!("pid={pid},");
    let mut total = 0;
    let mut mine = false;
    for line in text.lines() {
        if !line.starts_with(char::is_whitespace) {
            mine = line.contains(&owner);
            continue;
        }
        if mine {
            total += line
                .split_whitespace()
                .find_map(|w| w.strip_prefix("bytes_received:"))
                .and_then(|n| n.parse::<u64>().ok())
                .unwrap_or(0);
        }
    }
    total
}

/// CPU seconds (user + system) the process `pid` has used, from /proc.
pub fn cpu_seconds(pid: u32) -> f64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    let fields: Vec<&str> = stat
        .rsplit_once(')')
        .map(|(_, rest)| rest.split_whitespace().collect())
        .unwrap_or_default();
    let ticks = |i: usize| {
        fields
            .get(i)
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(0.0)
    };
    // utime and stime, fields 14 and 15 of the line (11 and 12 after the name).
    (ticks(11) + ticks(12)) / 100.0
}

/// Resident memory of the process `pid`, MiB.
pub fn rss_mib(pid: u32) -> f64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .unwrap_or_default()
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next()?.parse::<f64>().ok())
        .map_or(0.0, |kb| kb / 1024.0)
}
