//! MAVLink out: VISION_POSITION_ESTIMATE (and optionally VISION_SPEED_ESTIMATE,
//! ODOMETRY) at a fixed rate from the latest fused pose, HEARTBEAT at 1 Hz, to every
//! configured endpoint and/or through mavlink-server on Zenoh.
//!
//! The thread that fuses a sample hands each new pose to [`VpeSender::on_pose`], which
//! sends the VPE at once when one is due (no hop to another thread). Each endpoint has its own task
//! and a small bounded queue (`udpout` frames leave with a non-blocking send): a link
//! that is down or slow loses its own frames (counted) and reconnects with back-off; it
//! never delays the others, and nothing here waits, so nothing can block the estimator.

use super::vpe::{self, MessageSet, VpeError};
use crate::clock::now_us;
use crate::config::Endpoint;
use crate::config::MavlinkConfig;
use crate::estimator::FusedPose;
use crate::pipeline::PoseReceiver;
use mavlink::MavHeader;
use serde::Serialize;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::io::AsyncWriteExt;
use tokio::sync::mpsc;

/// Frames waiting per endpoint before new ones are dropped.
const LINK_QUEUE: usize = 64;
const BACKOFF_MIN: Duration = Duration::from_millis(250);
const BACKOFF_MAX: Duration = Duration::from_secs(10);
const HEARTBEAT_INTERVAL_US: i64 = 1_000_000;
/// Staleness and heartbeats are checked this often when no pose arrives.
const CHECK_INTERVAL: Duration = Duration::from_millis(20);
/// A pose this early for the schedule still goes (poses come every few ms).
const SEND_SLACK_US: i64 = 2_000;
/// The autopilot's own component (MAV_COMP_ID_AUTOPILOT1), the target of SETUP_SIGNING.
const MAV_COMP_ID_AUTOPILOT1: u8 = 1;

/// Counters of one endpoint.
#[derive(Debug, Default)]
pub struct LinkStats {
    pub sent: AtomicU64,
    pub dropped: AtomicU64,
    pub errors: AtomicU64,
    /// Frames read back refused: unsigned or badly signed while signing is required.
    pub refused: AtomicU64,
    pub connected: AtomicBool,
    pub last_error: Mutex<Option<String>>,
}

impl LinkStats {
    fn error(&self, e: impl std::fmt::Display) {
        self.errors.fetch_add(1, Relaxed);
        let msg = e.to_string();
        let mut l = crate::sync::lock(&self.last_error);
        if l.as_deref() != Some(msg.as_str()) {
            tracing::warn!("MAVLink output: {msg}");
        }
        *l = Some(msg);
    }
}

/// Counters of the MAVLink output as a whole.
#[derive(Debug, Default)]
pub struct MavlinkStats {
    /// VISION_POSITION_ESTIMATEs handed to the links.
    pub vpe_sent: AtomicU64,
    pub heartbeats: AtomicU64,
    /// SET_GPS_GLOBAL_ORIGIN messages sent (`[mavlink] ekf_origin`).
    pub origin_sent: AtomicU64,
    /// SETUP_SIGNING messages sent (on request).
    pub setup_signing_sent: AtomicU64,
    /// Ticks with nothing sent because the estimate was invalid, stale or non-finite.
    pub withheld: AtomicU64,
    pub not_sending_reason: Mutex<Option<String>>,
    /// When a VISION_POSITION_ESTIMATE last went out, and how fast they go.
    clock: super::SendClock,
    pub last_reset_counter: AtomicU64,
    pub links: Vec<(String, Arc<LinkStats>)>,
    /// The autopilot's clock, from the TIMESYNC answers the links read back.
    pub timesync: Mutex<super::timesync::TimeSync>,
    /// Frames to the endpoints are signed.
    pub signed: bool,
}

/// Our TIMESYNC requests go out this often (PX4 and MAVROS: 1–10 Hz).
const TIMESYNC_INTERVAL_US: i64 = 500_000;

/// What a link needs to answer the autopilot: the output's clock estimate and our
/// MAVLink identity.
#[derive(Clone)]
struct Incoming {
    stats: Arc<MavlinkStats>,
    system_id: u8,
    component_id: u8,
    /// The link's signing (its key and link id), and whether unsigned frames back are
    /// refused.
    signing: Option<Arc<mavlink::SigningData>>,
    required: bool,
    link: Arc<LinkStats>,
}

impl Incoming {
    /// Bytes read from a link at `now_us`: TIMESYNC answers update the clock estimate;
    /// the autopilot's requests get the frames to send back.
    fn read(&self, bytes: &[u8], now_us: i64) -> Vec<Vec<u8>> {
        self.handle(crate::codec::mavlink::timesyncs(bytes), now_us)
    }

    /// TIMESYNCs read at `now_us` (from a datagram, or reassembled from a stream).
    fn handle(&self, reads: Vec<crate::codec::mavlink::ReadTimesync>, now_us: i64) -> Vec<Vec<u8>> {
        let mut replies = Vec::new();
        for read in reads {
            if self.required {
                let ok = self
                    .signing
                    .as_ref()
                    .is_some_and(|sd| crate::codec::mavlink::signature_ok(&read.frame, sd));
                if !ok {
                    self.link.refused.fetch_add(1, Relaxed);
                    continue;
                }
            }
            let t = read.data;
            let handled = {
                let mut ts = crate::sync::lock(&self.stats.timesync);
                let was = ts.status().converged;
                let h = ts.on_message(t.tc1, t.ts1, now_us.saturating_mul(1000));
                let st = ts.status();
                if st.converged != was {
                    if st.converged {
                        tracing::info!(
                            rtt_ms = st.rtt_ms.unwrap_or(f64::NAN),
                            rate = st.rate.unwrap_or(1.0),
                            "MAVLink TIMESYNC converged: poses now carry the autopilot's time"
                        );
                    } else {
                        tracing::warn!(
                            "MAVLink TIMESYNC reset: the autopilot's clock jumped (a reboot?)"
                        );
                    }
                }
                h
            };
            if let super::timesync::Handled::Answer { tc1, ts1 } = handled {
                let msg = mavlink::dialects::common::MavMessage::TIMESYNC(
                    mavlink::dialects::common::TIMESYNC_DATA {
                        tc1,
                        ts1,
                        target_system: t.target_system,
                        target_component: t.target_component,
                    },
                );
                let header = MavHeader {
                    system_id: u32::from(self.system_id),
                    component_id: self.component_id,
                    sequence: 0,
                };
                let frame = match &self.signing {
                    Some(sd) => crate::codec::mavlink::encode_raw_v2_signed(header, &msg, sd),
                    None => crate::codec::mavlink::encode_raw_v2(header, &msg),
                };
                if let Ok(f) = frame {
                    replies.push(f);
                }
            }
        }
        replies
    }
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LinkStatus {
    pub endpoint: String,
    pub sent: u64,
    pub dropped: u64,
    pub errors: u64,
    /// Frames it sends are signed (MAVLink 2 signing).
    pub signed: bool,
    pub refused: u64,
    pub connected: bool,
    pub last_error: Option<String>,
}

/// Why nothing is sent when the config names nowhere to send to.
pub const NO_ENDPOINT: &str =
    "no MAVLink endpoint configured (`[mavlink] endpoints`, `--mavlink`, or zenoh_raw / zenoh_json)";

impl MavlinkStats {
    pub fn status(&self, now: i64, rate_hz: f64) -> super::OutputStatus {
        // Nowhere to send is said first: it is what the user has to change.
        let reason = if self.links.is_empty() {
            Some(NO_ENDPOINT.to_string())
        } else {
            crate::sync::lock(&self.not_sending_reason).clone()
        };
        let links: Vec<LinkStatus> = self
            .links
            .iter()
            .map(|(name, l)| LinkStatus {
                endpoint: name.clone(),
                sent: l.sent.load(Relaxed),
                dropped: l.dropped.load(Relaxed),
                errors: l.errors.load(Relaxed),
                // The Zenoh routes carry mavlink-server's frames unsigned.
                signed: self.signed && !name.starts_with("zenoh:"),
                refused: l.refused.load(Relaxed),
                connected: l.connected.load(Relaxed),
                last_error: crate::sync::lock(&l.last_error).clone(),
            })
            .collect();
        let sum = |f: fn(&LinkStatus) -> u64| links.iter().map(f).sum::<u64>();
        super::OutputStatus {
            name: "mavlink",
            kind: "mavlink",
            endpoint: self
                .links
                .iter()
                .map(|(n, _)| n.as_str())
                .collect::<Vec<_>>()
                .join(", "),
            sent: self.vpe_sent.load(Relaxed),
            dropped: sum(|l| l.dropped),
            errors: sum(|l| l.errors),
            last_error: links.iter().find_map(|l| l.last_error.clone()),
            sending: reason.is_none() && self.clock.recent(now),
            not_sending_reason: reason,
            rate_hz: self.clock.rate_hz(now),
            last_sent_age_ms: self.clock.age_ms(now),
            detail: super::OutputDetail::Mavlink {
                configured_rate_hz: rate_hz,
                heartbeats: self.heartbeats.load(Relaxed),
                origin_sent: self.origin_sent.load(Relaxed),
                setup_signing_sent: self.setup_signing_sent.load(Relaxed),
                withheld: self.withheld.load(Relaxed),
                reset_counter: self.last_reset_counter.load(Relaxed),
                links,
                timesync: crate::sync::lock(&self.timesync).status(),
            },
        }
    }
}

/// A UDP link's socket, its destination and its name, once the link's task set it up.
type DirectUdp = Arc<std::sync::OnceLock<(tokio::net::UdpSocket, SocketAddr, String)>>;

/// An endpoint and its own choice of pose messages (`?messages=`; `None`: `[mavlink]`'s).
pub type EndpointSpec = (Endpoint, Option<MessageSet>);

/// A frame to one endpoint; never waits.
struct Link {
    /// The pose messages this endpoint takes.
    messages: MessageSet,
    tx: mpsc::Sender<Arc<[u8]>>,
    stats: Arc<LinkStats>,
    /// MAVLink 2 signing with this link's id, when a key is configured.
    signing: Option<Arc<mavlink::SigningData>>,
    /// `udpout`: frames leave from the caller at once (a non-blocking send), not through
    /// the link's task, which only sets the socket up: one task hop less between the
    /// pose and the autopilot.
    direct: DirectUdp,
}

impl Link {
    fn offer(&self, frame: &Arc<[u8]>) {
        if let Some((sock, to, name)) = self.direct.get() {
            match sock.try_send_to(frame, *to) {
                Ok(_) => {
                    self.stats.sent.fetch_add(1, Relaxed);
                }
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                    self.stats.dropped.fetch_add(1, Relaxed);
                }
                // ICMP port unreachable surfaces as a send error: nobody listens (yet).
                Err(e) => self.stats.error(format!("{name}: {e}")),
            }
            return;
        }
        if self.tx.try_send(frame.clone()).is_err() {
            self.stats.dropped.fetch_add(1, Relaxed);
        }
    }
}

fn spawn_link(
    ep: Endpoint,
    messages: MessageSet,
    stats: Arc<LinkStats>,
    incoming: Incoming,
) -> Link {
    let (tx, rx) = mpsc::channel(LINK_QUEUE);
    let s = stats.clone();
    let direct = DirectUdp::default();
    let d = direct.clone();
    let signing = incoming.signing.clone();
    tokio::spawn(async move {
        match ep {
            Endpoint::UdpOut(addr) => udp_out(addr, rx, s, d, incoming).await,
            Endpoint::UdpIn(addr) => udp_in(addr, rx, s, incoming).await,
            Endpoint::TcpOut(addr) => tcp_out(addr, rx, s, incoming).await,
            Endpoint::Serial { path, baud } => serial(path, baud, rx, s, incoming).await,
        }
    });
    Link {
        messages,
        tx,
        stats,
        signing,
        direct,
    }
}

/// Drain what arrived while the link could not send, counting it as dropped.
fn drain_dropped(rx: &mut mpsc::Receiver<Arc<[u8]>>, stats: &LinkStats) {
    while rx.try_recv().is_ok() {
        stats.dropped.fetch_add(1, Relaxed);
    }
}

/// Sleep for the back-off, dropping frames meanwhile; `false` when the output stopped.
async fn back_off(
    delay: &mut Duration,
    rx: &mut mpsc::Receiver<Arc<[u8]>>,
    stats: &LinkStats,
) -> bool {
    let until = tokio::time::Instant::now() + *delay;
    *delay = (*delay * 2).min(BACKOFF_MAX);
    loop {
        tokio::select! {
            _ = tokio::time::sleep_until(until) => return true,
            f = rx.recv() => match f {
                Some(_) => { stats.dropped.fetch_add(1, Relaxed); }
                None => return false,
            }
        }
    }
}

async fn resolve(addr: &str) -> std::io::Result<SocketAddr> {
    tokio::net::lookup_host(addr)
        .await?
        .next()
        .ok_or_else(|| std::io::Error::other(format!("{addr} resolves to nothing")))
}

async fn udp_out(
    addr: String,
    mut rx: mpsc::Receiver<Arc<[u8]>>,
    stats: Arc<LinkStats>,
    direct: DirectUdp,
    incoming: Incoming,
) {
    let mut delay = BACKOFF_MIN;
    loop {
        let setup = async {
            let to = resolve(&addr).await?;
            let bind: SocketAddr = if to.is_ipv4() {
                "0.0.0.0:0".parse().map_err(std::io::Error::other)?
            } else {
                "[::]:0".parse().map_err(std::io::Error::other)?
            };
            let sock = tokio::net::UdpSocket::bind(bind).await?;
            Ok::<_, std::io::Error>((sock, to))
        };
        let (sock, to) = match setup.await {
            Ok(x) => x,
            Err(e) => {
                stats.error(format!("udpout:{addr}: {e}"));
                if !back_off(&mut delay, &mut rx, &stats).await {
                    return;
                }
                continue;
            }
        };
        stats.connected.store(true, Relaxed);
        // From now on frames go out from Link::offer; what was queued before goes here.
        let (sock, to, name) = direct.get_or_init(|| (sock, to, format!("udpout:{addr}")));
        while let Ok(f) = rx.try_recv() {
            match sock.send_to(&f, *to).await {
                Ok(_) => {
                    stats.sent.fetch_add(1, Relaxed);
                }
                Err(e) => stats.error(format!("{name}: {e}")),
            }
        }
        // What the autopilot sends back (TIMESYNC) is read here until the output stops.
        let mut buf = [0u8; 2048];
        loop {
            tokio::select! {
                r = sock.recv_from(&mut buf) => {
                    if let Ok((n, from)) = r {
                        for reply in incoming.read(&buf[..n], now_us()) {
                            let _ = sock.send_to(&reply, from).await;
                        }
                    }
                }
                f = rx.recv() => {
                    let Some(f) = f else { return };
                    if let Err(e) = sock.send_to(&f, *to).await {
                        stats.error(format!("{name}: {e}"));
                    } else {
                        stats.sent.fetch_add(1, Relaxed);
                    }
                }
            }
        }
    }
}

async fn udp_in(
    addr: String,
    mut rx: mpsc::Receiver<Arc<[u8]>>,
    stats: Arc<LinkStats>,
    incoming: Incoming,
) {
    let mut delay = BACKOFF_MIN;
    let sock = loop {
        match tokio::net::UdpSocket::bind(&addr).await {
            Ok(s) => break s,
            Err(e) => {
                stats.error(format!("udpin:{addr}: cannot bind: {e}"));
                if !back_off(&mut delay, &mut rx, &stats).await {
                    return;
                }
            }
        }
    };
    let mut peer: Option<SocketAddr> = None;
    let mut buf = [0u8; 2048];
    loop {
        tokio::select! {
            r = sock.recv_from(&mut buf) => {
                if let Ok((n, from)) = r {
                    if peer != Some(from) {
                        tracing::info!("MAVLink output udpin:{addr}: sending to {from}");
                    }
                    peer = Some(from);
                    stats.connected.store(true, Relaxed);
                    for reply in incoming.read(&buf[..n], now_us()) {
                        let _ = sock.send_to(&reply, from).await;
                    }
                }
            }
            f = rx.recv() => {
                let Some(f) = f else { return };
                match peer {
                    Some(p) => match sock.send_to(&f, p).await {
                        Ok(_) => { stats.sent.fetch_add(1, Relaxed); }
                        Err(e) => stats.error(format!("udpin:{addr} to {p}: {e}")),
                    },
                    // Nobody has talked to us yet: there is no one to send to.
                    None => { stats.dropped.fetch_add(1, Relaxed); }
                }
            }
        }
    }
}

async fn tcp_out(
    addr: String,
    rx: mpsc::Receiver<Arc<[u8]>>,
    stats: Arc<LinkStats>,
    incoming: Incoming,
) {
    let open = || {
        let addr = addr.clone();
        async move {
            let connect = tokio::net::TcpStream::connect(&addr);
            match tokio::time::timeout(Duration::from_secs(3), connect).await {
                Ok(Ok(s)) => {
                    let _ = s.set_nodelay(true);
                    Ok(s)
                }
                Ok(Err(e)) => Err(e.to_string()),
                Err(_) => Err("connect timed out".to_string()),
            }
        }
    };
    stream_link(format!("tcpout:{addr}"), open, rx, stats, incoming).await
}

async fn serial(
    path: String,
    baud: u32,
    rx: mpsc::Receiver<Arc<[u8]>>,
    stats: Arc<LinkStats>,
    incoming: Incoming,
) {
    let open = || {
        let path = path.clone();
        async move {
            // Raw 8N1 at the baud rate, on any OS tokio-serial supports. A device that is
            // absent (unplugged) fails here and is tried again after the back-off.
            tokio_serial::SerialStream::open(&tokio_serial::new(&path, baud))
                .map_err(|e| format!("cannot open: {e}"))
        }
    };
    stream_link(format!("serial:{path}:{baud}"), open, rx, stats, incoming).await
}

/// A byte-stream link (TCP, serial): open it, write frames until a write fails (or the
/// other end closes), then back off and open it again. Frames queued while it was down
/// are dropped and counted: a pose must be fresh or not at all. What the autopilot sends
/// back is read for TIMESYNC (frames reassembled across reads), answered on the link.
async fn stream_link<S, Open, Opening>(
    name: String,
    mut open: Open,
    mut rx: mpsc::Receiver<Arc<[u8]>>,
    stats: Arc<LinkStats>,
    incoming: Incoming,
) where
    S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin,
    Open: FnMut() -> Opening,
    Opening: std::future::Future<Output = Result<S, String>>,
{
    use tokio::io::AsyncReadExt;
    let mut delay = BACKOFF_MIN;
    loop {
        let mut link = match open().await {
            Ok(w) => w,
            Err(e) => {
                stats.error(format!("{name}: {e}"));
                if !back_off(&mut delay, &mut rx, &stats).await {
                    return;
                }
                continue;
            }
        };
        tracing::info!("MAVLink output {name}: connected");
        stats.connected.store(true, Relaxed);
        delay = BACKOFF_MIN;
        drain_dropped(&mut rx, &stats);
        let mut reassembly = crate::codec::mavlink::StreamTimesyncs::default();
        let mut buf = vec![0u8; 2048];
        loop {
            // One frame to write, or bytes read back (each side whole before the other).
            let (frames, why): (Vec<Vec<u8>>, Option<String>) = tokio::select! {
                f = rx.recv() => match f {
                    Some(f) => (vec![f.to_vec()], None),
                    None => return,
                },
                r = link.read(&mut buf) => match r {
                    Ok(0) => (vec![], Some("closed by the other end".to_string())),
                    Ok(n) => (incoming.handle(reassembly.push(&buf[..n]), now_us()), None),
                    Err(e) => (vec![], Some(e.to_string())),
                },
            };
            let mut failed = why;
            for f in frames {
                if failed.is_some() {
                    break;
                }
                let written = async {
                    link.write_all(&f).await?;
                    link.flush().await
                };
                match written.await {
                    Ok(()) => {
                        stats.sent.fetch_add(1, Relaxed);
                    }
                    Err(e) => failed = Some(e.to_string()),
                }
            }
            if let Some(e) = failed {
                stats.error(format!("{name}: {e}"));
                stats.connected.store(false, Relaxed);
                break;
            }
        }
    }
}

/// Set up the endpoints' tasks; returns the stats the status API shows.
pub fn build_stats(cfg: &MavlinkConfig) -> (Arc<MavlinkStats>, Vec<EndpointSpec>) {
    let mut eps = Vec::new();
    let mut links = Vec::new();
    for s in &cfg.endpoints {
        // Validated with the config; a bad one here is skipped, not fatal.
        match Endpoint::parse_with_messages(s) {
            Ok(ep) => {
                eps.push(ep);
                links.push((s.clone(), Arc::new(LinkStats::default())));
            }
            Err(e) => tracing::error!("{e}"),
        }
    }
    if cfg.zenoh_raw {
        links.push((
            "zenoh:mavlink_raw/in".into(),
            Arc::new(LinkStats::default()),
        ));
    }
    if cfg.zenoh_json {
        links.push(("zenoh:mavlink/in".into(), Arc::new(LinkStats::default())));
    }
    (
        Arc::new(MavlinkStats {
            links,
            signed: !cfg.signing_key_file.is_empty(),
            ..MavlinkStats::default()
        }),
        eps,
    )
}

/// Key of mavlink-server's raw input (`zenohraw://` endpoint).
pub const ZENOH_RAW_IN: &str = "mavlink_raw/in";
/// Key of mavlink-server's JSON input (`zenoh://` endpoint).
pub const ZENOH_JSON_IN: &str = "mavlink/in";

/// Run the output until `pose` closes.
/// A frame the task publishes on Zenoh (its put is async; the sender never waits).
type ZenohFrame = (MavHeader, mavlink::dialects::common::MavMessage, Arc<[u8]>);
/// Frames waiting for the Zenoh publisher before new ones are dropped.
const ZENOH_QUEUE: usize = 64;

/// What decides and encodes the frames: the VPE schedule, heartbeats, the EKF origin.
/// Synchronous, so the thread that fuses sends a VPE the moment it makes the pose (no
/// hop to another thread); the output task calls it on a timer for heartbeats and to
/// report a stale estimate when no pose comes.
pub struct VpeSender {
    cfg: MavlinkConfig,
    max_std_m: f64,
    stats: Arc<MavlinkStats>,
    links: Vec<Link>,
    /// `[mavlink]`'s pose messages (endpoints without `?messages=`, the Zenoh routes).
    set: MessageSet,
    /// Every pose message some endpoint takes: what each pose is built into.
    built: MessageSet,
    period_us: i64,
    max_age_us: i64,
    next_due: Option<i64>,
    seq: u8,
    last_heartbeat: Option<i64>,
    last_origin: Option<i64>,
    started: i64,
    last_sent_pose_us: Option<i64>,
    last_timesync: Option<i64>,
    tap: crate::tap::Tap,
    zenoh: Option<mpsc::Sender<ZenohFrame>>,
    /// The Zenoh routes' counters (`zenoh:…` links).
    zenoh_stats: Vec<Arc<LinkStats>>,
    /// The estimator's clock: the VPE rate, its age limit and the heartbeat are kept
    /// in it (the autopilot's time when it runs faster than real time).
    time: Arc<crate::clock::SharedTimeBase>,
}

/// The sender, shared by the fusing thread (new poses) and the output task (timer).
pub type VpeHandle = Arc<Mutex<VpeSender>>;

/// Set the output up: the links' tasks start here. Returns the sender and, with a Zenoh
/// route (`zenoh_raw`/`zenoh_json`), the queue the output task publishes from.
pub fn start(
    cfg: MavlinkConfig,
    max_std_m: f64,
    stats: Arc<MavlinkStats>,
    endpoints: Vec<EndpointSpec>,
    tap: crate::tap::Tap,
    time: Arc<crate::clock::SharedTimeBase>,
) -> (VpeHandle, Option<mpsc::Receiver<ZenohFrame>>) {
    // Checked with the config; a key that cannot be read here leaves frames unsigned,
    // said in the log.
    let key = cfg.signing_key().unwrap_or_else(|e| {
        tracing::error!("MAVLink signing off: {e}");
        None
    });
    let global = MessageSet {
        vision_position_estimate: cfg.vision_position_estimate,
        vision_speed_estimate: cfg.vision_speed_estimate,
        odometry: cfg.odometry,
    };
    let built = endpoints
        .iter()
        .filter_map(|(_, m)| *m)
        .fold(global, MessageSet::union);
    let links: Vec<Link> = endpoints
        .into_iter()
        .zip(stats.links.iter())
        .enumerate()
        .map(|(i, ((ep, messages), (_, s)))| {
            // Link ids from 1, in the order of the endpoints.
            let signing = key.map(|k| {
                Arc::new(crate::codec::mavlink::signing_data(
                    k,
                    (i + 1).min(255) as u8,
                    !cfg.signing_required,
                ))
            });
            let incoming = Incoming {
                stats: stats.clone(),
                system_id: cfg.system_id,
                component_id: cfg.component_id,
                signing,
                required: cfg.signing_required,
                link: s.clone(),
            };
            spawn_link(ep, messages.unwrap_or(global), s.clone(), incoming)
        })
        .collect();
    let (zenoh, zenoh_rx) = if cfg.zenoh_raw || cfg.zenoh_json {
        let (tx, rx) = mpsc::channel(ZENOH_QUEUE);
        (Some(tx), Some(rx))
    } else {
        (None, None)
    };
    tracing::info!(
        endpoints = ?cfg.endpoints,
        zenoh_raw = cfg.zenoh_raw,
        zenoh_json = cfg.zenoh_json,
        rate_hz = cfg.rate_hz,
        "MAVLink output running as {}/{}",
        cfg.system_id,
        cfg.component_id
    );
    let zenoh_stats = stats
        .links
        .iter()
        .filter(|(n, _)| n.starts_with("zenoh:"))
        .map(|(_, s)| s.clone())
        .collect();
    let sender = VpeSender {
        set: global,
        built,
        period_us: (1e6 / cfg.rate_hz) as i64,
        max_age_us: (cfg.max_age_ms * 1e3) as i64,
        next_due: None,
        seq: 0,
        last_heartbeat: None,
        last_origin: None,
        started: now_us(),
        last_sent_pose_us: None,
        last_timesync: None,
        cfg,
        max_std_m,
        stats,
        links,
        tap,
        zenoh,
        zenoh_stats,
        time,
    };
    (Arc::new(Mutex::new(sender)), zenoh_rx)
}

impl VpeSender {
    /// SETUP_SIGNING to the autopilot (`target_system`, its autopilot component) with
    /// our key and the signing clock's time now: the autopilot then takes only frames
    /// signed with it. Sent only when asked (the control API), never at start: the key
    /// crosses the link in the clear, so do it over a link you trust. Returns the
    /// number of links it went to.
    pub fn setup_signing(&mut self, now: i64) -> Result<usize, String> {
        let key = self
            .cfg
            .signing_key()?
            .ok_or("no [mavlink] signing_key_file: there is no key to give the autopilot")?;
        if self.links.is_empty() && self.zenoh.is_none() {
            return Err(NO_ENDPOINT.to_string());
        }
        let msg = mavlink::dialects::common::MavMessage::SETUP_SIGNING(
            mavlink::dialects::common::SETUP_SIGNING_DATA {
                initial_timestamp: crate::codec::mavlink::signing_timestamp(now),
                target_system: self.cfg.target_system,
                target_component: MAV_COMP_ID_AUTOPILOT1,
                secret_key: key,
            },
        );
        self.emit(now, vec![msg]);
        self.stats.setup_signing_sent.fetch_add(1, Relaxed);
        tracing::warn!(
            target_system = self.cfg.target_system,
            "SETUP_SIGNING sent on request: the autopilot now requires our key"
        );
        Ok(self.links.len() + usize::from(self.zenoh.is_some()))
    }

    /// A new pose from the estimator: it goes out at once if a frame is due.
    pub fn on_pose(&mut self, pose: &FusedPose) {
        self.step(now_us(), Some(pose), true);
    }

    /// Heartbeats, the EKF origin, and the VPE schedule at `now`. `current`: the newest
    /// pose; `fresh`: it was just made. A good pose goes out only when fresh (a pose
    /// that waited for the timer would be older than the next one); a stale, invalid
    /// or missing one is reported (withheld) from the timer too.
    fn step(&mut self, now: i64, current: Option<&FusedPose>, fresh: bool) {
        let cfg = &self.cfg;
        let stats = &self.stats;
        // Host µs per µs of the estimator's clock (1 unless a simulator runs fast).
        let base = self.time.get();
        let host = |fusion_us: i64| (fusion_us as f64 / base.rate) as i64;
        let due = self.next_due.is_none_or(|d| now + host(SEND_SLACK_US) >= d);
        let heartbeat_due = cfg.heartbeat
            && self
                .last_heartbeat
                .is_none_or(|h| now - h >= host(HEARTBEAT_INTERVAL_US));
        let timesync_due = !stats.links.is_empty()
            && self
                .last_timesync
                .is_none_or(|t| now - t >= TIMESYNC_INTERVAL_US);
        if !due && !heartbeat_due && !timesync_due {
            return;
        }
        let mut frames: Vec<mavlink::dialects::common::MavMessage> = Vec::new();
        if timesync_due {
            self.last_timesync = Some(now);
            frames.push(mavlink::dialects::common::MavMessage::TIMESYNC(
                mavlink::dialects::common::TIMESYNC_DATA {
                    tc1: 0,
                    ts1: now.saturating_mul(1000),
                    target_system: cfg.target_system,
                    target_component: 0,
                },
            ));
        }
        // Poses and the origin carry the autopilot's time once TIMESYNC knows it (PX4
        // stamps them at arrival until then); before, the estimator's clock (ours, or
        // the vehicle's when it runs at another rate).
        let autopilot_us = |t: i64| -> u64 {
            let remote = crate::sync::lock(&stats.timesync).remote_ns(t.saturating_mul(1000));
            remote
                .map_or_else(|| base.to_fusion(t), |ns| ns / 1000)
                .max(0) as u64
        };
        let valid_now = current.is_some_and(|p| p.valid);
        if heartbeat_due {
            self.last_heartbeat = Some(now);
            frames.push(vpe::heartbeat(valid_now));
            stats.heartbeats.fetch_add(1, Relaxed);
            if let Some(origin) = cfg.ekf_origin {
                let since_start = (now - self.started) as f64 * 1e-6;
                let burst = since_start <= crate::config::ORIGIN_BURST_S;
                let resend = self
                    .last_origin
                    .is_none_or(|l| (now - l) as f64 * 1e-6 >= crate::config::ORIGIN_RESEND_S);
                if burst || resend {
                    match vpe::origin_messages(origin, cfg.target_system, autopilot_us(now)) {
                        Ok([set_origin, home]) => {
                            self.last_origin = Some(now);
                            frames.push(set_origin);
                            if burst {
                                frames.push(home);
                            }
                            stats.origin_sent.fetch_add(1, Relaxed);
                        }
                        Err(e) => tracing::warn!("EKF origin not sent: {e}"),
                    }
                }
            }
        }
        let outcome = match current {
            _ if !due => Ok(None),
            None => Err("estimator not initialised".to_string()),
            Some(p) if base.scale(now - p.time_us) > self.max_age_us => Err(format!(
                "estimate stale: newest is {} ms old (limit {} ms)",
                base.scale(now - p.time_us) / 1000,
                cfg.max_age_ms
            )),
            // The same pose twice would tell the autopilot time stood still.
            Some(p) if self.last_sent_pose_us == Some(p.time_us) => Ok(None),
            Some(p) if !fresh && p.valid => Ok(None),
            Some(p) => {
                match vpe::pose_messages(p, autopilot_us(p.time_us), self.built, self.max_std_m) {
                    Ok(m) => Ok(Some((p.time_us, p.reset_counter, m))),
                    Err(VpeError::Invalid(why)) => Err(format!("estimate invalid: {why}")),
                    Err(e) => Err(format!("estimate rejected: {e}")),
                }
            }
        };
        let period_us = host(self.period_us);
        let advance = |next_due: &mut Option<i64>| {
            let base = match *next_due {
                Some(d) if (now - d).abs() <= period_us => d,
                _ => now,
            };
            *next_due = Some(base + period_us);
        };
        // With no link, a pose made is not a pose sent: nothing is counted as sent.
        let outcome = match outcome {
            Ok(Some(_)) if stats.links.is_empty() => Ok(None),
            other => other,
        };
        match outcome {
            Ok(Some((t, reset, msgs))) => {
                advance(&mut self.next_due);
                self.last_sent_pose_us = Some(t);
                stats.vpe_sent.fetch_add(1, Relaxed);
                stats.clock.sent(now);
                stats.last_reset_counter.store(u64::from(reset), Relaxed);
                *crate::sync::lock(&stats.not_sending_reason) = None;
                frames.extend(msgs);
            }
            Ok(None) => {}
            Err(why) => {
                advance(&mut self.next_due);
                stats.withheld.fetch_add(1, Relaxed);
                let mut r = crate::sync::lock(&stats.not_sending_reason);
                // Logged when the kind of reason changes ("estimate stale", "estimate
                // invalid", ...), not each time the age in its text grows.
                let kind = |t: &str| t.split(':').next().unwrap_or(t).to_string();
                if r.as_deref().map(kind) != Some(kind(&why)) {
                    tracing::warn!("MAVLink output: not sending: {why}");
                }
                *r = Some(why);
            }
        }
        self.emit(now, frames);
    }

    /// Encode `frames` (signed per link when a key is set) and offer them to every link
    /// and the Zenoh route.
    fn emit(&mut self, now: i64, frames: Vec<mavlink::dialects::common::MavMessage>) {
        for msg in frames {
            self.seq = self.seq.wrapping_add(1);
            let header = MavHeader {
                system_id: u32::from(self.cfg.system_id),
                component_id: self.cfg.component_id,
                sequence: self.seq,
            };
            match crate::codec::mavlink::encode_raw_v2(header, &msg) {
                Ok(frame) => {
                    let frame: Arc<[u8]> = frame.into();
                    self.tap.mavlink_out(now, &frame);
                    let id = mavlink::Message::message_id(&msg);
                    for l in self.links.iter().filter(|l| l.messages.passes(id)) {
                        match &l.signing {
                            None => l.offer(&frame),
                            Some(sd) => {
                                match crate::codec::mavlink::encode_raw_v2_signed(header, &msg, sd)
                                {
                                    Ok(signed) => l.offer(&Arc::from(signed)),
                                    Err(e) => tracing::error!("MAVLink output: cannot sign: {e}"),
                                }
                            }
                        }
                    }
                    if let Some(z) = self.zenoh.as_ref().filter(|_| self.set.passes(id)) {
                        if z.try_send((header, msg, frame)).is_err() {
                            for s in &self.zenoh_stats {
                                s.dropped.fetch_add(1, Relaxed);
                            }
                        }
                    }
                }
                Err(e) => tracing::error!("MAVLink output: cannot encode: {e}"),
            }
        }
    }
}

/// The output's task: heartbeats and staleness on a timer (the fusing thread sends the
/// VPEs through [`VpeSender::on_pose`]), and the frames routed through Zenoh.
pub async fn run(
    sender: VpeHandle,
    pose: PoseReceiver,
    session: Option<zenoh::Session>,
    mut zenoh_frames: Option<mpsc::Receiver<ZenohFrame>>,
) {
    let (cfg, zenoh_stats) = {
        let s = crate::sync::lock(&sender);
        (s.cfg.clone(), s.zenoh_stats.clone())
    };
    let mut check = tokio::time::interval(CHECK_INTERVAL);
    check.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    loop {
        tokio::select! {
            _ = check.tick() => {
                if pose.has_changed().is_err() { break; }
                let current = pose.borrow().clone();
                crate::sync::lock(&sender).step(now_us(), current.as_deref(), false);
            }
            f = async { match zenoh_frames.as_mut() { Some(rx) => rx.recv().await, None => std::future::pending().await } } => {
                let Some((header, msg, frame)) = f else { break };
                if let Some(s) = &session {
                    publish_zenoh(s, &cfg, &zenoh_stats, header, &msg, &frame).await;
                }
            }
        }
    }
}

async fn publish_zenoh(
    session: &zenoh::Session,
    cfg: &MavlinkConfig,
    stats: &[Arc<LinkStats>],
    header: MavHeader,
    msg: &mavlink::dialects::common::MavMessage,
    frame: &Arc<[u8]>,
) {
    let mut i = 0;
    if cfg.zenoh_raw {
        let s = &stats[i];
        i += 1;
        match session.put(ZENOH_RAW_IN, frame.to_vec()).await {
            Ok(()) => {
                s.sent.fetch_add(1, Relaxed);
            }
            Err(e) => s.error(format!("zenoh {ZENOH_RAW_IN}: {e}")),
        }
    }
    if cfg.zenoh_json {
        let s = &stats[i];
        match crate::codec::mavlink::encode_json(header, msg) {
            Ok(json) => match session.put(ZENOH_JSON_IN, json).await {
                Ok(()) => {
                    s.sent.fetch_add(1, Relaxed);
                }
                Err(e) => s.error(format!("zenoh {ZENOH_JSON_IN}: {e}")),
            },
            Err(e) => s.error(format!("zenoh {ZENOH_JSON_IN}: {e}")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn a_dead_tcp_endpoint_backs_off_and_counts_drops_without_blocking() {
        // A port nobody listens on.
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .map(|a| a.port())
            .expect("port");
        let stats = Arc::new(LinkStats::default());
        let incoming = Incoming {
            stats: Arc::new(MavlinkStats::default()),
            system_id: 1,
            component_id: 197,
            signing: None,
            required: false,
            link: stats.clone(),
        };
        let all = MessageSet {
            vision_position_estimate: true,
            vision_speed_estimate: true,
            odometry: true,
        };
        let link = spawn_link(
            Endpoint::TcpOut(format!("127.0.0.1:{port}")),
            all,
            stats.clone(),
            incoming,
        );
        let frame: Arc<[u8]> = vec![0xFDu8; 20].into();
        let start = std::time::Instant::now();
        for _ in 0..1000 {
            link.offer(&frame);
        }
        // Offering never waits on the link.
        assert!(start.elapsed() < Duration::from_millis(100));
        tokio::time::sleep(Duration::from_millis(300)).await;
        assert!(stats.errors.load(Relaxed) >= 1);
        assert!(stats.dropped.load(Relaxed) >= 1000 - LINK_QUEUE as u64);
        assert_eq!(stats.sent.load(Relaxed), 0);
        assert!(!stats.connected.load(Relaxed));
    }
}
