//! HTTP adapter: the JSON API, the live websocket (`/ws`, see `web/PROTOCOL.md`), the
//! controls, and the page. Handlers only read shared state or send a command; nothing
//! here blocks the data path.

use crate::event::Event;
use crate::pipeline::Command;
use crate::protocol::{ClientMessage, ServerFrame};
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{ConnectInfo, DefaultBodyLimit, Path, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use serde_json::json;
use std::sync::atomic::Ordering::Relaxed;
use std::sync::Arc;
use std::time::Duration;

pub(crate) mod assets;
pub mod metrics;
pub mod starting;
mod state;
pub mod tls;

pub use state::{AppState, SensorView, Status};

pub fn router(state: Arc<AppState>) -> Router {
    Router::new()
        .route("/", get(|| assets::serve("index.html")))
        .route("/app.js", get(|| assets::serve("app.js")))
        .route("/app.css", get(|| assets::serve("app.css")))
        .route("/access", get(|| assets::serve("access.html")))
        .route("/vendor/{file}", get(vendor))
        .route("/healthz", get(healthz))
        .route("/api/v1/status", get(status))
        .route("/metrics", get(metrics_text))
        .route("/api/v1/config", get(config))
        .route("/api/v1/ros/topics", get(ros_topics))
        .route("/api/v1/discovered", get(discovered))
        .route("/api/v1/control/{action}", post(control))
        .route("/ws", get(ws))
        // Control bodies are a few bytes; nothing the API takes is larger.
        .layer(DefaultBodyLimit::max(MAX_BODY_BYTES))
        .with_state(state)
}

async fn vendor(Path(file): Path<String>) -> Response {
    assets::serve_vendor(&file)
}

/// Liveness: the process serves HTTP and its Zenoh session is open.
async fn healthz(State(s): State<Arc<AppState>>) -> Response {
    if s.zenoh_closed() {
        return (StatusCode::SERVICE_UNAVAILABLE, "zenoh session closed\n").into_response();
    }
    ([(header::CONTENT_TYPE, "text/plain")], "ok\n").into_response()
}

async fn status(State(s): State<Arc<AppState>>) -> Json<serde_json::Value> {
    Json(s.status_json())
}

/// `GET /metrics` (Prometheus, OpenMetrics text).
async fn metrics_text(State(s): State<Arc<AppState>>) -> Response {
    let body = metrics::render(&s.status(), metrics::ProcessStats::read());
    ([(header::CONTENT_TYPE, metrics::CONTENT_TYPE)], body).into_response()
}

async fn discovered(State(s): State<Arc<AppState>>) -> axum::response::Response {
    use axum::response::IntoResponse;
    match s.discovered() {
        Some(d) => Json(d).into_response(),
        None => (
            axum::http::StatusCode::NOT_FOUND,
            Json(serde_json::json!({"error": "discovery is off ([discovery] enabled = false)"})),
        )
            .into_response(),
    }
}

async fn ros_topics(State(s): State<Arc<AppState>>) -> Json<serde_json::Value> {
    Json(s.ros_topics_json())
}

async fn config(State(s): State<Arc<AppState>>) -> Json<serde_json::Value> {
    Json(s.config.redacted_json())
}

/// Largest request body accepted, bytes.
const MAX_BODY_BYTES: usize = 16 * 1024;
/// Largest websocket message a client may send (a `subscribe` is ~40 bytes), bytes.
const MAX_WS_MESSAGE_BYTES: usize = 4 * 1024;
/// Refused control requests allowed per peer address within [`REFUSAL_WINDOW_US`];
/// beyond that the address gets 429 until the window ends, token or not (guessing
/// the token costs a minute per ten tries).
const MAX_REFUSALS: u32 = 10;
const REFUSAL_WINDOW_US: i64 = 60_000_000;

/// Whether `ip` has used up its refusals; counts this one if `refused`.
fn refusals_exhausted(s: &AppState, ip: std::net::IpAddr, now: i64, refused: bool) -> bool {
    let mut map = crate::sync::lock(&s.refusals);
    map.retain(|_, (start, _)| now - *start < REFUSAL_WINDOW_US);
    if refused {
        let e = map.entry(ip).or_insert((now, 0));
        e.1 += 1;
    }
    map.get(&ip).is_some_and(|&(_, n)| n > MAX_REFUSALS)
}

/// Compare without an early exit, so response time does not leak the token's prefix.
fn token_matches(given: &str, want: &str) -> bool {
    let (g, w) = (given.as_bytes(), want.as_bytes());
    let mut diff = g.len() ^ w.len();
    for (i, b) in w.iter().enumerate() {
        diff |= usize::from(g.get(i).copied().unwrap_or(0) ^ b);
    }
    diff == 0
}

/// Ok, or why the request is refused.
fn authorised(s: &AppState, headers: &HeaderMap) -> Result<(), &'static str> {
    let want = s.config.http.token.as_str();
    if want.is_empty() {
        return Err("controls are disabled: set http.token in the config to enable them");
    }
    let given = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.strip_prefix("Bearer "))
        .unwrap_or("");
    if token_matches(given.trim(), want) {
        Ok(())
    } else {
        Err("missing or wrong token (Authorization: Bearer <token>)")
    }
}

async fn control(
    State(s): State<Arc<AppState>>,
    ConnectInfo(peer): ConnectInfo<std::net::SocketAddr>,
    Path(action): Path<String>,
    headers: HeaderMap,
    body: axum::body::Bytes,
) -> Response {
    let now = crate::clock::now_us();
    if refusals_exhausted(&s, peer.ip(), now, false) {
        s.controls_refused.fetch_add(1, Relaxed);
        tracing::warn!(action, %peer, "control refused: too many refused requests from this address");
        return (
            StatusCode::TOO_MANY_REQUESTS,
            [(header::RETRY_AFTER, (REFUSAL_WINDOW_US / 1_000_000).to_string())],
            Json(json!({ "error": format!("more than {MAX_REFUSALS} refused requests from {} within {} s: try again later", peer.ip(), REFUSAL_WINDOW_US / 1_000_000) })),
        )
            .into_response();
    }
    if let Err(why) = authorised(&s, &headers) {
        s.controls_refused.fetch_add(1, Relaxed);
        refusals_exhausted(&s, peer.ip(), now, true);
        tracing::warn!(action, %peer, "control refused: {why}");
        return (
            StatusCode::UNAUTHORIZED,
            [(header::WWW_AUTHENTICATE, "Bearer")],
            Json(json!({ "error": why })),
        )
            .into_response();
    }
    let bad =
        |msg: String| (StatusCode::BAD_REQUEST, Json(json!({ "error": msg }))).into_response();
    let cmd = match action.as_str() {
        "reset-origin" => Command::ResetOrigin,
        "flow-calibration" => Command::StartFlowCalibration,
        "setup-signing" => {
            // Only here, on request: the key crosses the link in the clear.
            let sent = crate::sync::lock(&s.vpe).setup_signing(now);
            return match sent {
                Ok(n) => {
                    let msg = format!(
                        "SETUP_SIGNING sent to system {} on {n} link(s): it now takes only frames signed with our key",
                        s.config.mavlink.target_system
                    );
                    Json(json!({ "ok": true, "message": msg })).into_response()
                }
                Err(e) => (
                    StatusCode::CONFLICT,
                    Json(json!({ "error": format!("SETUP_SIGNING not sent: {e}") })),
                )
                    .into_response(),
            };
        }
        "fault" => {
            let Some(inj) = s.faults.as_ref() else {
                return bad("fault injection exists only in `skyfuse demo`".into());
            };
            return match serde_json::from_slice::<crate::sim::faults::FaultRequest>(&body) {
                Ok(req) => match inj.inject(&req) {
                    Ok(msg) => {
                        // Logged (and counted) with the other events.
                        s.publish_service_event(Event::FaultInjected, Some(&req.sensor), &msg);
                        Json(json!({ "ok": true, "message": msg })).into_response()
                    }
                    Err(e) => bad(e),
                },
                Err(e) => bad(format!("fault request: {e}")),
            };
        }
        other => {
            return (
                StatusCode::NOT_FOUND,
                Json(json!({ "error": format!("unknown control {other:?}; known: reset-origin, flow-calibration, setup-signing, fault") })),
            )
                .into_response()
        }
    };
    let (tx, rx) = tokio::sync::oneshot::channel();
    if s.commands.send((cmd, tx)).await.is_err() {
        return (StatusCode::SERVICE_UNAVAILABLE, "estimator stopped\n").into_response();
    }
    match tokio::time::timeout(Duration::from_secs(5), rx).await {
        Ok(Ok(events)) => Json(json!({
            "ok": true,
            "events": events.iter().map(|e| &e.message).collect::<Vec<_>>(),
        }))
        .into_response(),
        _ => (
            StatusCode::SERVICE_UNAVAILABLE,
            "estimator did not answer\n",
        )
            .into_response(),
    }
}

async fn ws(State(s): State<Arc<AppState>>, up: WebSocketUpgrade) -> Response {
    up.max_message_size(MAX_WS_MESSAGE_BYTES)
        .max_frame_size(MAX_WS_MESSAGE_BYTES)
        .on_upgrade(move |socket| client(s, socket))
}

/// One websocket client: snapshot, then whatever its queue holds. Its queue is the
/// only thing it can fill; a client that stops reading only loses its own frames.
async fn client(s: Arc<AppState>, mut socket: WebSocket) {
    let hub = s.hub.clone();
    let queue = hub.connect();
    let snapshot = hub.snapshot(s.status_json());
    let mut ok = socket.send(Message::Text(snapshot.into())).await.is_ok();
    while ok {
        tokio::select! {
            m = socket.recv() => match m {
                Some(Ok(Message::Text(t))) => {
                    match serde_json::from_str::<ClientMessage>(t.as_str()) {
                        Ok(ClientMessage::Subscribe { max_rate_hz }) => queue.set_max_rate_hz(max_rate_hz),
                        // Not ours to act on; a client may send what a newer page knows.
                        Err(_) => {}
                    }
                }
                Some(Ok(Message::Close(_))) | None | Some(Err(_)) => break,
                Some(Ok(_)) => {}
            },
            _ = queue.notify.notified() => {}
        }
        let dropped = queue.dropped_unreported.swap(0, Relaxed);
        if dropped > 0 {
            let notice = ServerFrame::Dropped {
                dropped,
                total: queue.dropped_total.load(Relaxed),
            };
            let text = serde_json::to_string(&notice).unwrap_or_default();
            ok &= socket.send(Message::Text(text.into())).await.is_ok();
        }
        for f in queue.drain() {
            if !ok {
                break;
            }
            ok &= socket.send(Message::Text(f.as_ref().into())).await.is_ok();
        }
    }
    hub.disconnect(&queue);
}

#[cfg(test)]
mod tests {
    use super::token_matches;

    #[test]
    fn token_comparison() {
        assert!(token_matches("abc", "abc"));
        assert!(!token_matches("abd", "abc"));
        assert!(!token_matches("ab", "abc"));
        assert!(!token_matches("abcd", "abc"));
        assert!(!token_matches("", "abc"));
    }
}
