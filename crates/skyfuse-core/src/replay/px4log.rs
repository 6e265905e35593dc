//! PX4 flight logs → samples for offline replay: a ULog file read directly (PX4's own
//! `px4-ulog` crate), or the per-topic CSV export of pyulog's `ulog2csv` (a directory of
//! `<topic>_<instance>.csv`, each optionally gzip-compressed as `.csv.gz`). Both become
//! the same rows of named fields (`timestamp` in µs since boot; unknown values NaN),
//! mapped once.
//!
//! | topic (PX4 1.12 – 1.15)                         | source          | sample |
//! |-------------------------------------------------|-----------------|--------|
//! | `sensor_combined`                               | `imu`           | [`Imu`] (gyro, accel) |
//! | `vehicle_attitude`                              | `attitude`      | [`Attitude`]; rates from `vehicle_angular_velocity` |
//! | `sensor_gps` / `vehicle_gps_position`           | `gps`           | [`GnssFix`] (1e-7° or 1.15's degrees) |
//! | `distance_sensor`                               | `range`         | [`Range`] |
//! | `vehicle_optical_flow` / `optical_flow`         | `flow`          | [`OpticalFlow`] |
//! | `vehicle_visual_odometry`                       | `vio`           | [`Odometry`] (≤ 1.13 and ≥ 1.14 layouts) |
//! | `vehicle_local_position`                        | `ekf2`          | [`AutopilotEstimate`] (comparison only) |
//! | `vehicle_land_detected`, `actuator_armed`       | `land_detected`, `armed` | [`VehicleState`] |
//! | `vehicle_imu`, `estimator_states`               | `vehicle_imu`, `attitude_states` | low-rate IMU and EKF2 quaternion |
//!
//! Instance `i` > 0 gets `_i` (`optical_flow_1` → `flow_1`). Stand-ins, used only where
//! the real topic is absent and listed in [`Px4Log::stand_ins`]: `vehicle_imu` as `imu`
//! without `sensor_combined`; EKF2's heading (`vehicle_local_position`) tilted as its
//! nearest quaternion (`estimator_states`, which it then replaces) as `attitude` without
//! `vehicle_attitude`; EKF2's flow gyro (`estimator_optical_flow_vel`)
//! for flow samples without a gyro. A topic of the wanted set that is absent is listed
//! in [`Px4Log::missing`], not fatal. The barometer (`vehicle_air_data`) is not read:
//! the estimator has no barometer input.
//!
//! Conventions, as `crate::sample` fixes them: NED/FRD in, ENU/FLU out, SI units.
//! `stamp_us` and `arrival_us` are both the row's `timestamp` (PX4's publication time,
//! one clock for everything offline). Where a topic also has `timestamp_sample` (the
//! measurement time) that is earlier: about 1 ms for the EKF2 and IMU topics, but a
//! median 22 ms (up to 53 ms) for vehicle_visual_odometry, the camera pipeline's delay.
//!
//! Rows: one that is malformed (wrong field count, text that is not a number) or that no
//! sample can be formed from (a non-finite position, a zero integration time) is skipped
//! and counted in its [`TopicSummary`], the first such error kept. Only a file that
//! cannot be read, a header without a column we need, or a log with none of the topics
//! above fails the whole read.

use crate::estimator::attitude::yaw_of;
use crate::sample::{
    frames, Attitude, AutopilotEstimate, GnssFix, GnssFixType, Imu, LandedState, Micros, Odometry,
    OpticalFlow, Range, Sample, SensorData, Tof, VehicleState,
};
use nalgebra::{Matrix3, Matrix6, Quaternion, UnitQuaternion, Vector2, Vector3};
use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// A replayable log: samples sorted by `stamp_us`, and what each topic contributed.
#[derive(Debug)]
pub struct Px4Log {
    pub samples: Vec<Sample>,
    /// One entry per topic instance read, in reading order (the tie order of `samples`).
    pub topics: Vec<TopicSummary>,
    /// Stand-ins used for absent topics, as sentences.
    pub stand_ins: Vec<String>,
    /// Wanted topics the log does not have, as sentences.
    pub missing: Vec<String>,
}

/// What one CSV file contributed.
#[derive(Debug)]
pub struct TopicSummary {
    /// File stem, e.g. `optical_flow_1`.
    pub name: String,
    /// The sample source its rows became, e.g. `flow_1`.
    pub source: String,
    /// Data rows in the file (blank lines not counted).
    pub rows: usize,
    /// Rows that produced no sample.
    pub skipped: usize,
    /// Why the first skipped row was skipped.
    pub first_error: Option<Px4LogError>,
    /// First and last `stamp_us` of the samples it produced.
    pub span_us: Option<(Micros, Micros)>,
}

impl TopicSummary {
    /// Samples this file produced.
    pub fn samples(&self) -> usize {
        self.rows - self.skipped
    }
}

#[derive(Debug, thiserror::Error)]
pub enum Px4LogError {
    #[error("{}: cannot list the directory: {source}", dir.display())]
    ListDir {
        dir: PathBuf,
        source: std::io::Error,
    },
    #[error("{}: no PX4 topic CSV that replay reads (looked for {looked_for})", dir.display())]
    NoKnownTopics { dir: PathBuf, looked_for: String },
    #[error("{}: cannot open: {source}", file.display())]
    Open {
        file: PathBuf,
        source: std::io::Error,
    },
    #[error("{}:{line}: read failed: {source}", file.display())]
    Io {
        file: PathBuf,
        line: usize,
        source: std::io::Error,
    },
    #[error("{}:1: empty file, no header row", file.display())]
    NoHeader { file: PathBuf },
    #[error("{}:{line}: not UTF-8", file.display())]
    NotUtf8 { file: PathBuf, line: usize },
    #[error("{}: cannot read the ULog: {reason}", file.display())]
    Ulog { file: PathBuf, reason: String },
    #[error("{}:1: the header has no column `{column}` (not a PX4 v1.12 to v1.15 layout?)", file.display())]
    MissingColumn { file: PathBuf, column: String },
    #[error("{}:{line}:{column}: {found} fields where the header has {expected}", file.display())]
    ColumnCount {
        file: PathBuf,
        line: usize,
        /// 1-based column of the first missing or extra field.
        column: usize,
        expected: usize,
        found: usize,
    },
    #[error("{}:{line}:{column}: `{name}` is {text:?}, not {expected}", file.display())]
    BadValue {
        file: PathBuf,
        line: usize,
        column: usize,
        name: String,
        text: String,
        expected: &'static str,
    },
    #[error("{}:{line}:{column}: `{name}`: {reason}", file.display())]
    Unusable {
        file: PathBuf,
        line: usize,
        column: usize,
        name: String,
        reason: &'static str,
    },
}

/// Reads every known topic CSV in `dir` (see the module doc).
pub fn read_dir(dir: &Path) -> Result<Px4Log, Px4LogError> {
    read_dir_with_progress(dir, &mut |_, _| {})
}

/// [`read_dir`], calling `progress(done, total)` as the files are read (about every
/// 256 KiB, and once at the end with `done == total`).
pub fn read_dir_with_progress(
    dir: &Path,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<Px4Log, Px4LogError> {
    read_topics(find_topic_files(dir)?, progress)
}

/// Reads a ULog file (`.ulg`) directly; `progress` counts rows.
pub fn read_ulog_with_progress(
    file: &Path,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<Px4Log, Px4LogError> {
    read_topics(ulog_topic_files(file)?, progress)
}

/// A ULog file or a CSV export directory, whichever `path` is.
pub fn read_path_with_progress(
    path: &Path,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<Px4Log, Px4LogError> {
    if path.is_dir() {
        read_dir_with_progress(path, progress)
    } else {
        read_ulog_with_progress(path, progress)
    }
}

fn read_topics(
    files: Vec<TopicFile>,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<Px4Log, Px4LogError> {
    let total = files.iter().map(TopicFile::weight).sum();
    let mut prog = Progress {
        done: 0,
        total,
        reported: 0,
        cb: progress,
    };
    let mut samples = Vec::new();
    let mut topics = Vec::with_capacity(files.len());
    for f in &files {
        topics.push(read_topic(f, &mut samples, &mut prog)?);
    }
    // Stable: equal stamps keep topic order (the TOPICS order, then instance).
    samples.sort_by_key(|s| s.stamp_us);
    let has = |t: &str| files.iter().any(|f| TOPICS[f.order.0].0 == t);
    let mut stand_ins = Vec::new();
    attach_angular_velocity(&mut samples);
    if attach_ekf2_flow_gyro(&mut samples) > 0 {
        stand_ins.push(
            "flow gyro: EKF2's (estimator_optical_flow_vel) for flow samples without their own"
                .to_string(),
        );
    }
    if !has("sensor_combined") && has("vehicle_imu") {
        rename(&mut samples, "vehicle_imu", "imu");
        stand_ins.push(
            "imu: vehicle_imu (logged at a low rate) stands in for sensor_combined (absent)"
                .to_string(),
        );
    }
    if !has("vehicle_attitude") && attitude_from_ekf2_heading(&mut samples) > 0 {
        stand_ins.push(
            "attitude: EKF2's heading (vehicle_local_position) tilted as EKF2's quaternion (estimator_states, logged at a low rate) stands in for vehicle_attitude (absent)"
                .to_string(),
        );
    }
    let missing = WANTED
        .iter()
        .filter(|(_, names)| !names.iter().any(|n| has(n)))
        .map(|(what, names)| format!("{what}: none of {}", names.join(", ")))
        .collect();
    (prog.cb)(prog.total, prog.total);
    Ok(Px4Log {
        samples,
        topics,
        stand_ins,
        missing,
    })
}

/// Source `from` (and its instances `from_i`) becomes `to` (`to_i`).
fn rename(samples: &mut [Sample], from: &str, to: &str) {
    for s in samples.iter_mut() {
        if let Some(rest) = s.source.strip_prefix(from) {
            if rest.is_empty() || rest.starts_with('_') {
                s.source = Arc::from(format!("{to}{rest}"));
            }
        }
    }
}

/// Takes the rows of an internal rate source out of `samples`: (time, gyro), by time.
fn take_rates(samples: &mut Vec<Sample>, source: &str) -> Vec<(i64, Vector3<f64>)> {
    let rows = samples
        .iter()
        .filter(|s| s.source.as_ref() == source)
        .filter_map(|s| match (&s.data, s.stamp_us) {
            (SensorData::Imu(i), Some(t)) => i.gyro.map(|g| (t, g)),
            _ => None,
        })
        .collect();
    samples.retain(|s| s.source.as_ref() != source);
    rows
}

/// The attitude topic has no rates; `vehicle_angular_velocity` (its own topic, FRD)
/// gives them to the attitude samples of the same time (within 10 ms), as MAVLink's
/// ATTITUDE carries both. Its rows are then dropped.
fn attach_angular_velocity(samples: &mut Vec<Sample>) {
    let rates = take_rates(samples, "angular_velocity");
    if rates.is_empty() {
        return;
    }
    for s in samples
        .iter_mut()
        .filter(|s| s.source.as_ref() == "attitude")
    {
        let (Some(t), SensorData::Attitude(a)) = (s.stamp_us, &mut s.data) else {
            continue;
        };
        if let Some((rt, g)) = nearest(&rates, t) {
            if (rt - t).abs() <= 10_000 {
                a.rates = Some(g);
            }
        }
    }
}

/// The row of `rows` (sorted by time) nearest to `t`.
fn nearest(rows: &[(i64, Vector3<f64>)], t: i64) -> Option<(i64, Vector3<f64>)> {
    let i = rows.partition_point(|r| r.0 < t);
    [i.checked_sub(1), Some(i)]
        .into_iter()
        .flatten()
        .filter_map(|j| rows.get(j))
        .min_by_key(|r| (r.0 - t).abs())
        .copied()
}

/// Without `vehicle_attitude` (this export logs only EKF2's 1 Hz quaternion), EKF2's
/// heading (`vehicle_local_position`, 10 Hz) stands in as source `attitude`, tilted as
/// the nearest EKF2 quaternion (`attitude_states`, within [`TILT_NEAREST_US`]) says, or
/// level when there is none. A level stand-in would be a lie while the vehicle is
/// tilted (held on its side, the range finder then reads the far wall). The
/// `attitude_states` rows it was built from are then dropped: one attitude source, not
/// two disagreeing at different rates. Returns how many samples it made.
fn attitude_from_ekf2_heading(samples: &mut Vec<Sample>) -> usize {
    let tilts: Vec<(i64, UnitQuaternion<f64>)> = samples
        .iter()
        .filter(|s| s.source.as_ref() == "attitude_states")
        .filter_map(|s| match (&s.data, s.stamp_us) {
            (SensorData::Attitude(a), Some(t)) => Some((t, a.orientation)),
            _ => None,
        })
        .collect();
    let tilt_at = |t: i64| -> UnitQuaternion<f64> {
        let i = tilts.partition_point(|r| r.0 < t);
        let near = [i.checked_sub(1), Some(i)]
            .into_iter()
            .flatten()
            .filter_map(|j| tilts.get(j))
            .filter(|r| (r.0 - t).abs() <= TILT_NEAREST_US)
            .min_by_key(|r| (r.0 - t).abs());
        // The quaternion without its heading: body → a level frame of the same yaw.
        near.map_or_else(UnitQuaternion::identity, |(_, q)| {
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), -yaw_of(q)) * q
        })
    };
    let mut extra = Vec::new();
    for s in samples.iter() {
        match &s.data {
            SensorData::AutopilotEstimate(a) if s.source.as_ref() == "ekf2" => {
                if let (Some(yaw), Some(t)) = (a.yaw.filter(|y| y.is_finite()), s.stamp_us) {
                    extra.push(Sample {
                        source: "attitude".into(),
                        stamp_us: s.stamp_us,
                        arrival_us: s.arrival_us,
                        data: SensorData::Attitude(crate::sample::Attitude {
                            orientation: UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw)
                                * tilt_at(t),
                            rates: None,
                        }),
                    });
                }
            }
            _ => {}
        }
    }
    let n = extra.len();
    if n > 0 {
        samples.retain(|s| s.source.as_ref() != "attitude_states");
    }
    samples.extend(extra);
    samples.sort_by_key(|s| s.stamp_us);
    n
}

/// Flow modules without a gyro (NaN in `optical_flow`) leave rotation compensation to
/// the autopilot's IMU. When the log has no high-rate IMU, EKF2's logged gyro integral
/// over each flow interval (`estimator_optical_flow_vel`, `gyro_rate_integral`, FRD,
/// with the opposite sign to the body rate — checked against the VIO's rates) is
/// attached to the `flow` samples it belongs to (same sample time within 5 ms), as
/// OPTICAL_FLOW_RAD's integrated gyro would carry it. Its rows are then dropped. Returns
/// how many flow samples got one.
fn attach_ekf2_flow_gyro(samples: &mut Vec<Sample>) -> usize {
    let rows = take_rates(samples, EKF2_FLOW_GYRO);
    let mut n = 0;
    for s in samples.iter_mut().filter(|s| s.source.as_ref() == "flow") {
        let (Some(t), SensorData::Flow(f)) = (s.stamp_us, &mut s.data) else {
            continue;
        };
        let (Some(dt), None) = (f.integration_s, f.gyro) else {
            continue;
        };
        if let Some((rt, g)) = nearest(&rows, t) {
            if (rt - t).abs() <= 5_000 {
                f.gyro = Some(frames::frd_to_flu(-g / dt));
                n += 1;
            }
        }
    }
    n
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    VehicleAttitude,
    Attitude,
    SensorCombined,
    Imu,
    AngularVelocity,
    Gps,
    Range,
    Flow,
    VehicleFlow,
    Vio,
    Ekf2,
    Ekf2FlowGyro,
    LandDetected,
    Armed,
}

/// Topic name, source name, kind; the order is the preference when two topics would
/// give the same source (the later one is then named after its topic) and the tie
/// order of equal stamps. Field layouts of PX4 v1.12 to v1.15 are read: where a topic
/// changed (vehicle_gps_position → sensor_gps, optical_flow → vehicle_optical_flow,
/// vehicle_visual_odometry's frames, sensor_gps's degrees in 1.15) both forms are.
const TOPICS: [(&str, &str, Kind); 15] = [
    ("vehicle_attitude", "attitude", Kind::VehicleAttitude),
    ("estimator_states", "attitude_states", Kind::Attitude),
    ("sensor_combined", "imu", Kind::SensorCombined),
    ("vehicle_imu", "vehicle_imu", Kind::Imu),
    (
        "vehicle_angular_velocity",
        "angular_velocity",
        Kind::AngularVelocity,
    ),
    ("sensor_gps", "gps", Kind::Gps),
    ("vehicle_gps_position", "gps", Kind::Gps),
    ("distance_sensor", "range", Kind::Range),
    ("vehicle_optical_flow", "flow", Kind::VehicleFlow),
    ("optical_flow", "flow", Kind::Flow),
    ("vehicle_visual_odometry", "vio", Kind::Vio),
    ("vehicle_local_position", "ekf2", Kind::Ekf2),
    (
        "estimator_optical_flow_vel",
        EKF2_FLOW_GYRO,
        Kind::Ekf2FlowGyro,
    ),
    ("vehicle_land_detected", "land_detected", Kind::LandDetected),
    ("actuator_armed", "armed", Kind::Armed),
];

/// The topics a replay wants, for the "missing" report: (what, any of these topics).
const WANTED: [(&str, &[&str]); 7] = [
    ("IMU", &["sensor_combined", "vehicle_imu"]),
    ("attitude", &["vehicle_attitude"]),
    ("GNSS", &["sensor_gps", "vehicle_gps_position"]),
    ("range finder", &["distance_sensor"]),
    ("optical flow", &["vehicle_optical_flow", "optical_flow"]),
    ("visual odometry", &["vehicle_visual_odometry"]),
    ("land detector", &["vehicle_land_detected"]),
];

/// Internal source of EKF2's flow gyro rows, attached to the flow samples and dropped.
const EKF2_FLOW_GYRO: &str = "ekf2_flow_gyro";
/// The attitude stand-in takes its tilt from an EKF2 quaternion at most this far away,
/// µs (estimator_states is logged at about 1 Hz).
const TILT_NEAREST_US: i64 = 1_000_000;

/// One topic instance to read: a CSV file, or a ULog topic already in memory.
struct TopicFile {
    /// The CSV file, or the `.ulg` file (errors name it with the topic).
    path: PathBuf,
    name: String,
    source: String,
    kind: Kind,
    order: (usize, u32),
    data: TopicData,
}

enum TopicData {
    Csv {
        bytes: u64,
        gzip: bool,
    },
    /// Header and column-major values.
    Ulog {
        header: Vec<String>,
        columns: Vec<Vec<f64>>,
    },
}

impl TopicFile {
    fn weight(&self) -> u64 {
        match &self.data {
            TopicData::Csv { bytes, .. } => *bytes,
            TopicData::Ulog { columns, .. } => columns.first().map_or(0, |c| c.len() as u64),
        }
    }
}

/// `<prefix>_<digits>` → (TOPICS index, instance).
fn match_topic(stem: &str) -> Option<(usize, u32)> {
    TOPICS.iter().enumerate().find_map(|(i, (prefix, _, _))| {
        let inst = stem.strip_prefix(prefix)?.strip_prefix('_')?;
        // All digits, so `vehicle_local_position_setpoint_0` is not a match.
        if inst.is_empty() || !inst.bytes().all(|b| b.is_ascii_digit()) {
            return None;
        }
        Some((i, inst.parse().ok()?))
    })
}

/// Source names: instance `i` > 0 gets `_i`; a topic whose source an earlier topic of
/// TOPICS already gives (sensor_gps and vehicle_gps_position both present) is named
/// after itself.
fn name_sources(files: &mut [TopicFile]) {
    files.sort_by_key(|f| f.order);
    let mut claimed: Vec<(&str, usize)> = Vec::new();
    for f in files.iter_mut() {
        let (prefix, base, _) = TOPICS[f.order.0];
        let base = match claimed.iter().find(|(b, _)| *b == base) {
            Some((_, owner)) if *owner != f.order.0 => prefix,
            Some(_) => base,
            None => {
                claimed.push((base, f.order.0));
                base
            }
        };
        f.source = if f.order.1 == 0 {
            base.to_string()
        } else {
            format!("{base}_{}", f.order.1)
        };
    }
}

fn find_topic_files(dir: &Path) -> Result<Vec<TopicFile>, Px4LogError> {
    let list_err = |source| Px4LogError::ListDir {
        dir: dir.to_path_buf(),
        source,
    };
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(list_err)? {
        let entry = entry.map_err(list_err)?;
        let file_name = entry.file_name();
        let Some(file_name) = file_name.to_str() else {
            continue;
        };
        let (stem, gzip) = match (
            file_name.strip_suffix(".csv.gz"),
            file_name.strip_suffix(".csv"),
        ) {
            (Some(s), _) => (s, true),
            (None, Some(s)) => (s, false),
            _ => continue,
        };
        let Some((ti, inst)) = match_topic(stem) else {
            continue;
        };
        let path = entry.path();
        let bytes = std::fs::metadata(&path)
            .map_err(|source| Px4LogError::Open {
                file: path.clone(),
                source,
            })?
            .len();
        files.push(TopicFile {
            name: format!("{}_{inst}", TOPICS[ti].0),
            source: String::new(),
            kind: TOPICS[ti].2,
            order: (ti, inst),
            data: TopicData::Csv { bytes, gzip },
            path,
        });
    }
    if files.is_empty() {
        let looked_for = TOPICS
            .iter()
            .map(|(p, _, _)| format!("{p}_<i>.csv"))
            .collect::<Vec<_>>()
            .join(", ");
        return Err(Px4LogError::NoKnownTopics {
            dir: dir.to_path_buf(),
            looked_for,
        });
    }
    name_sources(&mut files);
    Ok(files)
}

/// The topics of a ULog file that replay reads, parsed by PX4's `px4-ulog` crate.
fn ulog_topic_files(file: &Path) -> Result<Vec<TopicFile>, Px4LogError> {
    use px4_ulog::full_parser::SomeVec;
    let path_str = file.to_str().ok_or_else(|| Px4LogError::Ulog {
        file: file.to_path_buf(),
        reason: "the path is not UTF-8".into(),
    })?;
    // The crate panics on some corrupt files instead of returning an error: a bad log
    // must be an error that names it, never a crash of the replay.
    let parsed = std::panic::catch_unwind(|| px4_ulog::full_parser::read_file(path_str))
        .map_err(|_| Px4LogError::Ulog {
            file: file.to_path_buf(),
            reason: "the ULog parser failed on a corrupt record".into(),
        })?
        .map_err(|e| Px4LogError::Ulog {
            file: file.to_path_buf(),
            reason: e.to_string(),
        })?;
    let mut files = Vec::new();
    for (name, instances) in &parsed.messages {
        let Some(ti) = TOPICS.iter().position(|(p, _, _)| p == name) else {
            continue;
        };
        for (multi, fields) in instances {
            let inst = u32::from(multi.value());
            let mut cols: Vec<(&String, Vec<f64>)> = fields
                .iter()
                .map(|(k, v)| {
                    let col: Vec<f64> = match v {
                        SomeVec::Int8(x) => x.iter().map(|&v| v.into()).collect(),
                        SomeVec::UInt8(x) => x.iter().map(|&v| v.into()).collect(),
                        SomeVec::Int16(x) => x.iter().map(|&v| v.into()).collect(),
                        SomeVec::UInt16(x) => x.iter().map(|&v| v.into()).collect(),
                        SomeVec::Int32(x) => x.iter().map(|&v| v.into()).collect(),
                        SomeVec::UInt32(x) => x.iter().map(|&v| v.into()).collect(),
                        SomeVec::Int64(x) => x.iter().map(|&v| v as f64).collect(),
                        SomeVec::UInt64(x) => x.iter().map(|&v| v as f64).collect(),
                        SomeVec::Float(x) => x.iter().map(|&v| v.into()).collect(),
                        SomeVec::Double(x) => x.clone(),
                        SomeVec::Bool(x) => x.iter().map(|&v| f64::from(u8::from(v))).collect(),
                        SomeVec::Char(x) => x.iter().map(|&v| f64::from(u32::from(v))).collect(),
                    };
                    (k, col)
                })
                .collect();
            // `timestamp` first, the rest by name: a stable header.
            cols.sort_by(|a, b| (a.0 != "timestamp", a.0).cmp(&(b.0 != "timestamp", b.0)));
            let header = cols.iter().map(|(k, _)| (*k).clone()).collect();
            let columns = cols.into_iter().map(|(_, c)| c).collect();
            files.push(TopicFile {
                path: file.to_path_buf(),
                name: format!("{name}_{inst}"),
                source: String::new(),
                kind: TOPICS[ti].2,
                order: (ti, inst),
                data: TopicData::Ulog { header, columns },
            });
        }
    }
    if files.is_empty() {
        return Err(Px4LogError::Ulog {
            file: file.to_path_buf(),
            reason: "none of the topics replay reads is in the log".into(),
        });
    }
    name_sources(&mut files);
    Ok(files)
}

struct Progress<'a> {
    done: u64,
    total: u64,
    reported: u64,
    cb: &'a mut dyn FnMut(u64, u64),
}

impl Progress<'_> {
    const STEP: u64 = 256 * 1024;

    fn advance(&mut self, bytes: usize) {
        // A file that grew since it was listed must not report past the total.
        self.done = (self.done + bytes as u64).min(self.total);
        if self.done - self.reported >= Self::STEP {
            self.reported = self.done;
            (self.cb)(self.done, self.total);
        }
    }
}

/// Counts one row's outcome and keeps its sample.
fn take_row(
    summary: &mut TopicSummary,
    source: &Arc<str>,
    result: Result<(Micros, SensorData), Px4LogError>,
    samples: &mut Vec<Sample>,
) {
    summary.rows += 1;
    match result {
        Ok((stamp, data)) => {
            summary.span_us = Some(match summary.span_us {
                None => (stamp, stamp),
                Some((a, b)) => (a.min(stamp), b.max(stamp)),
            });
            samples.push(Sample {
                source: source.clone(),
                stamp_us: Some(stamp),
                arrival_us: stamp,
                data,
            });
        }
        Err(e) => {
            summary.skipped += 1;
            summary.first_error.get_or_insert(e);
        }
    }
}

fn read_topic(
    tf: &TopicFile,
    samples: &mut Vec<Sample>,
    prog: &mut Progress<'_>,
) -> Result<TopicSummary, Px4LogError> {
    let mut summary = TopicSummary {
        name: tf.name.clone(),
        source: tf.source.clone(),
        rows: 0,
        skipped: 0,
        first_error: None,
        span_us: None,
    };
    let source: Arc<str> = Arc::from(tf.source.as_str());
    let file = tf.path.as_path();
    match &tf.data {
        TopicData::Ulog { header, columns } => {
            let mapper = Mapper::new(tf.kind, file, header)?;
            let rows = columns.first().map_or(0, Vec::len);
            let mut values = vec![0.0; columns.len()];
            for i in 0..rows {
                for (v, c) in values.iter_mut().zip(columns) {
                    *v = c.get(i).copied().unwrap_or(f64::NAN);
                }
                let row = Row {
                    file,
                    line: i + 1,
                    header,
                    fields: Fields::Num(&values),
                };
                take_row(&mut summary, &source, mapper.map(&row), samples);
                prog.advance(1);
            }
        }
        TopicData::Csv { gzip, .. } => {
            let f = File::open(file).map_err(|source| Px4LogError::Open {
                file: file.to_path_buf(),
                source,
            })?;
            let reader: Box<dyn BufRead> = if *gzip {
                Box::new(BufReader::with_capacity(
                    1 << 16,
                    flate2::read::GzDecoder::new(f),
                ))
            } else {
                Box::new(BufReader::with_capacity(1 << 16, f))
            };
            read_csv(tf, reader, &source, &mut summary, samples, prog)?;
        }
    }
    Ok(summary)
}

fn read_csv(
    tf: &TopicFile,
    mut reader: Box<dyn BufRead>,
    source: &Arc<str>,
    summary: &mut TopicSummary,
    samples: &mut Vec<Sample>,
    prog: &mut Progress<'_>,
) -> Result<(), Px4LogError> {
    let file = tf.path.as_path();
    let io_err = |line, source| Px4LogError::Io {
        file: file.to_path_buf(),
        line,
        source,
    };
    // Progress counts the file's bytes on disk: compressed ones advance by a share.
    let ratio = match &tf.data {
        TopicData::Csv { gzip: true, .. } => 0.2,
        _ => 1.0,
    };
    let mut buf = Vec::with_capacity(1024);
    let n = reader
        .read_until(b'\n', &mut buf)
        .map_err(|e| io_err(1, e))?;
    prog.advance((n as f64 * ratio) as usize);
    let header_text = std::str::from_utf8(&buf).map_err(|_| Px4LogError::NotUtf8 {
        file: file.to_path_buf(),
        line: 1,
    })?;
    let header: Vec<String> = header_text
        .trim_end_matches(['\r', '\n'])
        .split(',')
        .map(|s| s.trim().to_string())
        .collect();
    if n == 0 || header.iter().all(|h| h.is_empty()) {
        return Err(Px4LogError::NoHeader {
            file: file.to_path_buf(),
        });
    }
    let mapper = Mapper::new(tf.kind, file, &header)?;
    let mut line = 1;
    loop {
        buf.clear();
        let n = reader
            .read_until(b'\n', &mut buf)
            .map_err(|e| io_err(line + 1, e))?;
        if n == 0 {
            break;
        }
        line += 1;
        prog.advance((n as f64 * ratio) as usize);
        let result = match std::str::from_utf8(&buf) {
            Ok(text) => {
                let text = text.trim_end_matches(['\r', '\n']);
                // A trailing blank line is layout, not a row.
                if text.trim().is_empty() {
                    continue;
                }
                let fields: Vec<&str> = text.split(',').collect();
                let row = Row {
                    file,
                    line,
                    header: &header,
                    fields: Fields::Text(&fields),
                };
                row.check_len().and_then(|()| mapper.map(&row))
            }
            Err(_) => Err(Px4LogError::NotUtf8 {
                file: file.to_path_buf(),
                line,
            }),
        };
        take_row(summary, source, result, samples);
    }
    Ok(())
}

/// One data row with what its errors need to name: CSV text, or a ULog row's values.
struct Row<'a> {
    file: &'a Path,
    line: usize,
    header: &'a [String],
    fields: Fields<'a>,
}

#[derive(Clone, Copy)]
enum Fields<'a> {
    Text(&'a [&'a str]),
    Num(&'a [f64]),
}

impl Fields<'_> {
    fn len(&self) -> usize {
        match self {
            Fields::Text(t) => t.len(),
            Fields::Num(n) => n.len(),
        }
    }
}

impl Row<'_> {
    fn check_len(&self) -> Result<(), Px4LogError> {
        let (expected, found) = (self.header.len(), self.fields.len());
        if expected == found {
            return Ok(());
        }
        Err(Px4LogError::ColumnCount {
            file: self.file.to_path_buf(),
            line: self.line,
            column: expected.min(found) + 1,
            expected,
            found,
        })
    }

    fn text(&self, c: usize) -> String {
        match self.fields {
            Fields::Text(t) => t.get(c).map_or("", |s| s.trim()).to_string(),
            Fields::Num(n) => n.get(c).map_or(String::new(), |v| v.to_string()),
        }
    }

    fn name(&self, c: usize) -> String {
        self.header.get(c).cloned().unwrap_or_default()
    }

    fn bad(&self, c: usize, expected: &'static str) -> Px4LogError {
        Px4LogError::BadValue {
            file: self.file.to_path_buf(),
            line: self.line,
            column: c + 1,
            name: self.name(c),
            text: self.text(c),
            expected,
        }
    }

    fn unusable(&self, c: usize, reason: &'static str) -> Px4LogError {
        Px4LogError::Unusable {
            file: self.file.to_path_buf(),
            line: self.line,
            column: c + 1,
            name: self.name(c),
            reason,
        }
    }

    /// A float; `nan`/`inf` parse (PX4's "unknown").
    fn f64(&self, c: usize) -> Result<f64, Px4LogError> {
        match self.fields {
            Fields::Text(t) => t
                .get(c)
                .map_or("", |s| s.trim())
                .parse()
                .map_err(|_| self.bad(c, "a number")),
            Fields::Num(n) => n.get(c).copied().ok_or_else(|| self.bad(c, "a number")),
        }
    }

    fn finite(&self, c: usize, reason: &'static str) -> Result<f64, Px4LogError> {
        let v = self.f64(c)?;
        if v.is_finite() {
            Ok(v)
        } else {
            Err(self.unusable(c, reason))
        }
    }

    fn int(
        &self,
        c: usize,
        min: i64,
        max: i64,
        expected: &'static str,
    ) -> Result<i64, Px4LogError> {
        let v = match self.fields {
            Fields::Text(t) => t.get(c).and_then(|s| s.trim().parse::<i64>().ok()),
            Fields::Num(n) => n
                .get(c)
                .filter(|v| v.fract() == 0.0 && v.abs() < 9.0e18)
                .map(|v| *v as i64),
        };
        match v {
            Some(v) if (min..=max).contains(&v) => Ok(v),
            _ => Err(self.bad(c, expected)),
        }
    }

    fn u8(&self, c: usize) -> Result<u8, Px4LogError> {
        Ok(self.int(c, 0, 255, "an integer 0..=255")? as u8)
    }

    fn stamp(&self, c: usize) -> Result<Micros, Px4LogError> {
        self.int(c, 0, i64::MAX, "a timestamp in µs")
    }

    fn vec3(&self, c: [usize; 3]) -> Result<Vector3<f64>, Px4LogError> {
        Ok(Vector3::new(
            self.f64(c[0])?,
            self.f64(c[1])?,
            self.f64(c[2])?,
        ))
    }

    /// Quaternion w, x, y, z; `None` if non-finite or zero (PX4's "invalid").
    fn quat(&self, c: [usize; 4]) -> Result<Option<UnitQuaternion<f64>>, Px4LogError> {
        let q = Quaternion::new(
            self.f64(c[0])?,
            self.f64(c[1])?,
            self.f64(c[2])?,
            self.f64(c[3])?,
        );
        let n = q.norm();
        Ok((n.is_finite() && n > 1e-6).then(|| UnitQuaternion::from_quaternion(q)))
    }

    /// A 6×6 covariance from its row-major upper triangle (21 values); `None` if any is
    /// NaN (PX4 marks an unknown block with NaN and we keep no half-known matrices).
    fn urt6(&self, c: &[usize; 21]) -> Result<Option<Matrix6<f64>>, Px4LogError> {
        let mut m = Matrix6::zeros();
        let mut k = 0;
        for i in 0..6 {
            for j in i..6 {
                let v = self.f64(c[k])?;
                if !v.is_finite() {
                    return Ok(None);
                }
                m[(i, j)] = v;
                m[(j, i)] = v;
                k += 1;
            }
        }
        Ok(Some(m))
    }
}

/// Column positions for one topic's fields, resolved from its header once.
struct Cols<'a> {
    file: &'a Path,
    header: &'a [String],
}

impl Cols<'_> {
    fn get(&self, name: &str) -> Result<usize, Px4LogError> {
        self.opt(name).ok_or_else(|| Px4LogError::MissingColumn {
            file: self.file.to_path_buf(),
            column: name.to_string(),
        })
    }

    fn opt(&self, name: &str) -> Option<usize> {
        self.header.iter().position(|h| h == name)
    }

    fn arr<const N: usize>(&self, name: &str) -> Result<[usize; N], Px4LogError> {
        let mut out = [0; N];
        for (i, o) in out.iter_mut().enumerate() {
            *o = self.get(&format!("{name}[{i}]"))?;
        }
        Ok(out)
    }

    fn list<const N: usize>(&self, names: [&str; N]) -> Result<[usize; N], Px4LogError> {
        let mut out = [0; N];
        for (o, n) in out.iter_mut().zip(names) {
            *o = self.get(n)?;
        }
        Ok(out)
    }
}

enum Mapper {
    Attitude(AttitudeCols),
    Imu(ImuCols),
    SensorCombined(Vec3Pair),
    AngularVelocity(Vec3Pair),
    Gps(GpsCols),
    Range(RangeCols),
    Flow(FlowCols),
    Vio(Box<VioCols>),
    Ekf2(Ekf2Cols),
    Ekf2FlowGyro(Vec3Pair),
    LandDetected(FlagCol),
    Armed(FlagCol),
}

/// A timestamp and up to two vectors (sensor_combined: gyro, accel).
struct Vec3Pair {
    t: usize,
    a: [usize; 3],
    b: Option<[usize; 3]>,
}

struct FlagCol {
    t: usize,
    flag: usize,
}

struct GpsCols {
    t: usize,
    /// (lat, lon, alt): 1e-7° and mm (≤ 1.14) or degrees and metres (1.15).
    lat_lon_alt: [usize; 3],
    degrees: bool,
    fix: usize,
    eph: usize,
    epv: usize,
    vel: [usize; 3],
    vel_valid: usize,
    satellites: usize,
    hdop: usize,
    vdop: usize,
}

struct AttitudeCols {
    t: usize,
    q: [usize; 4],
}

struct ImuCols {
    t: usize,
    dang: [usize; 3],
    dvel: [usize; 3],
    dang_dt: usize,
    dvel_dt: usize,
}

struct RangeCols {
    t: usize,
    distance: usize,
    min: usize,
    max: usize,
    variance: usize,
    quality: usize,
    orientation: usize,
}

struct FlowCols {
    t: usize,
    flow: [usize; 2],
    gyro: [usize; 3],
    dt: usize,
    quality: usize,
    /// vehicle_optical_flow's module distance (NaN without one).
    distance: Option<usize>,
}

struct VioCols {
    t: usize,
    pos: [usize; 3],
    q: [usize; 4],
    vel: [usize; 3],
    rates: [usize; 3],
    /// `local_frame` (≤ 1.13) or `pose_frame` (≥ 1.14).
    pose_frame: usize,
    velocity_frame: usize,
    reset_counter: usize,
    /// Added to vehicle_odometry after v1.13; absent in older logs.
    quality: Option<usize>,
    cov: VioCov,
    /// The frame constants: ≤ 1.13 earth-fixed NED 0 / FRD 1, ≥ 1.14 NED 1 / FRD 2;
    /// body FRD is 3 in both.
    earth_frames: [i64; 2],
}

/// How vehicle_visual_odometry carries its uncertainty (inside a boxed `VioCols`: one
/// per topic, so the size difference of the variants costs nothing).
#[allow(clippy::large_enum_variant)]
enum VioCov {
    /// ≤ 1.13: 6×6 upper triangles (pose, velocity).
    Urt { pose: [usize; 21], vel: [usize; 21] },
    /// ≥ 1.14: per-axis variances.
    Var {
        pos: [usize; 3],
        att: [usize; 3],
        vel: [usize; 3],
    },
}

struct Ekf2Cols {
    t: usize,
    pos: [usize; 3],
    vel: [usize; 3],
    heading: usize,
    /// xy_valid, z_valid, v_xy_valid, v_z_valid.
    valid: [usize; 4],
}

/// uORB vehicle_odometry frame constants (v1.12/1.13).
const LOCAL_FRAME_NED: i64 = 0;
/// Earth-fixed FRD with an arbitrary heading: down is down, so it converts like NED.
const LOCAL_FRAME_FRD: i64 = 1;
const BODY_FRAME_FRD: i64 = 3;

/// NED → ENU (and FRD → FLU below) as matrices, for covariances.
fn ned_to_enu_matrix() -> Matrix3<f64> {
    Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0)
}

fn frd_to_flu_matrix() -> Matrix3<f64> {
    Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0))
}

/// `c` transformed by the block-diagonal map `diag(a, b)`.
fn transform_cov6(c: Matrix6<f64>, a: Matrix3<f64>, b: Matrix3<f64>) -> Matrix6<f64> {
    let mut j = Matrix6::zeros();
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&a);
    j.fixed_view_mut::<3, 3>(3, 3).copy_from(&b);
    j * c * j.transpose()
}

impl Mapper {
    fn new(kind: Kind, file: &Path, header: &[String]) -> Result<Self, Px4LogError> {
        let h = Cols { file, header };
        let t = h.get("timestamp")?;
        Ok(match kind {
            Kind::Attitude => Mapper::Attitude(AttitudeCols {
                t,
                q: h.list(["states[0]", "states[1]", "states[2]", "states[3]"])?,
            }),
            Kind::VehicleAttitude => Mapper::Attitude(AttitudeCols { t, q: h.arr("q")? }),
            Kind::Imu => Mapper::Imu(ImuCols {
                t,
                dang: h.arr("delta_angle")?,
                dvel: h.arr("delta_velocity")?,
                dang_dt: h.get("delta_angle_dt")?,
                dvel_dt: h.get("delta_velocity_dt")?,
            }),
            Kind::SensorCombined => Mapper::SensorCombined(Vec3Pair {
                t,
                a: h.arr("gyro_rad")?,
                b: Some(h.arr("accelerometer_m_s2")?),
            }),
            Kind::AngularVelocity => Mapper::AngularVelocity(Vec3Pair {
                t,
                a: h.arr("xyz")?,
                b: None,
            }),
            Kind::Gps => {
                let degrees = h.opt("latitude_deg").is_some();
                Mapper::Gps(GpsCols {
                    t,
                    lat_lon_alt: if degrees {
                        h.list(["latitude_deg", "longitude_deg", "altitude_msl_m"])?
                    } else {
                        h.list(["lat", "lon", "alt"])?
                    },
                    degrees,
                    fix: h.get("fix_type")?,
                    eph: h.get("eph")?,
                    epv: h.get("epv")?,
                    vel: h.list(["vel_n_m_s", "vel_e_m_s", "vel_d_m_s"])?,
                    vel_valid: h.get("vel_ned_valid")?,
                    satellites: h.get("satellites_used")?,
                    hdop: h.get("hdop")?,
                    vdop: h.get("vdop")?,
                })
            }
            Kind::Range => Mapper::Range(RangeCols {
                t,
                distance: h.get("current_distance")?,
                min: h.get("min_distance")?,
                max: h.get("max_distance")?,
                variance: h.get("variance")?,
                quality: h.get("signal_quality")?,
                orientation: h.get("orientation")?,
            }),
            Kind::Flow => Mapper::Flow(FlowCols {
                t,
                flow: h.list(["pixel_flow_x_integral", "pixel_flow_y_integral"])?,
                gyro: h.list([
                    "gyro_x_rate_integral",
                    "gyro_y_rate_integral",
                    "gyro_z_rate_integral",
                ])?,
                dt: h.get("integration_timespan")?,
                quality: h.get("quality")?,
                distance: None,
            }),
            Kind::VehicleFlow => Mapper::Flow(FlowCols {
                t,
                flow: h.arr("pixel_flow")?,
                gyro: h.arr("delta_angle")?,
                dt: h.get("integration_timespan_us")?,
                quality: h.get("quality")?,
                distance: h.opt("distance_m"),
            }),
            Kind::Vio if h.opt("local_frame").is_some() => Mapper::Vio(Box::new(VioCols {
                t,
                pos: h.list(["x", "y", "z"])?,
                q: h.arr("q")?,
                vel: h.list(["vx", "vy", "vz"])?,
                rates: h.list(["rollspeed", "pitchspeed", "yawspeed"])?,
                pose_frame: h.get("local_frame")?,
                velocity_frame: h.get("velocity_frame")?,
                reset_counter: h.get("reset_counter")?,
                quality: h.opt("quality"),
                cov: VioCov::Urt {
                    pose: h.arr("pose_covariance")?,
                    vel: h.arr("velocity_covariance")?,
                },
                earth_frames: [LOCAL_FRAME_NED, LOCAL_FRAME_FRD],
            })),
            Kind::Vio => Mapper::Vio(Box::new(VioCols {
                t,
                pos: h.arr("position")?,
                q: h.arr("q")?,
                vel: h.arr("velocity")?,
                rates: h.arr("angular_velocity")?,
                pose_frame: h.get("pose_frame")?,
                velocity_frame: h.get("velocity_frame")?,
                reset_counter: h.get("reset_counter")?,
                quality: Some(h.get("quality")?),
                cov: VioCov::Var {
                    pos: h.arr("position_variance")?,
                    att: h.arr("orientation_variance")?,
                    vel: h.arr("velocity_variance")?,
                },
                earth_frames: [1, 2],
            })),
            Kind::Ekf2 => Mapper::Ekf2(Ekf2Cols {
                t,
                pos: h.list(["x", "y", "z"])?,
                vel: h.list(["vx", "vy", "vz"])?,
                heading: h.get("heading")?,
                valid: h.list(["xy_valid", "z_valid", "v_xy_valid", "v_z_valid"])?,
            }),
            Kind::Ekf2FlowGyro => Mapper::Ekf2FlowGyro(Vec3Pair {
                t: h.get("timestamp_sample")?,
                a: h.arr("gyro_rate_integral")?,
                b: None,
            }),
            Kind::LandDetected => Mapper::LandDetected(FlagCol {
                t,
                flag: h.get("landed")?,
            }),
            Kind::Armed => Mapper::Armed(FlagCol {
                t,
                flag: h.get("armed")?,
            }),
        })
    }

    fn map(&self, r: &Row<'_>) -> Result<(Micros, SensorData), Px4LogError> {
        match self {
            Mapper::Attitude(c) => attitude(c, r),
            Mapper::Imu(c) => imu(c, r),
            Mapper::SensorCombined(c) => sensor_combined(c, r),
            Mapper::AngularVelocity(c) | Mapper::Ekf2FlowGyro(c) => {
                // Kept raw (FRD): the post-processing that attaches them converts.
                let t = r.stamp(c.t)?;
                let g = r.vec3(c.a)?;
                if !g.iter().all(|v| v.is_finite()) {
                    return Err(r.unusable(c.a[0], "not finite"));
                }
                let g = match self {
                    Mapper::AngularVelocity(_) => frames::frd_to_flu(g),
                    _ => g,
                };
                Ok((t, SensorData::Imu(Imu::from_rates(Some(g), None))))
            }
            Mapper::Gps(c) => gps(c, r),
            Mapper::Range(c) => range(c, r),
            Mapper::Flow(c) => flow(c, r),
            Mapper::Vio(c) => vio(c, r),
            Mapper::Ekf2(c) => ekf2(c, r),
            Mapper::LandDetected(c) => {
                let landed = r.int(c.flag, 0, 1, "0 or 1")? == 1;
                Ok((
                    r.stamp(c.t)?,
                    SensorData::VehicleState(VehicleState {
                        armed: None,
                        landed: Some(if landed {
                            LandedState::OnGround
                        } else {
                            LandedState::InAir
                        }),
                    }),
                ))
            }
            Mapper::Armed(c) => Ok((
                r.stamp(c.t)?,
                SensorData::VehicleState(VehicleState {
                    armed: Some(r.int(c.flag, 0, 1, "0 or 1")? == 1),
                    landed: None,
                }),
            )),
        }
    }
}

/// sensor_combined: gyro (rad/s) and specific force (m/s²), FRD → FLU.
fn sensor_combined(c: &Vec3Pair, r: &Row<'_>) -> Result<(Micros, SensorData), Px4LogError> {
    let t = r.stamp(c.t)?;
    let finite = |v: &Vector3<f64>| v.iter().all(|x| x.is_finite());
    let g = r.vec3(c.a)?;
    let a = match c.b {
        Some(b) => r.vec3(b)?,
        None => Vector3::repeat(f64::NAN),
    };
    let gyro = finite(&g).then(|| frames::frd_to_flu(g));
    let accel = finite(&a).then(|| frames::frd_to_flu(a));
    if gyro.is_none() && accel.is_none() {
        return Err(r.unusable(c.a[0], "neither gyro nor accel finite"));
    }
    Ok((t, SensorData::Imu(Imu::from_rates(gyro, accel))))
}

/// sensor_gps / vehicle_gps_position: fix, position, velocity (NED → ENU), accuracy.
fn gps(c: &GpsCols, r: &Row<'_>) -> Result<(Micros, SensorData), Px4LogError> {
    let t = r.stamp(c.t)?;
    let [la, lo, al] = c.lat_lon_alt;
    let (lat, lon, alt) = if c.degrees {
        (r.f64(la)?, r.f64(lo)?, r.f64(al)?)
    } else {
        (r.f64(la)? * 1e-7, r.f64(lo)? * 1e-7, r.f64(al)? * 1e-3)
    };
    if !(lat.is_finite() && lon.is_finite() && alt.is_finite())
        || lat.abs() > 90.0
        || lon.abs() > 180.0
    {
        return Err(r.unusable(la, "position not on Earth"));
    }
    // PX4's fix_type: 0-1 none, 2 2D, 3 3D, 4 SBAS, 5 RTK float, 6 RTK fixed, 8 extrapolated.
    let fix = match r.int(c.fix, 0, 255, "an integer 0..=255")? {
        2 => GnssFixType::Fix2d,
        3 | 8 => GnssFixType::Fix3d,
        4 => GnssFixType::Dgps,
        5 => GnssFixType::RtkFloat,
        6 => GnssFixType::RtkFixed,
        _ => GnssFixType::NoFix,
    };
    let (eph, epv) = (r.f64(c.eph)?, r.f64(c.epv)?);
    let position_cov = (eph.is_finite() && epv.is_finite() && eph > 0.0 && epv > 0.0)
        .then(|| Matrix3::from_diagonal(&Vector3::new(eph * eph, eph * eph, epv * epv)));
    let vel = r.vec3(c.vel)?;
    let velocity = (r.int(c.vel_valid, 0, 1, "0 or 1")? == 1 && vel.iter().all(|v| v.is_finite()))
        .then(|| frames::ned_to_enu(vel));
    let dop = |col: usize| -> Result<Option<f64>, Px4LogError> {
        let v = r.f64(col)?;
        Ok((v.is_finite() && v > 0.0).then_some(v))
    };
    Ok((
        t,
        SensorData::Gnss(GnssFix {
            lat_deg: lat,
            lon_deg: lon,
            alt_m: alt,
            fix,
            position_cov,
            satellites: Some(r.u8(c.satellites)?),
            hdop: dop(c.hdop)?,
            vdop: dop(c.vdop)?,
            velocity,
        }),
    ))
}

/// EKF2's quaternion (body FRD → NED), standing in for the autopilot attitude a
/// companion computer would receive. estimator_states has no body rates, and is logged
/// at only 1 Hz in this export.
fn attitude(c: &AttitudeCols, r: &Row<'_>) -> Result<(Micros, SensorData), Px4LogError> {
    let t = r.stamp(c.t)?;
    let q = r
        .quat(c.q)?
        .ok_or_else(|| r.unusable(c.q[0], "quaternion not finite or zero"))?;
    Ok((
        t,
        SensorData::Attitude(Attitude {
            orientation: frames::q_ned_frd_to_enu_flu(q),
            rates: None,
        }),
    ))
}

/// vehicle_imu: delta angle/velocity over their dt (µs), FRD → FLU. NOTE: ulog exports
/// log this topic at only 2–20 Hz (here ~2 Hz), far too slow to drive the prediction;
/// it is useful as a bias and gravity check only.
fn imu(c: &ImuCols, r: &Row<'_>) -> Result<(Micros, SensorData), Px4LogError> {
    let t = r.stamp(c.t)?;
    let per_s = |d: Vector3<f64>, dt_col: usize| -> Result<Option<Vector3<f64>>, Px4LogError> {
        let dt = r.int(dt_col, 0, u32::MAX.into(), "an interval in µs")? as f64 * 1e-6;
        Ok((dt > 0.0 && d.iter().all(|v| v.is_finite())).then(|| frames::frd_to_flu(d / dt)))
    };
    let gyro = per_s(r.vec3(c.dang)?, c.dang_dt)?;
    let accel = per_s(r.vec3(c.dvel)?, c.dvel_dt)?;
    if gyro.is_none() && accel.is_none() {
        return Err(r.unusable(c.dang_dt, "no finite delta with a non-zero dt"));
    }
    Ok((t, SensorData::Imu(Imu::from_rates(gyro, accel))))
}

fn range(c: &RangeCols, r: &Row<'_>) -> Result<(Micros, SensorData), Px4LogError> {
    let t = r.stamp(c.t)?;
    let distance_m = r.finite(c.distance, "distance not finite")?;
    if distance_m < 0.0 {
        return Err(r.unusable(c.distance, "negative distance"));
    }
    let (min, max) = (r.f64(c.min)?, r.f64(c.max)?);
    // Some drivers leave both limits 0: that is "not set", not a zero-width window.
    let limits =
        (min.is_finite() && max.is_finite() && min >= 0.0 && max > min).then_some((min, max));
    let variance = r.f64(c.variance)?;
    // PX4: -1 unknown, 0 invalid, 1..100 percent. The sample follows MAVLink (0 unknown,
    // 1 invalid), and this is the mapping PX4's own DISTANCE_SENSOR stream applies.
    let signal_quality = match r.int(c.quality, i8::MIN.into(), 100, "an integer -128..=100")? {
        q if q < 0 => None,
        0 => Some(1),
        q => Some(q as u8),
    };
    Ok((
        t,
        SensorData::Range(Range {
            distance_m,
            min_m: limits.map(|l| l.0),
            max_m: limits.map(|l| l.1),
            signal_quality,
            variance: (variance.is_finite() && variance > 0.0).then_some(variance),
            orientation: Some(r.u8(c.orientation)?),
        }),
    ))
}

/// optical_flow: PX4 integrates flow and gyro in the sensor's (rotated to body) FRD
/// axes, a right-handed rotation about an axis counting positive, so that
/// flow = ω + (−v_y, v_x)/d in FRD. The sample's convention (sample.rs, the simulator,
/// the estimator) is the same sign rule in FLU axes, rate = ω + (v_y, −v_x)/d: y of both
/// the flow and the gyro changes sign. Checked on the real flight against VIO (tests).
/// A row without an integration time has no rate and is skipped; a NaN gyro (modules
/// without one) becomes `None`.
fn flow(c: &FlowCols, r: &Row<'_>) -> Result<(Micros, SensorData), Px4LogError> {
    let t = r.stamp(c.t)?;
    let dt_us = r.int(c.dt, 0, u32::MAX.into(), "an interval in µs")?;
    if dt_us == 0 {
        return Err(r.unusable(c.dt, "integration_timespan is 0: no rate"));
    }
    let dt = dt_us as f64 * 1e-6;
    let fx = r.finite(c.flow[0], "flow integral not finite")?;
    let fy = r.finite(c.flow[1], "flow integral not finite")?;
    let g = r.vec3(c.gyro)?;
    Ok((
        t,
        SensorData::Flow(OpticalFlow {
            rate: Some(Vector2::new(fx / dt, -fy / dt)),
            gyro: g
                .iter()
                .all(|v| v.is_finite())
                .then(|| frames::frd_to_flu(g / dt)),
            velocity: None,
            integration_s: Some(dt),
            quality: r.u8(c.quality)?,
            status: None,
            // optical_flow's ground_distance_m is 0 without a module ToF (not read);
            // vehicle_optical_flow's distance_m is NaN without one. The range finder is
            // its own topic.
            tof: match c.distance {
                Some(col) => {
                    let d = r.f64(col)?;
                    (d.is_finite() && d > 0.0).then_some(Tof {
                        distance_m: d,
                        strength: None,
                        precision: None,
                        status: None,
                    })
                }
                None => None,
            },
        }),
    ))
}

/// vehicle_visual_odometry, both layouts: pose in an earth-fixed NED frame (or FRD with
/// an arbitrary heading, which converts the same way), body FRD; velocity in
/// `velocity_frame`, turned into body FLU as nav_msgs/Odometry has it; covariances as
/// 6×6 upper triangles (≤ 1.13) or per-axis variances (≥ 1.14).
fn vio(c: &VioCols, r: &Row<'_>) -> Result<(Micros, SensorData), Px4LogError> {
    let t = r.stamp(c.t)?;
    let pose_frame = r.int(c.pose_frame, 0, 255, "a frame constant")?;
    if !c.earth_frames.contains(&pose_frame) {
        return Err(r.unusable(c.pose_frame, "pose frame is neither NED nor FRD"));
    }
    let pos = r.vec3(c.pos)?;
    if !pos.iter().all(|v| v.is_finite()) {
        return Err(r.unusable(c.pos[0], "position not finite"));
    }
    let q_ned = r
        .quat(c.q)?
        .ok_or_else(|| r.unusable(c.q[0], "quaternion not finite or zero"))?;
    let q = frames::q_ned_frd_to_enu_flu(q_ned);
    let p = ned_to_enu_matrix();
    let f = frd_to_flu_matrix();
    // The linear map from the message's velocity to body FLU, if its frame is known.
    let vel_map = match r.int(c.velocity_frame, 0, 255, "a frame constant")? {
        v if c.earth_frames.contains(&v) => Some(q.to_rotation_matrix().matrix().transpose() * p),
        BODY_FRAME_FRD => Some(f),
        _ => None,
    };
    let vel = r.vec3(c.vel)?;
    let velocity = vel_map
        .filter(|_| vel.iter().all(|v| v.is_finite()))
        .map(|m| m * vel);
    let rates = r.vec3(c.rates)?;
    let angular_velocity = rates
        .iter()
        .all(|v| v.is_finite())
        .then(|| frames::frd_to_flu(rates));
    let (pose_cov, vel_cov) = match &c.cov {
        VioCov::Urt { pose, vel } => (r.urt6(pose)?, r.urt6(vel)?),
        VioCov::Var { pos, att, vel } => (
            diag6(r.vec3(*pos)?, r.vec3(*att)?),
            diag6(r.vec3(*vel)?, Vector3::zeros()),
        ),
    };
    let pose_cov = pose_cov.map(|cov| transform_cov6(cov, p, p));
    let twist_cov = match (vel_map, vel_cov) {
        (Some(m), Some(cov)) => Some(transform_cov6(cov, m, f)),
        _ => None,
    };
    let quality = match c.quality {
        Some(col) => {
            Some(r.int(col, i8::MIN.into(), i8::MAX.into(), "an integer -128..=127")? as i8)
        }
        None => None,
    };
    Ok((
        t,
        SensorData::Odometry(Odometry {
            position: frames::ned_to_enu(pos),
            orientation: q,
            velocity,
            angular_velocity,
            pose_cov,
            twist_cov,
            frame_id: "px4_vio_odom".to_string(),
            child_frame_id: "px4_vio_body".to_string(),
            reset_counter: Some(r.u8(c.reset_counter)?),
            quality,
        }),
    ))
}

/// A 6×6 diagonal covariance from two per-axis variance triples; `None` unless all are
/// finite and non-negative.
fn diag6(a: Vector3<f64>, b: Vector3<f64>) -> Option<Matrix6<f64>> {
    a.iter()
        .chain(b.iter())
        .all(|v| v.is_finite() && *v >= 0.0)
        .then(|| {
            let mut m = Matrix6::zeros();
            for i in 0..3 {
                m[(i, i)] = a[i];
                m[(i + 3, i + 3)] = b[i];
            }
            m
        })
}

/// vehicle_local_position: position and velocity only where PX4 flags them valid (PX4's
/// own LOCAL_POSITION_NED stream holds back invalid ones too); heading where finite. No
/// geodetic position: an indoor log has no reference (ref_lat/lon NaN).
fn ekf2(c: &Ekf2Cols, r: &Row<'_>) -> Result<(Micros, SensorData), Px4LogError> {
    let t = r.stamp(c.t)?;
    let flag = |col: usize| -> Result<bool, Px4LogError> { Ok(r.int(col, 0, 1, "0 or 1")? == 1) };
    let [xy, z, vxy, vz] = c.valid;
    let pos = r.vec3(c.pos)?;
    let vel = r.vec3(c.vel)?;
    let finite = |v: &Vector3<f64>| v.iter().all(|x| x.is_finite());
    let local_position = (flag(xy)? && flag(z)? && finite(&pos)).then(|| frames::ned_to_enu(pos));
    let velocity = (flag(vxy)? && flag(vz)? && finite(&vel)).then(|| frames::ned_to_enu(vel));
    let heading = r.f64(c.heading)?;
    let yaw = heading.is_finite().then(|| frames::yaw_ned_to_enu(heading));
    if local_position.is_none() && velocity.is_none() && yaw.is_none() {
        return Err(r.unusable(c.heading, "no valid position, velocity or heading"));
    }
    Ok((
        t,
        SensorData::AutopilotEstimate(AutopilotEstimate {
            local_position,
            geodetic: None,
            velocity,
            yaw,
        }),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    /// The real flight, trimmed copy in the repository's tests/data.
    const DATA_DIR: &str = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/data/px4-flow-vio-7c824ee5"
    );

    fn real() -> &'static Px4Log {
        static LOG: std::sync::OnceLock<Px4Log> = std::sync::OnceLock::new();
        LOG.get_or_init(|| match read_dir(Path::new(DATA_DIR)) {
            Ok(log) => log,
            Err(e) => panic!("reading {DATA_DIR}: {e}"),
        })
    }

    fn first_of<'a>(log: &'a Px4Log, source: &str) -> &'a Sample {
        match log.samples.iter().find(|s| &*s.source == source) {
            Some(s) => s,
            None => panic!("no sample from {source}"),
        }
    }

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol
    }

    /// A scratch directory removed on drop.
    struct TempDir(PathBuf);

    impl TempDir {
        fn new(tag: &str) -> Self {
            static N: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
            let n = N.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            let dir =
                std::env::temp_dir().join(format!("px4log-test-{}-{tag}-{n}", std::process::id()));
            let _ = std::fs::remove_dir_all(&dir);
            std::fs::create_dir_all(&dir).unwrap();
            TempDir(dir)
        }

        fn write(&self, name: &str, text: &str) {
            std::fs::write(self.0.join(name), text).unwrap();
        }
    }

    impl Drop for TempDir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    #[test]
    fn real_flight_topics_and_row_counts() {
        let log = real();
        let got: BTreeMap<&str, (&str, usize, usize)> = log
            .topics
            .iter()
            .map(|t| (t.name.as_str(), (t.source.as_str(), t.rows, t.skipped)))
            .collect();
        let want = BTreeMap::from([
            ("actuator_armed_0", ("armed", 616, 0)),
            ("distance_sensor_0", ("range", 14982, 0)),
            ("distance_sensor_1", ("range_1", 11849, 0)),
            ("estimator_optical_flow_vel_0", (EKF2_FLOW_GYRO, 17683, 0)),
            ("estimator_states_0", ("attitude_states", 308, 0)),
            ("optical_flow_0", ("flow", 17666, 0)),
            ("optical_flow_1", ("flow_1", 14438, 0)),
            ("vehicle_imu_0", ("vehicle_imu", 615, 0)),
            ("vehicle_imu_1", ("vehicle_imu_1", 615, 0)),
            ("vehicle_land_detected_0", ("land_detected", 311, 0)),
            ("vehicle_local_position_0", ("ekf2", 3077, 0)),
            ("vehicle_visual_odometry_0", ("vio", 8978, 0)),
        ]);
        assert_eq!(got, want);
        let total: usize = log.topics.iter().map(TopicSummary::samples).sum();
        assert_eq!(total, 72528 + 616 + 311 + 17683);
        // EKF2's flow gyro rows go into the flow samples; one `attitude` per EKF2
        // heading (vehicle_local_position rows), the stand-in for vehicle_attitude,
        // replaces the 308 EKF2 quaternions it takes its tilt from.
        assert_eq!(log.samples.len(), total - 17683 + 3077 - 308);
        assert!(!log
            .samples
            .iter()
            .any(|s| s.source.as_ref() == "attitude_states"));
        assert!(log.samples.iter().any(|s| s.source.as_ref() == "imu"));
        assert_eq!(log.stand_ins.len(), 3, "{:?}", log.stand_ins);
        let missing: Vec<&str> = log
            .missing
            .iter()
            .map(|m| m.split(':').next().unwrap_or(""))
            .collect();
        assert_eq!(missing, ["attitude", "GNSS"]);
    }

    #[test]
    fn real_flight_is_time_ordered_and_offline_stamped() {
        let log = real();
        assert!(log
            .samples
            .windows(2)
            .all(|w| w[0].stamp_us <= w[1].stamp_us));
        assert!(log.samples.iter().all(|s| s.stamp_us == Some(s.arrival_us)));
        let first = log.samples.first().and_then(|s| s.stamp_us);
        let last = log.samples.last().and_then(|s| s.stamp_us);
        assert_eq!(first, Some(1_009_456)); // actuator_armed's first row
        assert_eq!(last, Some(308_978_366)); // distance_sensor_0's last row
    }

    #[test]
    fn first_vio_row_converts_ned_frd_to_enu_flu() {
        let s = first_of(real(), "vio");
        assert_eq!(s.stamp_us, Some(2_760_553));
        let SensorData::Odometry(o) = &s.data else {
            panic!("vio is not odometry: {:?}", s.data)
        };
        // NED (0.048492964, -0.02906012, -0.099466674) → ENU.
        let p = o.position;
        assert!(
            close(p.x, -0.02906012, 1e-7) && close(p.y, 0.048492964, 1e-7),
            "{p}"
        );
        assert!(close(p.z, 0.099466674, 1e-7), "{p}");
        // q ≈ identity in NED/FRD: facing north, so body x → ENU +y, body z → up.
        let fwd = o.orientation * Vector3::x();
        let up = o.orientation * Vector3::z();
        assert!(fwd.y > 0.999 && up.z > 0.999, "{fwd} {up}");
        let q_ned = UnitQuaternion::from_quaternion(Quaternion::new(
            0.9999507,
            0.007620548,
            0.006365071,
            -7.955756e-05,
        ));
        assert!(o.orientation.angle_to(&frames::q_ned_frd_to_enu_flu(q_ned)) < 1e-9);
        // velocity_frame 3 = body FRD: y and z change sign.
        let v = o.velocity.unwrap_or_else(|| panic!("no velocity"));
        assert!((v - Vector3::new(0.001767282, -0.00012230266, -0.0012259282)).norm() < 1e-9);
        let w = o.angular_velocity.unwrap_or_else(|| panic!("no rates"));
        assert!((w - Vector3::new(-0.0002890111, 0.00017851277, -0.003386891)).norm() < 1e-9);
        assert_eq!(o.pose_cov, None); // all NaN in this log
        assert_eq!(o.twist_cov, None);
        assert_eq!(o.reset_counter, Some(0));
        assert_eq!(o.quality, None);
        assert_eq!(o.frame_id, "px4_vio_odom");
        assert_eq!(o.child_frame_id, "px4_vio_body");
    }

    #[test]
    fn vio_velocity_matches_its_position_derivative() {
        // velocity_frame 3 is body FRD: rotated to the world it must be d(position)/dt.
        let odo: Vec<(f64, &Odometry)> = real()
            .samples
            .iter()
            .filter_map(|s| match (&s.data, s.stamp_us) {
                (SensorData::Odometry(o), Some(t)) => Some((t as f64 * 1e-6, o)),
                _ => None,
            })
            .filter(|(t, _)| (215.0..300.0).contains(t))
            .collect();
        let (mut err, mut mag) = (0.0, 0.0);
        for w in odo.windows(3) {
            let ((t0, a), (_, b), (t2, c)) = (w[0], w[1], w[2]);
            let diff = (c.position - a.position) / (t2 - t0);
            let v = b.orientation * b.velocity.unwrap_or_else(|| panic!("no velocity"));
            err += (diff - v).norm_squared();
            mag += v.norm_squared();
        }
        assert!(err < 0.05 * mag, "residual {err} of {mag}");
    }

    #[test]
    fn first_flow_row_of_instance_1() {
        let s = first_of(real(), "flow_1");
        assert_eq!(s.stamp_us, Some(71_402_222));
        let SensorData::Flow(f) = &s.data else {
            panic!("not flow: {:?}", s.data)
        };
        let dt = 23451e-6;
        assert_eq!(f.integration_s, Some(dt));
        let r = f.rate.unwrap_or_else(|| panic!("no rate"));
        // FRD (x, y) → FLU (x, −y).
        assert!(
            close(r.x, -3.496911e-10 / dt, 1e-15) && close(r.y, -0.004 / dt, 1e-12),
            "{r}"
        );
        assert_eq!(f.gyro, None); // NaN x/y in the log: the module has no gyro
        assert_eq!(f.quality, 78);
        assert_eq!(f.tof, None);
    }

    #[test]
    fn flow_sign_matches_vio_motion_in_the_sample_convention() {
        // sample.rs / the estimator: rate = ω + (v_y, −v_x)/d, body FLU. Fit
        // rate = a·ω + b·(translation term) per axis, with VIO's body velocity and rates
        // and the range finder while airborne: both coefficients must come out positive
        // (b near 1). PX4's FRD y axis left unconverted would make both negative on y.
        // VIO's roll rate is noisy, hence the loose bound on a.
        let log = real();
        let series = |src: &str| -> Vec<(i64, &'static SensorData)> {
            log.samples
                .iter()
                .filter(|s| &*s.source == src)
                .filter_map(|s| s.stamp_us.map(|t| (t, &s.data)))
                .collect()
        };
        fn nearest<'a>(v: &[(i64, &'a SensorData)], t: i64) -> &'a SensorData {
            let i = v.partition_point(|(ts, _)| *ts < t).min(v.len() - 1);
            v[i].1
        }
        let vio = series("vio");
        let range = series("range");
        for src in ["flow", "flow_1"] {
            // Normal equations of the 2-parameter fit, per axis: [ww wd; wd dd]·(a, b) = (wy, dy).
            let mut m = [[0.0; 5]; 2];
            let mut n = 0;
            for (t, d) in series(src) {
                if !(215_000_000..305_000_000).contains(&t) {
                    continue;
                }
                let (SensorData::Flow(f), SensorData::Odometry(o), SensorData::Range(r)) =
                    (d, nearest(&vio, t), nearest(&range, t))
                else {
                    panic!("wrong sample kinds");
                };
                let (Some(rate), Some(v), Some(w)) = (f.rate, o.velocity, o.angular_velocity)
                else {
                    continue;
                };
                if r.distance_m < 0.5 {
                    continue;
                }
                let trans = [v.y / r.distance_m, -v.x / r.distance_m];
                for ax in 0..2 {
                    let (wa, da, ya) = (w[ax], trans[ax], rate[ax]);
                    for (k, x) in [wa * wa, wa * da, da * da, wa * ya, da * ya]
                        .iter()
                        .enumerate()
                    {
                        m[ax][k] += x;
                    }
                }
                n += 1;
            }
            assert!(n > 3000, "{src}: {n} samples");
            for (ax, [ww, wd, dd, wy, dy]) in m.iter().copied().enumerate() {
                let det = ww * dd - wd * wd;
                let a = (wy * dd - wd * dy) / det;
                let b = (ww * dy - wd * wy) / det;
                println!("{src} axis {ax}: n {n} a {a:.3} b {b:.3}");
                assert!(
                    a > 0.1 && a < 1.3,
                    "{src} axis {ax}: rotation coefficient {a}"
                );
                assert!(
                    b > 0.8 && b < 1.25,
                    "{src} axis {ax}: translation coefficient {b}"
                );
            }
        }
    }

    #[test]
    fn first_range_rows() {
        let log = real();
        let SensorData::Range(r) = &first_of(log, "range").data else {
            panic!("not range")
        };
        assert!(close(r.distance_m, 0.0670166, 1e-9));
        assert_eq!((r.min_m, r.max_m), (Some(0.3), Some(200.0)));
        assert_eq!(r.signal_quality, Some(1)); // PX4 0 = invalid = MAVLink 1
        assert_eq!(r.variance, None);
        assert_eq!(r.orientation, Some(25));
        let SensorData::Range(r) = &first_of(log, "range_1").data else {
            panic!("not range")
        };
        // min = max = 0 in this driver's messages: unset, not a zero window.
        assert_eq!((r.min_m, r.max_m), (None, None));
    }

    /// EKF2's quaternions of the real log as read, before the stand-in replaces them.
    fn real_quaternions() -> &'static Px4Log {
        static RAW: std::sync::OnceLock<Px4Log> = std::sync::OnceLock::new();
        RAW.get_or_init(|| {
            let dir = TempDir::new("quaternions");
            let name = "estimator_states_0.csv.gz";
            if let Err(e) = std::fs::copy(Path::new(DATA_DIR).join(name), dir.0.join(name)) {
                panic!("copying {name}: {e}");
            }
            match read_dir(&dir.0) {
                Ok(log) => log,
                Err(e) => panic!("reading {name}: {e}"),
            }
        })
    }

    #[test]
    fn attitude_and_ekf2_heading_agree() {
        let log = real();
        let s = first_of(real_quaternions(), "attitude_states");
        assert_eq!(s.stamp_us, Some(1_692_866));
        let SensorData::Attitude(a) = &s.data else {
            panic!("not attitude")
        };
        let q_ned = UnitQuaternion::from_quaternion(Quaternion::new(
            0.9903907,
            0.0006691864,
            0.0056023533,
            0.13818274,
        ));
        assert!(a.orientation.angle_to(&frames::q_ned_frd_to_enu_flu(q_ned)) < 1e-9);
        let SensorData::AutopilotEstimate(e) = &first_of(log, "ekf2").data else {
            panic!("not ekf2")
        };
        // The first rows precede the flow fix: no valid xy yet, but a heading.
        assert_eq!(e.local_position, None);
        assert_eq!(e.velocity, None);
        let yaw = e.yaw.unwrap_or_else(|| panic!("no yaw"));
        assert!(close(yaw, frames::yaw_ned_to_enu(0.27689523), 1e-9));
        // EKF2's quaternion and its heading name the same yaw (0.277 rad NED).
        assert!(close(a.orientation.euler_angles().2, yaw, 0.01), "{yaw}");
        // The 10 Hz `attitude` stand-in is that heading, tilted as the quaternion
        // nearest in time.
        let stand_in = first_of(log, "attitude");
        let SensorData::Attitude(h) = &stand_in.data else {
            panic!("not attitude")
        };
        assert!(close(yaw_of(&h.orientation), yaw, 1e-9));
        let t = stand_in.stamp_us.unwrap_or_default();
        let nearest = real_quaternions()
            .samples
            .iter()
            .min_by_key(|s| (s.stamp_us.unwrap_or_default() - t).abs())
            .map(|s| &s.data);
        let Some(SensorData::Attitude(q)) = nearest else {
            panic!("no quaternion")
        };
        let level = |q: &UnitQuaternion<f64>| {
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), -yaw_of(q)) * q
        };
        assert!(level(&h.orientation).angle_to(&level(&q.orientation)) < 1e-9);
        assert!(level(&h.orientation).angle() > 1e-3, "tilted, not level");
    }

    #[test]
    fn the_attitude_stand_in_is_tilted_when_the_vehicle_is() {
        // 54–64 s of the log the vehicle is held on its side (EKF2's quaternion: 75–78°
        // of tilt; the range finder reads the far wall, 2.6–4.3 m). A level stand-in
        // would let those readings through as heights.
        let tilt = |s: &Sample| match &s.data {
            SensorData::Attitude(a) => (a.orientation * Vector3::z()).angle(&Vector3::z()),
            _ => f64::NAN,
        };
        let held: Vec<f64> = real()
            .samples
            .iter()
            .filter(|s| s.source.as_ref() == "attitude")
            .filter(|s| {
                s.stamp_us
                    .is_some_and(|t| (56_000_000..63_000_000).contains(&t))
            })
            .map(tilt)
            .collect();
        assert!(held.len() > 60, "{}", held.len());
        assert!(held.iter().all(|t| t.to_degrees() > 70.0), "{held:?}");
        let before = real()
            .samples
            .iter()
            .filter(|s| s.source.as_ref() == "attitude")
            .find(|s| s.stamp_us.is_some_and(|t| t > 40_000_000))
            .map(tilt);
        assert!(before.is_some_and(|t| t.to_degrees() < 3.0), "{before:?}");
    }

    #[test]
    fn imu_reads_gravity_up_in_flu() {
        let SensorData::Imu(i) = &first_of(real(), "imu").data else {
            panic!("not imu")
        };
        let a = i.accel.unwrap_or_else(|| panic!("no accel"));
        assert!(close(a.z, 0.038694493 / 3954e-6, 1e-9), "{a}");
        assert!(close(a.z, 9.79, 0.05), "{a}");
        assert!(i.gyro.is_some_and(|g| g.norm() < 0.01));
    }

    #[test]
    fn progress_reaches_the_total() {
        let mut calls = Vec::new();
        let log = read_dir_with_progress(Path::new(DATA_DIR), &mut |d, t| calls.push((d, t)));
        assert!(log.is_ok());
        assert!(calls.len() > 5, "{} calls", calls.len());
        assert!(calls
            .windows(2)
            .all(|w| w[0].0 <= w[1].0 && w[0].1 == w[1].1));
        let (done, total) = calls[calls.len() - 1];
        assert_eq!(done, total);
        let known: u64 = real()
            .topics
            .iter()
            .filter_map(|t| {
                std::fs::metadata(Path::new(DATA_DIR).join(format!("{}.csv.gz", t.name))).ok()
            })
            .map(|m| m.len())
            .sum();
        assert_eq!(total, known);
    }

    const FLOW_HEADER: &str = "timestamp,pixel_flow_x_integral,pixel_flow_y_integral,gyro_x_rate_integral,gyro_y_rate_integral,gyro_z_rate_integral,integration_timespan,quality\n";

    #[test]
    fn malformed_rows_are_skipped_with_the_first_error_kept() {
        let dir = TempDir::new("malformed");
        dir.write(
            "optical_flow_0.csv",
            &format!(
                "{FLOW_HEADER}\
                 1000,0.01,0.02,nan,nan,0.0,20000,100\n\
                 2000,0.01,0.02,nan,nan,20000,100\n\
                 3000,0.01,abc,nan,nan,0.0,20000,100\n\
                 4000,0.01,0.02,nan,nan,0.0,0,100\n\
                 5000,0.01,0.02,0.001,0.002,0.003,20000,300\n\
                 6000,inf,0.02,0.001,0.002,0.003,20000,100\n\
                 7000,0.01,0.02,0.001,0.002,0.003,20000,100\r\n\
                 \n"
            ),
        );
        dir.write("cpuload_0.csv", "timestamp,load\n1,0.5\n");
        let log = match read_dir(&dir.0) {
            Ok(l) => l,
            Err(e) => panic!("{e}"),
        };
        assert_eq!(log.topics.len(), 1);
        let t = &log.topics[0];
        assert_eq!((t.rows, t.skipped, t.samples()), (7, 5, 2));
        assert_eq!(t.span_us, Some((1000, 7000)));
        let e = t.first_error.as_ref().unwrap_or_else(|| panic!("no error"));
        assert!(
            matches!(
                e,
                Px4LogError::ColumnCount {
                    line: 3,
                    column: 8,
                    expected: 8,
                    found: 7,
                    ..
                }
            ),
            "{e:?}"
        );
        let msg = e.to_string();
        assert!(msg.contains("optical_flow_0.csv:3:8"), "{msg}");
        // The row with a gyro keeps it, in FLU.
        let SensorData::Flow(f) = &log.samples[1].data else {
            panic!("not flow")
        };
        let g = f.gyro.unwrap_or_else(|| panic!("no gyro"));
        assert!((g - Vector3::new(0.05, -0.1, -0.15)).norm() < 1e-12, "{g}");
    }

    #[test]
    fn each_bad_row_names_its_line_and_column() {
        let dir = TempDir::new("each");
        let rows = [
            (
                "1000,0.01,abc,nan,nan,0.0,20000,100",
                "optical_flow_0.csv:2:3",
            ),
            ("1000,0.01,0.02,nan,nan,0.0,0,100", "optical_flow_0.csv:2:7"),
            (
                "1000,0.01,0.02,nan,nan,0.0,20000,300",
                "optical_flow_0.csv:2:8",
            ),
            (
                "-5,0.01,0.02,nan,nan,0.0,20000,100",
                "optical_flow_0.csv:2:1",
            ),
            (
                "1000,nan,0.02,nan,nan,0.0,20000,100",
                "optical_flow_0.csv:2:2",
            ),
        ];
        for (row, want) in rows {
            dir.write("optical_flow_0.csv", &format!("{FLOW_HEADER}{row}\n"));
            let log = read_dir(&dir.0).unwrap_or_else(|e| panic!("{e}"));
            let msg = log.topics[0]
                .first_error
                .as_ref()
                .map(|e| e.to_string())
                .unwrap_or_default();
            assert!(msg.contains(want), "{row}: {msg}");
        }
    }

    #[test]
    fn missing_column_and_empty_file_fail_the_read() {
        let dir = TempDir::new("missing");
        dir.write(
            "distance_sensor_0.csv",
            "timestamp,current_distance,min_distance,max_distance,variance,orientation\n1,1.0,0.1,10,0,25\n",
        );
        match read_dir(&dir.0) {
            Err(e @ Px4LogError::MissingColumn { .. }) => {
                let msg = e.to_string();
                assert!(
                    msg.contains("distance_sensor_0.csv:1") && msg.contains("signal_quality"),
                    "{msg}"
                );
            }
            other => panic!("{other:?}"),
        }
        dir.write("distance_sensor_0.csv", "");
        assert!(matches!(
            read_dir(&dir.0),
            Err(Px4LogError::NoHeader { .. })
        ));
    }

    #[test]
    fn px4_1_14_and_1_15_layouts_read() {
        // PX4 1.14/1.15 field names (vehicle_optical_flow, the renumbered
        // vehicle_odometry frames with variances, sensor_gps in degrees), hand-built rows.
        let dir = TempDir::new("v115");
        dir.write(
            "sensor_combined_0.csv",
            "timestamp,gyro_rad[0],gyro_rad[1],gyro_rad[2],gyro_integral_dt,accelerometer_timestamp_relative,accelerometer_m_s2[0],accelerometer_m_s2[1],accelerometer_m_s2[2],accelerometer_integral_dt\n\
             1000,0.1,0.2,0.3,4000,0,0.5,0.0,-9.8,4000\n",
        );
        dir.write(
            "vehicle_attitude_0.csv",
            "timestamp,timestamp_sample,q[0],q[1],q[2],q[3],delta_q_reset[0],delta_q_reset[1],delta_q_reset[2],delta_q_reset[3],quat_reset_counter\n\
             2000,1990,1,0,0,0,1,0,0,0,0\n",
        );
        dir.write(
            "vehicle_angular_velocity_0.csv",
            "timestamp,timestamp_sample,xyz[0],xyz[1],xyz[2]\n2001,1995,0.0,0.0,0.5\n",
        );
        dir.write(
            "sensor_gps_0.csv",
            "timestamp,latitude_deg,longitude_deg,altitude_msl_m,fix_type,eph,epv,vel_n_m_s,vel_e_m_s,vel_d_m_s,vel_ned_valid,satellites_used,hdop,vdop\n\
             3000,47.3977419,8.5455938,488.1,3,0.8,1.2,1.0,2.0,0.5,1,14,0.7,1.1\n",
        );
        dir.write(
            "vehicle_optical_flow_0.csv",
            "timestamp,timestamp_sample,device_id,pixel_flow[0],pixel_flow[1],delta_angle[0],delta_angle[1],delta_angle[2],distance_m,integration_timespan_us,quality,max_flow_rate,min_ground_distance,max_ground_distance\n\
             4000,3990,1,0.002,0.004,0.001,0.002,0.0,1.5,20000,150,8,0.1,5\n",
        );
        dir.write(
            "vehicle_visual_odometry_0.csv",
            "timestamp,timestamp_sample,pose_frame,position[0],position[1],position[2],q[0],q[1],q[2],q[3],velocity_frame,velocity[0],velocity[1],velocity[2],angular_velocity[0],angular_velocity[1],angular_velocity[2],position_variance[0],position_variance[1],position_variance[2],orientation_variance[0],orientation_variance[1],orientation_variance[2],velocity_variance[0],velocity_variance[1],velocity_variance[2],reset_counter,quality\n\
             5000,4990,1,1.0,2.0,-3.0,1,0,0,0,1,0.5,0,0,nan,nan,nan,0.01,0.02,0.03,0.001,0.001,0.002,0.1,0.1,0.2,4,90\n",
        );
        let log = read_dir(&dir.0).unwrap_or_else(|e| panic!("{e}"));
        assert!(log.stand_ins.is_empty(), "{:?}", log.stand_ins);
        let get = |src: &str| {
            log.samples
                .iter()
                .find(|s| s.source.as_ref() == src)
                .map(|s| s.data.clone())
                .unwrap_or_else(|| panic!("no {src}"))
        };
        let SensorData::Imu(i) = get("imu") else {
            panic!("imu")
        };
        assert_eq!(i.gyro, Some(Vector3::new(0.1, -0.2, -0.3)));
        assert_eq!(i.accel, Some(Vector3::new(0.5, 0.0, 9.8)));
        // The attitude got its rates (FRD yaw rate 0.5 → FLU −0.5).
        let SensorData::Attitude(a) = get("attitude") else {
            panic!("attitude")
        };
        assert_eq!(a.rates, Some(Vector3::new(0.0, 0.0, -0.5)));
        assert!(!log
            .samples
            .iter()
            .any(|s| s.source.as_ref() == "angular_velocity"));
        let SensorData::Gnss(g) = get("gps") else {
            panic!("gps")
        };
        assert!(close(g.lat_deg, 47.3977419, 1e-9) && close(g.alt_m, 488.1, 1e-9));
        assert_eq!(g.fix, GnssFixType::Fix3d);
        assert_eq!(g.velocity, Some(Vector3::new(2.0, 1.0, -0.5)));
        assert_eq!(g.satellites, Some(14));
        let SensorData::Flow(f) = get("flow") else {
            panic!("flow")
        };
        let r = f.rate.unwrap_or_else(|| panic!("rate"));
        assert!(close(r.x, 0.1, 1e-12) && close(r.y, -0.2, 1e-12), "{r}");
        assert_eq!(f.tof.map(|t| t.distance_m), Some(1.5));
        let SensorData::Odometry(o) = get("vio") else {
            panic!("vio")
        };
        assert_eq!(o.position, Vector3::new(2.0, 1.0, 3.0));
        let cov = o.pose_cov.unwrap_or_else(|| panic!("pose cov"));
        // NED variances (0.01, 0.02, 0.03) → ENU (0.02, 0.01, 0.03).
        assert!(close(cov[(0, 0)], 0.02, 1e-12) && close(cov[(1, 1)], 0.01, 1e-12));
        // Facing north, 0.5 m/s north in NED → 0.5 m/s forward in the body.
        let v = o.velocity.unwrap_or_else(|| panic!("velocity"));
        assert!((v - Vector3::new(0.5, 0.0, 0.0)).norm() < 1e-12, "{v}");
        assert_eq!((o.reset_counter, o.quality), (Some(4), Some(90)));
        assert!(o.angular_velocity.is_none());
        assert_eq!(log.missing.len(), 2, "{:?}", log.missing); // range finder, land detector
    }

    #[test]
    fn the_real_ulog_reads_directly() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../tests/data/px4-gps-fmuv5/roboto_test_fmuv5_gps.ulg");
        let log = read_ulog_with_progress(&path, &mut |_, _| {}).unwrap_or_else(|e| panic!("{e}"));
        let count = |src: &str| {
            log.samples
                .iter()
                .filter(|s| s.source.as_ref() == src)
                .count()
        };
        // sensor_combined at ~194 Hz for 9 s, GPS at 2 Hz, EKF2 at 10 Hz.
        assert_eq!(count("imu"), 1737);
        assert!(
            count("gps") >= 10 && count("ekf2") > 80,
            "{} {}",
            count("gps"),
            count("ekf2")
        );
        assert!(count("attitude") > 100);
        assert!(log.stand_ins.is_empty(), "{:?}", log.stand_ins);
        let SensorData::Imu(i) = &log
            .samples
            .iter()
            .find(|s| s.source.as_ref() == "imu")
            .map(|s| &s.data)
            .unwrap_or_else(|| panic!("imu"))
        else {
            panic!("imu")
        };
        let a = i.accel.unwrap_or_else(|| panic!("accel"));
        assert!(close(a.norm(), 9.8, 0.3), "{a}");
        let SensorData::Gnss(g) = &log
            .samples
            .iter()
            .find(|s| s.source.as_ref() == "gps")
            .map(|s| &s.data)
            .unwrap_or_else(|| panic!("gps"))
        else {
            panic!("gps")
        };
        assert!(
            g.lat_deg.abs() > 1.0 && g.lat_deg.abs() <= 90.0,
            "{}",
            g.lat_deg
        );
        // A truncated or foreign file is an error that names it, never a panic.
        let dir = TempDir::new("badulog");
        dir.write("x.ulg", "ULog\u{1}\u{12}5 not really a log");
        let e = read_ulog_with_progress(&dir.0.join("x.ulg"), &mut |_, _| {});
        assert!(e.is_err());
    }

    #[test]
    fn a_directory_without_known_topics_says_what_it_looked_for() {
        let dir = TempDir::new("none");
        dir.write("vehicle_local_position_setpoint_0.csv", "timestamp\n1\n");
        dir.write("vehicle_imu_status_0.csv", "timestamp\n1\n");
        let e = match read_dir(&dir.0) {
            Err(e) => e,
            Ok(l) => panic!("read {:?}", l.topics),
        };
        let msg = e.to_string();
        assert!(msg.contains("optical_flow_<i>.csv"), "{msg}");
        assert!(msg.contains("vehicle_visual_odometry_<i>.csv"), "{msg}");
        assert!(matches!(
            read_dir(&dir.0.join("nope")),
            Err(Px4LogError::ListDir { .. })
        ));
    }

    #[test]
    fn equal_stamps_keep_topic_order() {
        let dir = TempDir::new("ties");
        dir.write(
            "optical_flow_0.csv",
            &format!("{FLOW_HEADER}5,0,0,nan,nan,nan,1000,1\n"),
        );
        dir.write(
            "distance_sensor_0.csv",
            "timestamp,current_distance,min_distance,max_distance,variance,signal_quality,orientation\n5,1.0,0.1,10,0.01,-1,25\n3,1.0,0,0,0,50,25\n",
        );
        let log = read_dir(&dir.0).unwrap_or_else(|e| panic!("{e}"));
        let order: Vec<(&str, Option<i64>)> = log
            .samples
            .iter()
            .map(|s| (&*s.source, s.stamp_us))
            .collect();
        assert_eq!(
            order,
            [("range", Some(3)), ("range", Some(5)), ("flow", Some(5))]
        );
        let SensorData::Range(r) = &log.samples[1].data else {
            panic!("not range")
        };
        assert_eq!(
            (r.signal_quality, r.variance, r.min_m),
            (None, Some(0.01), Some(0.1))
        );
        let SensorData::Range(r) = &log.samples[0].data else {
            panic!("not range")
        };
        assert_eq!((r.signal_quality, r.min_m, r.max_m), (Some(50), None, None));
    }

    #[test]
    fn vio_covariances_and_world_frame_velocity_convert() {
        let dir = TempDir::new("vio");
        let mut header = vec!["timestamp".to_string()];
        header.extend(["x", "y", "z"].map(String::from));
        header.extend((0..4).map(|i| format!("q[{i}]")));
        header.extend((0..21).map(|i| format!("pose_covariance[{i}]")));
        header.extend(["vx", "vy", "vz", "rollspeed", "pitchspeed", "yawspeed"].map(String::from));
        header.extend((0..21).map(|i| format!("velocity_covariance[{i}]")));
        header.extend(
            ["local_frame", "velocity_frame", "reset_counter", "quality"].map(String::from),
        );
        // Yaw 90° in NED (facing east), diagonal covariances 1..6 in NED order.
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let mut row = vec!["10".to_string(), "1".into(), "2".into(), "3".into()];
        row.extend([h, 0.0, 0.0, h].map(|v| v.to_string()));
        let diag = |k: usize| -> Option<f64> {
            [0, 6, 11, 15, 18, 20]
                .iter()
                .position(|&d| d == k)
                .map(|i| i as f64 + 1.0)
        };
        row.extend((0..21).map(|k| diag(k).unwrap_or(0.0).to_string()));
        // Velocity 1 m/s north, in the local frame.
        row.extend(["1", "0", "0", "0.1", "0.2", "0.3"].map(String::from));
        row.extend((0..21).map(|k| diag(k).unwrap_or(0.0).to_string()));
        row.extend(["0", "0", "7", "-1"].map(String::from));
        dir.write(
            "vehicle_visual_odometry_0.csv",
            &format!("{}\n{}\n", header.join(","), row.join(",")),
        );
        let log = read_dir(&dir.0).unwrap_or_else(|e| panic!("{e}"));
        let SensorData::Odometry(o) = &log.samples[0].data else {
            panic!("{:?}", log.topics[0].first_error)
        };
        assert!((o.position - Vector3::new(2.0, 1.0, -3.0)).norm() < 1e-12);
        // Facing east: body x is ENU +x.
        assert!((o.orientation * Vector3::x() - Vector3::x()).norm() < 1e-9);
        // North (ENU +y) is to the body's left (FLU +y).
        let v = o.velocity.unwrap_or_else(|| panic!("no velocity"));
        assert!((v - Vector3::new(0.0, 1.0, 0.0)).norm() < 1e-9, "{v}");
        let pc = o.pose_cov.unwrap_or_else(|| panic!("no pose cov"));
        let d: Vec<f64> = (0..6).map(|i| pc[(i, i)]).collect();
        // NED x,y,z,rx,ry,rz = 1..6 → ENU order (y, x, z) in both blocks.
        assert_eq!(d, [2.0, 1.0, 3.0, 5.0, 4.0, 6.0]);
        let tc = o.twist_cov.unwrap_or_else(|| panic!("no twist cov"));
        // World N/E variances 1, 2 seen from an east-facing body: forward = east (2),
        // left = north (1); angular FRD→FLU keeps the variances.
        let d: Vec<f64> = (0..6).map(|i| (tc[(i, i)] * 1e9).round() / 1e9).collect();
        assert_eq!(d, [2.0, 1.0, 3.0, 4.0, 5.0, 6.0]);
        assert_eq!((o.reset_counter, o.quality), (Some(7), Some(-1)));
    }

    #[test]
    #[ignore = "timing; run with --ignored --nocapture"]
    fn time_real_read() {
        let t0 = std::time::Instant::now();
        let log = read_dir(Path::new(DATA_DIR)).unwrap_or_else(|e| panic!("{e}"));
        let dt = t0.elapsed();
        println!("read {} samples in {dt:?}", log.samples.len());
        for t in &log.topics {
            println!(
                "{:28} {:9} rows {:6} skipped {:3} span {:?}",
                t.name, t.source, t.rows, t.skipped, t.span_us
            );
        }
    }
}
