//! The fleet view on Zenoh and HTTP: subscribes to every vehicle's outputs and liveliness
//! token under `[fleet] watch`, feeds [`Fleet`], and serves `/fleet` (the page),
//! `/api/v1/fleet` (the view with tracks) and `/ws/fleet` (a view every
//! [`FRAME_INTERVAL`]).
//!
//! In `skyfuse monitor` it watches from the start. On a vehicle it watches only while
//! someone looks (a request or an open `/ws/fleet` within [`IDLE_AFTER`]), so a fleet
//! of vehicles does not each pay for every other's poses when nobody has the page open.
//! Each websocket client holds only the newest frame (a watch channel): a slow browser
//! skips frames and stalls nothing.

use super::{Fleet, FleetView, ALIVE, EVENTS, HEALTH, POSE, SUMMARY};
use crate::clock::now_us;
use crate::config::FleetConfig;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::State;
use axum::http::header;
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::{Json, Router};
use std::sync::atomic::{AtomicI64, Ordering::Relaxed};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::watch;
use zenoh::sample::SampleKind;

/// How often the view is refreshed and sent to websocket clients.
pub const FRAME_INTERVAL: Duration = Duration::from_millis(500);
/// A vehicle stops watching the fleet this long after the last look.
pub const IDLE_AFTER: Duration = Duration::from_secs(30);
/// At most one warning per this interval about payloads the view could not read.
const WARN_INTERVAL_US: i64 = 10_000_000;

/// The fleet view's Zenoh side and its latest frame.
pub struct FleetWatch {
    session: zenoh::Session,
    cfg: FleetConfig,
    fleet: Arc<Mutex<Fleet>>,
    /// Watch regardless of lookers (`skyfuse monitor`).
    always: bool,
    last_look_us: AtomicI64,
    /// The data subscribers and the liveliness one, while watching.
    subscribers: tokio::sync::Mutex<Vec<zenoh::pubsub::Subscriber<()>>>,
    frames: watch::Sender<Arc<str>>,
    last_warn_us: Arc<AtomicI64>,
}

impl FleetWatch {
    pub fn new(session: zenoh::Session, cfg: FleetConfig, always: bool) -> Arc<Self> {
        let fleet = Arc::new(Mutex::new(Fleet::new(cfg.clone())));
        Arc::new(Self {
            session,
            cfg,
            fleet,
            always,
            last_look_us: AtomicI64::new(i64::MIN / 2),
            subscribers: tokio::sync::Mutex::new(Vec::new()),
            frames: watch::channel(Arc::from("")).0,
            last_warn_us: Arc::new(AtomicI64::new(i64::MIN / 2)),
        })
    }

    /// Someone looks at the fleet: keep (or start) watching.
    pub fn look(&self) {
        self.last_look_us.store(now_us(), Relaxed);
    }

    fn wanted(&self, now: i64) -> bool {
        self.always
            || self.frames.receiver_count() > 0
            || now - self.last_look_us.load(Relaxed) < IDLE_AFTER.as_micros() as i64
    }

    /// The view now, with the tracks.
    pub fn view(&self) -> FleetView {
        self.view_tracks(true)
    }

    /// The view now, with or without the tracks (a thousand vehicles' full tracks are
    /// 600 000 points: a poller that wants only states asks without).
    pub fn view_tracks(&self, with_tracks: bool) -> FleetView {
        let now = now_us();
        let f = self.refreshed(now);
        self.view_of(&f, now, with_tracks)
    }

    /// The fleet, locked, its pending poses read (unreadable ones logged, limited).
    fn refreshed(&self, now: i64) -> std::sync::MutexGuard<'_, Fleet> {
        let mut f = crate::sync::lock(&self.fleet);
        let errors = f.refresh(now);
        warn_limited(&self.last_warn_us, errors.iter().map(|e| e.to_string()));
        f
    }

    /// `/metrics` of `skyfuse monitor`: the fleet in aggregate (no per-vehicle series).
    pub fn metrics_text(&self) -> String {
        let now = now_us();
        let f = self.refreshed(now);
        let (c, (live, stale, gone)) = (f.counters(), f.presence_counts(now));
        drop(f);
        crate::http::metrics::render_fleet(
            crate::http::metrics::FleetNumbers {
                live,
                stale,
                gone,
                max_vehicles: self.cfg.max_vehicles,
                messages: c.messages,
                bytes: c.bytes,
                rejected: c.rejected,
                joined: c.joined,
                forgotten: c.forgotten,
                refused: c.refused,
            },
            crate::http::metrics::ProcessStats::read(),
        )
    }

    fn view_of(&self, f: &Fleet, now: i64, with_tracks: bool) -> FleetView {
        FleetView {
            monitor: self.always,
            ..f.view(now, with_tracks)
        }
    }

    /// Refreshes and publishes the view while wanted; subscribes and unsubscribes as
    /// lookers come and go. Runs until the task is aborted.
    pub async fn run(self: Arc<Self>) {
        let mut every = tokio::time::interval(FRAME_INTERVAL);
        every.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            every.tick().await;
            let now = now_us();
            let wanted = self.wanted(now);
            let subscribed = !self.subscribers.lock().await.is_empty();
            if wanted && !subscribed {
                self.subscribe().await;
            } else if !wanted && subscribed {
                self.unsubscribe().await;
                continue;
            }
            if !wanted {
                continue;
            }
            // The state stays current (tracks) while watched; text only for streams.
            let f = self.refreshed(now);
            if self.frames.receiver_count() == 0 {
                continue;
            }
            let text = serde_json::to_string(&self.view_of(&f, now, false)).unwrap_or_default();
            drop(f);
            self.frames.send_replace(Arc::from(text));
        }
    }

    async fn subscribe(&self) {
        let mut subs = self.subscribers.lock().await;
        let watch = self.cfg.watch.trim_end_matches('/');
        // The summary carries what the view shows of pose and health once a second; the
        // full-rate keys only when asked for (each subscription pulls every matching
        // sample of the fleet across the network to this process).
        let leaves: &[&str] = if self.cfg.summary_only {
            &[SUMMARY, EVENTS]
        } else {
            &[SUMMARY, POSE, HEALTH, EVENTS]
        };
        for &leaf in leaves {
            let key = format!("{watch}/{leaf}");
            let fleet = self.fleet.clone();
            let last_warn = self.last_warn_us.clone();
            let sub = self
                .session
                .declare_subscriber(&key)
                .callback(move |sample: zenoh::sample::Sample| {
                    let Some((id, leaf)) = Fleet::split_key(sample.key_expr().as_str()) else {
                        return;
                    };
                    let payload = sample.payload().to_bytes();
                    let result = crate::sync::lock(&fleet).accept(id, leaf, &payload, now_us());
                    if let Err(e) = result {
                        warn_limited(&last_warn, std::iter::once(e.to_string()));
                    }
                })
                .await;
            match sub {
                Ok(s) => subs.push(s),
                Err(e) => tracing::warn!(key, "fleet view: cannot subscribe: {e}"),
            }
        }
        let key = format!("{watch}/{ALIVE}");
        let fleet = self.fleet.clone();
        let tokens = self
            .session
            .liveliness()
            .declare_subscriber(&key)
            .history(true)
            .callback(move |sample: zenoh::sample::Sample| {
                let Some((id, _)) = Fleet::split_key(sample.key_expr().as_str()) else {
                    return;
                };
                let mut f = crate::sync::lock(&fleet);
                match sample.kind() {
                    SampleKind::Put => f.token_appeared(id, now_us()),
                    SampleKind::Delete => f.token_lost(id, now_us()),
                }
            })
            .await;
        match tokens {
            Ok(s) => subs.push(s),
            Err(e) => tracing::warn!(key, "fleet view: cannot watch liveliness: {e}"),
        }
        tracing::info!(watch, "fleet view: watching");
    }

    async fn unsubscribe(&self) {
        for s in self.subscribers.lock().await.drain(..) {
            if let Err(e) = s.undeclare().await {
                tracing::warn!("fleet view: undeclaring: {e}");
            }
        }
        tracing::info!("fleet view: nobody looking, stopped watching");
    }
}

fn warn_limited(last_warn_us: &AtomicI64, messages: impl Iterator<Item = String>) {
    for m in messages {
        let now = now_us();
        let last = last_warn_us.load(Relaxed);
        if now - last >= WARN_INTERVAL_US
            && last_warn_us
                .compare_exchange(last, now, Relaxed, Relaxed)
                .is_ok()
        {
            tracing::warn!("fleet view: {m} (further such warnings within 10 s are only counted)");
        }
    }
}

/// `/fleet`, its modules under `/js/`, `/api/v1/fleet`, `/ws/fleet`. Merged into both
/// the vehicle's dashboard and `skyfuse monitor`, so `/js/` is routed here, once.
pub fn routes(watch: Arc<FleetWatch>) -> Router {
    Router::new()
        .route("/fleet", get(|| crate::http::assets::serve("fleet.html")))
        .route(
            "/js/{file}",
            get(
                |axum::extract::Path(file): axum::extract::Path<String>| async move {
                    crate::http::assets::serve_module(&file)
                },
            ),
        )
        .route("/api/v1/fleet", get(fleet_json))
        .route("/ws/fleet", get(ws))
        .with_state(watch)
}

/// `?tracks=false` leaves the tracks out.
#[derive(Debug, serde::Deserialize)]
struct FleetQuery {
    #[serde(default = "yes")]
    tracks: bool,
}

fn yes() -> bool {
    true
}

async fn fleet_json(
    State(w): State<Arc<FleetWatch>>,
    axum::extract::Query(query): axum::extract::Query<FleetQuery>,
) -> Response {
    w.look();
    let tracks = query.tracks;
    (
        [(header::CACHE_CONTROL, "no-store")],
        Json(w.view_tracks(tracks)),
    )
        .into_response()
}

async fn ws(State(w): State<Arc<FleetWatch>>, up: WebSocketUpgrade) -> Response {
    w.look();
    // Clients send nothing the fleet view reads; small frames only.
    up.max_message_size(1024)
        .max_frame_size(1024)
        .on_upgrade(move |socket| client(w, socket))
}

/// One client: the view with tracks, then the newest frame whenever there is one.
async fn client(w: Arc<FleetWatch>, mut socket: WebSocket) {
    let mut frames = w.frames.subscribe();
    let first = serde_json::to_string(&w.view()).unwrap_or_default();
    let mut ok = socket.send(Message::Text(first.into())).await.is_ok();
    while ok {
        tokio::select! {
            m = socket.recv() => match m {
                Some(Ok(Message::Close(_))) | None | Some(Err(_)) => break,
                Some(Ok(_)) => {}
            },
            changed = frames.changed() => {
                if changed.is_err() { break; }
                let text = frames.borrow_and_update().clone();
                if !text.is_empty() {
                    ok = socket.send(Message::Text(text.as_ref().into())).await.is_ok();
                }
            }
        }
    }
}
