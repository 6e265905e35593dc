//! Zenoh input adapter: one session, one subscriber per enabled input key expression.
//! The callbacks decode on Zenoh's thread (decoding is cheap and pure) and hand the
//! samples to a [`SampleSink`] (the estimator's inlet, which fuses them there when the
//! estimator is free and queues them when another thread is fusing): a sample it does
//! not take is dropped and counted, and Zenoh is never blocked.

use super::{now_us, Ingest};
use crate::config::{ZenohConfig, ZenohMode};
use crate::sample::Sample;
use std::sync::atomic::Ordering::Relaxed;
use std::sync::Arc;
use thiserror::Error;

#[derive(Debug, Error)]
pub enum ZenohError {
    #[error("zenoh config: {0}")]
    Config(String),
    #[error(
        "cannot open zenoh session ({mode:?}, listen {listen:?}, connect {connect:?}): {message}"
    )]
    Open {
        mode: ZenohMode,
        listen: Vec<String>,
        connect: Vec<String>,
        message: String,
    },
    #[error("cannot subscribe input `{input}` to {key:?}: {message}")]
    Subscribe {
        input: String,
        key: String,
        message: String,
    },
}

/// Zenoh's own runtimes, unless the user set `ZENOH_RUNTIME`: links accepted by this
/// process are served by Zenoh's receiving runtime. By default a TCP link accepted by
/// the listener stays registered with the acceptor's runtime, whose thread then wakes
/// for every message only to wake a receiving thread: two thread wake-ups per sample
/// instead of one (measured: 20 % of the service's CPU samples were that thread).
pub const ZENOH_RUNTIME_DEFAULT: &str = "(acc: (handover: rx))";

/// Set [`ZENOH_RUNTIME_DEFAULT`] for Zenoh, which reads `ZENOH_RUNTIME` once, when its
/// first runtime starts. Call before any other thread exists (setting the environment
/// of a multi-threaded process is unsound); a value the user set is kept.
pub fn set_zenoh_runtime_default() {
    if std::env::var_os("ZENOH_RUNTIME").is_none() {
        std::env::set_var("ZENOH_RUNTIME", ZENOH_RUNTIME_DEFAULT);
    }
}

/// Build the Zenoh config from ours: mode, endpoints and scouting on top of an optional
/// user-supplied Zenoh config file.
pub fn zenoh_config(cfg: &ZenohConfig) -> Result<zenoh::Config, ZenohError> {
    let err = |e: zenoh::Error| ZenohError::Config(e.to_string());
    let mut z = match &cfg.config_file {
        Some(p) => zenoh::Config::from_file(p)
            .map_err(|e| ZenohError::Config(format!("cannot load {p}: {e}")))?,
        None => zenoh::Config::default(),
    };
    let mode = match cfg.mode {
        ZenohMode::Peer => "\"peer\"",
        ZenohMode::Client => "\"client\"",
    };
    z.insert_json5("mode", mode).map_err(err)?;
    if cfg.mode == ZenohMode::Client && cfg.config_file.is_none() {
        // Zenoh's client default is to give up at once when no router answers. A service
        // (in a container, started beside its router) waits instead, retrying with
        // Zenoh's back-off (1 s growing to 4 s), as routers and peers do by default.
        z.insert_json5("connect/timeout_ms", "-1").map_err(err)?;
        z.insert_json5("connect/exit_on_failure", "false")
            .map_err(err)?;
    }
    let list = |v: &Vec<String>| serde_json::to_string(v).unwrap_or_else(|_| "[]".into());
    if !cfg.listen.is_empty() {
        z.insert_json5("listen/endpoints", &list(&cfg.listen))
            .map_err(err)?;
    }
    if !cfg.connect.is_empty() {
        z.insert_json5("connect/endpoints", &list(&cfg.connect))
            .map_err(err)?;
    }
    z.insert_json5(
        "scouting/multicast/enabled",
        if cfg.multicast_scouting {
            "true"
        } else {
            "false"
        },
    )
    .map_err(err)?;
    if let Some(ns) = cfg.namespace() {
        let quoted = serde_json::to_string(ns).unwrap_or_default();
        z.insert_json5("namespace", &quoted).map_err(err)?;
    }
    Ok(z)
}

pub async fn open_session(cfg: &ZenohConfig) -> Result<zenoh::Session, ZenohError> {
    let z = zenoh_config(cfg)?;
    // Zenoh's open blocks the thread it runs on for as long as it retries (a client
    // waiting for its router: indefinitely), even awaited: its future is ready-made
    // from a blocking call. On a runtime worker that starves every task queued behind
    // it (on two cores, the HTTP port went unanswered), so it runs on a thread of its
    // own, left to finish on its own if the caller stops waiting.
    let (tx, rx) = tokio::sync::oneshot::channel();
    let spawned = std::thread::Builder::new()
        .name("zenoh-open".into())
        .spawn(move || {
            let _ = tx.send(zenoh::Wait::wait(zenoh::open(z)));
        });
    let opened = match spawned {
        Ok(_) => rx.await.unwrap_or_else(|_| {
            Err(zenoh::Error::from(
                "the thread opening the session ended without an answer",
            ))
        }),
        Err(e) => Err(zenoh::Error::from(format!(
            "cannot start a thread to open the session: {e}"
        ))),
    };
    opened.map_err(|e| ZenohError::Open {
        mode: cfg.mode,
        listen: cfg.listen.clone(),
        connect: cfg.connect.clone(),
        message: with_mode_hint(cfg, open_error_message(&e.to_string())),
    })
}

/// A client with no router to connect to is told how to give one.
fn with_mode_hint(cfg: &ZenohConfig, message: String) -> String {
    if cfg.mode == ZenohMode::Client && cfg.connect.is_empty() {
        let scouting = if cfg.multicast_scouting {
            "no router answered multicast scouting either"
        } else {
            "and multicast scouting is off"
        };
        format!(
            "{message}: client mode needs a Zenoh router and none is given ({scouting}); add --connect tcp/ROUTER:7447 ([zenoh] connect), or use --mode peer, which needs none"
        )
    } else {
        message
    }
}

/// Zenoh's error, without the source paths it carries (` at /…/registry/…/x.rs:12.`),
/// and with what to do about the usual causes.
fn open_error_message(raw: &str) -> String {
    let mut out = String::with_capacity(raw.len());
    let mut rest = raw;
    while let Some(i) = rest.find(" at /") {
        out.push_str(&rest[..i]);
        let tail = &rest[i + 4..];
        // The path runs to the first character a path here does not hold.
        let end = tail
            .find(|c: char| c.is_whitespace() || c == ']' || c == ',')
            .unwrap_or(tail.len());
        let path = &tail[..end];
        if !path.contains(".rs") {
            out.push_str(&rest[i..i + 4 + end]);
        }
        rest = &tail[end..];
    }
    out.push_str(rest);
    if out.contains("Address already in use") {
        out.push_str(
            ": another process listens there (another skyfuse, zenohd, mavlink-server?); listen elsewhere (--listen tcp/0.0.0.0:7448) or not at all ([zenoh] listen = [], SKYFUSE__ZENOH__LISTEN='[]') and --connect to it",
        );
    }
    out
}

/// Where the subscribers' samples go, on Zenoh's thread, in two steps: queued in
/// arrival order (under the subscribers' shared order lock), then fused by whichever
/// thread finds the estimator free.
pub trait SampleSink: Send + Sync + 'static {
    /// Queue a sample, never waiting on the estimator; `false`: not taken (counted as
    /// dropped).
    fn queue(&self, s: Sample) -> bool;
    /// Fuse what is queued unless another thread is fusing (which then fuses it).
    fn fuse_queued(&self);
}

/// Declare one subscriber per enabled input key expression.
pub async fn subscribe_inputs(
    session: &zenoh::Session,
    ingest: Arc<Ingest>,
    sink: Arc<dyn SampleSink>,
    tap: crate::tap::Tap,
) -> Result<Vec<zenoh::pubsub::Subscriber<()>>, ZenohError> {
    let mut subs = Vec::new();
    // Several Zenoh threads call back at once. Stamping the arrival, recording the
    // payload and queueing its samples happen under one lock, so the recording's order
    // is the order the estimator fuses in and a replay of it is the live run (without
    // it, a GNSS fix recorded before an IMU sample could be fused after it live). The
    // arrivals it hands out never go back, even when the host's clock does. Fusing is
    // outside it: a callback never waits on the filter under the lock.
    let order = Arc::new(std::sync::Mutex::new(0i64));
    for (idx, input) in ingest.inputs.iter().enumerate() {
        if !input.config.enabled {
            continue;
        }
        for key in input.config.key_exprs() {
            let ingest = ingest.clone();
            let sink = sink.clone();
            let tap = tap.clone();
            let order = order.clone();
            let sub = session
                .declare_subscriber(key.as_str())
                .callback(move |sample: zenoh::sample::Sample| {
                    let Some(input) = ingest.inputs.get(idx) else {
                        return;
                    };
                    let payload = sample.payload().to_bytes();
                    let key = sample.key_expr().as_str();
                    {
                        let mut last = crate::sync::lock(&order);
                        let arrival = now_us().max(*last);
                        *last = arrival;
                        tap.input(arrival, idx, key, &payload);
                        if input.config.transport == crate::config::RosTransport::RmwZenoh {
                            let attachment = sample.attachment().map(|a| a.to_bytes());
                            if !ingest.rmw_attachment_ok(input, attachment.as_deref(), arrival) {
                                return;
                            }
                        }
                        for s in ingest.accept(input, key, &payload, arrival) {
                            tap.decoded(idx, &s);
                            if !sink.queue(s) {
                                input.counters.dropped.fetch_add(1, Relaxed);
                            }
                        }
                    }
                    sink.fuse_queued();
                })
                .await
                .map_err(|e| ZenohError::Subscribe {
                    input: input.config.id.clone(),
                    key: key.clone(),
                    message: e.to_string(),
                })?;
            tracing::info!(input = %input.id, key = %key, format = %input.config.format, "subscribed");
            subs.push(sub);
        }
    }
    Ok(subs)
}

#[cfg(test)]
mod open_error_tests {
    use super::*;

    /// Issue 35, item 8: `--mode client` without `--connect` says what is missing.
    #[test]
    fn a_client_without_a_router_is_told_to_connect_to_one() {
        let mut cfg = ZenohConfig {
            mode: ZenohMode::Client,
            connect: vec![],
            ..Default::default()
        };
        let m = with_mode_hint(&cfg, "Unable to connect to any of []".into());
        assert!(
            m.contains("--connect tcp/ROUTER:7447") && m.contains("--mode peer"),
            "{m}"
        );
        cfg.connect = vec!["tcp/127.0.0.1:7447".into()];
        assert_eq!(with_mode_hint(&cfg, "x".into()), "x");
        cfg.mode = ZenohMode::Peer;
        cfg.connect.clear();
        assert_eq!(with_mode_hint(&cfg, "x".into()), "x");
    }

    #[test]
    fn an_open_error_loses_its_source_paths_and_says_what_to_do() {
        let raw = "Can not create a new TCP listener bound to tcp/0.0.0.0:7447: [0.0.0.0:7447: Address already in use (os error 98) at /root/.cargo/registry/src/index.crates.io-1949cf8c6b5b557f/zenoh-link-tcp-1.10.2/src/unicast.rs:361.] at /root/.cargo/registry/src/index.crates.io-1949cf8c6b5b557f/zenoh-1.10.2/src/net/runtime/orchestrator.rs:420.";
        let m = open_error_message(raw);
        assert!(!m.contains("registry") && !m.contains(".rs"), "{m}");
        assert!(m.contains("Address already in use (os error 98)"), "{m}");
        assert!(
            m.contains("--listen tcp/0.0.0.0:7448") && m.contains("listen = []"),
            "{m}"
        );
        assert_eq!(open_error_message("no route"), "no route");
    }
}
