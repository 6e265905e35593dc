//! The dashboard's static files, embedded at build time (the binary runs from any
//! directory). uPlot comes from npm (`web/package-lock.json`), installed by `build.rs`.

use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};

const INDEX_HTML: &str = include_str!("../../web/index.html");
const APP_JS: &str = include_str!("../../web/app.js");
const APP_CSS: &str = include_str!("../../web/app.css");
const ACCESS_HTML: &str = include_str!("../../web/access.html");
const FLEET_HTML: &str = include_str!("../../web/fleet.html");
const FLEET_JS: &str = include_str!("../../web/fleet.js");
const UPLOT_JS: &str = include_str!("../../web/node_modules/uplot/dist/uPlot.iife.min.js");
const UPLOT_CSS: &str = include_str!("../../web/node_modules/uplot/dist/uPlot.min.css");

const HTML: &str = "text/html; charset=utf-8";
const JS: &str = "text/javascript; charset=utf-8";
const CSS: &str = "text/css; charset=utf-8";

fn file(body: &'static str, content_type: &'static str) -> Response {
    (
        [
            (header::CONTENT_TYPE, content_type),
            // Small files, and a new binary may change them: always revalidate.
            (header::CACHE_CONTROL, "no-cache"),
        ],
        body,
    )
        .into_response()
}

pub async fn serve(name: &'static str) -> Response {
    match name {
        "index.html" => file(INDEX_HTML, HTML),
        "app.js" => file(APP_JS, JS),
        "app.css" => file(APP_CSS, CSS),
        "access.html" => file(ACCESS_HTML, HTML),
        "fleet.html" => file(FLEET_HTML, HTML),
        "fleet.js" => file(FLEET_JS, JS),
        _ => StatusCode::NOT_FOUND.into_response(),
    }
}

pub fn serve_vendor(name: &str) -> Response {
    match name {
        "uPlot.iife.min.js" => file(UPLOT_JS, JS),
        "uPlot.min.css" => file(UPLOT_CSS, CSS),
        _ => StatusCode::NOT_FOUND.into_response(),
    }
}
