//! Discovery: what is published on the Zenoh network and what skyfuse makes of it.
//!
//! Every key seen (one subscriber on `**`, and the topics ROS 2 bridges announce), with
//! its rate and size; which input reads it; for a key no input reads, what it would be
//! read as ([`crate::codec::sniff`]) and which configured input it looks meant for (a
//! namespace, a typo, another IMU message). The dashboard's Network panel and
//! `/api/v1/discovered` show it; `skyfuse discover` prints it and writes a starting
//! config ([`starting_config`]) that `skyfuse run` fuses from as it is.

use crate::clock::RateMeter;
use crate::codec::sniff::{self, Sniffed};
use crate::codec::{Format, RosType};
use crate::config::InputConfig;
use crate::sample::SensorKind;
use serde::Serialize;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::Mutex;

/// Keys remembered at most; more are counted, not kept (a network with a key per
/// message id must not grow the table without end).
pub const MAX_KEYS: usize = 1024;
/// Payloads of a key looked at to recognise it: the first ones only.
const SNIFF_TRIES: u32 = 3;
/// A key silent this long is dropped from the view, µs.
const FORGET_AFTER_US: i64 = 60_000_000;
/// Key names this close (characters) to a configured key are "near" it.
const NEAR_EDITS: usize = 3;

/// What is seen of one key.
#[derive(Debug)]
struct Seen {
    count: u64,
    bytes: u64,
    first_us: i64,
    last_us: i64,
    rate: RateMeter,
    sniffed: Option<Sniffed>,
    tries: u32,
}

/// The table of keys seen, filled on Zenoh's threads.
#[derive(Debug, Default)]
pub struct Discovery {
    table: Mutex<BTreeMap<String, Seen>>,
    /// Samples of keys not kept (the table was full).
    overflow: AtomicU64,
}

/// One key as `/api/v1/discovered` and `skyfuse discover` show it.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct DiscoveredKey {
    pub key: String,
    /// Messages per second over the last second (0 once it stops).
    pub rate_hz: f64,
    /// Messages per second since first seen.
    pub mean_rate_hz: f64,
    pub count: u64,
    pub mean_bytes: f64,
    /// Time since the last message, ms; `None`: announced by a bridge, nothing seen.
    pub last_age_ms: Option<f64>,
    /// The inputs whose key expression covers it.
    pub read_by: Vec<String>,
    /// This service's own output.
    pub own_output: bool,
    /// What it is: format, ROS type or MAVLink message, kinds of sample.
    pub format: Option<Format>,
    pub ros_type: Option<String>,
    /// Where the ROS type comes from: "announced" (a bridge's liveliness token) or
    /// "payload" (it decodes as that type and no other).
    pub type_from: Option<&'static str>,
    pub message: Option<String>,
    pub kinds: Vec<SensorKind>,
    /// CDR that fits several types (no bridge says which).
    pub candidates: Vec<&'static str>,
    /// A key no input reads: the input it looks meant for, and why.
    pub near: Option<Near>,
}

#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Near {
    pub input: String,
    pub why: String,
}

/// The whole view.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Discovered {
    pub keys: Vec<DiscoveredKey>,
    /// Messages on keys beyond [`MAX_KEYS`], not shown.
    pub overflow: u64,
}

/// A ROS 2 topic a bridge announces: its Zenoh key and type name.
pub type Announced = BTreeMap<String, String>;

impl Discovery {
    /// One message on `key`. Cheap after a key's first payloads (a map update).
    pub fn observe(&self, key: &str, payload: &[u8], now_us: i64) {
        self.observe_with(key, payload.len(), now_us, || payload);
    }

    /// As [`Discovery::observe`], the payload's bytes asked for only while the key is
    /// still being recognised (Zenoh may have to copy them out of fragments).
    pub fn observe_with<B: AsRef<[u8]>>(
        &self,
        key: &str,
        len: usize,
        now_us: i64,
        payload: impl FnOnce() -> B,
    ) {
        if sniff::is_mavlink_field_key(key) {
            return;
        }
        let mut t = crate::sync::lock(&self.table);
        if !t.contains_key(key) {
            if t.len() >= MAX_KEYS {
                self.overflow.fetch_add(1, Relaxed);
                return;
            }
            t.insert(
                key.to_string(),
                Seen {
                    count: 0,
                    bytes: 0,
                    first_us: now_us,
                    last_us: now_us,
                    rate: RateMeter::default(),
                    sniffed: None,
                    tries: 0,
                },
            );
        }
        let Some(seen) = t.get_mut(key) else { return };
        seen.count += 1;
        seen.bytes += len as u64;
        seen.last_us = now_us;
        seen.rate.tick(now_us);
        if seen.sniffed.is_none() && seen.tries < SNIFF_TRIES {
            seen.tries += 1;
            seen.sniffed = sniff::sniff(key, payload().as_ref());
        }
    }

    /// The view at `now_us`: every key seen in the last minute and every topic a bridge
    /// announces, against `inputs`; `own` are this service's output key expressions.
    pub fn snapshot(
        &self,
        now_us: i64,
        inputs: &[InputConfig],
        announced: &Announced,
        own: &[String],
    ) -> Discovered {
        let mut t = crate::sync::lock(&self.table);
        t.retain(|_, s| now_us - s.last_us < FORGET_AFTER_US);
        let mut keys: BTreeMap<String, DiscoveredKey> = BTreeMap::new();
        for (key, s) in t.iter() {
            let span_s = ((s.last_us - s.first_us) as f64 * 1e-6).max(1e-3);
            let mut k = blank(key);
            k.rate_hz = s.rate.rate_hz_at(now_us);
            k.mean_rate_hz = if s.count > 1 {
                (s.count - 1) as f64 / span_s
            } else {
                0.0
            };
            k.count = s.count;
            k.mean_bytes = s.bytes as f64 / s.count.max(1) as f64;
            k.last_age_ms = Some((now_us - s.last_us) as f64 / 1e3);
            if let Some(sn) = &s.sniffed {
                describe(&mut k, sn);
            }
            keys.insert(key.clone(), k);
        }
        drop(t);
        for (key, ty) in announced {
            let k = keys.entry(key.clone()).or_insert_with(|| blank(key));
            // The bridge's word beats the bytes.
            if let Some(rt) = RosType::from_name(ty) {
                k.format = Some(Format::Ros2);
                k.kinds = vec![rt.kind()];
                k.candidates.clear();
            }
            k.ros_type = Some(ty.clone());
            k.type_from = Some("announced");
        }
        let mut out: Vec<DiscoveredKey> = keys.into_values().collect();
        for k in &mut out {
            k.own_output = own.iter().any(|o| intersects(o, &k.key));
            k.read_by = inputs
                .iter()
                .filter(|i| i.enabled && i.key_exprs().iter().any(|e| intersects(e, &k.key)))
                .map(|i| i.id.clone())
                .collect();
            if k.read_by.is_empty() && !k.own_output {
                k.near = near(k, inputs);
            }
        }
        Discovered {
            keys: out,
            overflow: self.overflow.load(Relaxed),
        }
    }
}

/// Subscribe to every key into `discovery`; `None` (said in the log) when Zenoh refuses.
pub async fn watch(
    session: &zenoh::Session,
    discovery: std::sync::Arc<Discovery>,
) -> Option<zenoh::pubsub::Subscriber<()>> {
    let sub = session
        .declare_subscriber("**")
        .callback(move |sample: zenoh::sample::Sample| {
            discovery.observe_with(
                sample.key_expr().as_str(),
                sample.payload().len(),
                crate::clock::now_us(),
                || sample.payload().to_bytes(),
            );
        })
        .await;
    match sub {
        Ok(s) => Some(s),
        Err(e) => {
            tracing::warn!("discovery: cannot subscribe to every key: {e}");
            None
        }
    }
}

/// The topics bridges announce (alive ones), key → ROS type.
pub fn announced(table: &crate::ros_graph::TopicTable) -> Announced {
    crate::sync::lock(table)
        .values()
        .filter(|e| e.alive)
        .map(|e| (e.key.clone(), e.ros_type.clone()))
        .collect()
}

/// This service's own outputs as key expressions: its prefix, its ROS 2 pose and debug
/// topics.
pub fn own_outputs(config: &crate::config::Config) -> Vec<String> {
    let o = &config.output;
    vec![
        format!("{}/**", o.prefix_for(&config.service.vehicle)),
        o.ros2_pose_key.clone(),
        format!("{}/**", o.ros2_debug_prefix),
    ]
}

fn blank(key: &str) -> DiscoveredKey {
    DiscoveredKey {
        key: key.to_string(),
        rate_hz: 0.0,
        mean_rate_hz: 0.0,
        count: 0,
        mean_bytes: 0.0,
        last_age_ms: None,
        read_by: Vec::new(),
        own_output: false,
        format: None,
        ros_type: None,
        type_from: None,
        message: None,
        kinds: Vec::new(),
        candidates: Vec::new(),
        near: None,
    }
}

fn describe(k: &mut DiscoveredKey, s: &Sniffed) {
    k.format = Some(s.format);
    k.kinds = s.kinds.clone();
    k.message = s.message.clone();
    if let Some(t) = s.ros_type {
        k.ros_type = Some(t.ros2_name().to_string());
        k.type_from = Some("payload");
    }
    k.candidates = s.ambiguous.iter().map(|t| t.ros2_name()).collect();
}

/// Whether key expression `expr` covers `key` (both valid; anything else: no).
fn intersects(expr: &str, key: &str) -> bool {
    use zenoh::key_expr::keyexpr;
    match (keyexpr::new(expr), keyexpr::new(key)) {
        (Ok(a), Ok(b)) => a.intersects(b),
        _ => false,
    }
}

/// The last `/`-separated part of a key (a ROS topic's name, a MAVLink message).
fn last_part(key: &str) -> &str {
    key.rsplit('/').next().unwrap_or(key)
}

/// The configured input an unread key looks meant for: the same name in another
/// namespace or a few characters off, else the same kind of sample.
fn near(k: &DiscoveredKey, inputs: &[InputConfig]) -> Option<Near> {
    let enabled = || inputs.iter().filter(|i| i.enabled);
    let by_name = enabled()
        .filter_map(|i| {
            let want = i.key.trim_start_matches('/');
            let key = k.key.as_str();
            if want.ends_with(&format!("/{key}")) || key.ends_with(&format!("/{want}")) {
                return Some((
                    0,
                    i,
                    format!("the input's key is {want:?}: another namespace?"),
                ));
            }
            let d = crate::codec::edit_distance(want, key);
            (d <= NEAR_EDITS && !want.contains('*')).then(|| {
                (
                    d,
                    i,
                    format!(
                        "{d} character{} from the input's key {want:?}",
                        if d == 1 { "" } else { "s" }
                    ),
                )
            })
        })
        .min_by_key(|(d, _, _)| *d);
    if let Some((_, i, why)) = by_name {
        return Some(Near {
            input: i.id.clone(),
            why,
        });
    }
    let kind = *k.kinds.first()?;
    let i = enabled()
        .filter(|i| i.kind == kind)
        .min_by_key(|i| crate::codec::edit_distance(last_part(&i.key), last_part(&k.key)))?;
    Some(Near {
        input: i.id.clone(),
        why: format!("gives {kind} samples, as this input wants"),
    })
}

/// The input id a kind of sample gets in a written config.
fn id_for(kind: SensorKind, message: Option<&str>) -> &'static str {
    match (kind, message) {
        (SensorKind::VehicleState, Some("HEARTBEAT")) => "armed",
        (SensorKind::VehicleState, Some("EXTENDED_SYS_STATE")) => "landed",
        (SensorKind::VehicleState, _) => "vehicle_state",
        (SensorKind::Imu, _) => "imu",
        (SensorKind::Attitude, _) => "attitude",
        (SensorKind::Gnss, _) => "gps",
        (SensorKind::Flow, _) => "flow",
        (SensorKind::Range, _) => "rangefinder",
        (SensorKind::Odometry, _) => "odometry",
        (SensorKind::AutopilotEstimate, _) => "autopilot",
        (SensorKind::Baro, _) => "baro",
    }
}

/// A rate for the config from what was measured: a round number near it.
fn nice_rate(hz: f64) -> f64 {
    match hz {
        h if !h.is_finite() || h <= 0.0 => 10.0,
        h if h < 2.0 => (h * 10.0).round().max(1.0) / 10.0,
        h if h < 20.0 => h.round(),
        h => (h / 5.0).round() * 5.0,
    }
}

/// One input of a written config, and what it was made from.
#[derive(Debug, Clone, PartialEq)]
pub struct Proposed {
    pub id: String,
    pub kind: SensorKind,
    pub key: String,
    pub format: Format,
    pub ros_type: Option<RosType>,
    pub rate_hz: f64,
    pub note: String,
}

/// The inputs a config needs to read what was discovered: one per recognised key
/// (mavlink-server's per-message keys, ROS topics, skyfuse JSON), and a raw MAVLink
/// stream only for kinds nothing else gives. Own outputs and keys another input
/// already reads twice are left out.
pub fn propose(d: &Discovered) -> Vec<Proposed> {
    let mut out: Vec<Proposed> = Vec::new();
    let mut raw: Vec<(&DiscoveredKey, SensorKind)> = Vec::new();
    for k in d.keys.iter().filter(|k| !k.own_output) {
        let (Some(format), Some(&kind)) = (k.format, k.kinds.first()) else {
            continue;
        };
        let ros_type = k.ros_type.as_deref().and_then(RosType::from_name);
        let seen = match k.last_age_ms {
            Some(_) => format!("{:.1} Hz", k.mean_rate_hz),
            None => "announced, nothing seen yet".into(),
        };
        let what = match (ros_type, &k.message) {
            (Some(t), _) => format!(
                "{} ({})",
                t.ros2_name(),
                if k.type_from == Some("announced") {
                    "announced by a ROS 2 bridge"
                } else {
                    "decoded from the payload"
                }
            ),
            (None, Some(m)) => format!("MAVLink {m} (mavlink-server)"),
            (None, None) => format.as_str().to_string(),
        };
        let (key, format) = match format {
            Format::MavlinkRaw => {
                raw.extend(k.kinds.iter().map(|&kd| (k, kd)));
                continue;
            }
            // mavlink-server's all-messages key: its per-message keys are read instead.
            Format::MavlinkJson if k.message.is_none() => continue,
            Format::Ros1 => (ros1_topic(&k.key), format),
            _ => (k.key.clone(), format),
        };
        out.push(Proposed {
            id: id_for(kind, k.message.as_deref()).to_string(),
            kind,
            key,
            format,
            ros_type,
            rate_hz: nice_rate(k.mean_rate_hz),
            note: format!("{what}, {seen}"),
        });
    }
    for (k, kind) in raw {
        if out.iter().any(|p| p.kind == kind) {
            continue;
        }
        out.push(Proposed {
            id: id_for(kind, None).to_string(),
            kind,
            key: k.key.clone(),
            format: Format::MavlinkRaw,
            ros_type: None,
            rate_hz: nice_rate(k.mean_rate_hz),
            note: format!("raw MAVLink frames, {:.1} Hz", k.mean_rate_hz),
        });
    }
    // Ids by kind (imu, gps, …), numbered when a kind repeats.
    let mut used: BTreeMap<String, usize> = BTreeMap::new();
    for p in &mut out {
        let n = used.entry(p.id.clone()).or_insert(0);
        *n += 1;
        if *n > 1 {
            p.id = format!("{}_{n}", p.id);
        }
    }
    out
}

/// zenoh-plugin-ros1's key `<hex(type)>/<md5>/[<ns>/]<topic>` → the topic.
fn ros1_topic(key: &str) -> String {
    key.splitn(3, '/').nth(2).unwrap_or(key).to_string()
}

/// A config file with `proposed` as its inputs and `zenoh` (TOML lines of its
/// `[zenoh]` section, empty for the defaults), every line commented.
pub fn starting_config(proposed: &[Proposed], zenoh: &[String], header: &str) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    for line in header.lines() {
        let _ = writeln!(s, "# {line}");
    }
    let _ = writeln!(
        s,
        "# Check it with `skyfuse check-config FILE`, run it with `skyfuse run -c FILE`.\n\
         # Every other setting keeps its default (config/default.toml explains each).\n"
    );
    if !zenoh.is_empty() {
        let _ = writeln!(s, "[zenoh]\n# How discovery reached the network.");
        for l in zenoh {
            let _ = writeln!(s, "{l}");
        }
        s.push('\n');
    }
    if proposed.is_empty() {
        let _ = writeln!(
            s,
            "# Nothing skyfuse reads was seen: no [[inputs]] (run would refuse this file)."
        );
    }
    for p in proposed {
        let _ = writeln!(s, "# {}", p.note);
        let _ = writeln!(s, "[[inputs]]");
        let _ = writeln!(s, "id = {:?}", p.id);
        let _ = writeln!(s, "kind = {:?}", p.kind.as_str());
        let _ = writeln!(s, "key = {:?}", p.key);
        let _ = writeln!(s, "format = {:?}", p.format.as_str());
        if let Some(t) = p.ros_type {
            let name = if p.format == Format::Ros1 {
                t.ros1_name()
            } else {
                t.ros2_name()
            };
            let _ = writeln!(s, "type = {name:?}");
        }
        let _ = writeln!(s, "rate_hz = {:?}\n", p.rate_hz);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::{encode_sample, MavIdentity};
    use crate::sample::{Imu, SensorData};
    use nalgebra::Vector3;

    fn imu() -> SensorData {
        SensorData::Imu(Imu {
            gyro: Some(Vector3::new(0.01, 0.02, 0.03)),
            accel: Some(Vector3::new(0.1, 0.2, 9.8)),
            orientation: None,
            gyro_cov: None,
            accel_cov: None,
            orientation_cov: None,
        })
    }

    fn input(id: &str, kind: SensorKind, key: &str, format: Format) -> InputConfig {
        let text = format!(
            "[[inputs]]\nid = {id:?}\nkind = {:?}\nkey = {key:?}\nformat = {:?}\n{}rate_hz = 10.0\n",
            kind.as_str(),
            format.as_str(),
            if format.needs_ros_type() {
                "type = \"sensor_msgs/msg/Imu\"\n"
            } else {
                ""
            }
        );
        crate::config::Config::from_toml_str(&text, "t.toml")
            .expect("config")
            .inputs
            .remove(0)
    }

    /// The table says what each key is, who reads it, and for an unread IMU topic in
    /// another namespace, which input it looks meant for; a proposed config reads every
    /// recognised key once, and parses.
    #[test]
    fn keys_are_described_matched_and_proposed() {
        let d = Discovery::default();
        let mav = MavIdentity {
            system_id: 1,
            component_id: 1,
            sequence: 0,
        };
        let cdr = encode_sample(Format::Ros2, Some(RosType::Imu), 1, &imu(), mav)
            .unwrap()
            .payload;
        let json = encode_sample(Format::MavlinkJson, None, 1, &imu(), mav).unwrap();
        for i in 0..=50 {
            let t = i * 20_000;
            d.observe("imu/data", &cdr, t);
            d.observe("mavlink/1/1/HIGHRES_IMU", &json.payload, t);
            d.observe("mavlink/1/1/HIGHRES_IMU/xacc", b"0.1", t);
            d.observe("skyfuse/v1/pose", b"{}", t);
        }
        let inputs = vec![
            input("imu", SensorKind::Imu, "mavros/imu/data", Format::Ros2),
            input(
                "hr",
                SensorKind::Imu,
                "mavlink/*/*/HIGHRES_IMU",
                Format::MavlinkJson,
            ),
        ];
        let mut announced = Announced::new();
        announced.insert("gps/fix".into(), "sensor_msgs/msg/NavSatFix".into());
        let v = d.snapshot(
            1_000_000,
            &inputs,
            &announced,
            &["skyfuse/v1/**".to_string()],
        );
        let by_key = |k: &str| {
            v.keys
                .iter()
                .find(|x| x.key == k)
                .unwrap_or_else(|| panic!("{k}"))
        };
        assert!(
            v.keys.iter().all(|k| !k.key.ends_with("/xacc")),
            "field keys are left out"
        );
        let ros = by_key("imu/data");
        assert_eq!(ros.ros_type.as_deref(), Some("sensor_msgs/msg/Imu"));
        assert_eq!(ros.type_from, Some("payload"));
        assert!(ros.read_by.is_empty());
        let near = ros.near.as_ref().expect("near");
        assert_eq!(near.input, "imu");
        assert!(near.why.contains("namespace"), "{}", near.why);
        assert!(
            (ros.mean_rate_hz - 50.0).abs() < 0.5,
            "{}",
            ros.mean_rate_hz
        );
        assert_eq!(by_key("mavlink/1/1/HIGHRES_IMU").read_by, vec!["hr"]);
        assert!(by_key("skyfuse/v1/pose").own_output);
        let gps = by_key("gps/fix");
        assert_eq!((gps.type_from, gps.last_age_ms), (Some("announced"), None));
        assert_eq!(gps.kinds, vec![SensorKind::Gnss]);

        let proposed = propose(&v);
        let ids: Vec<(&str, &str)> = proposed
            .iter()
            .map(|p| (p.id.as_str(), p.key.as_str()))
            .collect();
        assert_eq!(
            ids,
            vec![
                ("gps", "gps/fix"),
                ("imu", "imu/data"),
                ("imu_2", "mavlink/1/1/HIGHRES_IMU")
            ]
        );
        let text = starting_config(&proposed, &["mode = \"client\"".into()], "test");
        let c = crate::config::Config::from_toml_str(&text, "found.toml").expect(&text);
        assert_eq!(c.inputs.len(), 3);
        assert_eq!(c.inputs[0].ros_type, Some(RosType::NavSatFix));
        assert_eq!(c.inputs[2].format, Format::MavlinkJson);
    }

    #[test]
    fn a_full_table_counts_instead_of_growing() {
        let d = Discovery::default();
        for i in 0..MAX_KEYS + 10 {
            d.observe(&format!("k/{i}"), b"x", 0);
        }
        let v = d.snapshot(0, &[], &Announced::new(), &[]);
        assert_eq!((v.keys.len(), v.overflow), (MAX_KEYS, 10));
    }
}
