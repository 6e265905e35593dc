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
//! | `vehicle_air_data`                              | `baro`          | [`Baro`] |
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
//! in [`Px4Log::missing`], not fatal.
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
use crate::sample::{frames, Attitude, Micros, OpticalFlow, Sample, SensorData};
use nalgebra::{UnitQuaternion, Vector3};
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
    /// Nothing read yet of `tf`.
    fn of(tf: &TopicFile) -> Self {
        Self {
            name: tf.name.clone(),
            source: tf.source.clone(),
            rows: 0,
            skipped: 0,
            first_error: None,
            span_us: None,
        }
    }

    /// Samples this file produced.
    pub fn samples(&self) -> usize {
        self.rows - self.skipped
    }
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

/// Where a ULog file is cut short, if it is: the offset of the message its end cuts in
/// two (a logger killed, a copy interrupted). The parser reads such a file up to there
/// and says nothing, so a cut flight would pass for a complete, shorter one. Walks the
/// message headers (`u16` size, `u8` type, after the 16-byte file header), buffered.
/// A file cut exactly between two messages cannot be told from a complete one.
pub fn ulog_cut_short(file: &Path) -> std::io::Result<Option<u64>> {
    use std::io::{BufReader, Read};
    let len = std::fs::metadata(file)?.len();
    let mut r = BufReader::with_capacity(1 << 16, std::fs::File::open(file)?);
    const FILE_HEADER: u64 = 16;
    if len < FILE_HEADER {
        return Ok(Some(0));
    }
    r.seek_relative(FILE_HEADER as i64)?;
    let mut at = FILE_HEADER;
    let mut header = [0u8; 3];
    while at < len {
        if len - at < 3 {
            return Ok(Some(at));
        }
        r.read_exact(&mut header)?;
        let size = u64::from(u16::from_le_bytes([header[0], header[1]]));
        if at + 3 + size > len {
            return Ok(Some(at));
        }
        r.seek_relative(size as i64)?;
        at += 3 + size;
    }
    Ok(None)
}

/// Reads a ULog file (`.ulg`) directly; `progress` counts rows.
pub fn read_ulog_with_progress(
    file: &Path,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<Px4Log, Px4LogError> {
    read_topics(ulog_topic_files(file)?, progress)
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
    // A ULog's rows are counted: room for them all at once, not regrown (and copied)
    // as they come.
    let mut samples = Vec::with_capacity(files.iter().map(TopicFile::ulog_rows).sum());
    let topics = match read_ulog_merged(&files, &mut |s| samples.push(s), &mut prog, true)? {
        Some(topics) => topics,
        None => {
            let mut topics = Vec::with_capacity(files.len());
            for f in &files {
                topics.push(read_topic(f, &mut samples, &mut prog)?);
            }
            // Stable: equal stamps keep topic order (the TOPICS order, then instance).
            crate::replay::sort_by_stamp(&mut samples);
            topics
        }
    };
    let has = |t: &str| files.iter().any(|f| TOPICS[f.order.0].0 == t);
    let mut stand_ins = Vec::new();
    attach_angular_velocity(&mut samples);
    if attach_ekf2_flow_gyro(&mut samples) > 0 {
        stand_ins.push(FLOW_GYRO_STAND_IN.to_string());
    }
    if !has("sensor_combined") && has("vehicle_imu") {
        for s in samples.iter_mut() {
            if let Some(to) = imu_name(&s.source) {
                s.source = Arc::from(to);
            }
        }
        stand_ins.push(IMU_STAND_IN.to_string());
    }
    if !has("vehicle_attitude") && attitude_from_ekf2_heading(&mut samples) > 0 {
        stand_ins.push(
            "attitude: EKF2's heading (vehicle_local_position) tilted as EKF2's quaternion (estimator_states, logged at a low rate) stands in for vehicle_attitude (absent)"
                .to_string(),
        );
    }
    let missing = missing_topics(&has);
    (prog.cb)(prog.total, prog.total);
    Ok(Px4Log {
        samples,
        topics,
        stand_ins,
        missing,
    })
}

/// The replay's sentence for EKF2's flow gyro standing in.
const FLOW_GYRO_STAND_IN: &str =
    "flow gyro: EKF2's (estimator_optical_flow_vel) for flow samples without their own";
/// The replay's sentence for `vehicle_imu` standing in.
const IMU_STAND_IN: &str =
    "imu: vehicle_imu (logged at a low rate) stands in for sensor_combined (absent)";

/// Wanted topics the log does not have (`has` says which it has), as sentences.
fn missing_topics(has: &dyn Fn(&str) -> bool) -> Vec<String> {
    WANTED
        .iter()
        .filter(|(_, names)| !names.iter().any(|n| has(n)))
        .map(|(what, names)| format!("{what}: none of {}", names.join(", ")))
        .collect()
}

/// The name `vehicle_imu`'s source (and its instances `vehicle_imu_i`) takes when it
/// stands in for `sensor_combined`: `imu` (`imu_i`).
fn imu_name(source: &str) -> Option<String> {
    let rest = source.strip_prefix("vehicle_imu")?;
    (rest.is_empty() || rest.starts_with('_')).then(|| format!("imu{rest}"))
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
        if let (Some(t), SensorData::Attitude(a)) = (s.stamp_us, &mut s.data) {
            attach_rate(a, &rates, t);
        }
    }
}

/// The rate of `rates` (time, rate; by time) nearest to the attitude's time `t`, within
/// 10 ms, as the attitude's rates.
fn attach_rate(a: &mut Attitude, rates: &[(i64, Vector3<f64>)], t: i64) {
    if let Some((rt, g)) = nearest(rates, t) {
        if (rt - t).abs() <= 10_000 {
            a.rates = Some(g);
        }
    }
}

/// The row of `rows` (sorted by time) nearest to `t`.
fn nearest<T: Copy>(rows: &[(i64, T)], t: i64) -> Option<(i64, T)> {
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
        let near = nearest(&tilts, t).filter(|(rt, _)| (rt - t).abs() <= TILT_NEAREST_US);
        // The quaternion without its heading: body → a level frame of the same yaw.
        near.map_or_else(UnitQuaternion::identity, |(_, q)| {
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), -yaw_of(&q)) * q
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
    crate::replay::sort_by_stamp(samples);
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
        if let (Some(t), SensorData::Flow(f)) = (s.stamp_us, &mut s.data) {
            n += usize::from(attach_flow_gyro(f, &rows, t));
        }
    }
    n
}

/// EKF2's gyro integral of `rows` (time, FRD integral; by time) for the flow sample at
/// `t` without a gyro of its own: the nearest within 5 ms, as a rate. Whether it got one.
fn attach_flow_gyro(f: &mut OpticalFlow, rows: &[(i64, Vector3<f64>)], t: i64) -> bool {
    let (Some(dt), None) = (f.integration_s, f.gyro) else {
        return false;
    };
    match nearest(rows, t) {
        Some((rt, g)) if (rt - t).abs() <= 5_000 => {
            f.gyro = Some(frames::frd_to_flu(-g / dt));
            true
        }
        _ => false,
    }
}

/// The topics a replay wants, for the "missing" report: (what, any of these topics).
const WANTED: [(&str, &[&str]); 8] = [
    ("IMU", &["sensor_combined", "vehicle_imu"]),
    ("attitude", &["vehicle_attitude"]),
    ("GNSS", &["sensor_gps", "vehicle_gps_position"]),
    ("range finder", &["distance_sensor"]),
    ("optical flow", &["vehicle_optical_flow", "optical_flow"]),
    ("visual odometry", &["vehicle_visual_odometry"]),
    ("land detector", &["vehicle_land_detected"]),
    ("barometer", &["vehicle_air_data"]),
];

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
            TopicData::Ulog { .. } => self.ulog_rows() as u64,
        }
    }

    /// A ULog topic's rows (0 for a CSV file: not counted before it is read).
    fn ulog_rows(&self) -> usize {
        match &self.data {
            // The columns not read are empty: the longest is the row count.
            TopicData::Ulog { columns, .. } => columns.iter().map(Vec::len).max().unwrap_or(0),
            TopicData::Csv { .. } => 0,
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

/// The topics of a ULog file that replay reads, parsed by PX4's `px4-ulog` crate: its
/// stream parser, keeping only the wanted topics' fields, each as it is decoded, as
/// numbers (a flight log holds a hundred topics; the crate's whole-file parser would
/// keep every one, and in a form converted again afterwards).
fn ulog_topic_files(file: &Path) -> Result<Vec<TopicFile>, Px4LogError> {
    use px4_ulog::stream_parser::{Message, SimpleCallbackResult};
    let path_str = file.to_str().ok_or_else(|| Px4LogError::Ulog {
        file: file.to_path_buf(),
        reason: "the path is not UTF-8".into(),
    })?;
    // (topic, instance) → (TOPICS index, field names, columns, the fields kept); by
    // message id. Only the fields the topic's mapper reads are kept (the others' columns
    // stay empty and read as NaN): a third of an IMU topic's, most of an estimator's.
    type Columns = (usize, u8, Vec<String>, Vec<Vec<f64>>, Vec<bool>);
    let mut by_id: Vec<Option<Columns>> = Vec::new();
    let mut unwanted: Vec<bool> = Vec::new();
    let mut collect = |m: &Message| {
        if let Message::Data(d) = m {
            let id = usize::from(d.msg_id);
            if id >= by_id.len() {
                by_id.resize_with(id + 1, || None);
                unwanted.resize(id + 1, false);
            }
            if unwanted[id] {
                return SimpleCallbackResult::KeepReading;
            }
            let format = d.flattened_format;
            let entry = match &mut by_id[id] {
                Some(e) => e,
                slot => {
                    let Some(ti) = TOPICS
                        .iter()
                        .position(|(p, _, _)| *p == format.message_name)
                    else {
                        unwanted[id] = true;
                        return SimpleCallbackResult::KeepReading;
                    };
                    let names: Vec<String> = format
                        .fields
                        .iter()
                        .map(|f| f.flattened_field_name.clone())
                        .collect();
                    let keep = fields_read(TOPICS[ti].2, file, &names);
                    slot.insert((
                        ti,
                        d.multi_id.value(),
                        names,
                        vec![Vec::new(); format.fields.len()],
                        keep,
                    ))
                }
            };
            for ((col, field), keep) in entry.3.iter_mut().zip(&format.fields).zip(&entry.4) {
                if *keep {
                    col.push(ulog_field(d.data, field));
                }
            }
        }
        SimpleCallbackResult::KeepReading
    };
    // The crate panics on some corrupt files instead of returning an error: a bad log
    // must be an error that names it, never a crash of the replay.
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        px4_ulog::stream_parser::read_file_with_simple_callback(path_str, &mut collect)
    }))
    .map_err(|_| Px4LogError::Ulog {
        file: file.to_path_buf(),
        reason: "the ULog parser failed on a corrupt record".into(),
    })?
    .map_err(|e| Px4LogError::Ulog {
        file: file.to_path_buf(),
        reason: e.to_string(),
    })?;
    let mut files = Vec::new();
    for (ti, multi, names, columns, _) in by_id.into_iter().flatten() {
        let name = TOPICS[ti].0;
        let inst = u32::from(multi);
        let mut cols: Vec<(String, Vec<f64>)> = names.into_iter().zip(columns).collect();
        sort_header(&mut cols, |c| &c.0);
        let (header, columns) = cols.into_iter().unzip();
        files.push(TopicFile {
            path: file.to_path_buf(),
            name: format!("{name}_{inst}"),
            source: String::new(),
            kind: TOPICS[ti].2,
            order: (ti, inst),
            data: TopicData::Ulog { header, columns },
        });
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

/// `timestamp` first, the rest by name: a ULog topic's stable header.
fn sort_header<T>(fields: &mut [T], name: impl Fn(&T) -> &String) {
    fields.sort_by(|a, b| {
        let (a, b) = (name(a), name(b));
        (a != "timestamp", a).cmp(&(b != "timestamp", b))
    });
}

/// Which of a ULog topic's fields (`names`, in message order) the mapper of `kind`
/// reads; all of them when it cannot map the topic (its error is reported later, with
/// the whole header).
fn fields_read(kind: Kind, file: &Path, names: &[String]) -> Vec<bool> {
    let mut header: Vec<&String> = names.iter().collect();
    sort_header(&mut header, |n| n);
    let header: Vec<String> = header.into_iter().cloned().collect();
    match Mapper::columns_read(kind, file, &header) {
        Some(read) => names
            .iter()
            .map(|n| header.iter().position(|h| h == n).is_some_and(|i| read[i]))
            .collect(),
        None => vec![true; names.len()],
    }
}

/// One field of a ULog data message as a number (NaN if the message is too short).
fn ulog_field(data: &[u8], field: &px4_ulog::stream_parser::model::FlattenedField) -> f64 {
    use px4_ulog::stream_parser::model::FlattenedFieldType as T;
    let at = usize::from(field.offset);
    fn take<const N: usize>(data: &[u8], at: usize) -> Option<[u8; N]> {
        data.get(at..at + N).and_then(|b| b.try_into().ok())
    }
    let v = match field.field_type {
        T::Int8 => take::<1>(data, at).map(|b| f64::from(i8::from_le_bytes(b))),
        T::UInt8 | T::Char => take::<1>(data, at).map(|b| f64::from(b[0])),
        T::Bool => take::<1>(data, at).map(|b| f64::from(u8::from(b[0] != 0))),
        T::Int16 => take::<2>(data, at).map(|b| f64::from(i16::from_le_bytes(b))),
        T::UInt16 => take::<2>(data, at).map(|b| f64::from(u16::from_le_bytes(b))),
        T::Int32 => take::<4>(data, at).map(|b| f64::from(i32::from_le_bytes(b))),
        T::UInt32 => take::<4>(data, at).map(|b| f64::from(u32::from_le_bytes(b))),
        T::Int64 => take::<8>(data, at).map(|b| i64::from_le_bytes(b) as f64),
        T::UInt64 => take::<8>(data, at).map(|b| u64::from_le_bytes(b) as f64),
        T::Float => take::<4>(data, at).map(|b| f64::from(f32::from_le_bytes(b))),
        T::Double => take::<8>(data, at).map(f64::from_le_bytes),
    };
    v.unwrap_or(f64::NAN)
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

/// A ULog's topics, each in time order, mapped row by row in the order of their merged
/// times: every sample is made once, in its place, where mapping topic by topic and
/// then sorting moved each (they are large) across memory again (a fifth of an hour-long
/// log's replay). The order is the stable sort's: at equal times, the file order (the
/// TOPICS order, then instance), then row order. None (nothing read) when a file is
/// not a ULog topic, or when `in_order` and a topic's times go back: the caller sorts
/// instead. Without `in_order`, a single topic is read in its rows' order.
fn read_ulog_merged(
    files: &[TopicFile],
    sink: &mut dyn FnMut(Sample),
    prog: &mut Progress<'_>,
    in_order: bool,
) -> Result<Option<Vec<TopicSummary>>, Px4LogError> {
    struct Cursor<'a> {
        tf: &'a TopicFile,
        header: &'a [String],
        columns: &'a [Vec<f64>],
        mapper: Mapper,
        /// Each row's time as the mapper reads it; a row without one takes the previous
        /// row's (it is skipped when mapped, so its place does not matter).
        keys: Vec<i64>,
        row: usize,
        source: Arc<str>,
        summary: TopicSummary,
    }
    let mut cursors = Vec::with_capacity(files.len());
    for tf in files {
        let TopicData::Ulog { header, columns } = &tf.data else {
            return Ok(None);
        };
        let mapper = Mapper::new(tf.kind, &tf.path, header)?;
        let keys = time_keys_of(columns, &mapper);
        if in_order && keys.windows(2).any(|w| w[1] < w[0]) {
            return Ok(None);
        }
        cursors.push(Cursor {
            tf,
            header,
            columns,
            mapper,
            keys,
            row: 0,
            source: Arc::from(tf.source.as_str()),
            summary: TopicSummary::of(tf),
        });
    }
    loop {
        // Few topics: a scan of their next rows beats a heap. Ties go to the first.
        let mut next: Option<(i64, usize)> = None;
        for (i, c) in cursors.iter().enumerate() {
            if let Some(&k) = c.keys.get(c.row) {
                if next.is_none_or(|(best, _)| k < best) {
                    next = Some((k, i));
                }
            }
        }
        let Some((_, i)) = next else { break };
        // That topic's rows up to the next other topic's time (theirs first at a tie
        // only when they come first in the file order).
        let until = cursors
            .iter()
            .enumerate()
            .filter(|&(j, _)| j != i)
            .filter_map(|(j, c)| c.keys.get(c.row).map(|&k| (k, j)))
            .min();
        let c = &mut cursors[i];
        while let Some(&k) = c.keys.get(c.row) {
            if until.is_some_and(|(u, j)| k > u || (k == u && j < i)) {
                break;
            }
            let row = Row {
                file: &c.tf.path,
                line: c.row + 1,
                header: c.header,
                fields: Fields::Num {
                    columns: c.columns,
                    row: c.row,
                },
            };
            take_row(&mut c.summary, &c.source, c.mapper.map(&row), sink);
            prog.advance(1);
            c.row += 1;
        }
    }
    Ok(Some(cursors.into_iter().map(|c| c.summary).collect()))
}

/// Each row's time as `mapper` reads it from a ULog topic's `columns`; a row without
/// one takes the previous row's (it is skipped when mapped, so its place does not
/// matter).
fn time_keys_of(columns: &[Vec<f64>], mapper: &Mapper) -> Vec<i64> {
    let time = columns
        .get(mapper.time_column())
        .map_or(&[][..], Vec::as_slice);
    let mut last = i64::MIN;
    time.iter()
        .map(|v| {
            if v.fract() == 0.0 && (0.0..9.0e18).contains(v) {
                last = *v as i64;
            }
            last
        })
        .collect()
}

/// A ULog topic's row times (see [`time_keys_of`]); empty for a CSV file.
fn time_keys(tf: &TopicFile) -> Result<Vec<i64>, Px4LogError> {
    match &tf.data {
        TopicData::Ulog { header, columns } => Ok(time_keys_of(
            columns,
            &Mapper::new(tf.kind, &tf.path, header)?,
        )),
        TopicData::Csv { .. } => Ok(Vec::new()),
    }
}

/// Counts one row's outcome and keeps its sample.
fn take_row(
    summary: &mut TopicSummary,
    source: &Arc<str>,
    result: Result<(Micros, SensorData), Px4LogError>,
    sink: &mut dyn FnMut(Sample),
) {
    summary.rows += 1;
    match result {
        Ok((stamp, data)) => {
            summary.span_us = Some(match summary.span_us {
                None => (stamp, stamp),
                Some((a, b)) => (a.min(stamp), b.max(stamp)),
            });
            sink(Sample {
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
    let mut summary = TopicSummary::of(tf);
    let source: Arc<str> = Arc::from(tf.source.as_str());
    let file = tf.path.as_path();
    match &tf.data {
        TopicData::Ulog { .. } => {
            // One topic: its rows in their order, whatever their times.
            let read = read_ulog_merged(
                std::slice::from_ref(tf),
                &mut |s| samples.push(s),
                prog,
                false,
            )?;
            summary = read.into_iter().flatten().next().unwrap_or(summary);
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
    let mut ends = Vec::with_capacity(header.len());
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
                field_ends(text, &mut ends);
                let row = Row {
                    file,
                    line,
                    header: &header,
                    fields: Fields::Text {
                        line: text,
                        ends: &ends,
                    },
                };
                row.check_len().and_then(|()| mapper.map(&row))
            }
            Err(_) => Err(Px4LogError::NotUtf8 {
                file: file.to_path_buf(),
                line,
            }),
        };
        take_row(summary, source, result, &mut |s| samples.push(s));
    }
    Ok(())
}

mod stream;
use crate::uorb::{field_ends, Fields, Kind, Mapper, Row, EKF2_FLOW_GYRO, TOPICS};
pub use crate::uorb::{MessageMapper, Px4LogError};
pub use stream::{read_ulog_for_replay, UlogRead, UlogSamples};

#[cfg(test)]
mod tests;
