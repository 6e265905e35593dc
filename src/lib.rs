//! skyfuse: sensor fusion for drones and robots.
//!
//! Samples arrive on Zenoh keys bridged from MAVLink and ROS; they are decoded into one
//! sample model, fused, checked, and published again. Everything that needs no network
//! lives in the `skyfuse-core` crate (`crates/skyfuse-core`), re-exported here under the
//! same names; this crate adds the transports. Map, from the pure core outwards:
//!
//! - core (re-exported): [`sample`] the sample model; [`codec`] bytes ↔ samples per
//!   wire format; [`geo`]; [`estimator`] and [`health`] (pure, time passed in);
//!   [`fusion`] the estimator under health supervision; [`sim`] the simulated vehicle
//!   (plus [`sim::publish`], its Zenoh publisher, here); [`replay`] flight logs;
//!   [`eval`] the APE metric; [`offline`] runs without network; [`sync`] locking.
//! - [`clock`]: the host clock (the service's only clock reads) and rate meters.
//! - [`config`]: the one TOML config struct, its defaults and environment overrides.
//! - [`ingest`]: payload → validated samples with per-input counters; [`ingest::zenoh_in`]
//!   wires Zenoh subscribers to it.
//! - [`pipeline`]: the estimator in the service: samples in (fused on the thread that
//!   brings them, through its `Inlet`), pose/events/live series out.
//! - [`output`]: the fused pose out: MAVLink (VISION_POSITION_ESTIMATE) and Zenoh.
//! - [`ros_graph`]: ROS 2 graph presence via the bridge's liveliness tokens.
//! - [`discovery`]: every key on the network, what it is and which input reads it
//!   (`/api/v1/discovered`, `skyfuse discover`).
//! - [`tap`]: copies for the recorder from the data path, never waiting; [`record`]: the
//!   MCAP flight recorder and the Foxglove live view (one thread behind the taps'
//!   bounded queue), and MCAP replay through ingest.
//! - [`protocol`]: the frames of `/ws` as types (web/PROTOCOL.md is checked against them).
//! - [`hub`]: the websocket fan-out: bounded per-client queues that drop oldest.
//! - [`http`]: the JSON API, the status views ([`http::AppState`]), the page.
//! - [`fleet`]: every skyfuse on the network on one page (`/fleet`, `skyfuse monitor`),
//!   from their outputs and liveliness tokens.
//! - [`app`]: `run(config, listeners, shutdown)`, wiring it all together.
//! - [`cli`]: the command line; `main.rs` only calls [`cli::main`].

pub use skyfuse_core::{
    codec, estimator, eval, event, fusion, geo, health, offline, rate_limit, replay, sample, sync,
    verdict,
};

pub mod app;
pub mod cli;
pub mod clock;
pub mod config;
pub mod discovery;
pub mod fleet;
pub mod http;
pub mod hub;
pub mod ingest;
pub mod output;
pub mod pipeline;
pub mod protocol;
pub mod record;
pub mod ros_graph;
pub mod sim;
pub mod tap;
