//! The live-data protocol of `/ws` as types: what web/PROTOCOL.md promises is what
//! these serialise to (a test reads the document's examples and compares keys).

use crate::estimator::FusedPose;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// `snapshot.protocol`: bumped when a frame changes incompatibly.
pub const PROTOCOL_VERSION: u32 = 1;

/// Server → client frames (the `snapshot` is assembled by the hub from stored frames).
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ServerFrame {
    Tick(Box<Tick>),
    Status {
        /// The object `GET /api/v1/status` returns.
        status: serde_json::Value,
    },
    Event {
        /// [`crate::event::EstimatorEvent::to_json`] with `time_us`.
        event: serde_json::Value,
    },
    /// Frames this client lost because it read too slowly.
    Dropped {
        dropped: u64,
        total: u64,
    },
}

/// The live series, at most `max_rate_hz` per client.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Tick {
    /// Seconds since the service started.
    pub t: f64,
    pub pose: Option<TickPose>,
    /// Accumulated position per position source, in the fused frame.
    pub sources: BTreeMap<String, [f64; 3]>,
    /// Per-step displacement per source, and of the fused pose (`fused`).
    pub deltas: BTreeMap<String, [f64; 3]>,
    /// The seed's flow-compensation plot, when all three parts are new.
    pub flow: Option<FlowPlot>,
}

/// Raw flow, the gyro as the compensation used it, compensated flow: rad/s, x and y.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FlowPlot {
    pub raw: [f64; 2],
    pub gyro: [f64; 2],
    pub comp: [f64; 2],
}

/// `tick.pose`: the fused pose as the dashboard plots it, rounded to what a plot shows
/// (0.1 mm, 1 mm/s).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TickPose {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    /// ENU heading, rad (0 = east, counter-clockwise).
    pub yaw: f64,
    pub vx: f64,
    pub vy: f64,
    pub vz: f64,
    pub valid: bool,
    pub invalid_reason: Option<String>,
    pub reset_counter: u8,
    /// Position σ per axis, m.
    pub std: [f64; 3],
    pub sources: Vec<String>,
}

impl TickPose {
    pub fn of(p: &FusedPose) -> Self {
        let d = p.position_cov.diagonal();
        Self {
            x: round(p.position.x, 4),
            y: round(p.position.y, 4),
            z: round(p.position.z, 4),
            yaw: round(p.orientation.euler_angles().2, 4),
            vx: round(p.velocity.x, 3),
            vy: round(p.velocity.y, 3),
            vz: round(p.velocity.z, 3),
            valid: p.valid,
            invalid_reason: p.invalid_reason.clone(),
            reset_counter: p.reset_counter,
            std: [
                round(d.x.sqrt(), 4),
                round(d.y.sqrt(), 4),
                round(d.z.sqrt(), 4),
            ],
            sources: p.sources.clone(),
        }
    }
}

fn round(v: f64, digits: i32) -> f64 {
    let k = 10f64.powi(digits);
    (v * k).round() / k
}

/// Client → server messages. Anything else is ignored.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ClientMessage {
    /// Downsample `tick` frames for this client (clamped to 1–50 Hz).
    Subscribe { max_rate_hz: f64 },
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The top-level keys of the first JSON example under `### \`name\`` in PROTOCOL.md
    /// (the examples hold `...` and comments, so they are scanned, not parsed).
    fn documented_keys(doc: &str, name: &str) -> Vec<String> {
        let head = format!("### `{name}`");
        let section = doc
            .split(&head)
            .nth(1)
            .unwrap_or_else(|| panic!("PROTOCOL.md has no section {head}"));
        let example = section
            .split("```json")
            .nth(1)
            .and_then(|s| s.split("```").next())
            .unwrap_or_else(|| panic!("{head}: no json example"));
        let (mut depth, mut keys, mut chars) = (0, vec![], example.chars().peekable());
        while let Some(c) = chars.next() {
            match c {
                '{' | '[' => depth += 1,
                '}' | ']' => depth -= 1,
                '"' => {
                    let s: String = chars.by_ref().take_while(|&c| c != '"').collect();
                    let colon = chars.clone().find(|c| !c.is_whitespace()) == Some(':');
                    if depth == 1 && colon {
                        keys.push(s);
                    }
                }
                _ => {}
            }
        }
        keys.sort();
        keys
    }

    fn keys_of(v: &serde_json::Value) -> Vec<String> {
        let mut k: Vec<String> = v
            .as_object()
            .map(|o| o.keys().cloned().collect())
            .unwrap_or_default();
        k.sort();
        k
    }

    const DOC: &str = include_str!("../web/PROTOCOL.md");

    #[test]
    fn every_frame_has_the_keys_the_document_shows() {
        let tick = ServerFrame::Tick(Box::new(Tick {
            t: 1.0,
            pose: None,
            sources: BTreeMap::new(),
            deltas: BTreeMap::new(),
            flow: None,
        }));
        let frames = [
            ("tick", tick),
            (
                "status",
                ServerFrame::Status {
                    status: serde_json::json!({}),
                },
            ),
            (
                "event",
                ServerFrame::Event {
                    event: serde_json::json!({}),
                },
            ),
            (
                "dropped",
                ServerFrame::Dropped {
                    dropped: 1,
                    total: 2,
                },
            ),
        ];
        for (name, frame) in frames {
            let v = serde_json::to_value(&frame).expect("serialises");
            assert_eq!(v["type"], name);
            assert_eq!(keys_of(&v), documented_keys(DOC, name), "frame {name}");
        }
        // The tick's pose object, as documented (the example lists the common keys).
        let pose = TickPose::of(&FusedPose {
            time_us: 0,
            position: nalgebra::Vector3::new(1.0, 2.0, 3.0),
            velocity: nalgebra::Vector3::zeros(),
            orientation: nalgebra::UnitQuaternion::identity(),
            angular_velocity: None,
            position_cov: nalgebra::Matrix3::identity(),
            velocity_cov: nalgebra::Matrix3::identity(),
            orientation_cov: nalgebra::Matrix3::identity(),
            sources: vec![],
            reset_counter: 0,
            valid: true,
            invalid_reason: None,
            origin: None,
            protection: Default::default(),
        });
        let v = serde_json::to_value(&pose).expect("pose");
        for k in [
            "x",
            "y",
            "z",
            "yaw",
            "vx",
            "vy",
            "vz",
            "valid",
            "reset_counter",
            "std",
        ] {
            assert!(v.get(k).is_some(), "tick.pose.{k}");
            assert!(
                DOC.contains(&format!("\"{k}\"")),
                "PROTOCOL.md names tick.pose.{k}"
            );
        }
    }

    #[test]
    fn the_snapshot_is_what_the_document_shows() {
        let hub = crate::hub::Hub::new(4);
        let text = hub.snapshot(serde_json::json!({}));
        let v: serde_json::Value = serde_json::from_str(&text).expect("snapshot is JSON");
        assert_eq!(keys_of(&v), documented_keys(DOC, "snapshot"));
        assert_eq!(v["protocol"], PROTOCOL_VERSION);
    }

    #[test]
    fn the_client_message_is_what_the_document_shows() {
        let m: ClientMessage =
            serde_json::from_str(r#"{"type": "subscribe", "max_rate_hz": 5}"#).expect("parses");
        assert_eq!(m, ClientMessage::Subscribe { max_rate_hz: 5.0 });
        assert!(DOC.contains(r#"{"type": "subscribe", "max_rate_hz": 5}"#));
        assert!(serde_json::from_str::<ClientMessage>(r#"{"type": "other"}"#).is_err());
    }
}
