//! skyfuse-core: everything of skyfuse that needs no network, no async runtime and no
//! clock — so its tests build and run in a fraction of the service's time
//! (`cargo test -p skyfuse-core`). The service crate (`skyfuse`) adds the transports
//! (Zenoh, MAVLink links, HTTP/websocket) on top and re-exports these modules.
//!
//! From the pure model outwards:
//!
//! - [`sample`]: the internal sample model (SI units, ENU/FLU, µs) every codec produces.
//! - [`codec`]: pure functions between bytes and samples, one module per wire format
//!   (ROS 2 CDR with PX4's px4_msgs, ROS 1, mavlink-server JSON, raw MAVLink, skyfuse
//!   JSON).
//! - [`uorb`]: PX4's uORB topics as rows of named values → samples: one mapping for a
//!   ULog's rows and for px4_msgs arriving live.
//! - [`geo`]: WGS-84 geodetic ↔ local ENU.
//! - [`estimator`]: the deterministic estimator (time passed in, never read).
//! - [`verdict`]: a sensor's health state and the reasons for it (the words only).
//! - [`health`]: per-sensor health checks with hysteresis.
//! - [`event`]: what happened, typed (estimator, health, service), JSON only at the edge.
//! - [`fusion`]: the estimator under health supervision, shared by service and offline.
//! - [`sim`]: the simulated vehicle (truth, sensor models, faults, scenarios).
//! - [`replay`]: recorded flights as samples (PX4 ULog and CSV, MAVLink tlogs).
//! - [`dead_reckoning`]: plain flow dead reckoning, the baseline flow fusion must beat.
//! - [`eval`]: TUM trajectories and the APE metric as evo computes it.
//! - [`offline`]: scenario and replay runs through the fusion core, files and scores.
//! - [`rate_limit`]: the output's rate, shared by the service and offline runs.
//! - [`shared_data`]: where tests find third-party data (../shared/data), and skip.
//! - [`source_map`]: per-source state looked up by name on every sample.
//! - [`sync`]: a lock that outlives a panicking holder.
//!
//! Comments cite "seed 000"–"seed 004", the design documents the project grew from;
//! `docs/SEEDS.md` says what each one gave the code.

pub mod codec;
pub mod dead_reckoning;
pub mod estimator;
pub mod eval;
pub mod event;
pub mod fusion;
pub mod geo;
pub mod health;
pub mod offline;
pub mod rate_limit;
pub mod replay;
pub mod sample;
pub mod shared_data;
pub mod sim;
pub mod source_map;
pub mod sync;
pub mod uorb;
pub mod verdict;
