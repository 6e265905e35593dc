//! What the estimator tells the world: the fused pose, its debug series and its
//! status (the service's `/api/v1/status` `estimator`, the replay's summary).

use super::CalState;
use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use serde::Serialize;
use std::collections::BTreeMap;

/// The fused estimate.
#[derive(Clone, Debug, Serialize)]
pub struct FusedPose {
    /// Host clock, µs: the time the estimate refers to.
    pub time_us: i64,
    /// ENU, m.
    pub position: Vector3<f64>,
    pub velocity: Vector3<f64>,
    /// Body FLU → ENU.
    pub orientation: UnitQuaternion<f64>,
    pub angular_velocity: Option<Vector3<f64>>,
    pub position_cov: Matrix3<f64>,
    pub velocity_cov: Matrix3<f64>,
    /// rad², roll/pitch/yaw small-angle.
    pub orientation_cov: Matrix3<f64>,
    pub sources: Vec<String>,
    /// Wraps, MAVLink style.
    pub reset_counter: u8,
    pub valid: bool,
    pub invalid_reason: Option<String>,
    /// Geodetic (lat, lon, alt) of the ENU origin if GNSS set it.
    pub origin: Option<(f64, f64, f64)>,
    /// The bound the pose is sent with: its true error is inside it (see
    /// `estimator::integrity`).
    pub protection: Protection,
}

/// The integrity monitor as the status shows it.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct IntegrityStatus {
    /// The protection levels of the estimate now and the alert limits.
    pub protection: Protection,
    pub tests: Vec<super::integrity::SeparationTest>,
    pub excluded: Vec<String>,
    pub exclusions: u64,
    /// Of the solutions the exclusions set aside (one per source out), the one
    /// farthest from the estimate: the source it keeps and where it is against the
    /// estimate, ENU m. The bound sent covers every one.
    pub set_aside: Option<SetAside>,
}

/// See [`IntegrityStatus::set_aside`].
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct SetAside {
    pub source: String,
    /// Estimate minus the set-aside solution, ENU, m.
    pub separation: [f64; 3],
}

/// Protection levels: horizontal and vertical bounds on the position error, m, and the
/// alert limits they are held to ("valid" means both are under theirs).
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq)]
pub struct Protection {
    pub horizontal_m: f64,
    pub vertical_m: f64,
    pub horizontal_alert_m: f64,
    pub vertical_alert_m: f64,
    /// In a frame of its own re-anchored (relative navigation), when the anchor was
    /// set, µs (host clock): the horizontal bound is on the position relative to where
    /// the estimate had the vehicle then. None: relative to the frame's origin.
    pub anchored_us: Option<i64>,
}

impl Protection {
    /// Both levels under their alert limits (what "valid" requires of them).
    pub fn within_alert_limits(&self) -> bool {
        self.horizontal_m <= self.horizontal_alert_m && self.vertical_m <= self.vertical_alert_m
    }
}

/// The estimator's debug series: the seed's rqt_plot topics (named as the seed names
/// them) and a few more the dashboard plots.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum DebugTopic {
    /// Raw flow rate (rad/s).
    OfData,
    /// Flow rate after rotation compensation (rad/s).
    CompensatedOf,
    /// The gyro as the flow compensation used it (low-passed, clamped).
    FlowGyro,
    /// Flow displacement integrated (m).
    OfSum,
    /// Flow displacement per fusion step (m).
    OriginDOf,
    /// Odometry position in the fused frame, and its step.
    OriUavT265,
    OriginDt265,
    /// GNSS position in the fused frame, and its step.
    OriUavGps,
    OriginDgps,
    /// The fused pose's step.
    FusionDisplace,
    /// The fused position.
    PoseMsg,
    ImuAngularVelocity,
}

impl DebugTopic {
    /// Published on Zenoh as geometry_msgs/PointStamped under `ros2_debug_prefix`.
    pub const PUBLISHED: [DebugTopic; 8] = [
        DebugTopic::CompensatedOf,
        DebugTopic::OfSum,
        DebugTopic::OriUavT265,
        DebugTopic::OriUavGps,
        DebugTopic::OriginDOf,
        DebugTopic::OriginDt265,
        DebugTopic::OriginDgps,
        DebugTopic::FusionDisplace,
    ];
    /// Accumulated position per source (the dashboard's `sources`).
    pub const POSITIONS: [DebugTopic; 3] = [
        DebugTopic::OriUavGps,
        DebugTopic::OriUavT265,
        DebugTopic::OfSum,
    ];
    /// Per-step displacement per source and of the fused pose (the dashboard's `deltas`).
    pub const DELTAS: [DebugTopic; 4] = [
        DebugTopic::OriginDgps,
        DebugTopic::OriginDt265,
        DebugTopic::OriginDOf,
        DebugTopic::FusionDisplace,
    ];

    /// The seed's name (the Zenoh key's last part).
    pub fn name(self) -> &'static str {
        match self {
            DebugTopic::OfData => "OF_data",
            DebugTopic::CompensatedOf => "compensated_OF",
            DebugTopic::FlowGyro => "flow_gyro",
            DebugTopic::OfSum => "OF_sum",
            DebugTopic::OriginDOf => "origin_dOF",
            DebugTopic::OriUavT265 => "oriUAV_t265",
            DebugTopic::OriginDt265 => "origin_dt265",
            DebugTopic::OriUavGps => "oriUAV_gps",
            DebugTopic::OriginDgps => "origin_dgps",
            DebugTopic::FusionDisplace => "fusion_displace",
            DebugTopic::PoseMsg => "pose_msg",
            DebugTopic::ImuAngularVelocity => "imu_angular_velocity",
        }
    }
}

impl Serialize for DebugTopic {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

/// One point of a debug series (the seed's rqt_plot topics).
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct DebugPoint {
    pub time_us: i64,
    pub source: String,
    pub value: [f64; 3],
}

/// The latest point per topic.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct DebugSeries {
    pub series: BTreeMap<DebugTopic, DebugPoint>,
}

/// Per-source state for the status API and the health layer.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct SourceStatus {
    pub kind: &'static str,
    pub last_time_us: Option<i64>,
    pub last_fused_us: Option<i64>,
    /// The fusion before the last: the source's own interval, for how long it counts
    /// as used (a 1 Hz HEARTBEAT is used between its beats).
    #[serde(skip)]
    pub prev_fused_us: Option<i64>,
    pub innovation: Vec<f64>,
    pub innovation_var: Vec<f64>,
    pub test_ratio: f64,
    pub accepted: u64,
    pub rejected: u64,
    /// Samples whose innovation was tested (fused, or probed while not fused), and of
    /// those the ones over the gate: a sample's several updates count once.
    pub tested: u64,
    pub tested_over_gate: u64,
    /// The latest tested sample is already counted over the gate.
    #[serde(skip)]
    latest_over_gate: bool,
    pub last_reject_reason: Option<String>,
    pub usable: bool,
    pub segment: Option<u32>,
    /// An odometry's frame drifting against the fused one, m/s over the last second
    /// (its offset state's change, less what the fused position's own corrections
    /// explain): a camera that lost track slides at decimetres a second, which its
    /// offset's random walk absorbs sample by sample without one large innovation.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub drift_mps: Option<f64>,
}

impl SourceStatus {
    /// Fused at `t`.
    pub fn fused(&mut self, t: i64) {
        if self.last_fused_us != Some(t) {
            self.prev_fused_us = self.last_fused_us;
        }
        self.last_fused_us = Some(t);
    }

    /// The innovation and its variances of `out`, copied into the vectors this status
    /// already has (no allocation once they have room for three rows).
    pub(super) fn set_innovation(&mut self, out: &super::ekf::UpdateOutcome) {
        self.innovation.clear();
        self.innovation.extend_from_slice(out.innovation());
        self.innovation_var.clear();
        self.innovation_var.extend_from_slice(out.innovation_var());
    }

    /// Count one gate test of the sample at `t` (the source's latest time from now
    /// on): the first of a new sample, or another update of the same one. Returns
    /// whether it was the same sample.
    pub(super) fn count_test(&mut self, t: i64, test_ratio: f64) -> bool {
        let same_sample = self.last_time_us.replace(t) == Some(t);
        if !same_sample {
            self.tested += 1;
            self.latest_over_gate = false;
        }
        // NaN counts as over: a ratio that cannot be computed is no agreement.
        if (test_ratio.is_nan() || test_ratio > 1.0) && !self.latest_over_gate {
            self.tested_over_gate += 1;
            self.latest_over_gate = true;
        }
        same_sample
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct CalibrationStatus {
    pub state: CalState,
    pub source: Option<String>,
    pub samples: [usize; 2],
    pub result: Option<[f64; 2]>,
}

#[derive(Clone, Debug, Serialize)]
pub struct EstimatorStatus {
    pub mode: &'static str,
    pub initialised: bool,
    pub valid: bool,
    pub invalid_reason: Option<String>,
    pub time_us: Option<i64>,
    pub origin: Option<(f64, f64, f64)>,
    pub reset_counter: u8,
    pub sources_used: Vec<String>,
    pub attitude_source: &'static str,
    pub covariance_trace: Option<f64>,
    pub position_std: Option<[f64; 3]>,
    pub accel_bias: Option<[f64; 3]>,
    pub gyro_bias: [f64; 3],
    pub sources: BTreeMap<String, SourceStatus>,
    pub calibration: CalibrationStatus,
    pub monitor: Option<(&'static str, f64, f64)>,
    pub history_len: usize,
    pub late_dropped: u64,
    pub clock_offsets_us: BTreeMap<String, i64>,
    /// Sources whose stamps do not run at the host's rate (measured rate), timed by
    /// arrival instead (see `timing`).
    pub timed_by_arrival: BTreeMap<String, f64>,
    /// The integrity monitor: each sub-filter's separation test, the sources excluded
    /// now and how many exclusions so far.
    pub integrity: IntegrityStatus,
}
