//! PX4 logs exported to CSV by pyulog's `ulog2csv` → samples for offline replay.
//!
//! The export is a directory of `<topic>_<instance>.csv` files, each with a header row of
//! field names and `timestamp` (µs since boot) first; PX4 writes unknown values as `nan`.
//! The topics read, and the sources they become (instance 0 keeps the plain name,
//! instance `i` gets `_i`, e.g. `optical_flow_1` → `flow_1`):
//!
//! | file                          | source     | sample                                   |
//! |-------------------------------|------------|------------------------------------------|
//! | `estimator_states_<i>`        | `attitude_states` | [`Attitude`] from states\[0..4\] (EKF2 quaternion, 1 Hz) |
//! | `vehicle_local_position_0` heading | `attitude` | [`Attitude`], yaw only (10 Hz stand-in) |
//! | `vehicle_imu_<i>`             | `imu`      | [`Imu`] from delta angle/velocity ÷ dt   |
//! | `distance_sensor_<i>`         | `range`    | [`Range`]                                |
//! | `optical_flow_<i>`            | `flow`     | [`OpticalFlow`]; gyro from `estimator_optical_flow_vel` |
//! | `vehicle_visual_odometry_<i>` | `vio`      | [`Odometry`]                             |
//! | `vehicle_local_position_<i>`  | `ekf2`     | [`AutopilotEstimate`]                    |
//!
//! The field layout is that of the PX4 v1.12/v1.13 uORB messages (`optical_flow`, the
//! `vehicle_odometry` with `local_frame`/`velocity_frame`); a file of a known topic that
//! lacks a column we need is an error, so a log from a newer PX4 fails loudly.
//!
//! Conventions, as `crate::sample` fixes them: NED/FRD in, ENU/FLU out, SI units.
//! `stamp_us` and `arrival_us` are both the row's `timestamp` (PX4's publication time,
//! one clock for everything offline). Where a topic also has `timestamp_sample` (the
//! measurement time) that is earlier: about 1 ms for the EKF2 and IMU topics, but a
//! median 22 ms (up to 53 ms) for vehicle_visual_odometry, the camera pipeline's delay.
//!
//! Rows: one that is malformed (wrong field count, text that is not a number) or that no
//! sample can be formed from (a non-finite position, a zero integration time) is skipped
//! and counted in its [`TopicSummary`], the first such error kept. Only a directory or
//! file that cannot be read, a header without a column we need, or a directory with none
//! of the topics above fails the whole read.

use crate::sample::{
    frames, Attitude, AutopilotEstimate, Imu, Micros, Odometry, OpticalFlow, Range, Sample,
    SensorData,
};
use nalgebra::{Matrix3, Matrix6, Quaternion, UnitQuaternion, Vector2, Vector3};
use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// A replayable log: samples sorted by `stamp_us`, and what each file contributed.
#[derive(Debug)]
pub struct Px4CsvLog {
    pub samples: Vec<Sample>,
    /// One entry per file read, in reading order (the tie order of `samples`).
    pub topics: Vec<TopicSummary>,
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
    pub first_error: Option<Px4CsvError>,
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
pub enum Px4CsvError {
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
    #[error("{}:1: the header has no column `{column}` (not the PX4 v1.12/1.13 layout?)", file.display())]
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
pub fn read_dir(dir: &Path) -> Result<Px4CsvLog, Px4CsvError> {
    read_dir_with_progress(dir, &mut |_, _| {})
}

/// [`read_dir`], calling `progress(bytes_done, bytes_total)` as the files are read (about
/// every 256 KiB, and once at the end with `bytes_done == bytes_total`).
pub fn read_dir_with_progress(
    dir: &Path,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<Px4CsvLog, Px4CsvError> {
    let files = find_topic_files(dir)?;
    let total = files.iter().map(|f| f.bytes).sum();
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
    // Stable: equal stamps keep file order (the TOPICS order, then instance).
    samples.sort_by_key(|s| s.stamp_us);
    attach_ekf2_flow_gyro(dir, &mut samples);
    attitude_from_ekf2_heading(&mut samples);
    (prog.cb)(prog.total, prog.total);
    Ok(Px4CsvLog { samples, topics })
}

/// The export's attitude (`estimator_states`) is logged at 1 Hz only; a companion
/// computer would get ATTITUDE at tens of Hz. EKF2's heading (`vehicle_local_position`,
/// 10 Hz) stands in for it as source `attitude`: yaw only, level (the flight is gentle;
/// the 1 Hz quaternion stays available as `attitude_states`).
fn attitude_from_ekf2_heading(samples: &mut Vec<Sample>) {
    let mut extra = Vec::new();
    for s in samples.iter_mut() {
        match &s.data {
            SensorData::AutopilotEstimate(a) if s.source.as_ref() == "ekf2" => {
                if let Some(yaw) = a.yaw.filter(|y| y.is_finite()) {
                    extra.push(Sample {
                        source: "attitude".into(),
                        stamp_us: s.stamp_us,
                        arrival_us: s.arrival_us,
                        data: SensorData::Attitude(crate::sample::Attitude {
                            orientation: UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
                            rates: None,
                        }),
                    });
                }
            }
            _ => {}
        }
    }
    samples.extend(extra);
    samples.sort_by_key(|s| s.stamp_us);
}

/// Flow modules without a gyro (NaN in `optical_flow`) leave rotation compensation to
/// the autopilot's IMU. The export has no high-rate IMU, but EKF2 logged the gyro
/// integral it used over each flow interval (`estimator_optical_flow_vel`,
/// `gyro_rate_integral`, FRD, with the opposite sign to the body rate — checked against
/// the VIO's rates). Attach it to the `flow` samples it belongs to (same sample time
/// within 5 ms), as OPTICAL_FLOW_RAD's integrated gyro would carry it. Best effort: a
/// missing or unreadable file changes nothing.
fn attach_ekf2_flow_gyro(dir: &Path, samples: &mut [Sample]) {
    let Ok(text) = std::fs::read_to_string(dir.join("estimator_optical_flow_vel_0.csv")) else {
        return;
    };
    let mut lines = text.lines();
    let Some(header) = lines.next() else { return };
    let cols: Vec<&str> = header.split(',').collect();
    let find = |n: &str| cols.iter().position(|c| *c == n);
    let (Some(ts), Some(g0), Some(g1), Some(g2)) = (
        find("timestamp_sample"),
        find("gyro_rate_integral[0]"),
        find("gyro_rate_integral[1]"),
        find("gyro_rate_integral[2]"),
    ) else {
        return;
    };
    let mut rows: Vec<(i64, Vector3<f64>)> = lines
        .filter_map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            let num = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok());
            let t = f.get(ts)?.parse::<i64>().ok()?;
            let g = Vector3::new(num(g0)?, num(g1)?, num(g2)?);
            g.iter().all(|v| v.is_finite()).then_some((t, g))
        })
        .collect();
    rows.sort_by_key(|r| r.0);
    for s in samples.iter_mut().filter(|s| s.source.as_ref() == "flow") {
        let (Some(t), SensorData::Flow(f)) = (s.stamp_us, &mut s.data) else {
            continue;
        };
        let (Some(dt), None) = (f.integration_s, f.gyro) else {
            continue;
        };
        let i = rows.partition_point(|r| r.0 < t);
        let best = [i.checked_sub(1), Some(i)]
            .into_iter()
            .flatten()
            .filter_map(|j| rows.get(j))
            .min_by_key(|r| (r.0 - t).abs());
        if let Some((rt, g)) = best {
            if (rt - t).abs() <= 5_000 {
                f.gyro = Some(frames::frd_to_flu(-g / dt));
            }
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Attitude,
    Imu,
    Range,
    Flow,
    Vio,
    Ekf2,
}

/// File prefix, source name, kind; the order is also the tie order of equal stamps.
const TOPICS: [(&str, &str, Kind); 6] = [
    ("estimator_states", "attitude_states", Kind::Attitude),
    ("vehicle_imu", "imu", Kind::Imu),
    ("distance_sensor", "range", Kind::Range),
    ("optical_flow", "flow", Kind::Flow),
    ("vehicle_visual_odometry", "vio", Kind::Vio),
    ("vehicle_local_position", "ekf2", Kind::Ekf2),
];

struct TopicFile {
    path: PathBuf,
    name: String,
    source: String,
    kind: Kind,
    bytes: u64,
    order: (usize, u32),
}

/// `<prefix>_<digits>.csv` → (TOPICS index, instance).
fn match_topic(file_name: &str) -> Option<(usize, u32)> {
    let stem = file_name.strip_suffix(".csv")?;
    TOPICS.iter().enumerate().find_map(|(i, (prefix, _, _))| {
        let inst = stem.strip_prefix(prefix)?.strip_prefix('_')?;
        // All digits, so `vehicle_local_position_setpoint_0` is not a match.
        if inst.is_empty() || !inst.bytes().all(|b| b.is_ascii_digit()) {
            return None;
        }
        Some((i, inst.parse().ok()?))
    })
}

fn find_topic_files(dir: &Path) -> Result<Vec<TopicFile>, Px4CsvError> {
    let list_err = |source| Px4CsvError::ListDir {
        dir: dir.to_path_buf(),
        source,
    };
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(list_err)? {
        let entry = entry.map_err(list_err)?;
        let file_name = entry.file_name();
        let Some((ti, inst)) = file_name.to_str().and_then(match_topic) else {
            continue;
        };
        let path = entry.path();
        let bytes = std::fs::metadata(&path)
            .map_err(|source| Px4CsvError::Open {
                file: path.clone(),
                source,
            })?
            .len();
        let (prefix, source, kind) = TOPICS[ti];
        files.push(TopicFile {
            name: format!("{prefix}_{inst}"),
            source: if inst == 0 {
                source.to_string()
            } else {
                format!("{source}_{inst}")
            },
            kind,
            bytes,
            order: (ti, inst),
            path,
        });
    }
    if files.is_empty() {
        let looked_for = TOPICS
            .iter()
            .map(|(p, _, _)| format!("{p}_<i>.csv"))
            .collect::<Vec<_>>()
            .join(", ");
        return Err(Px4CsvError::NoKnownTopics {
            dir: dir.to_path_buf(),
            looked_for,
        });
    }
    files.sort_by_key(|f| f.order);
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

fn read_topic(
    tf: &TopicFile,
    samples: &mut Vec<Sample>,
    prog: &mut Progress<'_>,
) -> Result<TopicSummary, Px4CsvError> {
    let file = tf.path.as_path();
    let io_err = |line, source| Px4CsvError::Io {
        file: file.to_path_buf(),
        line,
        source,
    };
    let f = File::open(file).map_err(|source| Px4CsvError::Open {
        file: file.to_path_buf(),
        source,
    })?;
    let mut reader = BufReader::with_capacity(1 << 16, f);
    let mut buf = Vec::with_capacity(1024);
    let n = reader
        .read_until(b'\n', &mut buf)
        .map_err(|e| io_err(1, e))?;
    prog.advance(n);
    let header_text = std::str::from_utf8(&buf).map_err(|_| Px4CsvError::NotUtf8 {
        file: file.to_path_buf(),
        line: 1,
    })?;
    let header: Vec<String> = header_text
        .trim_end_matches(['\r', '\n'])
        .split(',')
        .map(|s| s.trim().to_string())
        .collect();
    if n == 0 || header.iter().all(|h| h.is_empty()) {
        return Err(Px4CsvError::NoHeader {
            file: file.to_path_buf(),
        });
    }
    let mapper = Mapper::new(tf.kind, file, &header)?;
    let source: Arc<str> = Arc::from(tf.source.as_str());
    let mut summary = TopicSummary {
        name: tf.name.clone(),
        source: tf.source.clone(),
        rows: 0,
        skipped: 0,
        first_error: None,
        span_us: None,
    };
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
        prog.advance(n);
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
                    fields: &fields,
                };
                row.check_len().and_then(|()| mapper.map(&row))
            }
            Err(_) => Err(Px4CsvError::NotUtf8 {
                file: file.to_path_buf(),
                line,
            }),
        };
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
    Ok(summary)
}

/// One data row with what its errors need to name.
struct Row<'a> {
    file: &'a Path,
    line: usize,
    header: &'a [String],
    fields: &'a [&'a str],
}

impl Row<'_> {
    fn check_len(&self) -> Result<(), Px4CsvError> {
        let (expected, found) = (self.header.len(), self.fields.len());
        if expected == found {
            return Ok(());
        }
        Err(Px4CsvError::ColumnCount {
            file: self.file.to_path_buf(),
            line: self.line,
            column: expected.min(found) + 1,
            expected,
            found,
        })
    }

    fn text(&self, c: usize) -> &str {
        self.fields.get(c).map_or("", |s| s.trim())
    }

    fn name(&self, c: usize) -> String {
        self.header.get(c).cloned().unwrap_or_default()
    }

    fn bad(&self, c: usize, expected: &'static str) -> Px4CsvError {
        Px4CsvError::BadValue {
            file: self.file.to_path_buf(),
            line: self.line,
            column: c + 1,
            name: self.name(c),
            text: self.text(c).to_string(),
            expected,
        }
    }

    fn unusable(&self, c: usize, reason: &'static str) -> Px4CsvError {
        Px4CsvError::Unusable {
            file: self.file.to_path_buf(),
            line: self.line,
            column: c + 1,
            name: self.name(c),
            reason,
        }
    }

    /// A float; `nan`/`inf` parse (PX4's "unknown").
    fn f64(&self, c: usize) -> Result<f64, Px4CsvError> {
        self.text(c).parse().map_err(|_| self.bad(c, "a number"))
    }

    fn finite(&self, c: usize, reason: &'static str) -> Result<f64, Px4CsvError> {
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
    ) -> Result<i64, Px4CsvError> {
        match self.text(c).parse::<i64>() {
            Ok(v) if (min..=max).contains(&v) => Ok(v),
            _ => Err(self.bad(c, expected)),
        }
    }

    fn u8(&self, c: usize) -> Result<u8, Px4CsvError> {
        Ok(self.int(c, 0, 255, "an integer 0..=255")? as u8)
    }

    fn stamp(&self, c: usize) -> Result<Micros, Px4CsvError> {
        self.int(c, 0, i64::MAX, "a timestamp in µs")
    }

    fn vec3(&self, c: [usize; 3]) -> Result<Vector3<f64>, Px4CsvError> {
        Ok(Vector3::new(
            self.f64(c[0])?,
            self.f64(c[1])?,
            self.f64(c[2])?,
        ))
    }

    /// Quaternion w, x, y, z; `None` if non-finite or zero (PX4's "invalid").
    fn quat(&self, c: [usize; 4]) -> Result<Option<UnitQuaternion<f64>>, Px4CsvError> {
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
    fn urt6(&self, c: &[usize; 21]) -> Result<Option<Matrix6<f64>>, Px4CsvError> {
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
    fn get(&self, name: &str) -> Result<usize, Px4CsvError> {
        self.opt(name).ok_or_else(|| Px4CsvError::MissingColumn {
            file: self.file.to_path_buf(),
            column: name.to_string(),
        })
    }

    fn opt(&self, name: &str) -> Option<usize> {
        self.header.iter().position(|h| h == name)
    }

    fn arr<const N: usize>(&self, name: &str) -> Result<[usize; N], Px4CsvError> {
        let mut out = [0; N];
        for (i, o) in out.iter_mut().enumerate() {
            *o = self.get(&format!("{name}[{i}]"))?;
        }
        Ok(out)
    }

    fn list<const N: usize>(&self, names: [&str; N]) -> Result<[usize; N], Px4CsvError> {
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
    Range(RangeCols),
    Flow(FlowCols),
    Vio(Box<VioCols>),
    Ekf2(Ekf2Cols),
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
}

struct VioCols {
    t: usize,
    pos: [usize; 3],
    q: [usize; 4],
    pose_cov: [usize; 21],
    vel: [usize; 3],
    rates: [usize; 3],
    vel_cov: [usize; 21],
    local_frame: usize,
    velocity_frame: usize,
    reset_counter: usize,
    /// Added to vehicle_odometry after v1.13; absent in older logs.
    quality: Option<usize>,
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
    fn new(kind: Kind, file: &Path, header: &[String]) -> Result<Self, Px4CsvError> {
        let h = Cols { file, header };
        let t = h.get("timestamp")?;
        Ok(match kind {
            Kind::Attitude => Mapper::Attitude(AttitudeCols {
                t,
                q: h.list(["states[0]", "states[1]", "states[2]", "states[3]"])?,
            }),
            Kind::Imu => Mapper::Imu(ImuCols {
                t,
                dang: h.arr("delta_angle")?,
                dvel: h.arr("delta_velocity")?,
                dang_dt: h.get("delta_angle_dt")?,
                dvel_dt: h.get("delta_velocity_dt")?,
            }),
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
            }),
            Kind::Vio => Mapper::Vio(Box::new(VioCols {
                t,
                pos: h.list(["x", "y", "z"])?,
                q: h.arr("q")?,
                pose_cov: h.arr("pose_covariance")?,
                vel: h.list(["vx", "vy", "vz"])?,
                rates: h.list(["rollspeed", "pitchspeed", "yawspeed"])?,
                vel_cov: h.arr("velocity_covariance")?,
                local_frame: h.get("local_frame")?,
                velocity_frame: h.get("velocity_frame")?,
                reset_counter: h.get("reset_counter")?,
                quality: h.opt("quality"),
            })),
            Kind::Ekf2 => Mapper::Ekf2(Ekf2Cols {
                t,
                pos: h.list(["x", "y", "z"])?,
                vel: h.list(["vx", "vy", "vz"])?,
                heading: h.get("heading")?,
                valid: h.list(["xy_valid", "z_valid", "v_xy_valid", "v_z_valid"])?,
            }),
        })
    }

    fn map(&self, r: &Row<'_>) -> Result<(Micros, SensorData), Px4CsvError> {
        match self {
            Mapper::Attitude(c) => attitude(c, r),
            Mapper::Imu(c) => imu(c, r),
            Mapper::Range(c) => range(c, r),
            Mapper::Flow(c) => flow(c, r),
            Mapper::Vio(c) => vio(c, r),
            Mapper::Ekf2(c) => ekf2(c, r),
        }
    }
}

/// EKF2's quaternion (body FRD → NED), standing in for the autopilot attitude a
/// companion computer would receive. estimator_states has no body rates, and is logged
/// at only 1 Hz in this export.
fn attitude(c: &AttitudeCols, r: &Row<'_>) -> Result<(Micros, SensorData), Px4CsvError> {
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
fn imu(c: &ImuCols, r: &Row<'_>) -> Result<(Micros, SensorData), Px4CsvError> {
    let t = r.stamp(c.t)?;
    let per_s = |d: Vector3<f64>, dt_col: usize| -> Result<Option<Vector3<f64>>, Px4CsvError> {
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

fn range(c: &RangeCols, r: &Row<'_>) -> Result<(Micros, SensorData), Px4CsvError> {
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
fn flow(c: &FlowCols, r: &Row<'_>) -> Result<(Micros, SensorData), Px4CsvError> {
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
            // optical_flow's ground_distance_m is 0 without a module ToF; the range
            // finder is its own topic.
            tof: None,
        }),
    ))
}

/// vehicle_visual_odometry (v1.12/1.13 layout): pose in `local_frame` (NED, or FRD
/// earth-fixed with an arbitrary heading, which converts the same way), body FRD;
/// velocity in `velocity_frame`, turned into body FLU as nav_msgs/Odometry has it.
fn vio(c: &VioCols, r: &Row<'_>) -> Result<(Micros, SensorData), Px4CsvError> {
    let t = r.stamp(c.t)?;
    let local_frame = r.int(c.local_frame, 0, 255, "a frame constant")?;
    if local_frame != LOCAL_FRAME_NED && local_frame != LOCAL_FRAME_FRD {
        return Err(r.unusable(c.local_frame, "pose frame is neither NED nor FRD"));
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
        LOCAL_FRAME_NED | LOCAL_FRAME_FRD => Some(q.to_rotation_matrix().matrix().transpose() * p),
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
    let pose_cov = r.urt6(&c.pose_cov)?.map(|cov| transform_cov6(cov, p, p));
    let twist_cov = match (vel_map, r.urt6(&c.vel_cov)?) {
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

/// vehicle_local_position: position and velocity only where PX4 flags them valid (PX4's
/// own LOCAL_POSITION_NED stream holds back invalid ones too); heading where finite. No
/// geodetic position: an indoor log has no reference (ref_lat/lon NaN).
fn ekf2(c: &Ekf2Cols, r: &Row<'_>) -> Result<(Micros, SensorData), Px4CsvError> {
    let t = r.stamp(c.t)?;
    let flag = |col: usize| -> Result<bool, Px4CsvError> { Ok(r.int(col, 0, 1, "0 or 1")? == 1) };
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

    /// The real flight (resolves to /work/shared/data/... from the crate root).
    const DATA_DIR: &str = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../shared/data/px4-flow-vio-7c824ee5"
    );

    fn real() -> &'static Px4CsvLog {
        static LOG: std::sync::OnceLock<Px4CsvLog> = std::sync::OnceLock::new();
        LOG.get_or_init(|| match read_dir(Path::new(DATA_DIR)) {
            Ok(log) => log,
            Err(e) => panic!("reading {DATA_DIR}: {e}"),
        })
    }

    fn first_of<'a>(log: &'a Px4CsvLog, source: &str) -> &'a Sample {
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
                std::env::temp_dir().join(format!("px4csv-test-{}-{tag}-{n}", std::process::id()));
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
            ("distance_sensor_0", ("range", 14982, 0)),
            ("distance_sensor_1", ("range_1", 11849, 0)),
            ("estimator_states_0", ("attitude_states", 308, 0)),
            ("optical_flow_0", ("flow", 17666, 0)),
            ("optical_flow_1", ("flow_1", 14438, 0)),
            ("vehicle_imu_0", ("imu", 615, 0)),
            ("vehicle_imu_1", ("imu_1", 615, 0)),
            ("vehicle_local_position_0", ("ekf2", 3077, 0)),
            ("vehicle_visual_odometry_0", ("vio", 8978, 0)),
        ]);
        assert_eq!(got, want);
        let total: usize = log.topics.iter().map(TopicSummary::samples).sum();
        assert_eq!(total, 72528);
        // Plus one `attitude` per EKF2 heading (vehicle_local_position rows).
        assert_eq!(log.samples.len(), total + 3077);
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
        assert_eq!(first, Some(1_431_940)); // vehicle_local_position's first row
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

    #[test]
    fn attitude_and_ekf2_heading_agree() {
        let log = real();
        let s = first_of(log, "attitude_states");
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
        // The 10 Hz `attitude` stand-in is that heading, level.
        let SensorData::Attitude(h) = &first_of(log, "attitude").data else {
            panic!("not attitude")
        };
        assert!(close(h.orientation.euler_angles().2, yaw, 1e-9));
        assert!(h.orientation.euler_angles().0.abs() < 1e-12);
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
        assert!(calls.len() > 10, "{} calls", calls.len());
        assert!(calls
            .windows(2)
            .all(|w| w[0].0 <= w[1].0 && w[0].1 == w[1].1));
        let (done, total) = calls[calls.len() - 1];
        assert_eq!(done, total);
        let known: u64 = real()
            .topics
            .iter()
            .filter_map(|t| {
                std::fs::metadata(Path::new(DATA_DIR).join(format!("{}.csv", t.name))).ok()
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
                Px4CsvError::ColumnCount {
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
            Err(e @ Px4CsvError::MissingColumn { .. }) => {
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
            Err(Px4CsvError::NoHeader { .. })
        ));
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
            Err(Px4CsvError::ListDir { .. })
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
