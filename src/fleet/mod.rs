//! The fleet view: every skyfuse on the Zenoh network on one page, from what each already
//! publishes (`<prefix>/pose`, `<prefix>/health`, `<prefix>/events`) and the liveliness
//! token it holds while it runs (`<prefix>/alive`).
//!
//! [`Fleet`] is the pure part: payloads and times in, a [`FleetView`] out; nothing here
//! reads a clock or the network. [`watch`] subscribes on Zenoh, feeds it and serves the
//! view to `/api/v1/fleet` and `/ws/fleet`.
//!
//! Thinning: each vehicle publishes `<prefix>/summary` once a second (its pose and the
//! parts of its health this view reads, in one small message), and the view reads that
//! by default instead of the full-rate pose and the full health: a thousand vehicles
//! cost a monitor a thousand small messages a second, whatever their pose rate. Zenoh's
//! downsampling cannot do this thinning per vehicle (zenohd 1.10 keeps one timer per
//! rule, so `**/skyfuse/*/pose` at 1 Hz lets one pose a second through for the whole
//! fleet); see config/zenohd-fleet.json5. A pose payload (read only with
//! `[fleet] summary_only = false`) is stored as it arrives and parsed when the view is
//! refreshed (2 Hz); the track keeps a point a second.
//!
//! Bounded: at most `[fleet] max_vehicles` entries (more are refused and counted), ids,
//! payloads, sensor lists and texts are capped, so outside data cannot grow the monitor
//! beyond a fixed size per vehicle.

pub mod watch;

use crate::config::FleetConfig;
use crate::geo::LocalEnu;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet, VecDeque};

/// Time on the host clock, µs.
type Micros = i64;

/// Keys under a vehicle's prefix that the fleet view reads, as the vehicle's output
/// publishes them (the publisher owns the names and the summary's shape).
pub use crate::output::summary::{summary_json, ALIVE, EVENTS, HEALTH, POSE, SUMMARY};

/// A track point at most this often, µs.
const TRACK_INTERVAL_US: Micros = 1_000_000;
/// Larger payloads are refused unread: a real pose is under 1 KB, a health message a few
/// KB; this bounds what one stored pose (or one parse) can cost.
pub const MAX_PAYLOAD: usize = 64 * 1024;
/// A vehicle id (its key prefix) longer than this is refused: ids are kept per vehicle
/// and sent to every page.
pub const MAX_ID_LEN: usize = 200;
/// Sensors and sources kept per vehicle, and the length of each text kept.
const MAX_LIST: usize = 32;
const MAX_TEXT: usize = 300;

/// How a vehicle is doing, as far as the fleet view can tell.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Presence {
    /// Its outputs arrive.
    Live,
    /// Nothing from it for `stale_after_s`, its token still held.
    Stale,
    /// Its token is gone, or nothing from it for `gone_after_s`: shown grey, dropped
    /// after `forget_after_s`.
    Gone,
}

/// The parts of `<prefix>/pose` the fleet view uses (zenoh_out::PoseMessage).
#[derive(Debug, Clone, Deserialize)]
struct PoseIn {
    position: [f64; 3],
    orientation: [f64; 4],
    velocity: [f64; 3],
    position_covariance: [f64; 9],
    #[serde(default)]
    sources: Vec<String>,
    valid: bool,
    invalid_reason: Option<String>,
    origin: Option<GeoIn>,
}

#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq)]
pub struct GeoIn {
    pub lat: f64,
    pub lon: f64,
    pub alt: f64,
}

/// The parts of `<prefix>/health` the fleet view uses (AppState::health_json).
#[derive(Debug, Clone, Deserialize)]
struct HealthIn {
    #[serde(default)]
    service: Option<ServiceIn>,
    #[serde(default)]
    vpe: Option<VpeIn>,
    #[serde(default)]
    zenoh: Option<ZenohIn>,
    #[serde(default)]
    sensors: Vec<SensorIn>,
}

/// `<prefix>/summary`: the pose (null before the first) and the health's verdict parts.
#[derive(Debug, Clone, Deserialize)]
struct SummaryIn {
    #[serde(default)]
    pose: Option<PoseIn>,
    #[serde(flatten)]
    health: HealthIn,
}

#[derive(Debug, Clone, Deserialize)]
struct ServiceIn {
    vehicle: String,
    version: String,
    started_us: i64,
    dashboard: Option<String>,
}

#[derive(Debug, Clone, Deserialize)]
struct VpeIn {
    endpoints: usize,
    sending: bool,
    reason: Option<String>,
}

#[derive(Debug, Clone, Copy, Deserialize, Serialize)]
pub struct ZenohIn {
    pub routers: u64,
    pub peers: u64,
}

#[derive(Debug, Clone, Deserialize)]
struct SensorIn {
    id: String,
    health: String,
}

#[derive(Debug, Clone, Deserialize)]
struct EventIn {
    #[serde(default)]
    time_us: Option<i64>,
    #[serde(default)]
    kind: Option<String>,
    #[serde(default)]
    source: Option<String>,
    message: String,
}

/// A payload the fleet view could not read (counted, named in the log by the caller).
#[derive(Debug, thiserror::Error)]
#[error("{key}: {message}")]
pub struct FleetInputError {
    pub key: String,
    pub message: String,
}

/// One vehicle's entry.
#[derive(Debug, Clone)]
struct Vehicle {
    /// Place in the table and colour on the map, kept while the vehicle is known (a
    /// restart keeps it).
    slot: usize,
    last_heard_us: Micros,
    /// Since when its liveliness token is gone (None: held, or never seen).
    token_lost_us: Option<Micros>,
    /// The newest pose, placed at the next refresh.
    pose_pending: Option<PendingPose>,
    pose: Option<PoseIn>,
    /// Where `pose` is on the map: east/north and the frame (see `map_position`),
    /// computed once when the pose is read.
    placed: Option<([f64; 2], &'static str)>,
    health: Option<HealthIn>,
    last_event: Option<EventView>,
    started_us: Option<i64>,
    restarts: u32,
    track: VecDeque<[f64; 2]>,
    last_track_us: Option<Micros>,
    /// The frame the track is in (`geo`/`local` and the vehicle's origin).
    track_frame: Option<(&'static str, Option<GeoIn>)>,
}

/// A pose waiting for the next refresh: a full-rate payload is parsed only then (the
/// newest of many), a summary's was parsed with the summary.
#[derive(Debug, Clone)]
enum PendingPose {
    Raw(Vec<u8>),
    Parsed(Box<PoseIn>),
}

/// The last event a vehicle published.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct EventView {
    pub time_us: Option<i64>,
    pub kind: Option<String>,
    pub source: Option<String>,
    pub message: String,
}

/// One row of the fleet view.
#[derive(Debug, Clone, Serialize)]
pub struct VehicleView {
    /// The vehicle's output prefix on the network (unique), e.g. `bot1/skyfuse/drone`.
    pub id: String,
    /// Its `[service] vehicle` name (the prefix's last part until its health arrives).
    pub name: String,
    pub slot: usize,
    pub presence: Presence,
    /// Seconds since anything arrived from it.
    pub heard_s_ago: f64,
    pub version: Option<String>,
    pub dashboard: Option<String>,
    pub restarts: u32,
    /// The estimate: valid or why not; null before its first pose.
    pub valid: Option<bool>,
    pub invalid_reason: Option<String>,
    pub sources: Vec<String>,
    /// Horizontal position standard deviation, m.
    pub position_std_m: Option<f64>,
    /// `ok`, `degraded`, `no_data`, `stale` or `failed`: its worst enabled sensor.
    pub worst_health: Option<String>,
    /// Sensors not `ok` (`id: state`).
    pub unhealthy: Vec<String>,
    /// VISION_POSITION_ESTIMATE: `sending`, `withheld`, or `off` (no MAVLink endpoint).
    pub vpe: Option<&'static str>,
    pub vpe_reason: Option<String>,
    /// Its own Zenoh link: routers and peers it is connected to.
    pub zenoh: Option<ZenohIn>,
    pub last_event: Option<EventView>,
    /// `geo`: placed by its GNSS origin in the fleet's frame; `local`: its own frame.
    pub frame: Option<&'static str>,
    /// East, north in the map frame, m; altitude (up), m.
    pub xy: Option<[f64; 2]>,
    pub z: Option<f64>,
    /// Compass heading, degrees from north, clockwise.
    pub heading_deg: Option<f64>,
    pub speed_m_s: Option<f64>,
    /// Track in the map frame (only in full views).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub track: Option<Vec<[f64; 2]>>,
}

/// The whole fleet at one time.
#[derive(Debug, Clone, Serialize)]
pub struct FleetView {
    #[serde(rename = "type")]
    pub kind: &'static str,
    pub time_us: Micros,
    /// The GNSS point the map's `geo` frame is anchored at (the first origin seen).
    pub reference: Option<GeoIn>,
    pub vehicles: Vec<VehicleView>,
    pub counters: FleetCounters,
    /// Served by `skyfuse monitor` (no vehicle dashboard beside it).
    pub monitor: bool,
}

#[derive(Debug, Clone, Copy, Default, Serialize, PartialEq)]
pub struct FleetCounters {
    pub messages: u64,
    /// Payload bytes received on the fleet keys.
    pub bytes: u64,
    pub rejected: u64,
    pub joined: u64,
    pub forgotten: u64,
    /// Vehicles not taken in because `max_vehicles` were known (or their id was too long).
    pub refused: u64,
}

/// The fleet: pure state, fed payloads with their arrival times.
pub struct Fleet {
    cfg: FleetConfig,
    vehicles: BTreeMap<String, Vehicle>,
    /// Slots held by known vehicles (a join takes the lowest free one without a scan of
    /// every vehicle).
    slots: BTreeSet<usize>,
    reference: Option<(GeoIn, LocalEnu)>,
    counters: FleetCounters,
}

impl Fleet {
    pub fn new(cfg: FleetConfig) -> Self {
        Self {
            cfg,
            vehicles: BTreeMap::new(),
            slots: BTreeSet::new(),
            reference: None,
            counters: FleetCounters::default(),
        }
    }

    /// Splits `…/<prefix>/<leaf>` into the vehicle id (the prefix) and the leaf.
    pub fn split_key(key: &str) -> Option<(&str, &str)> {
        let (id, leaf) = key.rsplit_once('/')?;
        (!id.is_empty()).then_some((id, leaf))
    }

    /// The vehicle's entry, created on first sight; None when it cannot be taken in
    /// (`max_vehicles` known, or an id too long), counted in `refused`.
    fn entry(&mut self, id: &str, now: Micros) -> Option<&mut Vehicle> {
        if !self.vehicles.contains_key(id) {
            if self.vehicles.len() >= self.cfg.max_vehicles || id.len() > MAX_ID_LEN {
                self.counters.refused += 1;
                return None;
            }
            // The lowest slot no known vehicle holds: a vehicle that left and was
            // forgotten frees its colour.
            let slot = self
                .slots
                .iter()
                .enumerate()
                .find(|(i, s)| i != *s)
                .map_or(self.slots.len(), |(i, _)| i);
            self.slots.insert(slot);
            self.counters.joined += 1;
            self.vehicles.insert(
                id.to_string(),
                Vehicle {
                    slot,
                    last_heard_us: now,
                    token_lost_us: None,
                    pose_pending: None,
                    pose: None,
                    placed: None,
                    health: None,
                    last_event: None,
                    started_us: None,
                    restarts: 0,
                    track: VecDeque::new(),
                    last_track_us: None,
                    track_frame: None,
                },
            );
        }
        let v = self.vehicles.get_mut(id)?;
        v.last_heard_us = v.last_heard_us.max(now);
        Some(v)
    }

    /// How many vehicles are known (live, stale or gone and not yet forgotten).
    pub fn len(&self) -> usize {
        self.vehicles.len()
    }

    pub fn is_empty(&self) -> bool {
        self.vehicles.is_empty()
    }

    /// Vehicles by presence now: (live, stale, gone).
    pub fn presence_counts(&self, now: Micros) -> (usize, usize, usize) {
        let mut n = (0, 0, 0);
        for v in self.vehicles.values() {
            match self.presence(v, now) {
                Presence::Live => n.0 += 1,
                Presence::Stale => n.1 += 1,
                Presence::Gone => n.2 += 1,
            }
        }
        n
    }

    pub fn counters(&self) -> FleetCounters {
        self.counters
    }

    /// A liveliness token appeared (a vehicle started, or its link came back; which of
    /// the two its health's start time tells).
    pub fn token_appeared(&mut self, id: &str, now: Micros) {
        if let Some(v) = self.entry(id, now) {
            v.token_lost_us = None;
        }
    }

    /// A liveliness token went away (the vehicle stopped, or its link did).
    pub fn token_lost(&mut self, id: &str, now: Micros) {
        if let Some(v) = self.vehicles.get_mut(id) {
            v.token_lost_us = Some(now);
        }
    }

    /// A payload on `<id>/<leaf>`. A full-rate pose is only stored (parsed at the next
    /// [`Fleet::refresh`]); summaries, health and events are read at once (1 Hz, rare).
    pub fn accept(
        &mut self,
        id: &str,
        leaf: &str,
        payload: &[u8],
        now: Micros,
    ) -> Result<(), FleetInputError> {
        self.counters.messages += 1;
        self.counters.bytes += payload.len() as u64;
        let err = |message: String| FleetInputError {
            key: format!("{id}/{leaf}"),
            message,
        };
        let result = if payload.len() > MAX_PAYLOAD {
            Err(err(format!(
                "{} bytes, more than the {MAX_PAYLOAD} a fleet message may have",
                payload.len()
            )))
        } else {
            match leaf {
                POSE => {
                    if let Some(v) = self.entry(id, now) {
                        v.pose_pending = Some(PendingPose::Raw(payload.to_vec()));
                    }
                    Ok(())
                }
                SUMMARY => match serde_json::from_slice::<SummaryIn>(payload) {
                    Ok(s) => match s.pose.map(check_pose).transpose() {
                        Ok(pose) => {
                            if let Some(v) = self.entry(id, now) {
                                apply_health(v, s.health);
                                if let Some(p) = pose {
                                    v.pose_pending = Some(PendingPose::Parsed(Box::new(p)));
                                }
                            }
                            Ok(())
                        }
                        Err(e) => Err(err(e)),
                    },
                    Err(e) => Err(err(format!("not a skyfuse summary: {e}"))),
                },
                HEALTH => match serde_json::from_slice::<HealthIn>(payload) {
                    Ok(h) => {
                        if let Some(v) = self.entry(id, now) {
                            apply_health(v, h);
                        }
                        Ok(())
                    }
                    Err(e) => Err(err(format!("not a skyfuse health message: {e}"))),
                },
                EVENTS => match serde_json::from_slice::<EventIn>(payload) {
                    Ok(e) => {
                        if let Some(v) = self.entry(id, now) {
                            v.last_event = Some(EventView {
                                time_us: e.time_us,
                                kind: e.kind.map(|k| truncated(k, MAX_TEXT)),
                                source: e.source.map(|k| truncated(k, MAX_TEXT)),
                                message: truncated(e.message, MAX_TEXT),
                            });
                        }
                        Ok(())
                    }
                    Err(e) => Err(err(format!("not a skyfuse event: {e}"))),
                },
                other => Err(err(format!("not a fleet key ({other})"))),
            }
        };
        if result.is_err() {
            self.counters.rejected += 1;
        }
        result
    }

    /// Parses the pending poses, extends the tracks, and forgets vehicles gone for
    /// `forget_after_s`. Returns the errors of poses that could not be read.
    pub fn refresh(&mut self, now: Micros) -> Vec<FleetInputError> {
        let mut errors = Vec::new();
        let forget_us = secs_us(self.cfg.forget_after_s);
        let gone_us = secs_us(self.cfg.gone_after_s);
        let before = self.vehicles.len();
        let slots = &mut self.slots;
        self.vehicles.retain(|_, v| {
            let gone_since = match v.token_lost_us {
                Some(t) => t.min(v.last_heard_us + gone_us),
                None => v.last_heard_us + gone_us,
            };
            let keep = now - gone_since < forget_us;
            if !keep {
                slots.remove(&v.slot);
            }
            keep
        });
        self.counters.forgotten += (before - self.vehicles.len()) as u64;
        let ids: Vec<String> = self.vehicles.keys().cloned().collect();
        for id in ids {
            let Some(pending) = self
                .vehicles
                .get_mut(&id)
                .and_then(|v| v.pose_pending.take())
            else {
                continue;
            };
            let parsed = match pending {
                PendingPose::Raw(raw) => parse_pose(&raw),
                PendingPose::Parsed(p) => Ok(*p),
            };
            match parsed {
                Ok(p) => {
                    if self.reference.is_none() {
                        if let Some(o) = p.origin {
                            self.reference = Some((o, LocalEnu::new(o.lat, o.lon, o.alt)));
                        }
                    }
                    let (xy, frame) = self.map_position(&p);
                    let max_points = self.cfg.track_points;
                    if let Some(v) = self.vehicles.get_mut(&id) {
                        // A track lives in one frame: a vehicle that gains a GNSS origin
                        // (or gets a new one, after a restart) starts a new track rather
                        // than drawing a line across the map from its old frame.
                        let track_frame = (frame, p.origin);
                        if v.track_frame != Some(track_frame) {
                            v.track.clear();
                            v.last_track_us = None;
                            v.track_frame = Some(track_frame);
                        }
                        if v.last_track_us.is_none_or(|t| now - t >= TRACK_INTERVAL_US) {
                            v.last_track_us = Some(now);
                            v.track.push_back(xy);
                            while v.track.len() > max_points {
                                v.track.pop_front();
                            }
                        }
                        v.pose = Some(p);
                        v.placed = Some((xy, frame));
                    }
                }
                Err(message) => {
                    self.counters.rejected += 1;
                    errors.push(FleetInputError {
                        key: format!("{id}/{POSE}"),
                        message,
                    });
                }
            }
        }
        errors
    }

    /// East/north in the map frame and the frame's name: a vehicle with a GNSS origin is
    /// placed relative to the fleet's reference; one without stays in its own frame.
    fn map_position(&self, p: &PoseIn) -> ([f64; 2], &'static str) {
        let local = Vector3::new(p.position[0], p.position[1], p.position[2]);
        match (p.origin, &self.reference) {
            (Some(o), Some((_, reference))) => {
                let (lat, lon, alt) = LocalEnu::new(o.lat, o.lon, o.alt).to_geodetic(local);
                let e = reference.to_enu(lat, lon, alt);
                ([e.x, e.y], "geo")
            }
            _ => ([local.x, local.y], "local"),
        }
    }

    fn presence(&self, v: &Vehicle, now: Micros) -> Presence {
        let age = now - v.last_heard_us;
        if v.token_lost_us.is_some() || age >= secs_us(self.cfg.gone_after_s) {
            Presence::Gone
        } else if age >= secs_us(self.cfg.stale_after_s) {
            Presence::Stale
        } else {
            Presence::Live
        }
    }

    /// The fleet as the page shows it, in slot order; tracks only when asked for.
    pub fn view(&self, now: Micros, with_tracks: bool) -> FleetView {
        let mut vehicles: Vec<VehicleView> = self
            .vehicles
            .iter()
            .map(|(id, v)| self.vehicle_view(id, v, now, with_tracks))
            .collect();
        vehicles.sort_by_key(|v| v.slot);
        FleetView {
            kind: "fleet",
            time_us: now,
            reference: self.reference.map(|(g, _)| g),
            vehicles,
            counters: self.counters,
            monitor: false,
        }
    }

    fn vehicle_view(&self, id: &str, v: &Vehicle, now: Micros, with_tracks: bool) -> VehicleView {
        let service = v.health.as_ref().and_then(|h| h.service.as_ref());
        let sensors = v.health.as_ref().map(|h| h.sensors.as_slice());
        let worst = sensors.and_then(|s| {
            s.iter()
                .filter_map(|s| health_rank(&s.health).map(|r| (r, s.health.as_str())))
                .max_by_key(|(r, _)| *r)
                .map(|(_, h)| h.to_string())
        });
        let unhealthy = sensors
            .unwrap_or_default()
            .iter()
            .filter(|s| health_rank(&s.health).is_some_and(|r| r > 0))
            .map(|s| format!("{}: {}", s.id, s.health))
            .collect();
        let vpe = v.health.as_ref().and_then(|h| h.vpe.as_ref());
        let pose = v.pose.as_ref();
        let placed = v.placed;
        VehicleView {
            id: id.to_string(),
            name: service.map_or_else(
                || id.rsplit('/').next().unwrap_or(id).to_string(),
                |s| s.vehicle.clone(),
            ),
            slot: v.slot,
            presence: self.presence(v, now),
            heard_s_ago: (now - v.last_heard_us).max(0) as f64 / 1e6,
            version: service.map(|s| s.version.clone()),
            dashboard: service.and_then(|s| s.dashboard.clone()),
            restarts: v.restarts,
            valid: pose.map(|p| p.valid),
            invalid_reason: pose.and_then(|p| p.invalid_reason.clone()),
            sources: pose.map(|p| p.sources.clone()).unwrap_or_default(),
            position_std_m: pose.map(|p| {
                (p.position_covariance[0] + p.position_covariance[4])
                    .max(0.0)
                    .sqrt()
            }),
            worst_health: worst,
            unhealthy,
            vpe: vpe.map(|x| match (x.endpoints, x.sending) {
                (0, _) => "off",
                (_, true) => "sending",
                (_, false) => "withheld",
            }),
            vpe_reason: vpe.and_then(|x| x.reason.clone()),
            zenoh: v.health.as_ref().and_then(|h| h.zenoh),
            last_event: v.last_event.clone(),
            frame: placed.map(|(_, f)| f),
            xy: placed.map(|(xy, _)| xy),
            z: pose.map(|p| p.position[2]),
            heading_deg: pose.map(|p| heading_deg(p.orientation)),
            speed_m_s: pose.map(|p| Vector3::from(p.velocity).norm()),
            track: with_tracks.then(|| v.track.iter().copied().collect()),
        }
    }
}

fn secs_us(s: f64) -> Micros {
    (s * 1e6) as Micros
}

/// Severity of a sensor state; None for a disabled sensor (not part of the verdict).
fn health_rank(state: &str) -> Option<u8> {
    match state {
        "ok" => Some(0),
        "degraded" => Some(1),
        "no_data" => Some(2),
        "stale" => Some(3),
        "failed" => Some(4),
        _ => None,
    }
}

/// Compass heading of a body FLU → ENU quaternion (x, y, z, w), degrees in [0, 360).
fn heading_deg(q: [f64; 4]) -> f64 {
    let [x, y, z, w] = q;
    let yaw_enu = (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z));
    (90.0 - yaw_enu.to_degrees()).rem_euclid(360.0)
}

/// A health message's parts, kept with their lists and texts capped; a new start time
/// is a restart (a token that went and came back may only have been the link).
fn apply_health(v: &mut Vehicle, mut h: HealthIn) {
    if let Some(s) = &mut h.service {
        if v.started_us.is_some_and(|t| t != s.started_us) {
            v.restarts += 1;
        }
        v.started_us = Some(s.started_us);
        s.vehicle = truncated(std::mem::take(&mut s.vehicle), MAX_TEXT);
        s.version = truncated(std::mem::take(&mut s.version), MAX_TEXT);
        s.dashboard = s.dashboard.take().map(|d| truncated(d, MAX_TEXT));
    }
    if let Some(vpe) = &mut h.vpe {
        vpe.reason = vpe.reason.take().map(|r| truncated(r, MAX_TEXT));
    }
    h.sensors.truncate(MAX_LIST);
    for s in &mut h.sensors {
        s.id = truncated(std::mem::take(&mut s.id), MAX_TEXT);
    }
    v.health = Some(h);
}

/// `s` cut to at most `max` bytes, on a character boundary.
fn truncated(mut s: String, max: usize) -> String {
    if s.len() > max {
        let mut end = max;
        while !s.is_char_boundary(end) {
            end -= 1;
        }
        s.truncate(end);
    }
    s
}

/// Reads a pose and refuses one with non-finite numbers (nothing invalid is drawn).
fn parse_pose(raw: &[u8]) -> Result<PoseIn, String> {
    let p: PoseIn = serde_json::from_slice(raw).map_err(|e| format!("not a skyfuse pose: {e}"))?;
    check_pose(p)
}

/// A pose with every number finite, its texts and lists capped.
fn check_pose(mut p: PoseIn) -> Result<PoseIn, String> {
    p.sources.truncate(MAX_LIST);
    for s in &mut p.sources {
        *s = truncated(std::mem::take(s), MAX_TEXT);
    }
    p.invalid_reason = p.invalid_reason.map(|r| truncated(r, MAX_TEXT));
    let finite = p
        .position
        .iter()
        .chain(&p.orientation)
        .chain(&p.velocity)
        .chain(&p.position_covariance)
        .all(|x| x.is_finite())
        && p.origin
            .is_none_or(|o| o.lat.is_finite() && o.lon.is_finite() && o.alt.is_finite());
    if !finite {
        return Err("non-finite number in the pose".into());
    }
    Ok(p)
}

#[cfg(test)]
mod tests;
