//! The dashboard's static files, embedded at build time (the binary runs from any
//! directory). The pages' code is ES modules (`web/app.js` and `web/js/*.js`), one per
//! panel, which the browser loads by `import`: no bundler, nothing generated. uPlot
//! comes from npm (`web/package-lock.json`), installed by `build.rs`.

use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};

const INDEX_HTML: &str = include_str!("../../web/index.html");
const APP_JS: &str = include_str!("../../web/app.js");
const APP_CSS: &str = include_str!("../../web/app.css");
const ACCESS_HTML: &str = include_str!("../../web/access.html");
const FLEET_HTML: &str = include_str!("../../web/fleet.html");
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
        _ => StatusCode::NOT_FOUND.into_response(),
    }
}

/// The pages' ES modules (`web/js/`, served at `/js/<name>`): each panel's code in a
/// file of its own, loaded by the browser's own `import` (no bundler).
const MODULES: [(&str, &str); 14] = [
    (
        "fleet-common.js",
        include_str!("../../web/js/fleet-common.js"),
    ),
    ("fleet-list.js", include_str!("../../web/js/fleet-list.js")),
    ("fleet-map.js", include_str!("../../web/js/fleet-map.js")),
    ("fleet-main.js", include_str!("../../web/js/fleet-main.js")),
    ("dash-util.js", include_str!("../../web/js/dash-util.js")),
    ("dash-store.js", include_str!("../../web/js/dash-store.js")),
    (
        "dash-charts.js",
        include_str!("../../web/js/dash-charts.js"),
    ),
    ("dash-map.js", include_str!("../../web/js/dash-map.js")),
    ("dash-draw.js", include_str!("../../web/js/dash-draw.js")),
    (
        "dash-status.js",
        include_str!("../../web/js/dash-status.js"),
    ),
    (
        "dash-events.js",
        include_str!("../../web/js/dash-events.js"),
    ),
    (
        "dash-connection.js",
        include_str!("../../web/js/dash-connection.js"),
    ),
    (
        "dash-controls.js",
        include_str!("../../web/js/dash-controls.js"),
    ),
    (
        "dash-network.js",
        include_str!("../../web/js/dash-network.js"),
    ),
];

pub fn serve_module(name: &str) -> Response {
    match MODULES.iter().find(|(n, _)| *n == name) {
        Some((_, body)) => file(body, JS),
        None => StatusCode::NOT_FOUND.into_response(),
    }
}

pub fn serve_vendor(name: &str) -> Response {
    match name {
        "uPlot.iife.min.js" => file(UPLOT_JS, JS),
        "uPlot.min.css" => file(UPLOT_CSS, CSS),
        _ => StatusCode::NOT_FOUND.into_response(),
    }
}
