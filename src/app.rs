//! Wiring: [`run`] takes a validated config, already-bound listeners (so tests bind
//! port 0) and a shutdown future, and runs ingest, the estimator task and HTTP until
//! shutdown.

use crate::config::Config;
use crate::ingest::{now_us, zenoh_in, Ingest};
use crate::sample::{Micros, Sample};
use serde_json::json;
use std::future::Future;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};
use std::sync::Arc;
use thiserror::Error;
use tokio::sync::mpsc;

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
}

/// What the estimator task has consumed.
#[derive(Debug, Default)]
pub struct CoreCounters {
    pub consumed: AtomicU64,
    pub last_sample_arrival_us: AtomicU64,
}

/// State shared by the HTTP handlers.
pub struct AppState {
    pub config: Arc<Config>,
    pub ingest: Arc<Ingest>,
    pub core: Arc<CoreCounters>,
    pub started_us: Micros,
    pub zenoh_zid: String,
    pub zenoh_locators: Vec<String>,
    queue: mpsc::WeakSender<Sample>,
    zenoh_closed: AtomicBool,
}

impl AppState {
    pub fn zenoh_closed(&self) -> bool {
        self.zenoh_closed.load(Relaxed)
    }

    pub fn status_json(&self) -> serde_json::Value {
        let now = now_us();
        let (queue_capacity, queue_free) = match self.queue.upgrade() {
            Some(tx) => (tx.max_capacity(), tx.capacity()),
            None => (self.config.ingest.channel_capacity, 0),
        };
        json!({
            "service": {
                "name": "skyfuse",
                "version": env!("CARGO_PKG_VERSION"),
                "vehicle": self.config.service.vehicle,
                "uptime_s": (now - self.started_us) as f64 / 1e6,
                "zenoh": {
                    "zid": self.zenoh_zid,
                    "mode": self.config.zenoh.mode,
                    "locators": self.zenoh_locators,
                },
            },
            "ingest": {
                "queue_capacity": queue_capacity,
                "queue_len": queue_capacity - queue_free,
                "consumed": self.core.consumed.load(Relaxed),
            },
            "sensors": self.ingest.statuses(now),
            // Filled by the estimator and output stages.
            "estimator": serde_json::Value::Null,
            "outputs": [],
        })
    }
}

/// Run the service until `shutdown` resolves.
pub async fn run(
    config: Config,
    listeners: Listeners,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<(), RunError> {
    let config = Arc::new(config);
    let ingest = Arc::new(Ingest::new(&config));
    let (tx, rx) = mpsc::channel::<Sample>(config.ingest.channel_capacity);
    let session = listeners.zenoh;
    let zid = session.zid().to_string();
    let locators = config.zenoh.listen.clone();
    let subscribers = zenoh_in::subscribe_inputs(&session, ingest.clone(), tx.clone()).await?;
    let core = Arc::new(CoreCounters::default());
    let state = Arc::new(AppState {
        config: config.clone(),
        ingest: ingest.clone(),
        core: core.clone(),
        started_us: now_us(),
        zenoh_zid: zid.clone(),
        zenoh_locators: locators.clone(),
        queue: tx.downgrade(),
        zenoh_closed: AtomicBool::new(false),
    });
    drop(tx);
    let estimator = tokio::spawn(estimator_task(rx, core));

    let http_addr = listeners.http.local_addr().map_err(RunError::Http)?;
    tracing::info!(
        vehicle = %config.service.vehicle,
        zid = %zid,
        zenoh = ?locators,
        http = %http_addr,
        inputs = config.inputs.iter().filter(|i| i.enabled).count(),
        "skyfuse running"
    );
    let app = crate::http::router(state.clone());
    axum::serve(listeners.http, app)
        .with_graceful_shutdown(shutdown)
        .await
        .map_err(RunError::Http)?;

    tracing::info!("shutting down");
    for s in subscribers {
        if let Err(e) = s.undeclare().await {
            tracing::warn!("undeclaring subscriber: {e}");
        }
    }
    // The last sender was in the subscriber callbacks: the estimator task ends.
    let _ = estimator.await;
    state.zenoh_closed.store(true, Relaxed);
    if let Err(e) = session.close().await {
        tracing::warn!("closing zenoh session: {e}");
    }
    Ok(())
}

/// Consumes samples. The estimator (its own issue) plugs in here; until then this
/// counts what arrives so the queue is drained and its depth is observable.
async fn estimator_task(mut rx: mpsc::Receiver<Sample>, core: Arc<CoreCounters>) {
    while let Some(s) = rx.recv().await {
        core.consumed.fetch_add(1, Relaxed);
        core.last_sample_arrival_us
            .store(s.arrival_us.max(0) as u64, Relaxed);
    }
}

/// Resolves on SIGINT or SIGTERM.
pub async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {},
        _ = term => {},
    }
}
