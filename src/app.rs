//! Wiring: [`run`] takes a validated config, already-bound listeners (so tests bind
//! port 0) and a shutdown future, and runs ingest, the estimator ([`pipeline`]),
//! the outputs and HTTP until shutdown.
//!
//! [`pipeline`]: crate::pipeline

use crate::clock::now_us;
use crate::config::Config;
use crate::event::Event;
use crate::fleet::watch::FleetWatch;
pub use crate::http::AppState;
use crate::hub::Hub;
use crate::ingest::{zenoh_in, Ingest};
use crate::output::mavlink_out;
use crate::output::zenoh_out::{self, ZenohOutInputs, ZenohOutStats};
use crate::pipeline::{self, PipelineShared};
use crate::sim::faults::FaultSchedule;
use std::future::Future;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};
use std::sync::Arc;
use std::time::Duration;
use thiserror::Error;
use tokio::sync::{mpsc, oneshot, watch};

/// Listeners and sessions opened by the caller.
pub struct Listeners {
    pub http: tokio::net::TcpListener,
    /// The Zenoh session to subscribe on (see [`zenoh_in::open_session`]).
    pub zenoh: zenoh::Session,
}

#[derive(Debug, Error)]
pub enum RunError {
    #[error(transparent)]
    Zenoh(#[from] zenoh_in::ZenohError),
    #[error("HTTP server: {0}")]
    Http(std::io::Error),
    #[error(transparent)]
    Record(#[from] crate::record::RecordError),
    #[error(transparent)]
    Tls(#[from] crate::http::tls::TlsError),
}

/// Optional parts of a run.
#[derive(Default)]
pub struct RunOptions {
    /// The demo's simulator faults, for the fault-injection control.
    pub faults: Option<Arc<FaultSchedule>>,
    /// The Foxglove server takes any free port when its configured one is taken (the
    /// demo: a second demo on one machine still starts).
    pub foxglove_any_port: bool,
}

/// Kernel send buffer of each HTTP/websocket connection, bytes (Linux doubles it).
const HTTP_SEND_BUFFER: usize = 32 * 1024;

/// Publishes the status to websocket clients while the service runs.
const STATUS_FRAME_INTERVAL: Duration = Duration::from_millis(500);
/// How often the Zenoh links are looked at.
const ZENOH_LINK_INTERVAL: Duration = Duration::from_secs(1);

/// Run the service until `shutdown` resolves.
pub async fn run(
    config: Config,
    listeners: Listeners,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<(), RunError> {
    run_with(config, listeners, RunOptions::default(), shutdown).await
}

/// [`run`] with optional parts.
pub async fn run_with(
    config: Config,
    listeners: Listeners,
    options: RunOptions,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<(), RunError> {
    let config = Arc::new(config);
    // HTTPS: a bad certificate or key fails the start, naming the file.
    let tls = crate::http::tls::configured(&config.http)?;
    let ingest = Arc::new(Ingest::new(&config));
    let session = listeners.zenoh;
    let zid = session.zid().to_string();
    let locators = config.zenoh.listen.clone();
    let (tap, recorder) = crate::record::spawn(
        &config.record,
        &config.foxglove,
        &config.service.vehicle,
        &config.output.ros2_frame_id,
        ingest.clone(),
        options.foxglove_any_port,
    )
    .await?;
    let recorder = recorder.map(Arc::new);
    let started_us = now_us();
    let hub = Arc::new(Hub::default());
    let shared = Arc::new(PipelineShared::new(
        hub.clone(),
        started_us,
        ingest.clock.clone(),
    ));
    let (pose_tx, pose_rx) = watch::channel(None);
    let (pose_out_tx, pose_out_rx) = watch::channel(None);
    let (debug_tx, debug_rx) = watch::channel(Arc::new(crate::estimator::DebugSeries::default()));
    let (mavlink_stats, endpoints) = mavlink_out::build_stats(&config.mavlink);
    let zenoh_out_stats = Arc::new(ZenohOutStats::default());
    // ROS 2 graph: announce our topics, watch the bridges' (discovery shows them too).
    let ros_tokens = if config.output.ros2_announce {
        crate::ros_graph::announce(
            &session,
            &config.output.announced_outputs(),
            &config.output.ros2_qos,
            &config.output.ros_distro,
        )
        .await
    } else {
        Vec::new()
    };
    let ros_watch = if config.output.ros2_announce || config.discovery.enabled {
        crate::ros_graph::discover(&session, ingest.ros_topics.clone()).await
    } else {
        None
    };
    let discovery = config
        .discovery
        .enabled
        .then(|| Arc::new(crate::discovery::Discovery::default()));
    let discovery_watch = match &discovery {
        Some(d) => crate::discovery::watch(&session, d.clone()).await,
        None => None,
    };
    let (cmd_tx, cmd_rx) = mpsc::channel(16);
    let pipeline_config = pipeline::PipelineConfig {
        estimator: config.estimator.clone(),
        health: config.health.clone(),
        inputs: config
            .inputs
            .iter()
            .map(|i| crate::fusion::InputSpec {
                id: i.id.clone(),
                kind: i.kind,
                rate_hz: i.rate_hz,
                enabled: i.enabled,
            })
            .collect(),
        follow_vehicle_clock: config.ingest.follow_vehicle_clock,
    };
    let (vpe, vpe_zenoh) = mavlink_out::start(
        config.mavlink.clone(),
        config.estimator.max_pos_std_m,
        mavlink_stats.clone(),
        endpoints,
        tap.clone(),
        shared.time.clone(),
    );
    let vpe_on_pose = vpe.clone();
    let inlet = Arc::new(pipeline::Inlet::new(
        pipeline::Pipeline::new(
            pipeline_config,
            shared.clone(),
            pipeline::PipelineOutputs {
                on_pose: Box::new(move |p| crate::sync::lock(&vpe_on_pose).on_pose(p)),
                pose: pose_tx,
                pose_out: pose_out_tx,
                pose_rate: pipeline::RateLimit::hz(config.output.pose_rate_hz),
                debug: debug_tx,
                debug_rate: pipeline::RateLimit::hz(config.output.debug_rate_hz),
            },
        ),
        config.ingest.channel_capacity,
    ));
    let subscribers =
        zenoh_in::subscribe_inputs(&session, ingest.clone(), inlet.clone(), tap.clone()).await?;
    let (stop_estimator, estimator_stopped) = oneshot::channel::<()>();
    let estimator = tokio::spawn(pipeline::run(
        inlet.clone(),
        cmd_rx,
        ingest.clone(),
        async move {
            let _ = estimator_stopped.await;
        },
    ));
    let http_addr = listeners.http.local_addr().map_err(RunError::Http)?;
    let dashboard_url = dashboard_url(&config.http, http_addr);
    let state = Arc::new(AppState {
        config: config.clone(),
        ingest: ingest.clone(),
        pipeline: shared.clone(),
        hub: hub.clone(),
        commands: cmd_tx,
        pose: pose_rx.clone(),
        faults: options.faults,
        controls_refused: AtomicU64::new(0),
        refusals: Default::default(),
        mavlink_stats: mavlink_stats.clone(),
        vpe: vpe.clone(),
        zenoh_out_stats: zenoh_out_stats.clone(),
        started_us,
        zenoh_zid: zid.clone(),
        zenoh_locators: locators.clone(),
        inlet: inlet.clone(),
        zenoh_closed: AtomicBool::new(false),
        zenoh_routers: AtomicU64::new(0),
        zenoh_peers: AtomicU64::new(0),
        recorder: recorder.clone(),
        dashboard_url,
        discovery,
    });
    let mavlink = tokio::spawn(mavlink_out::run(
        vpe,
        pose_rx.clone(),
        vpe_zenoh.is_some().then(|| session.clone()),
        vpe_zenoh,
    ));
    let health_state = Arc::downgrade(&state);
    let zenoh_output = tokio::spawn(zenoh_out::run(
        session.clone(),
        config.output.clone(),
        config.output.prefix_for(&config.service.vehicle),
        ZenohOutInputs {
            pose: pose_out_rx.clone(),
            debug: debug_rx.clone(),
            events: shared.events_tx.subscribe(),
            health: Arc::new(move || {
                health_state
                    .upgrade()
                    .map(|s| s.health_json())
                    .unwrap_or(serde_json::Value::Null)
            }),
            tap: tap.clone(),
            mavlink_px4_time: {
                let stats = mavlink_stats.clone();
                Arc::new(move |host_us: i64| {
                    crate::sync::lock(&stats.timesync)
                        .remote_ns(host_us.saturating_mul(1000))
                        .map(|ns| ns / 1000)
                })
            },
            max_std_m: config.estimator.max_pos_std_m,
        },
        zenoh_out_stats,
    ));
    let record_feed = tap.is_on().then(|| {
        tokio::spawn(record_feed(
            tap.clone(),
            state.clone(),
            pose_out_rx.clone(),
            debug_rx.clone(),
            shared.events_tx.subscribe(),
        ))
    });
    let status_frames = tokio::spawn(status_frames(state.clone()));
    let silent_inputs = tokio::spawn(report_silent_inputs(state.clone()));
    let zenoh_links = tokio::spawn(watch_zenoh_links(state.clone(), session.clone()));
    // The fleet view finds this vehicle by its token (and sees it go when we stop).
    let prefix = config.output.prefix_for(&config.service.vehicle);
    let alive = declare_alive(&session, &prefix).await;
    let fleet = FleetWatch::new(session.clone(), config.fleet.clone(), false);
    let fleet_task = tokio::spawn(fleet.clone().run());

    tracing::info!(
        vehicle = %config.service.vehicle,
        zid = %zid,
        zenoh = ?locators,
        http = %http_addr,
        https = tls.is_some(),
        inputs = config.inputs.iter().filter(|i| i.enabled).count(),
        "skyfuse running"
    );
    let app = crate::http::router(state.clone()).merge(crate::fleet::watch::routes(fleet));
    serve_http(listeners.http, tls, app, shutdown).await?;

    tracing::info!("shutting down");
    fleet_task.abort();
    if let Some(t) = alive {
        if let Err(e) = t.undeclare().await {
            tracing::warn!("undeclaring the fleet token: {e}");
        }
    }
    // Our ROS topics go away with us.
    for t in ros_tokens {
        if let Err(e) = t.undeclare().await {
            tracing::warn!("undeclaring liveliness token: {e}");
        }
    }
    if let Some(w) = ros_watch {
        let _ = w.undeclare().await;
    }
    if let Some(w) = discovery_watch {
        let _ = w.undeclare().await;
    }
    for s in subscribers {
        if let Err(e) = s.undeclare().await {
            tracing::warn!("undeclaring subscriber: {e}");
        }
    }
    // No more samples: the estimator stops (and its pose channel closes).
    let _ = stop_estimator.send(());
    let _ = estimator.await;
    status_frames.abort();
    silent_inputs.abort();
    zenoh_links.abort();
    // The pose channel closed with the estimator: the outputs end on their own.
    let _ = mavlink.await;
    zenoh_output.abort();
    if let Some(f) = record_feed {
        f.abort();
    }
    // Everything queued is logged and the MCAP file finalised (summary, footer).
    if let Some(r) = recorder {
        let _ = tokio::task::spawn_blocking(move || r.finish()).await;
    }
    state.zenoh_closed.store(true, Relaxed);
    if let Err(e) = session.close().await {
        tracing::warn!("closing zenoh session: {e}");
    }
    Ok(())
}

/// Serves `app` on the listener (HTTPS with `tls`) until `shutdown`.
async fn serve_http(
    listener: tokio::net::TcpListener,
    tls: Option<Arc<rustls::ServerConfig>>,
    app: axum::Router,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<(), RunError> {
    // A small kernel send buffer per connection: a stalled browser then fills its own
    // bounded queue (and drops, counted) within seconds instead of hiding megabytes
    // of stale frames in the kernel.
    let socket_options = |tcp: &tokio::net::TcpStream| {
        let _ = tcp.set_nodelay(true);
        let _ = socket2::SockRef::from(tcp).set_send_buffer_size(HTTP_SEND_BUFFER);
    };
    // The peer address reaches the handlers (refused controls are limited per address).
    let app = app.into_make_service_with_connect_info::<std::net::SocketAddr>();
    use axum::serve::ListenerExt;
    match tls {
        Some(tls) => {
            let https = crate::http::tls::TlsListener::new(listener, tls)
                .map_err(RunError::Http)?
                .tap_io(move |s| socket_options(s.get_ref().0));
            axum::serve(https, app)
                .with_graceful_shutdown(shutdown)
                .await
                .map_err(RunError::Http)
        }
        None => {
            let http = listener.tap_io(move |s| socket_options(s));
            axum::serve(http, app)
                .with_graceful_shutdown(shutdown)
                .await
                .map_err(RunError::Http)
        }
    }
}

/// The liveliness token `<prefix>/alive` the fleet view finds a vehicle by; Zenoh drops
/// it when this process or its link goes. None (logged) if Zenoh refuses it.
async fn declare_alive(
    session: &zenoh::Session,
    prefix: &str,
) -> Option<zenoh::liveliness::LivelinessToken> {
    let key = format!("{prefix}/{}", crate::fleet::ALIVE);
    match session.liveliness().declare_token(&key).await {
        Ok(t) => Some(t),
        Err(e) => {
            tracing::warn!(
                key,
                "the fleet view will not see this vehicle come and go: {e}"
            );
            None
        }
    }
}

/// Where people reach the dashboard: `[http] public_url`, else the bound address, with
/// the host's name when bound to every address (the fleet view links to it).
pub fn dashboard_url(http: &crate::config::HttpConfig, bound: std::net::SocketAddr) -> String {
    if let Some(u) = http.public_url.as_deref().filter(|u| !u.is_empty()) {
        return u.to_string();
    }
    let scheme = if http.tls().is_some() {
        "https"
    } else {
        "http"
    };
    let host = if bound.ip().is_unspecified() {
        host_name().unwrap_or_else(|| "localhost".into())
    } else if bound.is_ipv6() {
        format!("[{}]", bound.ip())
    } else {
        bound.ip().to_string()
    };
    format!("{scheme}://{host}:{}/", bound.port())
}

/// This host's name (Linux: the kernel's; elsewhere `HOSTNAME`).
fn host_name() -> Option<String> {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .or_else(|| std::env::var("HOSTNAME").ok())
        .map(|h| h.trim().to_string())
        .filter(|h| !h.is_empty())
}

/// `skyfuse monitor`: the fleet view alone (no estimator, no inputs) until `shutdown`.
pub async fn monitor(
    config: Config,
    listeners: Listeners,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<(), RunError> {
    let tls = crate::http::tls::configured(&config.http)?;
    let session = listeners.zenoh;
    let fleet = FleetWatch::new(session.clone(), config.fleet.clone(), true);
    let fleet_task = tokio::spawn(fleet.clone().run());
    let http_addr = listeners.http.local_addr().map_err(RunError::Http)?;
    tracing::info!(
        zid = %session.zid(),
        http = %http_addr,
        watch = %config.fleet.watch,
        "skyfuse monitor running: the fleet view at /fleet"
    );
    let app = axum::Router::new()
        .route(
            "/",
            axum::routing::get(|| async { axum::response::Redirect::temporary("/fleet") }),
        )
        .route(
            "/app.css",
            axum::routing::get(|| crate::http::assets::serve("app.css")),
        )
        .route("/healthz", axum::routing::get(|| async { "ok\n" }))
        .route(
            "/metrics",
            axum::routing::get({
                let fleet = fleet.clone();
                move || async move {
                    (
                        [(
                            axum::http::header::CONTENT_TYPE,
                            crate::http::metrics::CONTENT_TYPE,
                        )],
                        fleet.metrics_text(),
                    )
                }
            }),
        )
        .merge(crate::fleet::watch::routes(fleet));
    serve_http(listeners.http, tls, app, shutdown).await?;
    fleet_task.abort();
    if let Err(e) = session.close().await {
        tracing::warn!("closing zenoh session: {e}");
    }
    Ok(())
}

/// Follow the Zenoh session's links: the counts go to the status, and losing or regaining
/// every router (client mode) or peer is logged and put in the event log, because with
/// the link gone every sensor goes stale for a reason no sensor check can name.
async fn watch_zenoh_links(state: Arc<AppState>, session: zenoh::Session) {
    let client = state.config.zenoh.mode == crate::config::ZenohMode::Client;
    let mut every = tokio::time::interval(ZENOH_LINK_INTERVAL);
    every.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    // Not linked at start is quiet (a peer nobody has found yet); only changes speak.
    let mut was_linked = false;
    loop {
        every.tick().await;
        let routers: Vec<String> = session
            .info()
            .routers_zid()
            .await
            .map(|z| z.to_string())
            .collect();
        let peers = session.info().peers_zid().await.count();
        state.zenoh_routers.store(routers.len() as u64, Relaxed);
        state.zenoh_peers.store(peers as u64, Relaxed);
        let linked = if client {
            !routers.is_empty()
        } else {
            !routers.is_empty() || peers > 0
        };
        if linked == was_linked {
            continue;
        }
        was_linked = linked;
        let message = if linked {
            let message = format!(
                "Zenoh: connected ({} routers {routers:?}, {peers} peers)",
                routers.len()
            );
            tracing::info!("{message}");
            message
        } else {
            let what = if client { "router" } else { "router or peer" };
            let message = format!(
                "Zenoh: lost every {what} (connect {:?}); reconnecting, no samples until then",
                state.config.zenoh.connect
            );
            tracing::warn!("{message}");
            message
        };
        state.publish_service_event(Event::ZenohLink, None, &message);
    }
}

/// How often health goes to the recorder.
const RECORD_HEALTH_INTERVAL: Duration = Duration::from_secs(1);
/// The debug series go to the recorder at most this often.
const RECORD_DEBUG_INTERVAL: Duration = Duration::from_millis(50);

/// Feeds the recorder what is not tapped where it is made: the fused poses (`pose`: at the
/// pose output's rate, `[output] pose_rate_hz`, as Zenoh gets them), the debug series
/// (≤ 20 Hz), events and health (1 Hz).
async fn record_feed(
    tap: crate::tap::Tap,
    state: Arc<AppState>,
    mut pose: crate::pipeline::PoseReceiver,
    mut debug: crate::pipeline::DebugReceiver,
    mut events: tokio::sync::broadcast::Receiver<Arc<serde_json::Value>>,
) {
    let mut health = tokio::time::interval(RECORD_HEALTH_INTERVAL);
    health.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut debug_sent = tokio::time::Instant::now();
    loop {
        tokio::select! {
            changed = pose.changed() => {
                if changed.is_err() { break; }
                let p = pose.borrow_and_update().clone();
                if let Some(p) = p {
                    tap.pose(p);
                }
            }
            changed = debug.changed() => {
                if changed.is_err() { break; }
                if debug_sent.elapsed() >= RECORD_DEBUG_INTERVAL {
                    debug_sent = tokio::time::Instant::now();
                    let series = debug.borrow_and_update().clone();
                    tap.debug(now_us(), series);
                }
            }
            ev = events.recv() => match ev {
                Ok(e) => tap.event(now_us(), (*e).clone()),
                Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => {}
                Err(tokio::sync::broadcast::error::RecvError::Closed) => break,
            },
            _ = health.tick() => tap.health(now_us(), state.health_json()),
        }
    }
}

/// First said this long after start, then again at this interval while it lasts.
const SILENT_INPUTS_FIRST: Duration = Duration::from_secs(5);
const SILENT_INPUTS_EVERY: Duration = Duration::from_secs(60);

/// An input that has received nothing says so in the log, with the key it waits on and
/// what is published that looks meant for it (discovery): the log of a service nobody
/// feeds must not stop at "estimator not initialised".
async fn report_silent_inputs(state: Arc<AppState>) {
    tokio::time::sleep(SILENT_INPUTS_FIRST).await;
    let mut every = tokio::time::interval(SILENT_INPUTS_EVERY);
    loop {
        every.tick().await;
        let found = state.discovered();
        for input in state.ingest.inputs.iter().filter(|i| i.config.enabled) {
            if input.counters.received.load(Relaxed) > 0 {
                continue;
            }
            let near: Vec<String> = found
                .iter()
                .flat_map(|d| &d.keys)
                .filter(|k| k.near.as_ref().is_some_and(|n| n.input == input.config.id))
                .map(|k| {
                    let why = k.near.as_ref().map(|n| n.why.as_str()).unwrap_or_default();
                    format!("{} ({:.0} Hz: {why})", k.key, k.rate_hz)
                })
                .collect();
            let hint = if near.is_empty() {
                String::new()
            } else {
                format!("; published and looking meant for it: {}", near.join(", "))
            };
            tracing::warn!(
                input = %input.config.id,
                key = %input.config.key,
                format = %input.config.format,
                "nothing received on {} yet{hint}",
                input.config.key
            );
        }
    }
}

/// The `status` frame for websocket clients, twice a second.
async fn status_frames(state: Arc<AppState>) {
    let mut every = tokio::time::interval(STATUS_FRAME_INTERVAL);
    every.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        every.tick().await;
        let status = state.status_json();
        let frame = crate::protocol::ServerFrame::Status { status };
        state.hub.publish(now_us(), &frame);
    }
}

/// Resolves on SIGINT or SIGTERM. The handlers are installed when this is called, not
/// when the future is first polled: in a container skyfuse is PID 1, which the kernel
/// shields from signals it has no handler for, so a SIGTERM that arrived before the
/// first poll (while waiting for a Zenoh router, say) would be lost and `docker stop`
/// would end in SIGKILL.
pub fn shutdown_signal() -> impl std::future::Future<Output = ()> + Send + 'static {
    use tokio::signal::unix::{signal, SignalKind};
    async fn recv(s: Option<tokio::signal::unix::Signal>) {
        match s {
            Some(mut s) => {
                s.recv().await;
            }
            None => std::future::pending::<()>().await,
        }
    }
    let term = signal(SignalKind::terminate()).ok();
    let int = signal(SignalKind::interrupt()).ok();
    async move {
        tokio::select! {
            _ = recv(term) => {},
            _ = recv(int) => {},
        }
    }
}
