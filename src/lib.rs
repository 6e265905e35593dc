//! skyfuse: sensor fusion for drones and robots.
//!
//! Samples arrive on Zenoh keys bridged from MAVLink and ROS; they are decoded into one
//! sample model, fused, checked, and published again. Map of the crate, from the pure
//! core outwards:
//!
//! - [`sample`]: the internal sample model (SI units, ENU/FLU, µs) every codec produces.
//! - [`codec`]: pure functions between bytes and samples, one module per wire format
//!   (ROS 2 CDR, ROS 1, mavlink-server JSON, raw MAVLink, skyfuse JSON).
//! - [`geo`]: WGS-84 geodetic ↔ local ENU.
//! - [`config`]: the one TOML config struct, its defaults and environment overrides.
//! - [`ingest`]: payload → validated samples with per-input counters; [`ingest::zenoh_in`]
//!   wires Zenoh subscribers to it.
//! - [`sim`]: the built-in simulated vehicle (truth, sensor models, faults, scenarios,
//!   Zenoh publisher).
//! - [`replay`]: recorded flights (PX4 logs exported to CSV) as samples.
//! - [`eval`]: TUM trajectories and the APE metric as evo computes it.
//! - [`offline`]: scenario and replay runs through the estimator, without network.
//! - [`estimator`]: the pure, deterministic estimator (no clock, no I/O).
//! - [`health`]: per-sensor health checks with hysteresis (pure, like the estimator).
//! - [`fusion`]: the estimator under health supervision, shared by service and offline.
//! - [`pipeline`]: the estimator task: samples in, pose/events/live series out.
//! - [`output`]: the fused pose out: MAVLink (VISION_POSITION_ESTIMATE) and Zenoh.
//! - [`ros_graph`]: ROS 2 graph presence via the bridge's liveliness tokens.
//! - [`http`]: the JSON API, the websocket hub and the page.
//! - [`app`]: `run(config, listeners, shutdown)`, wiring it all together.
//! - [`cli`]: the command line; `main.rs` only calls [`cli::main`].
//! - [`sync`]: a lock that outlives a panicking holder (its data is still valid).

pub mod app;
pub mod cli;
pub mod codec;
pub mod config;
pub mod estimator;
pub mod eval;
pub mod fusion;
pub mod geo;
pub mod health;
pub mod http;
pub mod ingest;
pub mod offline;
pub mod output;
pub mod pipeline;
pub mod replay;
pub mod ros_graph;
pub mod sample;
pub mod sim;
pub mod sync;
