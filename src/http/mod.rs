//! HTTP adapter: the JSON API and the static page. Handlers only read shared state;
//! nothing here blocks the data path.

use crate::app::AppState;
use axum::extract::State;
use axum::http::{header, StatusCode};
use axum::response::{Html, IntoResponse, Response};
use axum::routing::get;
use axum::{Json, Router};
use std::sync::Arc;

/// The page, compiled into the binary so it runs from any directory.
const INDEX_HTML: &str = include_str!("../../web/index.html");

pub fn router(state: Arc<AppState>) -> Router {
    Router::new()
        .route("/", get(index))
        .route("/healthz", get(healthz))
        .route("/api/v1/status", get(status))
        .route("/api/v1/config", get(config))
        .with_state(state)
}

async fn index() -> Html<&'static str> {
    Html(INDEX_HTML)
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

async fn config(State(s): State<Arc<AppState>>) -> Json<serde_json::Value> {
    Json(s.config.redacted_json())
}
