//! Publish the simulator's measurements on Zenoh in real time, each in the format and
//! on the key its config input expects: CDR on the ROS 2 topic key as
//! zenoh-bridge-ros2dds would, mavlink-server JSON on `mavlink/<sys>/<comp>/<MSG>`,
//! zenoh-plugin-ros1's `<hex(type)>/<md5>/<topic>`, raw frames, or skyfuse JSON.

use super::sensors::StreamSpec;
use super::Simulator;
use crate::codec::{self, Format, MavIdentity};
use crate::config::{Config, InputConfig};
use crate::ingest::hex_encode;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::Arc;
use tokio::time::Instant;

/// The autopilot's MAVLink identity as the simulated vehicle sends it.
pub const SIM_MAV_SYSTEM: u8 = 1;
pub const SIM_MAV_COMPONENT: u8 = 1;

/// Where and how one stream is published.
#[derive(Debug, Clone)]
struct Route {
    input: InputConfig,
    /// Fixed key for formats whose key does not depend on the message.
    key: Option<String>,
}

#[derive(Debug, Default)]
pub struct PublishCounters {
    pub published: AtomicU64,
    pub errors: AtomicU64,
}

/// Work out the route of each stream from the config, or say why it has none.
fn routes(config: &Config, streams: &[StreamSpec]) -> Vec<Option<Route>> {
    streams
        .iter()
        .map(|s| {
            let input = config
                .inputs
                .iter()
                .find(|i| i.id == s.input_id && i.enabled && i.kind == s.kind)?;
            let key = match input.format {
                Format::Ros1 => {
                    let ty = input.ros_type?;
                    Some(format!(
                        "{}/{}/{}",
                        hex_encode(ty.ros1_name()),
                        ty.ros1_md5(),
                        input.key.trim_start_matches('/')
                    ))
                }
                Format::MavlinkJson => None,
                _ => Some(input.key.clone()),
            };
            if let Some(k) = &key {
                if k.contains('*') || k.contains('$') {
                    tracing::warn!(input = %input.id, key = %k, "sim: cannot publish on a wildcard key; stream skipped");
                    return None;
                }
            }
            Some(Route {
                input: input.clone(),
                key,
            })
        })
        .collect()
}

/// Run the simulator at `speedup` times real time (1: real time; 5: as SITL's
/// `--speedup 5`, its stamps running five times the host's clock), publishing on
/// `session` until it ends or `shutdown` resolves. Returns the number of messages
/// published.
pub async fn run_publisher(
    session: zenoh::Session,
    config: Arc<Config>,
    mut sim: Simulator,
    speedup: f64,
    counters: Arc<PublishCounters>,
    shutdown: impl std::future::Future<Output = ()>,
) -> u64 {
    let routes = routes(&config, &sim.streams);
    for (s, r) in sim.streams.iter().zip(&routes) {
        match r {
            Some(r) => {
                tracing::info!(stream = s.input_id, format = %r.input.format, key = r.key.as_deref().unwrap_or(&r.input.key), rate_hz = s.rate_hz, "sim: publishing")
            }
            None => tracing::info!(
                stream = s.input_id,
                "sim: no enabled input of this id and kind in the config; not published"
            ),
        }
    }
    let start = Instant::now();
    let epoch_us = crate::clock::now_us();
    let mut seq: u8 = 0;
    tokio::pin!(shutdown);
    for ev in sim.by_ref() {
        let Some(route) = routes.get(ev.stream).and_then(|r| r.as_ref()) else {
            continue;
        };
        let due = start + std::time::Duration::from_secs_f64(ev.publish_t.max(0.0) / speedup);
        tokio::select! {
            _ = tokio::time::sleep_until(due) => {}
            _ = &mut shutdown => break,
        }
        let measured_us = (ev.measured_t * 1e6) as i64;
        // ROS stamps are wall-clock (from the start, at the simulator's rate); MAVLink
        // stamps are time since the autopilot booted.
        let stamp_us = match route.input.format {
            Format::MavlinkJson | Format::MavlinkRaw => measured_us,
            _ => epoch_us + measured_us,
        };
        seq = seq.wrapping_add(1);
        let mav = MavIdentity {
            system_id: SIM_MAV_SYSTEM,
            component_id: SIM_MAV_COMPONENT,
            sequence: seq,
        };
        match codec::encode_sample(
            route.input.format,
            route.input.ros_type,
            stamp_us,
            &ev.data,
            mav,
        ) {
            Ok(enc) => {
                let key = match (&route.key, enc.mavlink_name) {
                    (Some(k), _) => k.clone(),
                    (None, Some(name)) => {
                        format!("mavlink/{SIM_MAV_SYSTEM}/{SIM_MAV_COMPONENT}/{name}")
                    }
                    (None, None) => continue,
                };
                match session.put(&key, enc.payload).await {
                    Ok(()) => {
                        counters.published.fetch_add(1, Relaxed);
                    }
                    Err(e) => {
                        counters.errors.fetch_add(1, Relaxed);
                        tracing::warn!(key = %key, "sim: put failed: {e}");
                    }
                }
            }
            Err(e) => {
                counters.errors.fetch_add(1, Relaxed);
                tracing::warn!(stream = route.input.id, "sim: cannot encode: {e}");
            }
        }
    }
    counters.published.load(Relaxed)
}
