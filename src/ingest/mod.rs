//! Ingest: payload bytes of one configured input → validated [`Sample`]s, with the
//! per-input counters that `/api/v1/status` shows.
//!
//! [`Ingest::accept`] is synchronous and transport-free, so it is tested without a
//! network; [`zenoh_in`] only wires Zenoh subscribers to it and hands the samples to
//! the estimator's inlet (overload is counted as `dropped`).

pub mod stamps;
pub mod zenoh_in;

use crate::clock::{now_us, RateMeter};
use crate::codec::{self, Format, RosType};
use crate::config::{Config, InputConfig, ERROR_LOG_INTERVAL_MS};
use crate::sample::{Decoded, Micros, Sample};
use serde::Serialize;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::{Arc, Mutex};

/// Why one payload was not turned into samples.
#[derive(Debug, Clone, PartialEq)]
pub enum Rejection {
    Decode(codec::DecodeError),
    /// The key says the payload is another ROS type than the input expects.
    WrongType(String),
    /// The sensor's timestamp went backwards.
    TimeBackwards {
        previous_us: Micros,
        now_us: Micros,
    },
    /// The sensor's timestamp jumped further ahead than the time that passed.
    TimeAhead {
        previous_us: Micros,
        now_us: Micros,
        elapsed_us: Micros,
    },
}

impl std::fmt::Display for Rejection {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Rejection::Decode(e) => write!(f, "{e}"),
            Rejection::WrongType(s) => f.write_str(s),
            Rejection::TimeBackwards {
                previous_us,
                now_us,
            } => write!(
                f,
                "timestamp went backwards by {:.3} ms ({previous_us} µs → {now_us} µs)",
                (previous_us - now_us) as f64 / 1000.0
            ),
            Rejection::TimeAhead {
                previous_us,
                now_us,
                elapsed_us,
            } => write!(
                f,
                "timestamp jumped ahead by {:.3} ms in {:.3} ms ({previous_us} µs → {now_us} µs)",
                now_us.saturating_sub(*previous_us) as f64 / 1000.0,
                *elapsed_us as f64 / 1000.0
            ),
        }
    }
}

/// Counters and recent history of one input. Counters are atomics because the Zenoh
/// callbacks of different inputs run on different threads.
#[derive(Debug, Default)]
pub struct InputCounters {
    /// Payloads that arrived.
    pub received: AtomicU64,
    /// Samples decoded and accepted.
    pub accepted: AtomicU64,
    /// Payloads (or frames) rejected: malformed, NaN, wrong type, time backwards…
    pub rejected: AtomicU64,
    /// Valid messages of no use to this input (another sensor kind, our own MAVLink).
    pub ignored: AtomicU64,
    /// Accepted samples dropped because the estimator queue was full.
    pub dropped: AtomicU64,
    /// Samples shed because the input arrived far above its configured rate (a flood):
    /// one misbehaving publisher must not fill the queue the other sensors share.
    pub shed: AtomicU64,
    /// The sensor's clock restarted (a consistent new series of stamps was adopted).
    pub clock_restarts: AtomicU64,
}

#[derive(Debug, Default)]
struct InputHistory {
    last_error: Option<String>,
    last_error_us: Option<Micros>,
    last_arrival_us: Option<Micros>,
    /// The first payload's arrival (the announcement grace counts from it).
    first_arrival_us: Option<Micros>,
    stamps: stamps::StampTracker,
    /// The last clock restart, as text.
    last_clock_restart: Option<String>,
    rate: RateMeter,
    last_log_us: Option<Micros>,
    suppressed_logs: u64,
    /// Admission token bucket: (tokens, last refill).
    admission: (f64, Option<Micros>),
    /// `type = "auto"` on rmw_zenoh: the type the last sample's key named.
    key_type: Option<String>,
}

impl InputHistory {
    /// Admit one sample at `now` from a token bucket refilled at `rate` per second and
    /// holding one second's worth (bursts of a second are fine, a flood is not).
    fn admit(&mut self, now: Micros, rate: f64) -> bool {
        let (tokens, last) = &mut self.admission;
        let dt = last.map_or(1.0, |l| ((now - l) as f64 * 1e-6).clamp(0.0, 1.0));
        *tokens = (*tokens + dt * rate).min(rate.max(1.0));
        *last = Some(now);
        if *tokens >= 1.0 {
            *tokens -= 1.0;
            true
        } else {
            false
        }
    }
}

/// An input may arrive this much above `max_rate_factor` × its rate_hz before its
/// excess is shed, Hz (slack for slow inputs and jitter).
const FLOOD_SLACK_HZ: f64 = 20.0;

/// One configured input and its state.
#[derive(Debug)]
pub struct InputState {
    pub config: InputConfig,
    pub id: Arc<str>,
    pub counters: InputCounters,
    history: Mutex<InputHistory>,
}

/// Status of one input as `/api/v1/status` shows it.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct InputStatus {
    pub id: String,
    pub kind: crate::sample::SensorKind,
    pub key: String,
    pub format: Format,
    #[serde(rename = "type")]
    pub ros_type: Option<String>,
    /// For `type = "auto"`: the type a bridge announces for the key, which is decoded.
    pub resolved_type: Option<String>,
    pub enabled: bool,
    pub received: u64,
    pub accepted: u64,
    pub rejected: u64,
    pub ignored: u64,
    pub dropped: u64,
    /// Shed for arriving far above the configured rate.
    pub shed: u64,
    /// Times the sensor's clock restarted (reboot, clock step) and was followed.
    pub clock_restarts: u64,
    pub last_clock_restart: Option<String>,
    pub last_error: Option<String>,
    pub last_error_age_ms: Option<f64>,
    pub rate_hz: f64,
    pub expected_rate_hz: f64,
    pub age_ms: Option<f64>,
    /// The transport-level verdict (arriving, at rate, decodable).
    #[serde(rename = "ingest")]
    pub ingest: IngestHealth,
}

/// Ingest-level health of a stream: is data arriving, at the rate expected, and
/// decodable. The estimator's sensor checks add their verdicts on top of this.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct IngestHealth {
    pub state: HealthState,
    pub reasons: Vec<Reason>,
}

// The same states and reasons as the sensor checks (crate::health), a subset of them.
pub use crate::health::{HealthState, Reason};

/// How long after an input's first payload a missing type announcement (`type =
/// "auto"`) is waited for before its samples are refused, µs. A bridge's token follows
/// its first sample by milliseconds when it does not precede it.
const ANNOUNCEMENT_GRACE_US: Micros = 2_000_000;

/// Recent rejections make a stream `degraded` for this long.
const RECENT_ERROR_MS: f64 = 5000.0;
/// Below this fraction of the expected rate a stream is `degraded`.
const LOW_RATE_FRACTION: f64 = 0.5;

impl InputState {
    pub fn new(config: InputConfig) -> Self {
        Self {
            id: Arc::from(config.id.as_str()),
            config,
            counters: InputCounters::default(),
            history: Mutex::new(InputHistory::default()),
        }
    }

    fn history(&self) -> std::sync::MutexGuard<'_, InputHistory> {
        crate::sync::lock(&self.history)
    }

    /// Within [`ANNOUNCEMENT_GRACE_US`] of this input's first payload: a type still
    /// unannounced may yet be (the bridge's token is on its way).
    fn awaiting_announcement(&self, arrival_us: Micros) -> bool {
        let mut h = self.history();
        let first = *h.first_arrival_us.get_or_insert(arrival_us);
        arrival_us - first < ANNOUNCEMENT_GRACE_US
    }

    pub fn status(&self, now: Micros) -> InputStatus {
        let h = self.history();
        let c = &self.counters;
        let age_ms = h.last_arrival_us.map(|t| (now - t) as f64 / 1000.0);
        let last_error_age_ms = h.last_error_us.map(|t| (now - t) as f64 / 1000.0);
        let stale_after = self.config.stale_after_ms();
        let rate_hz = match age_ms {
            Some(a) if a <= stale_after => h.rate.rate_hz(),
            _ => 0.0,
        };
        let mut reasons = Vec::new();
        let state = if !self.config.enabled {
            HealthState::Disabled
        } else if let Some(age) = age_ms {
            if age > stale_after {
                reasons.push(Reason {
                    code: "stale",
                    text: format!("no data for {:.0} ms (limit {stale_after:.0} ms)", age),
                });
                HealthState::Stale
            } else {
                // The meter needs a full window before its rate means anything.
                if h.rate.rate_hz() > 0.0 && rate_hz < LOW_RATE_FRACTION * self.config.rate_hz {
                    reasons.push(Reason {
                        code: "low_rate",
                        text: format!(
                            "rate {rate_hz:.1} Hz, expected {:.1} Hz",
                            self.config.rate_hz
                        ),
                    });
                }
                if let (Some(a), Some(e)) = (last_error_age_ms, &h.last_error) {
                    if a < RECENT_ERROR_MS {
                        reasons.push(Reason {
                            code: "rejecting",
                            text: format!("rejected input {a:.0} ms ago: {e}"),
                        });
                    }
                }
                if reasons.is_empty() {
                    HealthState::Ok
                } else {
                    HealthState::Degraded
                }
            }
        } else {
            reasons.push(Reason {
                code: "no_data",
                text: "no valid sample received yet".into(),
            });
            if let Some(e) = &h.last_error {
                reasons.push(Reason {
                    code: "rejecting",
                    text: format!("last rejection: {e}"),
                });
            }
            HealthState::NoData
        };
        InputStatus {
            id: self.config.id.clone(),
            kind: self.config.kind,
            key: self.config.key.clone(),
            format: self.config.format,
            ros_type: if self.config.auto_type {
                Some("auto".to_string())
            } else {
                self.config.ros_type.map(|t| t.ros2_name().to_string())
            },
            resolved_type: None,
            enabled: self.config.enabled,
            received: c.received.load(Relaxed),
            accepted: c.accepted.load(Relaxed),
            rejected: c.rejected.load(Relaxed),
            ignored: c.ignored.load(Relaxed),
            dropped: c.dropped.load(Relaxed),
            shed: c.shed.load(Relaxed),
            clock_restarts: c.clock_restarts.load(Relaxed),
            last_clock_restart: h.last_clock_restart.clone(),
            last_error: h.last_error.clone(),
            last_error_age_ms,
            rate_hz,
            expected_rate_hz: self.config.rate_hz,
            age_ms,
            ingest: IngestHealth { state, reasons },
        }
    }

    fn reject(&self, why: Rejection, now: Micros) {
        self.counters.rejected.fetch_add(1, Relaxed);
        self.note_error(why.to_string(), "rejected payload", now);
    }

    /// The last error shown in the status, logged at most every ERROR_LOG_INTERVAL_MS.
    fn note_error(&self, text: String, what: &str, now: Micros) {
        let mut h = self.history();
        h.last_error_us = Some(now);
        let due = h
            .last_log_us
            .is_none_or(|t| now - t >= (ERROR_LOG_INTERVAL_MS * 1000) as Micros);
        if due {
            tracing::warn!(
                input = %self.id,
                key = %self.config.key,
                format = %self.config.format,
                suppressed = h.suppressed_logs,
                "{what}: {text}"
            );
            h.last_log_us = Some(now);
            h.suppressed_logs = 0;
        } else {
            h.suppressed_logs += 1;
        }
        h.last_error = Some(text);
    }
}

/// All inputs and the decoding of their payloads.
#[derive(Debug)]
pub struct Ingest {
    pub inputs: Vec<Arc<InputState>>,
    /// Our own MAVLink (system, component): skipped when it comes back.
    own_mav: (u8, u8),
    /// `[ingest] max_rate_factor`: above it (plus FLOOD_SLACK_HZ) an input is shed.
    max_rate_factor: f64,
    /// ROS 2 topics the bridges announce (filled by `ros_graph::discover`): the type of
    /// `type = "auto"` inputs, and a check of configured types.
    pub ros_topics: crate::ros_graph::TopicTable,
    /// The estimator's clock: a vehicle clock running N× the host's (a fast
    /// simulator) brings N× the samples per host second, which is no flood.
    pub clock: Arc<crate::clock::SharedTimeBase>,
}

impl Ingest {
    /// An rmw_zenoh sample's attachment (sequence number, source time, publisher id):
    /// rmw_zenoh drops a sample without a readable one (its reader throws), and so does
    /// this, counted against the input with the reason.
    pub fn rmw_attachment_ok(
        &self,
        input: &InputState,
        attachment: Option<&[u8]>,
        arrival_us: Micros,
    ) -> bool {
        let error = match attachment.map(codec::ros::rmw_zenoh::Attachment::parse) {
            Some(Ok(_)) => return true,
            Some(Err(e)) => e,
            None => codec::DecodeError::MissingField {
                message: "rmw_zenoh sample".into(),
                field: "attachment".into(),
            },
        };
        input.counters.received.fetch_add(1, Relaxed);
        input.reject(Rejection::Decode(error), arrival_us);
        false
    }

    pub fn new(config: &Config) -> Self {
        Self {
            inputs: config
                .inputs
                .iter()
                .cloned()
                .map(|c| Arc::new(InputState::new(c)))
                .collect(),
            own_mav: (config.mavlink.system_id, config.mavlink.component_id),
            max_rate_factor: config.ingest.max_rate_factor,
            ros_topics: Default::default(),
            clock: Default::default(),
        }
    }

    /// The ROS type a live bridge token announces for `key`, if any.
    pub fn announced_type(&self, key: &str) -> Option<String> {
        crate::sync::lock(&self.ros_topics)
            .values()
            .find(|e| e.alive && e.key == key.trim_start_matches('/'))
            .map(|e| e.ros_type.clone())
    }

    pub fn statuses(&self, now: Micros) -> Vec<InputStatus> {
        self.inputs
            .iter()
            .map(|i| {
                let mut st = i.status(now);
                if i.config.auto_type {
                    st.resolved_type = match i.config.transport {
                        crate::config::RosTransport::RmwZenoh => i.history().key_type.clone(),
                        _ => self.announced_type(&i.config.key),
                    };
                }
                st
            })
            .collect()
    }

    /// Decode and validate one payload for `input`. Never panics, whatever the bytes;
    /// every outcome is counted on the input.
    pub fn accept(
        &self,
        input: &InputState,
        key: &str,
        payload: &[u8],
        arrival_us: Micros,
    ) -> Vec<Sample> {
        let c = &input.counters;
        c.received.fetch_add(1, Relaxed);
        if input.config.format == Format::Ros1 {
            if let Some(ty) = input.config.ros_type {
                if let Err(why) = check_ros1_key(key, ty) {
                    input.reject(Rejection::WrongType(why), arrival_us);
                    return Vec::new();
                }
            }
        }
        let mut ros_type = input.config.ros_type;
        if input.config.format == Format::Ros2 {
            // rmw_zenoh says the type in every sample's key; a bridge announces it once.
            let announced = match input.config.transport {
                crate::config::RosTransport::RmwZenoh => codec::ros::rmw_zenoh::type_of_key(key),
                crate::config::RosTransport::Bridge => self.announced_type(&input.config.key),
                crate::config::RosTransport::Px4Zenoh => None,
            };
            if let Some(why) = type_mismatch(&input.config, announced.as_deref()) {
                // Decoding another type's bytes would give garbage, not an error.
                input.reject(Rejection::WrongType(why), arrival_us);
                return Vec::new();
            }
            let topic = &input.config.key;
            match (input.config.auto_type, ros_type, announced) {
                (true, _, Some(a)) => match RosType::from_name(&a) {
                    Some(t) => {
                        if input.config.transport == crate::config::RosTransport::RmwZenoh {
                            let mut h = input.history();
                            if h.key_type.as_deref() != Some(a.as_str()) {
                                h.key_type = Some(a.clone());
                            }
                        }
                        ros_type = Some(t)
                    }
                    None => {
                        input.reject(
                            Rejection::WrongType(format!(
                                "{topic} is announced as {a}, which skyfuse cannot decode"
                            )),
                            arrival_us,
                        );
                        return Vec::new();
                    }
                },
                // A bridge sends its first sample and its liveliness token at nearly
                // the same moment, in either order: a sample that beats the
                // announcement is set aside (counted as ignored), not a fault.
                (true, _, None) if input.awaiting_announcement(arrival_us) => {
                    c.ignored.fetch_add(1, Relaxed);
                    return Vec::new();
                }
                (true, _, None) => {
                    input.reject(
                        Rejection::WrongType(format!(
                            "type = \"auto\" but no bridge announces {topic} (no liveliness token)"
                        )),
                        arrival_us,
                    );
                    return Vec::new();
                }
                _ => {}
            }
            if let Some(RosType::Px4(m)) = ros_type {
                match px4_layout(&input.config, m, key) {
                    Ok(m) => ros_type = Some(RosType::Px4(m)),
                    Err(e) => {
                        input.reject(Rejection::Decode(e), arrival_us);
                        return Vec::new();
                    }
                }
            }
        }
        let mut decoded: Vec<Decoded> = Vec::new();
        let result = codec::decode(input.config.format, ros_type, payload, &mut decoded);
        // A message with two parts (HIGHRES_IMU: IMU and pressure) whose other part is
        // bad is no fault of this input; its own bad part is.
        let mut rejected = false;
        match result {
            Err(codec::DecodeError::Part { kind, .. }) if kind != input.config.kind => {}
            Err(codec::DecodeError::Part { error, .. }) => {
                rejected = true;
                input.reject(Rejection::Decode(*error), arrival_us);
            }
            Err(e) => {
                rejected = true;
                input.reject(Rejection::Decode(e), arrival_us);
            }
            // A valid message with nothing for us (a HEARTBEAT).
            Ok(()) if decoded.is_empty() => {
                c.ignored.fetch_add(1, Relaxed);
            }
            Ok(()) => {}
        }
        let mut out = Vec::with_capacity(decoded.len());
        // A message may carry a second kind (HIGHRES_IMU: IMU and barometer): the part
        // of another kind beside one of ours is not "ignored", only a message with
        // nothing of our kind is.
        let any_ours = decoded.iter().any(|d| d.data.kind() == input.config.kind);
        for d in decoded {
            if d.data.kind() != input.config.kind {
                if !any_ours && !rejected {
                    c.ignored.fetch_add(1, Relaxed);
                }
                continue;
            }
            if d.mav_origin == Some(self.own_mav) {
                c.ignored.fetch_add(1, Relaxed);
                continue;
            }
            {
                let mut h = input.history();
                let clock_rate = self.clock.rate();
                let limit =
                    self.max_rate_factor * input.config.rate_hz * clock_rate + FLOOD_SLACK_HZ;
                if self.max_rate_factor > 0.0
                    && input.config.rate_hz > 0.0
                    && !h.admit(arrival_us, limit)
                {
                    drop(h);
                    c.shed.fetch_add(1, Relaxed);
                    let clock = if clock_rate == 1.0 {
                        String::new()
                    } else {
                        format!(" on a vehicle clock at {clock_rate:.2}×")
                    };
                    let text = format!(
                        "arriving above {limit:.0} Hz ({}× its rate_hz {}{clock} + {FLOOD_SLACK_HZ} Hz): the excess is shed",
                        self.max_rate_factor, input.config.rate_hz
                    );
                    input.note_error(text, "flooding", arrival_us);
                    continue;
                }
                if let Some(stamp) = d.stamp_us {
                    use stamps::StampVerdict as V;
                    let why = match h.stamps.check(stamp, arrival_us) {
                        V::Accept => None,
                        V::Backwards {
                            previous_us,
                            now_us,
                        } => Some(Rejection::TimeBackwards {
                            previous_us,
                            now_us,
                        }),
                        V::Ahead {
                            previous_us,
                            now_us,
                            elapsed_us,
                        } => Some(Rejection::TimeAhead {
                            previous_us,
                            now_us,
                            elapsed_us,
                        }),
                        V::Restart {
                            previous_us,
                            now_us,
                        } => {
                            let text = format!(
                                "the sensor's clock restarted ({:.3} s → {:.3} s): following the new series",
                                previous_us as f64 * 1e-6,
                                now_us as f64 * 1e-6
                            );
                            tracing::warn!(input = %input.id, key = %input.config.key, "{text}");
                            h.last_clock_restart = Some(text);
                            c.clock_restarts.fetch_add(1, Relaxed);
                            None
                        }
                    };
                    if let Some(why) = why {
                        drop(h);
                        input.reject(why, arrival_us);
                        continue;
                    }
                }
                h.last_arrival_us = Some(arrival_us);
                h.rate.tick(arrival_us);
            }
            c.accepted.fetch_add(1, Relaxed);
            out.push(Sample {
                source: input.id.clone(),
                stamp_us: d.stamp_us,
                arrival_us,
                data: d.data,
            });
        }
        out
    }
}

/// How a px4_msgs input's bytes are laid out: PX4 1.16's zenoh module (XCDR2, 1.16
/// fields), or the release an rmw_zenoh key's type hash names (else found from the
/// payload by the decoder).
fn px4_layout(
    input: &InputConfig,
    m: codec::ros::px4::Px4Msg,
    key: &str,
) -> Result<codec::ros::px4::Px4Msg, codec::DecodeError> {
    use crate::config::RosTransport;
    Ok(match input.transport {
        RosTransport::Px4Zenoh => codec::ros::px4::Px4Msg::px4_zenoh(m.ty),
        RosTransport::RmwZenoh => codec::ros::px4::Px4Msg {
            version: codec::ros::px4::version_of_hash(m.ty, key.rsplit('/').next().unwrap_or(""))?,
            ..m
        },
        RosTransport::Bridge => m,
    })
}

/// Why a ros2 input with a configured type cannot take what its key carries: a bridge
/// announces another type for it.
pub fn type_mismatch(input: &InputConfig, announced: Option<&str>) -> Option<String> {
    let (Some(t), Some(a)) = (input.ros_type, announced) else {
        return None;
    };
    if input.auto_type
        || input.format != Format::Ros2
        || RosType::from_name(a).is_some_and(|a| a.same_type(t))
    {
        return None;
    }
    Some(format!(
        "{} is announced as {a}, configured as {}",
        input.key.trim_start_matches('/'),
        t.ros2_name()
    ))
}

/// zenoh-plugin-ros1 keys start with `<hex(datatype)>/<md5>/`: check them against the
/// configured type so a mismatch is a clear error, not garbage decoded.
fn check_ros1_key(key: &str, ty: RosType) -> Result<(), String> {
    let mut chunks = key.split('/');
    let (Some(hex_type), Some(md5)) = (chunks.next(), chunks.next()) else {
        return Ok(());
    };
    let Some(announced) = hex_decode(hex_type) else {
        return Err(format!(
            "key {key:?} does not start with a hex-encoded ROS 1 type (zenoh-plugin-ros1 form)"
        ));
    };
    if announced != ty.ros1_name() || md5 != ty.ros1_md5() {
        return Err(format!(
            "key announces ROS 1 type {announced} (md5 {md5}), input is configured as {} (md5 {})",
            ty.ros1_name(),
            ty.ros1_md5()
        ));
    }
    Ok(())
}

fn hex_decode(s: &str) -> Option<String> {
    if !s.len().is_multiple_of(2) {
        return None;
    }
    let bytes: Option<Vec<u8>> = (0..s.len())
        .step_by(2)
        .map(|i| s.get(i..i + 2).and_then(|h| u8::from_str_radix(h, 16).ok()))
        .collect();
    String::from_utf8(bytes?).ok()
}

/// Hex of a ROS 1 datatype as zenoh-plugin-ros1 writes it in keys.
pub fn hex_encode(s: &str) -> String {
    s.bytes().map(|b| format!("{b:02x}")).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ingest_with(toml: &str) -> Ingest {
        let cfg = Config::from_toml_str(toml, "test").expect("config");
        Ingest::new(&cfg)
    }

    const JSON_IMU: &str =
        "[[inputs]]\nid=\"imu\"\nkind=\"imu\"\nkey=\"imu\"\nformat=\"json\"\nrate_hz=100\n";

    fn imu_json(stamp: i64) -> String {
        format!(r#"{{"kind":"imu","stamp_us":{stamp},"gyro":[0.1,0.2,0.3],"accel":[0,0,9.81]}}"#)
    }

    /// Feed `imu` at `hz` for `secs` seconds (stamps = arrivals); returns accepted.
    fn feed(ing: &Ingest, input: &InputState, hz: f64, secs: f64, t0: i64) -> usize {
        let n = (hz * secs) as i64;
        (0..n)
            .map(|i| {
                let t = t0 + (i as f64 * 1e6 / hz) as i64;
                ing.accept(input, "imu", imu_json(t).as_bytes(), t).len()
            })
            .sum()
    }

    /// HIGHRES_IMU carries an IMU and a pressure: a pressure that is no air pressure is
    /// the barometer input's rejection alone; the IMU input takes its part, uncharged.
    #[test]
    fn a_bad_pressure_in_highres_imu_costs_the_barometer_input_only() {
        use mavlink::dialects::common as mc;
        let ing = ingest_with(
            "[[inputs]]\nid=\"imu\"\nkind=\"imu\"\nkey=\"mavlink/1/1/HIGHRES_IMU\"\nformat=\"mavlink-json\"\nrate_hz=50\n\
             [[inputs]]\nid=\"baro\"\nkind=\"baro\"\nkey=\"mavlink/1/1/HIGHRES_IMU\"\nformat=\"mavlink-json\"\nrate_hz=50\n",
        );
        let header = mavlink::MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: 0,
        };
        let msg = |t: u64, abs_pressure: f32| {
            let m = mc::MavMessage::HIGHRES_IMU(mc::HIGHRES_IMU_DATA {
                time_usec: t,
                zacc: -9.81,
                abs_pressure,
                fields_updated: mc::HighresImuUpdatedFlags::all(),
                ..Default::default()
            });
            codec::mavlink::encode_json(header, &m).expect("json")
        };
        let (imu, baro) = (ing.inputs[0].clone(), ing.inputs[1].clone());
        let key = "mavlink/1/1/HIGHRES_IMU";
        // PX4's Pa, then a pressure that is neither hPa nor Pa.
        assert_eq!(
            ing.accept(&imu, key, msg(1_000_000, 95_578.8).as_bytes(), 1_000_000)
                .len(),
            1
        );
        assert_eq!(
            ing.accept(&baro, key, msg(1_000_000, 95_578.8).as_bytes(), 1_000_000)
                .len(),
            1
        );
        assert_eq!(
            ing.accept(&imu, key, msg(1_020_000, 3_000.0).as_bytes(), 1_020_000)
                .len(),
            1
        );
        assert_eq!(
            ing.accept(&baro, key, msg(1_020_000, 3_000.0).as_bytes(), 1_020_000)
                .len(),
            0
        );
        let (i, b) = (imu.status(1_100_000), baro.status(1_100_000));
        assert_eq!((i.accepted, i.rejected, i.ignored), (2, 0, 0), "{i:?}");
        assert_eq!((b.accepted, b.rejected, b.ignored), (1, 1, 0), "{b:?}");
        assert!(
            b.last_error
                .as_deref()
                .is_some_and(|e| e.contains("abs_pressure")),
            "{b:?}"
        );
    }

    #[test]
    fn a_flooding_input_is_shed_to_its_limit_and_a_normal_one_is_not() {
        let ing = ingest_with(JSON_IMU);
        let input = ing.inputs[0].clone();
        // At its rate (and at 3×, a burst): all of it.
        assert_eq!(feed(&ing, &input, 100.0, 5.0, 1_000_000), 500);
        assert_eq!(feed(&ing, &input, 300.0, 2.0, 7_000_000), 600);
        assert_eq!(input.counters.shed.load(Relaxed), 0);
        // At 10× for 10 s: the limit is 4 × 100 + 20 = 420 Hz, one second's burst on top.
        let got = feed(&ing, &input, 1000.0, 10.0, 10_000_000);
        assert!((4200..=4200 + 420 + 10).contains(&got), "{got}");
        let shed = input.counters.shed.load(Relaxed);
        assert_eq!(got as u64 + shed, 10_000);
        let st = input.status(20_000_000);
        assert_eq!(st.shed, shed);
        assert!(
            st.last_error.as_deref().is_some_and(|e| e.contains("shed")),
            "{:?}",
            st.last_error
        );
        // Back to its rate: all of it again.
        assert_eq!(feed(&ing, &input, 100.0, 3.0, 22_000_000), 300);
        // 0 turns the limit off.
        let off = ingest_with(&format!("[ingest]\nmax_rate_factor = 0\n{JSON_IMU}"));
        let i = off.inputs[0].clone();
        assert_eq!(feed(&off, &i, 1000.0, 2.0, 1_000_000), 2000);
    }

    #[test]
    fn good_bad_and_backwards_are_counted() {
        let ing = ingest_with(JSON_IMU);
        let input = ing.inputs[0].clone();
        assert_eq!(
            ing.accept(&input, "imu", imu_json(1000).as_bytes(), 10)
                .len(),
            1
        );
        assert!(ing.accept(&input, "imu", b"{not json", 20).is_empty());
        assert!(ing
            .accept(&input, "imu", imu_json(500).as_bytes(), 30)
            .is_empty());
        assert_eq!(
            ing.accept(&input, "imu", imu_json(2000).as_bytes(), 40)
                .len(),
            1
        );
        let s = input.status(50);
        assert_eq!((s.received, s.accepted, s.rejected), (4, 2, 2));
        let err = s.last_error.expect("last error");
        assert!(err.contains("backwards"), "{err}");
        assert_eq!(s.ingest.state, HealthState::Degraded);
        assert_eq!(s.ingest.reasons[0].code, "rejecting");
    }

    /// mavlink-server's JSON of an ArduPilot ATTITUDE at `time_boot_ms`.
    fn attitude_json(boot_ms: u32) -> String {
        format!(
            r#"{{"header":{{"system_id":1,"component_id":1,"sequence":7,"message_id":30}},"message":{{"type":"ATTITUDE","time_boot_ms":{boot_ms},"roll":0.01,"pitch":-0.02,"yaw":1.5,"rollspeed":0,"pitchspeed":0,"yawspeed":0}}}}"#
        )
    }

    #[test]
    fn an_autopilot_reboot_restarts_the_clock_and_the_input_carries_on() {
        let ing = ingest_with(
            "[[inputs]]\nid=\"attitude\"\nkind=\"attitude\"\nkey=\"mavlink/*/*/ATTITUDE\"\nformat=\"mavlink-json\"\nrate_hz=50\n",
        );
        let input = ing.inputs[0].clone();
        // `n` samples at 50 Hz from autopilot time `boot_ms`, arriving from `arrival_us`;
        // how many were accepted.
        let feed = |boot_ms: u32, arrival_us: i64, n: u32| -> usize {
            (0..n)
                .map(|i| {
                    let t = arrival_us + i64::from(i) * 20_000;
                    let payload = attitude_json(boot_ms + i * 20);
                    ing.accept(&input, "mavlink/1/1/ATTITUDE", payload.as_bytes(), t)
                        .len()
                })
                .sum()
        };
        // 150 samples up to 600 s of autopilot time, then it reboots: time_boot_ms
        // starts again at 1 s, as the reliability issue saw, for 5 s at 50 Hz.
        assert_eq!(feed(597_000, 1_000_000, 150), 150);
        // The first two of the new series are refused, then it is the series.
        assert_eq!(feed(1_000, 5_000_000, 250), 248);
        let s = input.status(10_000_000);
        assert_eq!((s.rejected, s.clock_restarts), (2, 1));
        let text = s.last_clock_restart.expect("restart text");
        assert!(text.contains("restarted (599.980 s → 1.040 s)"), "{text}");
        assert_eq!(
            s.ingest.state,
            HealthState::Degraded,
            "recent rejections show"
        );
        assert_eq!(input.status(16_000_000).ingest.state, HealthState::Stale);
    }

    #[test]
    fn one_stamp_from_the_far_future_costs_only_itself() {
        let ing = ingest_with(JSON_IMU);
        let input = ing.inputs[0].clone();
        // Genuine samples `range` at 100 Hz (stamp = arrival); how many were accepted.
        let genuine = |range: std::ops::Range<i64>| -> usize {
            range
                .map(|i| {
                    let t = 1_000_000 + i * 10_000;
                    ing.accept(&input, "imu", imu_json(t).as_bytes(), t).len()
                })
                .sum()
        };
        let mut n = genuine(0..100);
        // A mutated stamp 8.6 years ahead (the fuzzing campaign's finding).
        let garbage = imu_json(1_000_000 + 273_678_336_000_000);
        assert!(ing
            .accept(&input, "imu", garbage.as_bytes(), 2_000_000)
            .is_empty());
        n += genuine(100..200);
        assert_eq!(n, 200, "every genuine sample accepted");
        let s = input.status(3_000_000);
        assert_eq!((s.rejected, s.clock_restarts), (1, 0));
        assert!(s.last_error.expect("error").contains("jumped ahead"));
    }

    #[test]
    fn other_kinds_are_ignored_not_rejected() {
        let ing = ingest_with(JSON_IMU);
        let input = ing.inputs[0].clone();
        let range = br#"{"kind":"range","stamp_us":1,"distance_m":1.5}"#;
        assert!(ing.accept(&input, "imu", range, 1).is_empty());
        let s = input.status(2);
        assert_eq!((s.received, s.rejected, s.ignored), (1, 0, 1));
        assert_eq!(s.ingest.state, HealthState::NoData);
    }

    #[test]
    fn staleness_follows_the_expected_rate() {
        let ing = ingest_with(JSON_IMU);
        let input = ing.inputs[0].clone();
        ing.accept(&input, "imu", imu_json(1).as_bytes(), 1_000_000);
        // 100 Hz → stale after max(50 ms, 250 ms) = 250 ms.
        assert_eq!(input.status(1_200_000).ingest.state, HealthState::Ok);
        let s = input.status(1_300_000);
        assert_eq!(s.ingest.state, HealthState::Stale);
        assert_eq!(s.rate_hz, 0.0);
    }

    #[test]
    fn rate_meter_measures_arrivals() {
        let ing = ingest_with(JSON_IMU);
        let input = ing.inputs[0].clone();
        for i in 0..=250 {
            let t = 1_000_000 + i * 10_000; // 100 Hz for 2.5 s
            ing.accept(&input, "imu", imu_json(t).as_bytes(), t);
        }
        let s = input.status(3_500_000);
        assert!((s.rate_hz - 100.0).abs() < 1.5, "{}", s.rate_hz);
        assert_eq!(s.ingest.state, HealthState::Ok);
    }

    #[test]
    fn ros1_key_type_mismatch_is_rejected_with_both_names() {
        let ing = ingest_with(
            "[[inputs]]\nid=\"gps\"\nkind=\"gnss\"\nkey=\"gps/fix\"\nformat=\"ros1\"\ntype=\"sensor_msgs/NavSatFix\"\nrate_hz=10\n",
        );
        let input = ing.inputs[0].clone();
        let key = format!(
            "{}/{}/gps/fix",
            hex_encode("sensor_msgs/Imu"),
            RosType::Imu.ros1_md5()
        );
        assert!(ing.accept(&input, &key, &[0u8; 8], 1).is_empty());
        let err = input.status(2).last_error.expect("error");
        assert!(
            err.contains("sensor_msgs/Imu") && err.contains("sensor_msgs/NavSatFix"),
            "{err}"
        );
    }
}
