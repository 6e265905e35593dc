//! uORB topics → samples: the field layout of each topic, found once by name (PX4
//! 1.12 – 1.16 variants), and the mapping of one row of values into a sample, in the
//! conventions `crate::sample` fixes (NED/FRD in, ENU/FLU out, SI units). A ULog or its
//! CSV export (`replay::px4log`) gives rows of a file; px4_msgs arriving over Zenoh
//! (`codec::ros::px4`) give one row per message ([`MessageMapper`]): both map alike.

use crate::sample::{
    frames, Attitude, AutopilotEstimate, GnssFix, GnssFixType, Imu, LandedState, Micros, Odometry,
    OpticalFlow, Range, SensorData, Tof, VehicleState,
};
use nalgebra::{Matrix3, Matrix6, Quaternion, UnitQuaternion, Vector2, Vector3};
use std::path::{Path, PathBuf};

mod message;
mod topics;
pub use message::MessageMapper;
pub(crate) use topics::Mapper;

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

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Kind {
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
    AirData,
    /// vehicle_status's arming state (not read from logs, which have actuator_armed).
    ArmingState,
}

/// Topic name, source name, kind; the order is the preference when two topics would
/// give the same source (the later one is then named after its topic) and the tie
/// order of equal stamps. Field layouts of PX4 v1.12 to v1.15 are read: where a topic
/// changed (vehicle_gps_position → sensor_gps, optical_flow → vehicle_optical_flow,
/// vehicle_visual_odometry's frames, sensor_gps's degrees in 1.15) both forms are.
pub(crate) const TOPICS: [(&str, &str, Kind); 16] = [
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
    ("vehicle_air_data", "baro", Kind::AirData),
];

/// Internal source of EKF2's flow gyro rows, attached to the flow samples and dropped.
pub(crate) const EKF2_FLOW_GYRO: &str = "ekf2_flow_gyro";

/// One data row with what its errors need to name: CSV text, or a ULog row's values.
pub(crate) struct Row<'a> {
    pub(crate) file: &'a Path,
    pub(crate) line: usize,
    pub(crate) header: &'a [String],
    pub(crate) fields: Fields<'a>,
}

#[derive(Clone, Copy)]
pub(crate) enum Fields<'a> {
    /// A CSV line and where each of its fields ends (the comma after it, or the end).
    Text { line: &'a str, ends: &'a [usize] },
    /// Row `row` of a ULog topic's columns, read in place: a column not kept (empty)
    /// reads as NaN.
    Num { columns: &'a [Vec<f64>], row: usize },
    /// One message's values, in header order (px4_msgs arriving one at a time).
    One(&'a [f64]),
}

impl<'a> Fields<'a> {
    pub(crate) fn len(&self) -> usize {
        match self {
            Fields::Text { ends, .. } => ends.len(),
            Fields::Num { columns, .. } => columns.len(),
            Fields::One(values) => values.len(),
        }
    }

    /// Field `c` of a ULog row (None past its last column).
    pub(crate) fn num(&self, c: usize) -> Option<f64> {
        match *self {
            Fields::Num { columns, row } => {
                Some(columns.get(c)?.get(row).copied().unwrap_or(f64::NAN))
            }
            Fields::One(values) => values.get(c).copied(),
            Fields::Text { .. } => None,
        }
    }

    /// Field `c` of a CSV line, trimmed.
    pub(crate) fn text(&self, c: usize) -> Option<&'a str> {
        let Fields::Text { line, ends } = *self else {
            return None;
        };
        let end = *ends.get(c)?;
        let start = match c {
            0 => 0,
            _ => ends[c - 1] + 1,
        };
        line.get(start..end).map(str::trim)
    }
}

/// Where each field of a CSV line ends: one pass over its bytes, into a reused buffer
/// (a line is split for every row of every topic).
pub(crate) fn field_ends(line: &str, ends: &mut Vec<usize>) {
    ends.clear();
    ends.extend(
        line.bytes()
            .enumerate()
            .filter(|&(_, b)| b == b',')
            .map(|(i, _)| i),
    );
    ends.push(line.len());
}

impl Row<'_> {
    pub(crate) fn check_len(&self) -> Result<(), Px4LogError> {
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

    pub(crate) fn text(&self, c: usize) -> String {
        match self.fields {
            Fields::Text { .. } => self.fields.text(c).unwrap_or("").to_string(),
            Fields::Num { .. } | Fields::One(_) => {
                self.fields.num(c).map_or(String::new(), |v| v.to_string())
            }
        }
    }

    pub(crate) fn name(&self, c: usize) -> String {
        self.header.get(c).cloned().unwrap_or_default()
    }

    pub(crate) fn bad(&self, c: usize, expected: &'static str) -> Px4LogError {
        Px4LogError::BadValue {
            file: self.file.to_path_buf(),
            line: self.line,
            column: c + 1,
            name: self.name(c),
            text: self.text(c),
            expected,
        }
    }

    pub(crate) fn unusable(&self, c: usize, reason: &'static str) -> Px4LogError {
        Px4LogError::Unusable {
            file: self.file.to_path_buf(),
            line: self.line,
            column: c + 1,
            name: self.name(c),
            reason,
        }
    }

    /// A float; `nan`/`inf` parse (PX4's "unknown").
    pub(crate) fn f64(&self, c: usize) -> Result<f64, Px4LogError> {
        match self.fields {
            Fields::Text { .. } => self
                .fields
                .text(c)
                .unwrap_or("")
                .parse()
                .map_err(|_| self.bad(c, "a number")),
            Fields::Num { .. } | Fields::One(_) => {
                self.fields.num(c).ok_or_else(|| self.bad(c, "a number"))
            }
        }
    }

    pub(crate) fn finite(&self, c: usize, reason: &'static str) -> Result<f64, Px4LogError> {
        let v = self.f64(c)?;
        if v.is_finite() {
            Ok(v)
        } else {
            Err(self.unusable(c, reason))
        }
    }

    pub(crate) fn int(
        &self,
        c: usize,
        min: i64,
        max: i64,
        expected: &'static str,
    ) -> Result<i64, Px4LogError> {
        let v = match self.fields {
            Fields::Text { .. } => self.fields.text(c).and_then(|s| s.parse::<i64>().ok()),
            Fields::Num { .. } | Fields::One(_) => self
                .fields
                .num(c)
                .filter(|v| v.fract() == 0.0 && v.abs() < 9.0e18)
                .map(|v| v as i64),
        };
        match v {
            Some(v) if (min..=max).contains(&v) => Ok(v),
            _ => Err(self.bad(c, expected)),
        }
    }

    pub(crate) fn u8(&self, c: usize) -> Result<u8, Px4LogError> {
        Ok(self.int(c, 0, 255, "an integer 0..=255")? as u8)
    }

    pub(crate) fn stamp(&self, c: usize) -> Result<Micros, Px4LogError> {
        self.int(c, 0, i64::MAX, "a timestamp in µs")
    }

    pub(crate) fn vec3(&self, c: [usize; 3]) -> Result<Vector3<f64>, Px4LogError> {
        Ok(Vector3::new(
            self.f64(c[0])?,
            self.f64(c[1])?,
            self.f64(c[2])?,
        ))
    }

    /// Quaternion w, x, y, z; `None` if non-finite or zero (PX4's "invalid").
    pub(crate) fn quat(&self, c: [usize; 4]) -> Result<Option<UnitQuaternion<f64>>, Px4LogError> {
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
    pub(crate) fn urt6(&self, c: &[usize; 21]) -> Result<Option<Matrix6<f64>>, Px4LogError> {
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
pub(crate) struct Cols<'a> {
    file: &'a Path,
    header: &'a [String],
    /// Every column looked up, by index (a mapper reads only these).
    read: std::cell::RefCell<Vec<bool>>,
}

impl<'a> Cols<'a> {
    pub(crate) fn new(file: &'a Path, header: &'a [String]) -> Self {
        Self {
            file,
            header,
            read: std::cell::RefCell::new(vec![false; header.len()]),
        }
    }

    pub(crate) fn get(&self, name: &str) -> Result<usize, Px4LogError> {
        self.opt(name).ok_or_else(|| Px4LogError::MissingColumn {
            file: self.file.to_path_buf(),
            column: name.to_string(),
        })
    }

    /// `name`, or in a log older than the field's name, what PX4 called it before
    /// (vehicle_local_position's `heading` was `yaw`, distance_sensor's `variance` was
    /// `covariance`): a real log is not refused over a rename.
    pub(crate) fn get_renamed(&self, name: &str, before: &str) -> Result<usize, Px4LogError> {
        self.opt(name)
            .or_else(|| self.opt(before))
            .ok_or_else(|| Px4LogError::MissingColumn {
                file: self.file.to_path_buf(),
                column: name.to_string(),
            })
    }

    pub(crate) fn opt(&self, name: &str) -> Option<usize> {
        let i = self.header.iter().position(|h| h == name)?;
        self.read.borrow_mut()[i] = true;
        Some(i)
    }

    pub(crate) fn arr<const N: usize>(&self, name: &str) -> Result<[usize; N], Px4LogError> {
        let mut out = [0; N];
        for (i, o) in out.iter_mut().enumerate() {
            *o = self.get(&format!("{name}[{i}]"))?;
        }
        Ok(out)
    }

    pub(crate) fn list<const N: usize>(&self, names: [&str; N]) -> Result<[usize; N], Px4LogError> {
        let mut out = [0; N];
        for (o, n) in out.iter_mut().zip(names) {
            *o = self.get(n)?;
        }
        Ok(out)
    }
}
