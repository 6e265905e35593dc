//! Offline runs without any network: a simulated scenario or a recorded flight goes
//! straight through the estimator; trajectories are written as TUM files
//! (`t x y z qx qy qz qw`) with `events.jsonl` and `summary.json`, and scored with the
//! APE metric evo computes ([`crate::eval`]).
//!
//! Output files are a pure function of the input: replaying twice gives byte-identical
//! files (no wall-clock time, no hash-map ordering, fixed number formatting).

use crate::estimator::{
    DebugTopic, Estimator, EstimatorConfig, EstimatorEvent, Event, FusedPose, Mode, Protection,
};
use crate::eval::{evo_ape, ApeOptions, ApeStats, Trajectory};
use crate::fusion::{Fusion, InputList, InputSpec};
use crate::geo::LocalEnu;
use crate::health::HealthConfig;
use crate::rate_limit::{RateLimit, DEFAULT_POSE_RATE_HZ};
use crate::sample::{GnssFixType, Sample, SensorData, SensorKind};
use crate::sim::monte_carlo::Stress;
use crate::sim::scenario::Scenario;
use crate::sim::truth::truth_of;
use crate::source_map::SourceMap;
use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use serde::Serialize;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use thiserror::Error;

/// How often the main filter's state is written to `filter_state.jsonl`, µs.
const FILTER_STATE_INTERVAL_US: i64 = 1_000_000;

#[derive(Debug, Error)]
pub enum OfflineError {
    #[error("cannot create output directory {path}: {source}")]
    CreateDir {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot write {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("trajectory {name}: {source}")]
    Trajectory {
        name: String,
        source: crate::eval::EvalError,
    },
    #[error("--sources {unknown}: no such source or kind in this log; it has {known}")]
    UnknownSources { unknown: String, known: String },
    #[error("--reference {name}: no position source of that name in this log; its position sources: {known}")]
    UnknownReference { name: String, known: String },
    #[error("--reference {name}: none of its {samples} samples has a position ({why}); sources with positions: {known}")]
    ReferenceWithoutPositions {
        name: String,
        samples: usize,
        why: &'static str,
        known: String,
    },
}

/// Accumulates the trajectories and events of one run.
#[derive(Default)]
pub struct Recorder {
    /// The poses the service would have sent: valid ones only.
    pub fused: Trajectory,
    /// The position covariance each of them was sent with (ENU, m²).
    pub fused_cov: Vec<Matrix3<f64>>,
    /// The protection levels each of them was sent with.
    pub fused_pl: Vec<Protection>,
    /// Every pose, valid or not (`fused_all.tum`).
    pub fused_all: Trajectory,
    /// Validity of each recorded pose: (t, valid).
    pub validity: Vec<(f64, bool)>,
    /// The position 1σ (E, N, U) each recorded pose was sent with, m.
    pub fused_all_std: Vec<Vector3<f64>>,
    /// The protection levels each was sent with, horizontal and vertical, m.
    pub fused_all_pl: Vec<[f64; 2]>,
    /// Where a frame of its own was re-anchored: (t, the position and orientation of
    /// the first pose sent after it, valid or not). The horizontal bound of later poses
    /// is relative to it, and so is their error (see `Protection::anchored_us`).
    pub anchors: Vec<(f64, FusedPose)>,
    /// Per recorded pose, the anchor its horizontal bound is from: 0 the frame's
    /// origin, k the k-th of `anchors`.
    pub fused_all_anchor: Vec<usize>,
    last_anchor_us: Option<i64>,
    /// The frame the reference is given in, where it is geodetic (the simulator's
    /// home): a pose with a GNSS origin is put into it through that origin, so its
    /// error is the geodetic one (the origin is itself a fix, with that fix's error).
    pub truth_frame: Option<LocalEnu>,
    /// Airborne or not from the autopilot's land detector (or the simulator's truth):
    /// (t, airborne) at each change.
    pub airborne: Vec<(f64, bool)>,
    /// Per position source, raw (GNSS in local ENU from its first fix, odometry in its
    /// own frame, the autopilot's estimate) or as integrated by the estimator (flow).
    pub sources: SourceMap<Trajectory>,
    /// The position covariance each source pose came with, in its own frame (m²; zero
    /// where it came with none), parallel to `sources`: a reference's own uncertainty.
    pub source_cov: SourceMap<Vec<Matrix3<f64>>>,
    /// Plain flow dead reckoning of each flow source (`<source>_dr`), the baseline.
    pub dead_reckoning: crate::dead_reckoning::FlowDeadReckoning,
    pub events: Vec<String>,
    /// The main filter's state and 1σ once a second, one JSON object per line
    /// (`filter_state.jsonl`: for a developer tracing one flight).
    pub filter_states: Vec<String>,
    last_state_us: Option<i64>,
    /// The service's pose output rate: the poses recorded are the ones it would send.
    pose_rate: RateLimit,
    /// The last pose time seen (the service sends each new pose once).
    last_pose_us: Option<i64>,
    gnss_origin: Option<LocalEnu>,
    /// ENU origins of geodetic estimates, per source.
    geodetic_origins: SourceMap<LocalEnu>,
    /// Newest flow `OF_sum` point taken per source.
    flow_taken: SourceMap<i64>,
    /// Sources with positions and no orientation (GNSS): `()` per id.
    position_only: SourceMap<()>,
    /// Sources whose frame is north-referenced (GNSS, the autopilot's estimate): a
    /// georeferenced estimate is registered to them by a translation alone.
    north_referenced: SourceMap<()>,
    /// Some pose was sent with a GNSS origin (its frame is north-referenced).
    fused_georeferenced: bool,
    /// Time origin, µs (t = 0 in the files).
    pub t0_us: i64,
}

/// The track of source `id`: its key is made once (most samples, the IMU's, are not
/// positions and make none).
fn track<'a>(sources: &'a mut SourceMap<Trajectory>, id: &str) -> &'a mut Trajectory {
    sources.get_or_insert_with(id, Trajectory::default)
}

/// A source pose with the covariance it came with (zero: none), kept parallel.
fn push_source(
    rec: &mut Recorder,
    id: &str,
    t: f64,
    p: Vector3<f64>,
    q: UnitQuaternion<f64>,
    cov: Matrix3<f64>,
) {
    let tr = track(&mut rec.sources, id);
    let n = tr.t.len();
    push(tr, t, p, q);
    if tr.t.len() > n {
        let cov = if cov.iter().all(|v| v.is_finite()) {
            cov
        } else {
            Matrix3::zeros()
        };
        rec.source_cov.get_or_insert_with(id, Vec::new).push(cov);
    }
}

fn push(tr: &mut Trajectory, t: f64, p: Vector3<f64>, q: UnitQuaternion<f64>) {
    if p.iter().all(|v| v.is_finite()) && q.coords.iter().all(|v| v.is_finite()) {
        tr.t.push(t);
        tr.p.push(p);
        tr.q.push(q);
    }
}

impl Recorder {
    /// Poses recorded at the service's default output rate.
    pub fn new(t0_us: i64) -> Self {
        Self::with_pose_rate(t0_us, DEFAULT_POSE_RATE_HZ)
    }

    /// Poses recorded at `pose_rate_hz` (the recorded service's `[output]
    /// pose_rate_hz`; 0: every pose).
    pub fn with_pose_rate(t0_us: i64, pose_rate_hz: f64) -> Self {
        Self {
            t0_us,
            pose_rate: RateLimit::hz(pose_rate_hz),
            ..Self::default()
        }
    }

    fn secs(&self, us: i64) -> f64 {
        (us - self.t0_us) as f64 * 1e-6
    }

    /// Record a sample's own position (before or without fusion).
    pub fn source_sample(&mut self, s: &Sample) {
        let Some(stamp) = s.stamp_us else { return };
        let t = self.secs(stamp);
        self.dead_reckoning.sample(s, t);
        let id: &str = &s.source;
        match &s.data {
            SensorData::Gnss(g) if g.fix != GnssFixType::NoFix && g.lat_deg.is_finite() => {
                let origin = *self
                    .gnss_origin
                    .get_or_insert_with(|| LocalEnu::new(g.lat_deg, g.lon_deg, g.alt_m));
                let p = origin.to_enu(g.lat_deg, g.lon_deg, g.alt_m);
                let cov = g.position_cov.as_deref().copied().unwrap_or_default();
                self.position_only.get_or_insert_with(id, || ());
                self.north_referenced.get_or_insert_with(id, || ());
                push_source(self, id, t, p, UnitQuaternion::identity(), cov);
            }
            SensorData::Odometry(o) => {
                let cov = o
                    .pose_cov
                    .map(|c| c.fixed_view::<3, 3>(0, 0).into_owned())
                    .unwrap_or_default();
                push_source(self, id, t, o.position, o.orientation, cov);
            }
            SensorData::VehicleState(v) => {
                if let Some(l) = v.landed {
                    self.set_airborne(t, l != crate::sample::LandedState::OnGround);
                }
            }
            SensorData::AutopilotEstimate(a) => {
                let q = a
                    .yaw
                    .map(|y| UnitQuaternion::from_euler_angles(0.0, 0.0, y))
                    .unwrap_or_else(UnitQuaternion::identity);
                // A local position as it is; a geodetic one (GLOBAL_POSITION_INT, a
                // simulator's SIM_STATE) in ENU about its own first position.
                let p = a.local_position.or_else(|| {
                    let (lat, lon, alt) = a.geodetic?;
                    let o = *self
                        .geodetic_origins
                        .get_or_insert_with(id, || LocalEnu::new(lat, lon, alt));
                    Some(o.to_enu(lat, lon, alt))
                });
                if let Some(p) = p {
                    self.north_referenced.get_or_insert_with(id, || ());
                    push_source(self, id, t, p, q, Matrix3::zeros());
                }
            }
            _ => {}
        }
    }

    /// The vehicle is (or is not) in the air from `t` on.
    pub fn set_airborne(&mut self, t: f64, airborne: bool) {
        if self.airborne.last().is_none_or(|&(_, a)| a != airborne) {
            self.airborne.push((t, airborne));
        }
    }

    /// Record what the estimator produced after a sample.
    pub fn estimator_output(&mut self, est: &Estimator, events: &[EstimatorEvent]) {
        for e in events {
            self.events
                .push(e.to_json(self.secs(e.time_us), false).to_string());
        }
        if let Some(p) = est.debug().series.get(&DebugTopic::OfSum) {
            let taken = self.flow_taken.get_or_insert_with(&p.source, || i64::MIN);
            if p.time_us > *taken {
                *taken = p.time_us;
                let t = self.secs(p.time_us);
                let v = Vector3::from(p.value);
                let tr = track(&mut self.sources, &p.source);
                push(tr, t, v, UnitQuaternion::identity());
            }
        }
        // The pose's time first: most samples come within the output interval.
        let Some(time_us) = est.pose_time() else {
            return;
        };
        if self
            .last_state_us
            .is_none_or(|l| time_us >= l + FILTER_STATE_INTERVAL_US)
        {
            if let Some((x, var, names)) = est.filter_state() {
                self.last_state_us = Some(time_us);
                let mut state = serde_json::Map::new();
                for ((name, x), var) in names.iter().zip(&x).zip(&var) {
                    state.insert(name.clone(), serde_json::json!([x, var.max(0.0).sqrt()]));
                }
                let line = serde_json::json!({"t": self.secs(time_us), "state": state});
                self.filter_states.push(line.to_string());
            }
        }
        // As the pipeline does: each new pose once, through the output's rate limit.
        if self.last_pose_us == Some(time_us) {
            return;
        }
        self.last_pose_us = Some(time_us);
        if !self.pose_rate.due(time_us) {
            return;
        }
        let Some(mut pose) = est.pose() else { return };
        self.fused_georeferenced |= pose.origin.is_some();
        if let (Some(home), Some((lat, lon, alt))) = (self.truth_frame, pose.origin) {
            let (la, lo, al) = LocalEnu::new(lat, lon, alt).to_geodetic(pose.position);
            pose.position = home.to_enu(la, lo, al);
        }
        let t = self.secs(pose.time_us);
        push(&mut self.fused_all, t, pose.position, pose.orientation);
        self.validity.push((t, pose.valid));
        self.fused_all_std
            .push(pose.position_cov.diagonal().map(|v| v.max(0.0).sqrt()));
        self.fused_all_pl
            .push([pose.protection.horizontal_m, pose.protection.vertical_m]);
        let anchor = pose.protection.anchored_us;
        if anchor.is_some() && anchor != self.last_anchor_us {
            self.anchors.push((t, pose.clone()));
        }
        self.last_anchor_us = anchor;
        self.fused_all_anchor
            .push(anchor.map_or(0, |_| self.anchors.len()));
        if pose.valid {
            let before = self.fused.t.len();
            push(&mut self.fused, t, pose.position, pose.orientation);
            if self.fused.t.len() > before {
                self.fused_cov.push(pose.position_cov);
                self.fused_pl.push(pose.protection);
            }
        }
    }

    /// An event of the run itself (not the estimator's), at `t_s` of the run.
    pub fn event(&mut self, t_s: f64, source: Option<&str>, message: &str, what: Event) {
        let e = EstimatorEvent::new(0, source, message.to_string(), what);
        self.events.push(e.to_json(t_s, false).to_string());
    }
}

/// APE of one trajectory against the reference.
#[derive(Debug, Clone, Serialize)]
pub struct Score {
    pub name: String,
    pub poses: usize,
    /// SE(3)-aligned (`evo_ape -a`).
    pub ape: Option<ApeStats>,
    /// Aligned at the first pose only (`evo_ape --align_origin`): an offset the run
    /// carries from its start counts in full.
    pub ape_origin: Option<ApeStats>,
}

/// How much of the time the estimate was valid (what an autopilot gets).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Availability {
    /// Seconds from the first to the last recorded pose.
    pub span_s: f64,
    /// Fraction of that span with a valid estimate.
    pub valid_fraction: f64,
    /// Longest stretch without a valid estimate after the first valid one, s.
    pub longest_invalid_s: f64,
    /// Airborne seconds (land detector or truth), if known.
    pub airborne_s: Option<f64>,
    /// Fraction of the airborne time with a valid estimate.
    pub airborne_valid_fraction: Option<f64>,
    /// Longest airborne stretch without a valid estimate, s.
    pub airborne_longest_invalid_s: Option<f64>,
}

/// Availability from the validity ticks and the airborne changes.
fn availability(validity: &[(f64, bool)], airborne: &[(f64, bool)]) -> Availability {
    // In the air at `t`: the last change at or before it (on the ground before the first).
    let air_at = |t: f64| -> bool {
        let i = airborne.partition_point(|(ta, _)| *ta <= t);
        i > 0 && airborne[i - 1].1
    };
    let mut span = 0.0;
    let mut valid = 0.0;
    let mut air = 0.0;
    let mut air_valid = 0.0;
    let (mut gap, mut longest, mut air_gap, mut air_longest) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    let mut seen_valid = false;
    for w in validity.windows(2) {
        let (t, ok) = w[0];
        let dt = (w[1].0 - t).max(0.0);
        span += dt;
        seen_valid |= ok;
        if ok {
            valid += dt;
            gap = 0.0;
        } else if seen_valid {
            gap += dt;
            longest = longest.max(gap);
        }
        if air_at(t) {
            air += dt;
            if ok {
                air_valid += dt;
                air_gap = 0.0;
            } else {
                air_gap += dt;
                air_longest = air_longest.max(air_gap);
            }
        } else {
            air_gap = 0.0;
        }
    }
    // Airborne before the first pose (the filter not started yet) counts as invalid: a
    // flight whose filter starts only at its landing is not valid throughout
    // (randomised draw 189 read "100 %" over its last 4 s of 155).
    let first_pose = validity.first().map_or(0.0, |v| v.0);
    let mut uncovered = 0.0;
    for (i, &(ta, a)) in airborne.iter().enumerate() {
        if a {
            let next = airborne.get(i + 1).map_or(first_pose, |n| n.0);
            let before = (next.min(first_pose) - ta).max(0.0);
            air_longest = air_longest.max(before);
            uncovered += before;
        }
    }
    air += uncovered;
    let known = !airborne.is_empty();
    Availability {
        span_s: span,
        valid_fraction: if span > 0.0 { valid / span } else { 0.0 },
        longest_invalid_s: longest,
        airborne_s: known.then_some(air),
        airborne_valid_fraction: (known && air > 0.0).then(|| air_valid / air),
        airborne_longest_invalid_s: known.then_some(air_longest),
    }
}

/// Whether "valid" kept its promise: the reference inside the uncertainty sent with
/// each valid pose. Errors per axis of the reference's frame (E, N, U) over the σ sent
/// (rotated into that frame where the estimate had to be aligned).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Consistency {
    /// Valid poses compared with the reference.
    pub poses: usize,
    /// How the estimate was put into the reference's frame: `none` (the simulator's
    /// truth shares the estimator's frame) or `origin` (the first matched poses made
    /// one, as `evo_ape --align_origin`: a frame registration, not a fit to the errors,
    /// so an offset carried from the start counts).
    pub alignment: &'static str,
    /// Per axis: the fraction of poses within 3σ.
    pub within_3_sigma: [f64; 3],
    /// Poses with any axis beyond 5σ.
    pub beyond_5_sigma: usize,
    /// The largest |error| / σ on any axis, where (s into the run) and on which axis.
    pub worst_ratio: f64,
    pub worst_t: f64,
    pub worst_axis: usize,
    /// Mean position NEES, eᵀ Σ⁻¹ e (3 expected for a consistent filter).
    pub nees_mean: f64,
    /// Per axis, the mean of e² / σ² (1 expected): below 1/3 the σ sent is more than
    /// √3 times too large, above 3 too small.
    pub nees_axis: [f64; 3],
    /// Valid poses whose true error is beyond the protection level they were sent with
    /// (horizontal or vertical): integrity failures, the headline figure.
    pub integrity_failures: usize,
    /// The largest error over protection level of any valid pose, horizontal or
    /// vertical (below 1: every pose inside its bound), and when (s into the run).
    pub worst_pl_ratio: f64,
    pub worst_pl_t: f64,
}

impl Consistency {
    /// The promise as the tests hold it: at least 99 % of valid poses within 3σ on
    /// every axis, and none beyond 5σ.
    pub fn kept(&self) -> bool {
        self.within_3_sigma.iter().all(|f| *f >= 0.99) && self.beyond_5_sigma == 0
    }
}

/// The frame registration that puts the estimate's pose `est` onto the reference's
/// `reference`: both are level (z up, gravity), so a translation and, for a frame of
/// its own, a heading.
fn register(
    est: &(Vector3<f64>, UnitQuaternion<f64>),
    reference: &(Vector3<f64>, UnitQuaternion<f64>),
    registration: Option<Registration>,
) -> crate::eval::Sim3 {
    let pose = |p: Vector3<f64>, q: UnitQuaternion<f64>| {
        nalgebra::Isometry3::from_parts(nalgebra::Translation3::from(p), q)
    };
    let to_ref = pose(reference.0, reference.1) * pose(est.0, est.1).inverse();
    // Only the heading: the whole rotation of one instant would carry the two
    // attitudes' roll and pitch difference there (1° is 1.7 m at 100 m) into every
    // later pose as an error.
    let m = to_ref.rotation.to_rotation_matrix();
    let yaw = match registration {
        Some(Registration::Heading) => m[(1, 0)].atan2(m[(0, 0)]),
        _ => 0.0,
    };
    let rotation = *nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), yaw).matrix();
    crate::eval::Sim3 {
        rotation,
        translation: reference.0 - rotation * est.0,
        scale: 1.0,
    }
}

/// Consistency of `estimate` (with `cov` per pose) against `reference` (matched by
/// time within `max_diff_s`); `align`: register the frames at the first matched pose
/// first (a reference in its own frame).
/// How an estimate's frame is registered to the reference's at the first matched
/// pose: both are level (z up), so at most by a heading and a translation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Registration {
    /// Both north-referenced: the origins' offset only.
    Translation,
    /// A frame of its own (odometry, an estimate started without GNSS): its heading too.
    Heading,
}

/// Where a frame of its own was re-anchored (see `Recorder::anchors`): the time, the
/// estimate's pose there with the position covariance and the horizontal protection
/// level it was sent with (its own error is every later pose's, as at take-off), and
/// the reference's pose where it has one then.
struct Anchor {
    t: f64,
    pose: PoseAt,
    cov: Matrix3<f64>,
    hpl: f64,
    reference: Option<PoseAt>,
}
type PoseAt = (Vector3<f64>, UnitQuaternion<f64>);

impl Anchor {
    fn of(t: f64, pose: &FusedPose, reference: Option<PoseAt>) -> Self {
        Self {
            t,
            pose: (pose.position, pose.orientation),
            cov: pose.position_cov,
            hpl: pose.protection.horizontal_m,
            reference,
        }
    }

    /// The horizontal block of the covariance the anchor pose was sent with.
    fn horizontal_cov(&self) -> Matrix3<f64> {
        let mut c = Matrix3::zeros();
        c.fixed_view_mut::<2, 2>(0, 0)
            .copy_from(&self.cov.fixed_view::<2, 2>(0, 0));
        c
    }
}

#[allow(clippy::too_many_arguments)]
fn consistency(
    reference: &Trajectory,
    reference_cov: Option<&[Matrix3<f64>]>,
    estimate: &Trajectory,
    cov: &[Matrix3<f64>],
    pl: &[Protection],
    anchors: &[Anchor],
    max_diff_s: f64,
    registration: Option<Registration>,
) -> Option<Consistency> {
    let align = registration.is_some();
    let (ie, ir) = crate::eval::matching_time_indices(&estimate.t, &reference.t, max_diff_s, 0.0);
    if ie.len() < 2 {
        return None;
    }
    let (e, r) = (estimate.select(&ie), reference.select(&ir));
    let first = if align {
        register(&(e.p[0], e.q[0]), &(r.p[0], r.q[0]), registration)
    } else {
        crate::eval::Sim3 {
            rotation: Matrix3::identity(),
            translation: Vector3::zeros(),
            scale: 1.0,
        }
    };
    let mut rot = first;
    let mut within = [0usize; 3];
    let (mut beyond, mut worst, mut worst_t, mut worst_axis, mut nees) = (0, 0.0f64, 0.0, 0, 0.0);
    let mut nees_axis = [0.0; 3];
    let (mut failures, mut worst_pl, mut worst_pl_t) = (0, 0.0f64, 0.0);
    // Registered at the first matched pose, every later pose inherits that pose's own
    // error: its covariance counts too (the correlation between the two, which would
    // lessen it, is not known here).
    let registration_cov = if align { cov[ie[0]] } else { Matrix3::zeros() };
    // From an anchor, the height's part of the take-off registration (the horizontal
    // one is the anchor's).
    let mut vertical_registration_cov = Matrix3::zeros();
    vertical_registration_cov[(2, 2)] = registration_cov[(2, 2)];
    // The anchor in force (see `Anchor`), by its index: the estimate registered to the
    // reference there, horizontally (the height keeps the first pose's registration).
    let mut anchored: Option<usize> = None;
    for (k, &i) in ie.iter().enumerate() {
        let anchor = pl
            .get(i)
            .and_then(|p| p.anchored_us)
            .and_then(|_| anchors.iter().rposition(|a| a.t <= e.t[k]));
        // The reference where the pose was: between its samples on either side (a
        // truth logged at 10 Hz is 0.4 m from the nearest sample at 4 m/s).
        let rp = interpolated(reference, e.t[k], max_diff_s).unwrap_or(r.p[k]);
        if anchor != anchored {
            rot = match anchor {
                Some(a) => {
                    // Where the reference was at the anchor; else (none then) at this
                    // pose, the first valid one after it.
                    let (est, reference) = match anchors[a].reference {
                        Some(reference) => (anchors[a].pose, reference),
                        None => ((e.p[k], e.q[k]), (rp, r.q[k])),
                    };
                    let mut at = register(
                        &est,
                        &reference,
                        registration.or(Some(Registration::Translation)),
                    );
                    if !align {
                        at.rotation = Matrix3::identity();
                        at.translation = reference.0 - est.0;
                    }
                    at.translation.z = first.translation.z;
                    at
                }
                None => first,
            };
            anchored = anchor;
        }
        let err = rot.apply(&e.p[k]) - rp;
        let registration = match anchored {
            Some(a) => anchors[a].horizontal_cov() + vertical_registration_cov,
            None => registration_cov,
        };
        // The reference's own uncertainty, in its frame, where it has one (GNSS, an
        // odometry's covariance): the difference of two estimates has both.
        let own = reference_cov
            .and_then(|c| c.get(ir[k]))
            .copied()
            .unwrap_or_default();
        let c = rot.rotation * (cov[i] + registration) * rot.rotation.transpose() + own;
        // The protection level bounds the error in the estimate's own frame (the one
        // it was sent in); a registration's error is the estimate's at that pose.
        if let Some(p) = pl.get(i) {
            let e_own = rot.rotation.transpose() * err;
            let reg = pl.get(ie[0]).filter(|_| align);
            let reg_h = match anchored {
                Some(a) => anchors[a].hpl,
                None => reg.map_or(0.0, |r| r.horizontal_m),
            };
            let (h, v) = (
                p.horizontal_m + reg_h,
                p.vertical_m + reg.map_or(0.0, |r| r.vertical_m),
            );
            let ratio = (e_own.xy().norm() / h.max(1e-9)).max(e_own.z.abs() / v.max(1e-9));
            failures += usize::from(ratio > 1.0);
            if ratio > worst_pl {
                (worst_pl, worst_pl_t) = (ratio, e.t[k]);
            }
        }
        let mut out = false;
        for a in 0..3 {
            nees_axis[a] += err[a] * err[a] / c[(a, a)].max(1e-12);
            let ratio = err[a].abs() / c[(a, a)].max(1e-12).sqrt();
            if ratio <= 3.0 {
                within[a] += 1;
            }
            out |= ratio > 5.0;
            if ratio > worst {
                (worst, worst_t, worst_axis) = (ratio, e.t[k], a);
            }
        }
        beyond += usize::from(out);
        nees += c
            .try_inverse()
            .map_or(f64::INFINITY, |ci| (err.transpose() * ci * err)[(0, 0)]);
    }
    let n = ie.len() as f64;
    Some(Consistency {
        poses: ie.len(),
        alignment: if align { "origin" } else { "none" },
        within_3_sigma: within.map(|w| w as f64 / n),
        beyond_5_sigma: beyond,
        worst_ratio: worst,
        worst_t,
        worst_axis,
        nees_mean: nees / n,
        nees_axis: nees_axis.map(|x| x / n),
        integrity_failures: failures,
        worst_pl_ratio: worst_pl,
        worst_pl_t,
    })
}

/// What one run wrote and measured.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    pub input: String,
    pub mode: &'static str,
    pub samples: u64,
    pub fused_poses: usize,
    pub events: usize,
    pub reference: String,
    /// Scored time window, s, if limited (default: the whole run).
    pub window_s: Option<(f64, f64)>,
    /// `fused` is scored on the valid poses only: what the service would have sent.
    pub availability: Availability,
    /// APE of each trajectory against the reference, SE(3)- and origin-aligned.
    pub scores: Vec<Score>,
    /// The valid poses' errors against the σ they were sent with.
    pub consistency: Option<Consistency>,
    pub files: Vec<String>,
}

impl Summary {
    /// The fused score and the best single source's.
    pub fn fused_and_best_source(&self) -> (Option<f64>, Option<(String, f64)>) {
        let fused = self
            .scores
            .iter()
            .find(|s| s.name == "fused")
            .and_then(|s| s.ape.as_ref().map(|a| a.rmse));
        let best = self
            .scores
            .iter()
            .filter(|s| s.name != "fused")
            .filter_map(|s| s.ape.as_ref().map(|a| (s.name.clone(), a.rmse)))
            .min_by(|a, b| a.1.total_cmp(&b.1));
        (fused, best)
    }
}

fn write_file(dir: &Path, name: &str, text: &str) -> Result<String, OfflineError> {
    let path = dir.join(name);
    let mut f = std::fs::File::create(&path).map_err(|source| OfflineError::Write {
        path: path.clone(),
        source,
    })?;
    f.write_all(text.as_bytes())
        .map_err(|source| OfflineError::Write {
            path: path.clone(),
            source,
        })?;
    Ok(name.to_string())
}

/// How trajectories are scored.
pub enum Reference<'a> {
    /// The simulator's truth, evaluated at each trajectory's own times.
    Truth(&'a dyn Fn(f64) -> (Vector3<f64>, UnitQuaternion<f64>)),
    /// The same, for an estimate in a frame of its own (no GNSS: its start, turned by
    /// the autopilot's heading then): registered at the first valid pose to be scored.
    TruthInOwnFrame(&'a dyn Fn(f64) -> (Vector3<f64>, UnitQuaternion<f64>)),
    /// One of the recorded sources (e.g. `vio`), associated by time (`max_diff_s`).
    Source { name: &'a str, max_diff_s: f64 },
}

fn tum(name: &str, tr: &Trajectory) -> Result<String, OfflineError> {
    tr.to_tum().map_err(|source| OfflineError::Trajectory {
        name: name.to_string(),
        source,
    })
}

/// `t sigma_e sigma_n sigma_u valid hpl vpl anchor` per recorded pose: the uncertainty
/// and the protection levels each pose was sent with beside `fused_all.tum`, to plot
/// against the error, and the anchor its horizontal bound is from (0: the origin; k:
/// the k-th re-anchoring, at the first pose that has k).
fn sigma_text(rec: &Recorder) -> String {
    let mut out = Vec::with_capacity(rec.validity.len() * 64);
    out.extend_from_slice(b"# t sigma_e sigma_n sigma_u valid hpl vpl anchor\n");
    let poses = rec.validity.iter().zip(&rec.fused_all_std);
    for ((((t, valid), s), pl), anchor) in poses.zip(&rec.fused_all_pl).zip(&rec.fused_all_anchor) {
        crate::eval::push_fixed(&mut out, *t, 6);
        for v in s.iter() {
            out.push(b' ');
            crate::eval::push_fixed(&mut out, *v, 4);
        }
        out.extend_from_slice(if *valid { b" 1" } else { b" 0" });
        for v in pl {
            out.push(b' ');
            crate::eval::push_fixed(&mut out, *v, 3);
        }
        out.extend_from_slice(format!(" {anchor}\n").as_bytes());
    }
    String::from_utf8(out).unwrap_or_default()
}

/// APE with SE(3) alignment (`evo_ape -a`); where the trajectory is too degenerate to
/// align (a hover is nearly a vertical line), aligned at the first pose instead
/// (`--align_origin`).
fn ape_aligned(r: &Trajectory, e: &Trajectory, opts: ApeOptions) -> Option<ApeStats> {
    evo_ape(
        r,
        e,
        &ApeOptions {
            align: true,
            ..opts
        },
    )
    .or_else(|_| {
        evo_ape(
            r,
            e,
            &ApeOptions {
                align_origin: true,
                ..opts
            },
        )
    })
    .ok()
}

/// A reference with positions only (GNSS) given the estimate's orientation at each of
/// its poses (the nearest in time), so that registering the estimate at a first pose
/// moves it and never turns it: both are in the one geographic ENU frame, and the
/// reference's placeholder orientation (identity: facing east) would turn the estimate
/// by its heading at that pose.
fn with_orientation_of(r: &Trajectory, est: &Trajectory) -> Trajectory {
    let mut out = r.clone();
    if est.t.is_empty() {
        return out;
    }
    for (q, &t) in out.q.iter_mut().zip(&r.t) {
        let i = est.t.partition_point(|&x| x < t);
        let nearest = match (i.checked_sub(1), est.t.get(i)) {
            (Some(a), Some(&b)) if t - est.t[a] <= b - t => a,
            (_, Some(_)) => i,
            (Some(a), None) => a,
            (None, None) => continue,
        };
        *q = est.q[nearest];
    }
    out
}

/// Keep the poses with `t` inside `window` (s).
fn windowed(tr: &Trajectory, window: Option<(f64, f64)>) -> Trajectory {
    let Some((a, b)) = window else {
        return tr.clone();
    };
    let mut out = Trajectory::default();
    for i in 0..tr.t.len() {
        if tr.t[i] >= a && tr.t[i] <= b {
            out.t.push(tr.t[i]);
            out.p.push(tr.p[i]);
            out.q.push(tr.q[i]);
        }
    }
    out
}

/// A reference is interpolated between samples at most this far apart, s.
const INTERPOLATED_SPAN_S: f64 = 0.5;

/// The reference's position at `t`, between its samples on either side (at most
/// [`INTERPOLATED_SPAN_S`] apart), where one of them is within `max_diff_s` of it.
fn interpolated(r: &Trajectory, t: f64, max_diff_s: f64) -> Option<Vector3<f64>> {
    let j = r.t.partition_point(|&x| x < t);
    if r.t.get(j) == Some(&t) {
        return Some(r.p[j]);
    }
    let (t0, t1) = (*r.t.get(j.checked_sub(1)?)?, *r.t.get(j)?);
    if (t - t0).min(t1 - t) > max_diff_s || t1 - t0 > INTERPOLATED_SPAN_S || t1 <= t0 {
        return None;
    }
    let f = (t - t0) / (t1 - t0);
    Some(r.p[j - 1] + (r.p[j] - r.p[j - 1]) * f)
}

/// The reference's pose nearest `t` within `max_diff_s`, if any (the position
/// between its samples where it can be).
fn reference_at(r: &Trajectory, t: f64, max_diff_s: f64) -> Option<PoseAt> {
    let i = r.t.partition_point(|&x| x < t);
    [i.checked_sub(1), Some(i)]
        .into_iter()
        .flatten()
        .filter(|&j| j < r.t.len() && (r.t[j] - t).abs() <= max_diff_s)
        .min_by(|&a, &b| (r.t[a] - t).abs().total_cmp(&(r.t[b] - t).abs()))
        .map(|j| (interpolated(r, t, max_diff_s).unwrap_or(r.p[j]), r.q[j]))
}

/// The truth at each of `times`.
fn truth_at(
    truth: &dyn Fn(f64) -> (Vector3<f64>, UnitQuaternion<f64>),
    times: &[f64],
) -> Trajectory {
    let mut tr = Trajectory::default();
    for &t in times {
        let (p, q) = truth(t);
        tr.t.push(t);
        tr.p.push(p);
        tr.q.push(q);
    }
    tr
}

/// What a run was fed, for its summary.
struct RunInput {
    name: String,
    mode: Mode,
    samples: u64,
}

/// Write every trajectory, the events and the summary; score against `reference`
/// (SE(3)-aligned APE, as `evo_ape tum ref est -a`) over `window` (s) if given.
fn finish(
    rec: &Recorder,
    reference: Reference<'_>,
    window: Option<(f64, f64)>,
    out: &Path,
    input: RunInput,
) -> Result<Summary, OfflineError> {
    std::fs::create_dir_all(out).map_err(|source| OfflineError::CreateDir {
        path: out.to_path_buf(),
        source,
    })?;
    let mut files = Vec::new();
    if let Reference::Truth(truth) | Reference::TruthInOwnFrame(truth) = &reference {
        let t = truth_at(*truth, &rec.fused.t);
        files.push(write_file(out, "truth.tum", &tum("truth", &t)?)?);
        // At every pose, valid or not, beside `fused_all.tum`.
        let t = truth_at(*truth, &rec.fused_all.t);
        files.push(write_file(out, "truth_all.tum", &tum("truth_all", &t)?)?);
    }
    files.push(write_file(out, "fused.tum", &tum("fused", &rec.fused)?)?);
    files.push(write_file(
        out,
        "fused_all.tum",
        &tum("fused_all", &rec.fused_all)?,
    )?);
    files.push(write_file(out, "fused_sigma.txt", &sigma_text(rec))?);
    // The sources as they report themselves, then the flow dead reckoning baselines.
    let tracks = || rec.sources.iter().chain(rec.dead_reckoning.out.iter());
    for (name, tr) in tracks() {
        files.push(write_file(out, &format!("{name}.tum"), &tum(name, tr)?)?);
    }
    let mut events = rec.events.join("\n");
    if !events.is_empty() {
        events.push('\n');
    }
    files.push(write_file(out, "events.jsonl", &events)?);
    let mut states = rec.filter_states.join("\n");
    if !states.is_empty() {
        states.push('\n');
    }
    files.push(write_file(out, "filter_state.jsonl", &states)?);

    let (scores, consistency) = score(rec, &reference, window);
    files.push("summary.json".into());
    let summary = Summary {
        input: input.name,
        mode: input.mode.as_str(),
        samples: input.samples,
        fused_poses: rec.fused.t.len(),
        events: rec.events.len(),
        reference: match reference {
            Reference::Truth(_) | Reference::TruthInOwnFrame(_) => "truth".into(),
            Reference::Source { name, .. } => name.into(),
        },
        window_s: window,
        availability: availability(&rec.validity, &rec.airborne),
        scores,
        consistency,
        files,
    };
    let text = serde_json::to_string_pretty(&summary).unwrap_or_default() + "\n";
    write_file(out, "summary.json", &text)?;
    Ok(summary)
}

/// The APE of the fused track and of every source's against the reference, and the
/// valid poses' consistency with it.
fn score(
    rec: &Recorder,
    reference: &Reference<'_>,
    window: Option<(f64, f64)>,
) -> (Vec<Score>, Option<Consistency>) {
    let tracks = || rec.sources.iter().chain(rec.dead_reckoning.out.iter());
    let mut scores = Vec::new();
    let mut score = |name: &str, tr: &Trajectory| {
        let tr = windowed(tr, window);
        let (r, opts) = match reference {
            Reference::Truth(truth) | Reference::TruthInOwnFrame(truth) => {
                (Some(truth_at(*truth, &tr.t)), ApeOptions::default())
            }
            Reference::Source {
                name: rn,
                max_diff_s,
            } => (
                rec.sources.get(rn).map(|r| {
                    let r = windowed(r, window);
                    if rec.position_only.get(rn).is_some() {
                        with_orientation_of(&r, &tr)
                    } else {
                        r
                    }
                }),
                ApeOptions {
                    max_diff_s: *max_diff_s,
                    ..ApeOptions::default()
                },
            ),
        };
        let ape = r.as_ref().and_then(|r| ape_aligned(r, &tr, opts));
        let ape_origin = r.as_ref().and_then(|r| {
            evo_ape(
                r,
                &tr,
                &ApeOptions {
                    align_origin: true,
                    ..opts
                },
            )
            .ok()
        });
        scores.push(Score {
            name: name.to_string(),
            poses: tr.t.len(),
            ape,
            ape_origin,
        });
    };
    score("fused", &rec.fused);
    for (name, tr) in tracks() {
        if matches!(reference, Reference::Source { name: rn, .. } if *rn == name) {
            continue;
        }
        score(name, tr);
    }
    let consistency = match reference {
        Reference::Truth(truth) | Reference::TruthInOwnFrame(truth) => {
            let t = truth_at(*truth, &rec.fused.t);
            let register =
                matches!(reference, Reference::TruthInOwnFrame(_)).then_some(Registration::Heading);
            let anchors: Vec<Anchor> = rec
                .anchors
                .iter()
                .map(|(ta, p)| Anchor::of(*ta, p, Some(truth(*ta))))
                .collect();
            consistency(
                &t,
                None,
                &rec.fused,
                &rec.fused_cov,
                &rec.fused_pl,
                &anchors,
                1e-9,
                register,
            )
        }
        Reference::Source { name, max_diff_s } => rec.sources.get(name).and_then(|r| {
            let own = rec.source_cov.get(name).map(Vec::as_slice);
            let oriented;
            let r = if rec.position_only.get(name).is_some() {
                oriented = with_orientation_of(r, &rec.fused);
                &oriented
            } else {
                r
            };
            // Two north-referenced frames differ by their origins alone; a heading
            // registered at one pose would turn every later error by that pose's
            // heading difference.
            let registration =
                if rec.fused_georeferenced && rec.north_referenced.get(name).is_some() {
                    Registration::Translation
                } else {
                    Registration::Heading
                };
            let anchors: Vec<Anchor> = rec
                .anchors
                .iter()
                .map(|(ta, p)| Anchor::of(*ta, p, reference_at(r, *ta, *max_diff_s)))
                .collect();
            consistency(
                r,
                own,
                &rec.fused,
                &rec.fused_cov,
                &rec.fused_pl,
                &anchors,
                *max_diff_s,
                Some(registration),
            )
        }),
    };
    (scores, consistency)
}

/// Run a simulated scenario through the estimator.
pub fn run_scenario(
    scn: &Scenario,
    seed: u64,
    duration_s: f64,
    cfg: EstimatorConfig,
    health: HealthConfig,
    out: &Path,
    progress: &mut dyn FnMut(f64),
) -> Result<Summary, OfflineError> {
    let mode = cfg.mode;
    let (rec, samples) = fly(scn, seed, duration_s, cfg, health, progress);
    let input = RunInput {
        name: format!("scenario {} (seed {seed}, {duration_s} s)", scn.name),
        mode,
        samples,
    };
    let profile = scn.profile;
    let truth = move |t: f64| {
        let s = truth_of(profile, t);
        (s.position, s.attitude)
    };
    finish(&rec, Reference::Truth(&truth), None, out, input)
}

/// Fly a simulated scenario through the service's fusion (checks, estimator, health),
/// recording what it would have sent; returns the record and the samples fed.
fn fly(
    scn: &Scenario,
    seed: u64,
    duration_s: f64,
    cfg: EstimatorConfig,
    health: HealthConfig,
    progress: &mut dyn FnMut(f64),
) -> (Recorder, u64) {
    let sim = scn.simulator(seed, duration_s);
    let home = sim.origin();
    let inputs: InputList = scn
        .streams
        .iter()
        .map(|s| InputSpec::new(s.input_id, s.kind, s.rate_hz))
        .collect();
    let mut fusion = Fusion::new(cfg, health, &inputs);
    let mut rec = Recorder::new(0);
    rec.truth_frame = Some(home);
    for f in &scn.faults {
        rec.event(
            f.start_s,
            Some(&f.sensor),
            &format!("sim: fault {} on {} starts", f.kind.as_str(), f.sensor),
            Event::FaultInjected,
        );
        if f.end_s.is_finite() {
            rec.event(
                f.end_s,
                Some(&f.sensor),
                &format!("sim: fault {} on {} ends", f.kind.as_str(), f.sensor),
                Event::FaultCleared,
            );
        }
    }
    let mut samples = 0u64;
    let mut last_progress = 0.0;
    let profile = scn.profile;
    for ev in sim {
        rec.set_airborne(
            ev.publish_t,
            truth_of(profile, ev.publish_t).position.z > 0.05,
        );
        let spec = scn.streams[ev.stream];
        let s = Sample {
            source: spec.input_id.into(),
            stamp_us: Some((ev.measured_t * 1e6).round() as i64),
            arrival_us: (ev.publish_t * 1e6).round() as i64,
            data: ev.data,
        };
        samples += 1;
        rec.source_sample(&s);
        let events = fusion.process(&s, s.arrival_us);
        rec.estimator_output(&fusion.est, &events);
        if ev.publish_t - last_progress >= 1.0 {
            last_progress = ev.publish_t;
            progress(ev.publish_t / duration_s);
        }
    }
    progress(1.0);
    // Faults scheduled in order of time, among the estimator's own events.
    rec.events
        .sort_by(|a, b| event_time(a).total_cmp(&event_time(b)));
    (rec, samples)
}

/// What one randomised flight measured (see [`crate::sim::monte_carlo`]).
#[derive(Debug, Clone, Serialize)]
pub struct DrawResult {
    pub index: u64,
    pub seed: u64,
    pub family: String,
    pub description: String,
    pub duration_s: f64,
    pub samples: u64,
    pub availability: Availability,
    /// Scored against the truth in the frame the estimate is sent in: GNSS's, else the
    /// vehicle's own, registered at the first valid pose.
    pub frame: &'static str,
    pub consistency: Option<Consistency>,
    /// SE(3)-aligned APE RMSE of the valid poses, m.
    pub fused_rmse_m: Option<f64>,
    /// The best single source's (its own track) and the flow dead reckoning's, m.
    pub best_single: Option<(String, f64)>,
    pub flow_dead_reckoning_m: Option<f64>,
    /// Counts of the estimator's events by kind.
    pub events: BTreeMap<String, usize>,
}

impl DrawResult {
    /// Valid poses beyond their protection level.
    pub fn integrity_failures(&self) -> usize {
        self.consistency
            .as_ref()
            .map_or(0, |c| c.integrity_failures)
    }

    /// The fused track no farther from the truth than each single source and the flow
    /// dead reckoning (what fusing should buy), within 1 cm.
    pub fn fused_best(&self) -> bool {
        let Some(f) = self.fused_rmse_m else {
            return true;
        };
        let others = self
            .best_single
            .as_ref()
            .map(|b| b.1)
            .into_iter()
            .chain(self.flow_dead_reckoning_m);
        others.into_iter().all(|o| f <= o + 0.01)
    }
}

/// The truth of a flight: position and attitude at `t`.
type TruthFn = Box<dyn Fn(f64) -> (Vector3<f64>, UnitQuaternion<f64>)>;

/// Draw `index` of a run seeded `seed`, flown through `cfg`: the draw, what was
/// recorded, the samples flown and the flight's truth.
fn fly_draw(
    seed: u64,
    index: u64,
    stress: Stress,
    cfg: EstimatorConfig,
    health: HealthConfig,
) -> (crate::sim::monte_carlo::Draw, Recorder, u64, TruthFn) {
    let draw = crate::sim::monte_carlo::draw_stressed(seed, index, stress);
    let scn = draw.scenario();
    let (rec, samples) = fly(&scn, draw.seed, draw.duration_s(), cfg, health, &mut |_| {});
    let profile = scn.profile;
    let truth: TruthFn = Box::new(move |t: f64| {
        let s = truth_of(profile, t);
        (s.position, s.attitude)
    });
    (draw, rec, samples, truth)
}

/// A draw with a GNSS is scored in the absolute frame, else in its own (registered).
fn draw_reference<'a>(draw: &crate::sim::monte_carlo::Draw, truth: &'a TruthFn) -> Reference<'a> {
    if draw.absolute() {
        Reference::Truth(truth.as_ref())
    } else {
        Reference::TruthInOwnFrame(truth.as_ref())
    }
}

/// Fly randomised flight `index` of a run seeded `seed` and write its files as a
/// scenario run does (truth, fused and source tracks, σ, events, summary) into `out`.
pub fn run_draw_files(
    seed: u64,
    index: u64,
    stress: Stress,
    cfg: EstimatorConfig,
    health: HealthConfig,
    out: &Path,
) -> Result<Summary, OfflineError> {
    let mode = cfg.mode;
    let (draw, rec, samples, truth) = fly_draw(seed, index, stress, cfg, health);
    let reference = draw_reference(&draw, &truth);
    let input = RunInput {
        name: format!(
            "monte-carlo draw {index} of seed {seed}: {}",
            draw.describe()
        ),
        mode,
        samples,
    };
    finish(&rec, reference, None, out, input)
}

/// Fly randomised flight `index` of a run seeded `seed` through `cfg` and score it.
pub fn run_draw(seed: u64, index: u64, cfg: EstimatorConfig, health: HealthConfig) -> DrawResult {
    run_draw_stressed(seed, index, Stress::default(), cfg, health)
}

/// [`run_draw`] with the faults of `stress` on top of the draw's.
pub fn run_draw_stressed(
    seed: u64,
    index: u64,
    stress: Stress,
    cfg: EstimatorConfig,
    health: HealthConfig,
) -> DrawResult {
    let (draw, rec, samples, truth) = fly_draw(seed, index, stress, cfg, health);
    let duration_s = draw.duration_s();
    let reference = draw_reference(&draw, &truth);
    let (scores, consistency) = score(&rec, &reference, None);
    let rmse = |name: &str| {
        scores
            .iter()
            .find(|s| s.name == name)
            .and_then(|s| s.ape.as_ref().map(|a| a.rmse))
    };
    let best_single = scores
        .iter()
        .filter(|s| s.name != "fused" && !s.name.ends_with("_dr"))
        .filter_map(|s| s.ape.as_ref().map(|a| (s.name.clone(), a.rmse)))
        .min_by(|a, b| a.1.total_cmp(&b.1));
    let flow_dead_reckoning_m = scores
        .iter()
        .filter(|s| s.name.ends_with("_dr"))
        .filter_map(|s| s.ape.as_ref().map(|a| a.rmse))
        .min_by(f64::total_cmp);
    let mut events = BTreeMap::new();
    for line in &rec.events {
        let kind = serde_json::from_str::<serde_json::Value>(line)
            .ok()
            .and_then(|v| v["kind"].as_str().map(str::to_string))
            .unwrap_or_default();
        *events.entry(kind).or_insert(0) += 1;
    }
    DrawResult {
        index,
        seed: draw.seed,
        family: draw.family(),
        description: draw.describe(),
        duration_s,
        samples,
        availability: availability(&rec.validity, &rec.airborne),
        frame: if draw.absolute() { "gnss" } else { "own" },
        consistency,
        fused_rmse_m: rmse("fused"),
        best_single,
        flow_dead_reckoning_m,
        events,
    }
}

/// One scenario family's figures over its randomised flights (the Monte Carlo table).
#[derive(Debug, Clone, Serialize)]
pub struct FamilyRow {
    pub family: String,
    pub runs: usize,
    /// Valid poses beyond their protection level, summed, and the runs with any.
    pub integrity_failures: usize,
    pub runs_with_failures: usize,
    /// Valid poses beyond 5σ on any axis, summed.
    pub beyond_5_sigma: usize,
    /// Per axis (E, N, U): the lowest fraction of valid poses within 3σ over the runs.
    pub within_3_sigma_min: [f64; 3],
    /// Per axis: the median and the 5th-95th percentiles of the runs' mean e²/σ².
    pub nees_axis_median: [f64; 3],
    pub nees_axis_p5: [f64; 3],
    pub nees_axis_p95: [f64; 3],
    /// Valid fraction of the airborne time: median and lowest.
    pub availability_median: f64,
    pub availability_min: f64,
    /// Fused RMSE (SE(3)-aligned, valid poses), the best single source's and the flow
    /// dead reckoning's: medians, m.
    pub fused_rmse_median: Option<f64>,
    pub best_single_median: Option<f64>,
    pub flow_dr_median: Option<f64>,
    /// Runs whose fused track is no worse than every single source and the flow dead
    /// reckoning.
    pub fused_best: usize,
}

/// The `q`-quantile of `v` (nearest rank), None when empty.
pub fn quantile(v: &[f64], q: f64) -> Option<f64> {
    let mut v: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let i = ((v.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize;
    Some(v[i])
}

/// The table of `results` by family (sorted by name), and a last row `all`.
pub fn family_rows(results: &[DrawResult]) -> Vec<FamilyRow> {
    let mut by: BTreeMap<&str, Vec<&DrawResult>> = BTreeMap::new();
    for r in results {
        by.entry(r.family.as_str()).or_default().push(r);
    }
    let mut rows: Vec<FamilyRow> = by.iter().map(|(f, rs)| family_row(f, rs)).collect();
    let all: Vec<&DrawResult> = results.iter().collect();
    rows.push(family_row("all", &all));
    rows
}

fn family_row(family: &str, rs: &[&DrawResult]) -> FamilyRow {
    let cons: Vec<&Consistency> = rs.iter().filter_map(|r| r.consistency.as_ref()).collect();
    let axis =
        |f: &dyn Fn(&Consistency) -> f64| -> Vec<f64> { cons.iter().map(|c| f(c)).collect() };
    let mut nees_axis_median = [0.0; 3];
    let mut nees_axis_p5 = [0.0; 3];
    let mut nees_axis_p95 = [0.0; 3];
    let mut within_3_sigma_min = [1.0f64; 3];
    for a in 0..3 {
        let v = axis(&|c| c.nees_axis[a]);
        nees_axis_median[a] = quantile(&v, 0.5).unwrap_or(f64::NAN);
        nees_axis_p5[a] = quantile(&v, 0.05).unwrap_or(f64::NAN);
        nees_axis_p95[a] = quantile(&v, 0.95).unwrap_or(f64::NAN);
        within_3_sigma_min[a] = axis(&|c| c.within_3_sigma[a])
            .into_iter()
            .fold(1.0, f64::min);
    }
    let avail: Vec<f64> = rs
        .iter()
        .map(|r| r.availability.airborne_valid_fraction.unwrap_or(0.0))
        .collect();
    let med = |v: Vec<f64>| quantile(&v, 0.5);
    FamilyRow {
        family: family.to_string(),
        runs: rs.len(),
        integrity_failures: rs.iter().map(|r| r.integrity_failures()).sum(),
        runs_with_failures: rs.iter().filter(|r| r.integrity_failures() > 0).count(),
        beyond_5_sigma: cons.iter().map(|c| c.beyond_5_sigma).sum(),
        within_3_sigma_min,
        nees_axis_median,
        nees_axis_p5,
        nees_axis_p95,
        availability_median: quantile(&avail, 0.5).unwrap_or(0.0),
        availability_min: avail.iter().copied().fold(1.0, f64::min),
        fused_rmse_median: med(rs.iter().filter_map(|r| r.fused_rmse_m).collect()),
        best_single_median: med(rs
            .iter()
            .filter_map(|r| r.best_single.as_ref().map(|b| b.1))
            .collect()),
        flow_dr_median: med(rs.iter().filter_map(|r| r.flow_dead_reckoning_m).collect()),
        fused_best: rs.iter().filter(|r| r.fused_best()).count(),
    }
}

fn event_time(line: &str) -> f64 {
    serde_json::from_str::<serde_json::Value>(line)
        .ok()
        .and_then(|v| v["t"].as_f64())
        .unwrap_or(0.0)
}

/// What a replay needs to know of its samples before fusing them: each source's
/// kinds, count and first and last time (its mean rate), and the first sample's stamp.
#[derive(Debug, Default, PartialEq)]
pub(crate) struct SampleSurvey {
    sources: SourceMap<SourceSurvey>,
    /// The first sample's time and stamp.
    first: Option<(i64, Option<i64>)>,
    samples: usize,
}

/// One source's samples, as [`SampleSurvey`] saw them.
#[derive(Debug, PartialEq)]
struct SourceSurvey {
    first_kind: SensorKind,
    /// What `--sources` matches a kind against.
    last_kind: SensorKind,
    /// Any of its samples is the autopilot's armed/landed state.
    vehicle_state: bool,
    count: usize,
    /// Samples that carry a position a track can be made of (an autopilot estimate
    /// without a valid fix has none, a GNSS receiver without a fix neither).
    positions: usize,
    first_t: i64,
    last_t: i64,
}

/// How a survey gets its samples: one sequence (first seen is first, last seen is
/// last), or runs each in time order whose order breaks ties of time (the earliest
/// is first, the latest last).
#[derive(Clone, Copy)]
enum Seen {
    InSequence,
    InRuns,
}

impl SampleSurvey {
    pub(crate) fn of(samples: &dyn SampleSource) -> Self {
        let mut survey = Self::default();
        if !samples.for_each_in_runs(&mut |s| survey.add(s, Seen::InRuns)) {
            samples.for_each(&mut |s| survey.add(s, Seen::InSequence));
        }
        survey
    }

    /// Of the samples in one sequence, as `for_each` gives them.
    #[cfg(test)]
    pub(crate) fn in_sequence(samples: &dyn SampleSource) -> Self {
        let mut survey = Self::default();
        samples.for_each(&mut |s| survey.add(s, Seen::InSequence));
        survey
    }

    fn add(&mut self, s: &Sample, seen: Seen) {
        self.samples += 1;
        let t = s.stamp_us.unwrap_or(s.arrival_us);
        let earlier = |t: i64, than: i64| matches!(seen, Seen::InRuns) && t < than;
        let later = |t: i64, than: i64| matches!(seen, Seen::InSequence) || t >= than;
        if self.first.is_none_or(|(f, _)| earlier(t, f)) {
            self.first = Some((t, s.stamp_us));
        }
        let kind = s.data.kind();
        let e = self.sources.get_or_insert_with(&s.source, || SourceSurvey {
            first_kind: kind,
            last_kind: kind,
            vehicle_state: false,
            count: 0,
            positions: 0,
            first_t: t,
            last_t: t,
        });
        e.count += 1;
        e.positions += usize::from(has_position(&s.data));
        if earlier(t, e.first_t) {
            e.first_t = t;
            e.first_kind = kind;
        }
        if later(t, e.last_t) {
            e.last_t = t;
            e.last_kind = kind;
        }
        e.vehicle_state |= kind == SensorKind::VehicleState;
    }

    /// The inputs of a recording: each source with its kind and mean rate.
    fn inputs(&self) -> InputList {
        self.sources
            .iter()
            .map(|(id, e)| {
                let span = ((e.last_t - e.first_t) as f64 * 1e-6).max(1e-3);
                InputSpec::new(id, e.first_kind, (e.count as f64 / span).max(0.1))
            })
            .collect()
    }
}

/// Samples a replay reads, in time order: a slice in memory, or a log that makes them
/// as they are read (`replay::px4log::UlogSamples`). Read twice: once to survey them,
/// once to fuse.
pub trait SampleSource {
    /// Calls `f` with every sample, in time order.
    fn for_each(&self, f: &mut dyn FnMut(&Sample));
    /// How many samples there are, or about (for progress).
    fn len_hint(&self) -> usize;
    /// Calls `f` with every sample in runs, each in time order, the runs in the order
    /// that breaks ties of time (a log's topics one after another), where that is
    /// cheaper than [`Self::for_each`] and enough (a survey); false, calling nothing,
    /// when there are no such runs.
    fn for_each_in_runs(&self, _f: &mut dyn FnMut(&Sample)) -> bool {
        false
    }
}

impl SampleSource for &[Sample] {
    fn for_each(&self, f: &mut dyn FnMut(&Sample)) {
        self.iter().for_each(f);
    }

    fn len_hint(&self) -> usize {
        self.len()
    }
}

impl SampleSource for Vec<Sample> {
    fn for_each(&self, f: &mut dyn FnMut(&Sample)) {
        SampleSource::for_each(&self.as_slice(), f);
    }

    fn len_hint(&self) -> usize {
        self.len()
    }
}

/// Whether a sample carries a position a reference track is made of.
fn has_position(d: &SensorData) -> bool {
    match d {
        SensorData::Odometry(_) => true,
        SensorData::AutopilotEstimate(a) => a.local_position.is_some() || a.geodetic.is_some(),
        SensorData::Gnss(g) => g.fix != GnssFixType::NoFix,
        _ => false,
    }
}

/// A kind whose samples make a track a replay can be scored against.
fn is_position(k: SensorKind) -> bool {
    matches!(
        k,
        SensorKind::Odometry | SensorKind::AutopilotEstimate | SensorKind::Gnss | SensorKind::Flow
    )
}

/// Replay recorded samples (time-ordered) through the estimator. Sources not in
/// `fuse` (when given) are not fused but still written for comparison. `reference`
/// names the source the others are scored against (e.g. `vio`).
/// What a replay fuses and how it is scored.
#[derive(Debug, Clone, Default)]
pub struct ReplayOptions {
    /// Only these source ids are fused (all when `None`); the rest are still written.
    pub fuse: Option<Vec<String>>,
    /// The source the others are scored against (e.g. `vio`); empty: the log's best
    /// (a camera's odometry, then the autopilot's estimate, then GNSS).
    pub reference: String,
    /// Scored span, s from the log's start.
    pub window: Option<(f64, f64)>,
    /// Time zero of the files, µs (default: the first sample's stamp). A recording of
    /// live input starts at its first arrival instead: stamps there are the sensors' own
    /// clocks (an autopilot's time since boot), arrivals the host's.
    pub t0_us: Option<i64>,
    /// The poses recorded are the ones sent at this rate (`[output] pose_rate_hz`);
    /// `None`: the service's default.
    pub pose_rate_hz: Option<f64>,
}

/// The reference a replay scores against when none is named: a simulator's truth, else
/// the log's best independent estimate (a camera's odometry, the autopilot's estimate,
/// GNSS), the usual name of each kind first.
fn auto_reference(survey: &SampleSurvey) -> Option<String> {
    if survey
        .sources
        .get("sim_truth")
        .is_some_and(|e| e.positions > 0)
    {
        return Some("sim_truth".into());
    }
    [
        SensorKind::Odometry,
        SensorKind::AutopilotEstimate,
        SensorKind::Gnss,
    ]
    .iter()
    .find_map(|k| {
        let usable = |e: &SourceSurvey| e.last_kind == *k && e.positions > 0;
        let named = |id: &str| survey.sources.get(id).is_some_and(usable);
        ["vio", "ekf2", "ekf3", "autopilot", "gps"]
            .into_iter()
            .find(|n| named(n))
            .map(str::to_string)
            .or_else(|| {
                survey
                    .sources
                    .iter()
                    .find(|(_, e)| usable(e))
                    .map(|(id, _)| id.clone())
            })
    })
}

/// What a log holds, for choosing what to fuse and score: each source with its kind,
/// and the reference a replay would choose.
#[derive(Debug, Clone, PartialEq)]
pub struct LogSources {
    pub sources: Vec<(String, SensorKind)>,
    pub auto_reference: Option<String>,
}

/// Surveys `samples` (one pass, as [`run_replay`] does before fusing).
pub fn log_sources(samples: &dyn SampleSource) -> LogSources {
    let survey = SampleSurvey::of(samples);
    LogSources {
        sources: survey
            .sources
            .iter()
            .map(|(id, e)| (id.clone(), e.last_kind))
            .collect(),
        auto_reference: auto_reference(&survey),
    }
}

pub fn run_replay(
    input_name: &str,
    samples: &dyn SampleSource,
    mut cfg: EstimatorConfig,
    health: HealthConfig,
    opts: &ReplayOptions,
    out: &Path,
    progress: &mut dyn FnMut(f64),
) -> Result<Summary, OfflineError> {
    let window = opts.window;
    let survey = SampleSurvey::of(samples);
    // A name that matches nothing is a typo, not a request to fuse nothing.
    let listing = |keep: &dyn Fn(&SourceSurvey) -> bool| {
        survey
            .sources
            .iter()
            .filter(|(_, e)| keep(e))
            .map(|(id, e)| format!("{id} ({})", e.last_kind.as_str()))
            .collect::<Vec<_>>()
            .join(", ")
    };
    if let Some(list) = &opts.fuse {
        let unknown: Vec<&str> = list
            .iter()
            .filter(|l| {
                !survey
                    .sources
                    .iter()
                    .any(|(id, e)| *l == id || *l == e.last_kind.as_str())
            })
            .map(String::as_str)
            .collect();
        if !unknown.is_empty() {
            return Err(OfflineError::UnknownSources {
                unknown: unknown.join(","),
                known: listing(&|_| true),
            });
        }
    }
    // No reference asked for: the log's best independent one (a camera's odometry, the
    // autopilot's estimate, GNSS), said in the summary.
    let reference = if opts.reference.is_empty() {
        auto_reference(&survey).unwrap_or_default()
    } else {
        let Some(e) = survey
            .sources
            .get(&opts.reference)
            .filter(|e| is_position(e.last_kind))
        else {
            return Err(OfflineError::UnknownReference {
                name: opts.reference.clone(),
                known: listing(&|e| is_position(e.last_kind)),
            });
        };
        if e.positions == 0 {
            return Err(OfflineError::ReferenceWithoutPositions {
                name: opts.reference.clone(),
                samples: e.count,
                why: match e.last_kind {
                    SensorKind::AutopilotEstimate => {
                        "the autopilot never had a valid position: only heading or velocity"
                    }
                    SensorKind::Gnss => "the receiver never had a fix",
                    _ => "the kind carries none",
                },
                known: listing(&|e| e.positions > 0),
            });
        }
        opts.reference.clone()
    };
    if let Some(list) = &opts.fuse {
        // A source id (`flow_1`), or a sensor kind (`flow`: every flow sensor). The
        // autopilot's armed/landed state is not a sensor under comparison: it is used
        // whenever the log has it, as the service uses EXTENDED_SYS_STATE.
        for (id, e) in &survey.sources {
            cfg.sources.entry(id.clone()).or_default().fuse =
                list.iter().any(|l| l == id || l == e.last_kind.as_str()) || e.vehicle_state;
        }
    }
    let mode = cfg.mode;
    let mut fusion = Fusion::new(cfg, health, &survey.inputs());
    let t0 = opts.t0_us.or(survey.first.and_then(|f| f.1)).unwrap_or(0);
    let mut rec = Recorder::with_pose_rate(t0, opts.pose_rate_hz.unwrap_or(DEFAULT_POSE_RATE_HZ));
    let n = samples.len_hint().max(1);
    let mut i = 0;
    samples.for_each(&mut |s| {
        rec.source_sample(s);
        let events = fusion.process(s, s.arrival_us);
        rec.estimator_output(&fusion.est, &events);
        if i % 4096 == 0 {
            progress((i as f64 / n as f64).min(1.0));
        }
        i += 1;
    });
    progress(1.0);
    let input = RunInput {
        name: input_name.to_string(),
        mode,
        samples: survey.samples as u64,
    };
    // 20 ms: the reference (30 Hz VIO) and the fused poses (50 Hz) are never closer
    // than evo's default 10 ms for every pose.
    let reference = Reference::Source {
        name: &reference,
        max_diff_s: 0.02,
    };
    finish(&rec, reference, window, out, input)
}

#[cfg(test)]
mod reference_tests {
    use super::*;
    use crate::sample::{AutopilotEstimate, GnssFix};

    fn at(source: &str, t: i64, data: SensorData) -> Sample {
        Sample {
            source: source.into(),
            stamp_us: Some(t),
            arrival_us: t,
            data,
        }
    }

    #[test]
    fn airborne_before_the_first_pose_counts_as_invalid() {
        // In the air from 1 s; the filter's first pose at 8 s, valid to the end at 10 s.
        let validity: Vec<(f64, bool)> = (0..=20).map(|k| (8.0 + k as f64 * 0.1, true)).collect();
        let a = availability(&validity, &[(0.0, false), (1.0, true)]);
        let f = a.airborne_valid_fraction.unwrap_or(f64::NAN);
        assert!((f - 2.0 / 9.0).abs() < 1e-9, "{f}");
        assert_eq!(a.airborne_s, Some(9.0));
        assert_eq!(a.airborne_longest_invalid_s, Some(7.0));
        // Airborne only after the first pose: nothing added.
        let b = availability(&validity, &[(0.0, false), (9.0, true)]);
        assert_eq!(b.airborne_valid_fraction, Some(1.0));
    }

    /// A GNSS track has no orientation: registering a north-facing estimate on it at
    /// the first pose moves the estimate and does not turn it by its heading.
    #[test]
    fn a_position_only_reference_registers_without_turning() {
        let north = UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2);
        let mut gps = Trajectory::default();
        let mut est = Trajectory::default();
        for i in 0..50 {
            let t = f64::from(i) * 0.1;
            let p = Vector3::new(0.5 * t, 2.0 * t, 0.0);
            push(&mut gps, t, p, UnitQuaternion::identity());
            // The estimate's frame: the same axes, its origin 3 m away.
            push(&mut est, t, p + Vector3::new(3.0, -1.0, 0.0), north);
        }
        let origin = ApeOptions {
            align_origin: true,
            ..ApeOptions::default()
        };
        let turned = evo_ape(&gps, &est, &origin).unwrap();
        assert!(
            turned.rmse > 1.0,
            "as evo does with a placeholder: {}",
            turned.rmse
        );
        let oriented = with_orientation_of(&gps, &est);
        let moved = evo_ape(&oriented, &est, &origin).unwrap();
        assert!(moved.rmse < 1e-9, "{}", moved.rmse);
    }

    /// An autopilot estimate with a heading but never a position (EKF2 before its
    /// first fix) is no reference: not chosen by default, and an error that says why
    /// when named; GNSS with a fix is chosen instead.
    #[test]
    fn a_reference_without_positions_is_refused_and_said_why() {
        let heading_only = SensorData::AutopilotEstimate(AutopilotEstimate {
            local_position: None,
            geodetic: None,
            velocity: None,
            yaw: Some(0.3),
        });
        let fix = SensorData::Gnss(GnssFix {
            lat_deg: 47.0,
            lon_deg: 8.0,
            alt_m: 500.0,
            fix: GnssFixType::Fix3d,
            position_cov: None,
            satellites: Some(9),
            hdop: Some(0.8),
            vdop: None,
            velocity: None,
            velocity_up_known: false,
        });
        let samples: Vec<Sample> = (0..20)
            .flat_map(|i| {
                [
                    at("ekf2", i * 100_000, heading_only.clone()),
                    at("gps", i * 100_000 + 1, fix.clone()),
                ]
            })
            .collect();
        let found = log_sources(&samples);
        assert_eq!(found.auto_reference.as_deref(), Some("gps"));
        let dir = std::env::temp_dir().join(format!("skyfuse-ref-{}", std::process::id()));
        let opts = ReplayOptions {
            reference: "ekf2".into(),
            ..ReplayOptions::default()
        };
        let err = run_replay(
            "t",
            &samples,
            EstimatorConfig::default(),
            HealthConfig::default(),
            &opts,
            &dir,
            &mut |_| {},
        )
        .expect_err("refused");
        let _ = std::fs::remove_dir_all(&dir);
        let said = err.to_string();
        assert!(
            said.contains("none of its 20 samples has a position")
                && said.contains("never had a valid position")
                && said.contains("gps (gnss)"),
            "{said}"
        );
    }

    /// Two level frames differ by a heading at most; the attitudes of one instant
    /// differ by their roll and pitch too, which a registration must not carry into
    /// every later pose. And two north-referenced frames are registered by their
    /// origins alone.
    #[test]
    fn frames_are_registered_level_and_north_referenced_ones_by_their_origins() {
        let mut reference = Trajectory::default();
        let mut est = Trajectory::default();
        // At the first pose the two attitudes differ by 2° of pitch and 5° of heading
        // (a reference's own attitude error there), later by nothing.
        let first = UnitQuaternion::from_euler_angles(0.0, 2f64.to_radians(), 5f64.to_radians());
        for i in 0..=100 {
            let t = f64::from(i);
            let p = Vector3::new(0.0, t, 0.0);
            let q = if i == 0 {
                first
            } else {
                UnitQuaternion::identity()
            };
            push(&mut reference, t, p, q);
            push(
                &mut est,
                t,
                p + Vector3::new(2.0, 1.0, 0.5),
                UnitQuaternion::identity(),
            );
        }
        let cov = vec![Matrix3::identity() * 0.01; est.t.len()];
        let at = |r: Registration| {
            consistency(&reference, None, &est, &cov, &[], &[], 1e-6, Some(r))
                .map(|c| (c.beyond_5_sigma, c.worst_ratio))
                .expect("scored")
        };
        let (beyond, worst) = at(Registration::Translation);
        assert_eq!(beyond, 0, "worst {worst}");
        assert!(worst < 1e-6, "{worst}");
        // Turned by the 5° (8.7 m at 100 m) but not pitched by the 2° (3.5 m of height).
        let (_, worst) = at(Registration::Heading);
        assert!(worst > 50.0, "{worst}");
        let turned = consistency(
            &reference,
            None,
            &est,
            &cov,
            &[],
            &[],
            1e-6,
            Some(Registration::Heading),
        )
        .expect("scored");
        assert!(
            turned.within_3_sigma[2] > 0.99,
            "{:?}",
            turned.within_3_sigma
        );
    }

    /// An estimate drifting 0.1 m/s east, re-anchored every 5 s with a bound of 1 m:
    /// from take-off it is 3 m off at 30 s, beyond its bound; against each anchor it
    /// is at most 0.5 m off, inside it. The truth is registered where the estimate was
    /// at each anchor, and only the horizontal: the height keeps the first pose's.
    #[test]
    fn a_re_anchored_estimate_is_judged_from_its_anchor() {
        let (mut reference, mut est) = (Trajectory::default(), Trajectory::default());
        let mut pl = vec![];
        let mut anchors = vec![];
        for k in 0..=300 {
            let t = k as f64 * 0.1;
            let p = Vector3::new(t, 0.5 * t, 2.0);
            push(&mut reference, t, p, UnitQuaternion::identity());
            let e = p + Vector3::new(0.1 * t, 0.0, 0.05);
            push(&mut est, t, e, UnitQuaternion::identity());
            let anchor = (k / 50) as f64 * 5.0;
            if k % 50 == 0 && k > 0 {
                let q = UnitQuaternion::identity();
                anchors.push(Anchor {
                    t,
                    pose: (e, q),
                    cov: Matrix3::zeros(),
                    hpl: 0.0,
                    reference: Some((p, q)),
                });
            }
            pl.push(Protection {
                horizontal_m: 1.0,
                vertical_m: 1.0,
                horizontal_alert_m: 50.0,
                vertical_alert_m: 20.0,
                anchored_us: (k >= 50).then_some((anchor * 1e6) as i64),
            });
        }
        let cov = vec![Matrix3::identity() * 0.04; est.t.len()];
        let judged = |anchors: &[Anchor]| {
            consistency(&reference, None, &est, &cov, &pl, anchors, 1e-6, None).expect("scored")
        };
        let from_take_off = judged(&[]);
        assert!(from_take_off.integrity_failures > 100, "{from_take_off:?}");
        let anchored = judged(&anchors);
        assert_eq!(anchored.integrity_failures, 0, "{anchored:?}");
        assert!(anchored.worst_pl_ratio > 0.45, "{anchored:?}");
        // The σ too is judged from the anchor (0.49 m at most, σ 0.2 m); the height's
        // 5 cm stays.
        assert!(anchored.within_3_sigma == [1.0; 3] && anchored.worst_ratio < 3.0);
    }
}
