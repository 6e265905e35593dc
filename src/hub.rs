//! The websocket hub: the data path publishes frames without ever waiting; each client
//! has a bounded queue that drops its oldest frame when the browser is slow (foxglove's
//! websocket server does the same), counts the drops and tells the client.
//!
//! Frames are serialized once and shared (`Arc<str>`) by every client. `tick` frames are
//! downsampled per client (`subscribe` message); `status` and `event` frames are not.

use crate::protocol::ServerFrame;
use crate::sync::lock;
use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::{Arc, Mutex};
use tokio::sync::Notify;

/// Frames a client may have waiting before the oldest is dropped.
pub const CLIENT_QUEUE_FRAMES: usize = 256;
/// Default per-client tick rate, Hz.
pub const DEFAULT_TICK_HZ: f64 = 20.0;
pub const MAX_TICK_HZ: f64 = 50.0;
pub const MIN_TICK_HZ: f64 = 1.0;
/// Tick history for the snapshot: 60 s at ≤ 10 Hz.
const HISTORY_TICKS: usize = 600;
const HISTORY_TICK_INTERVAL_US: i64 = 100_000;
const HISTORY_EVENTS: usize = 200;
/// A tick this early for a client's schedule still goes (ticks come on a 20 ms grid).
const TICK_SLACK_US: i64 = 10_000;

/// `status.websocket` (web/PROTOCOL.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct HubStats {
    pub clients: usize,
    /// Frames dropped for slow clients since start (oldest first).
    pub dropped_total: u64,
    pub frames_published: u64,
    /// Frames each client's queue holds.
    pub queue_capacity: usize,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameKind {
    Tick,
    Status,
    Event,
}

/// One connected client's queue.
pub struct ClientQueue {
    frames: Mutex<VecDeque<Arc<str>>>,
    pub notify: Notify,
    capacity: usize,
    pub dropped_total: AtomicU64,
    /// Drops not yet reported to the client.
    pub dropped_unreported: AtomicU64,
    /// Minimum interval between ticks for this client, µs.
    tick_interval_us: AtomicU64,
    last_tick_us: Mutex<Option<i64>>,
}

impl ClientQueue {
    fn new(capacity: usize) -> Self {
        Self {
            frames: Mutex::new(VecDeque::with_capacity(capacity)),
            notify: Notify::new(),
            capacity,
            dropped_total: AtomicU64::new(0),
            dropped_unreported: AtomicU64::new(0),
            tick_interval_us: AtomicU64::new((1e6 / DEFAULT_TICK_HZ) as u64),
            last_tick_us: Mutex::new(None),
        }
    }

    /// Set this client's tick rate (clamped to [`MIN_TICK_HZ`], [`MAX_TICK_HZ`]).
    pub fn set_max_rate_hz(&self, hz: f64) {
        let hz = if hz.is_finite() {
            hz.clamp(MIN_TICK_HZ, MAX_TICK_HZ)
        } else {
            DEFAULT_TICK_HZ
        };
        self.tick_interval_us.store((1e6 / hz) as u64, Relaxed);
    }

    fn push(&self, kind: FrameKind, t_us: i64, frame: &Arc<str>) -> bool {
        if kind == FrameKind::Tick {
            // `due` is when the next tick may go: scheduled on a grid so a 20 Hz client
            // gets 20 Hz from 50 Hz ticks (not every third tick, 16.7 Hz).
            let mut due = lock(&self.last_tick_us);
            let interval = self.tick_interval_us.load(Relaxed) as i64;
            if let Some(d) = *due {
                // Too early for this client (a tick far before the schedule means the
                // clock moved back, a new run: take it and start over).
                if t_us + TICK_SLACK_US < d && d - t_us <= interval {
                    return false;
                }
            }
            let base = match *due {
                Some(d) if (t_us - d).abs() <= interval => d,
                _ => t_us,
            };
            *due = Some(base + interval);
        }
        let mut q = lock(&self.frames);
        if q.len() >= self.capacity {
            q.pop_front();
            self.dropped_total.fetch_add(1, Relaxed);
            self.dropped_unreported.fetch_add(1, Relaxed);
        }
        q.push_back(frame.clone());
        true
    }

    /// Take everything queued.
    pub fn drain(&self) -> Vec<Arc<str>> {
        lock(&self.frames).drain(..).collect()
    }

    pub fn len(&self) -> usize {
        lock(&self.frames).len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Shared by the data path (publishers) and the websocket handlers (clients).
pub struct Hub {
    clients: Mutex<Vec<Arc<ClientQueue>>>,
    ticks: Mutex<VecDeque<(i64, Arc<str>)>>,
    events: Mutex<VecDeque<Arc<str>>>,
    pub frames_published: AtomicU64,
    dropped_closed: AtomicU64,
    queue_capacity: usize,
}

impl Default for Hub {
    fn default() -> Self {
        Self::new(CLIENT_QUEUE_FRAMES)
    }
}

impl Hub {
    pub fn new(queue_capacity: usize) -> Self {
        Self {
            clients: Mutex::new(Vec::new()),
            ticks: Mutex::new(VecDeque::new()),
            events: Mutex::new(VecDeque::new()),
            frames_published: AtomicU64::new(0),
            dropped_closed: AtomicU64::new(0),
            queue_capacity,
        }
    }

    /// Publish a frame to every client. Never waits on a client.
    pub fn publish(&self, t_us: i64, frame: &ServerFrame) {
        let kind = match frame {
            ServerFrame::Tick(_) => FrameKind::Tick,
            ServerFrame::Status { .. } => FrameKind::Status,
            ServerFrame::Event { .. } => FrameKind::Event,
            // Per client, sent by its own connection task.
            ServerFrame::Dropped { .. } => return,
        };
        let text: Arc<str> = match serde_json::to_string(frame) {
            Ok(t) => t.into(),
            Err(e) => {
                tracing::error!("a websocket frame did not serialise: {e}");
                return;
            }
        };
        self.frames_published.fetch_add(1, Relaxed);
        match kind {
            FrameKind::Tick => {
                let mut h = lock(&self.ticks);
                let keep = match h.back() {
                    Some((last, _)) => t_us < *last || t_us - *last >= HISTORY_TICK_INTERVAL_US,
                    None => true,
                };
                if keep {
                    if h.len() >= HISTORY_TICKS {
                        h.pop_front();
                    }
                    h.push_back((t_us, text.clone()));
                }
            }
            FrameKind::Event => {
                // The snapshot lists the events themselves, kept serialized.
                if let ServerFrame::Event { event } = frame {
                    let mut e = lock(&self.events);
                    if e.len() >= HISTORY_EVENTS {
                        e.pop_front();
                    }
                    e.push_back(event.to_string().into());
                }
            }
            FrameKind::Status => {}
        }
        let clients = lock(&self.clients).clone();
        for c in clients {
            if c.push(kind, t_us, &text) {
                c.notify.notify_one();
            }
        }
    }

    /// Register a client; its snapshot is built from `status`.
    pub fn connect(&self) -> Arc<ClientQueue> {
        let c = Arc::new(ClientQueue::new(self.queue_capacity));
        lock(&self.clients).push(c.clone());
        c
    }

    pub fn disconnect(&self, c: &Arc<ClientQueue>) {
        lock(&self.clients).retain(|x| !Arc::ptr_eq(x, c));
        self.dropped_closed
            .fetch_add(c.dropped_total.load(Relaxed), Relaxed);
    }

    /// The `snapshot` frame for a new client: status, recent ticks and events. The
    /// stored frames are valid JSON already: joined as they are, not parsed again.
    pub fn snapshot(&self, status: serde_json::Value) -> String {
        let ticks = lock(&self.ticks)
            .iter()
            .map(|(_, f)| f.as_ref())
            .collect::<Vec<_>>()
            .join(",");
        let events = lock(&self.events)
            .iter()
            .map(|f| f.as_ref())
            .collect::<Vec<_>>()
            .join(",");
        format!(
            "{{\"type\":\"snapshot\",\"protocol\":{},\"status\":{status},\"ticks\":[{ticks}],\"events\":[{events}]}}",
            crate::protocol::PROTOCOL_VERSION
        )
    }

    pub fn stats(&self) -> HubStats {
        let clients = lock(&self.clients).clone();
        let live: u64 = clients.iter().map(|c| c.dropped_total.load(Relaxed)).sum();
        HubStats {
            clients: clients.len(),
            dropped_total: live + self.dropped_closed.load(Relaxed),
            frames_published: self.frames_published.load(Relaxed),
            queue_capacity: self.queue_capacity,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tick(t: i64) -> ServerFrame {
        ServerFrame::Tick(Box::new(crate::protocol::Tick {
            t: t as f64 / 1e6,
            pose: None,
            sources: Default::default(),
            deltas: Default::default(),
            flow: None,
        }))
    }

    fn event(message: &str) -> ServerFrame {
        ServerFrame::Event {
            event: serde_json::json!({ "message": message }),
        }
    }

    #[test]
    fn a_client_that_never_reads_drops_oldest_and_counts() {
        let hub = Hub::new(8);
        let slow = hub.connect();
        slow.set_max_rate_hz(MAX_TICK_HZ);
        for i in 0..100 {
            hub.publish(i * 100_000, &tick(i * 100_000));
        }
        assert_eq!(slow.len(), 8);
        assert_eq!(slow.dropped_total.load(Relaxed), 92);
        // The newest frames survive.
        let frames = slow.drain();
        assert!(frames[7].contains("9.9"), "{}", frames[7]);
        assert_eq!(hub.stats().dropped_total, 92);
    }

    #[test]
    fn ticks_are_downsampled_per_client_but_events_are_not() {
        let hub = Hub::new(1000);
        let fast = hub.connect();
        fast.set_max_rate_hz(50.0);
        let phone = hub.connect();
        phone.set_max_rate_hz(5.0);
        // 1 s of ticks at 100 Hz.
        for i in 0..100 {
            hub.publish(i * 10_000, &tick(i * 10_000));
        }
        hub.publish(990_000, &event("e"));
        // Ticks at 0, 10, 30, 50, ... 990 ms (50 Hz on a grid, 51 in the first second)
        // and 0, 190, 390, ... 990 ms (5 Hz, 6), plus the event each.
        assert_eq!(fast.len(), 51 + 1);
        assert_eq!(phone.len(), 6 + 1);
    }

    #[test]
    fn snapshot_carries_history_and_events() {
        let hub = Hub::new(10);
        for i in 0..50 {
            hub.publish(i * 50_000, &tick(i * 50_000));
        }
        hub.publish(0, &event("gps lost"));
        let snap: serde_json::Value =
            serde_json::from_str(&hub.snapshot(serde_json::json!({"sensors": []}))).expect("json");
        assert_eq!(snap["type"], "snapshot");
        // 2.5 s of ticks at 20 Hz kept at 10 Hz.
        assert_eq!(snap["ticks"].as_array().map(Vec::len), Some(25));
        assert_eq!(snap["events"][0]["message"], "gps lost");
    }
}
