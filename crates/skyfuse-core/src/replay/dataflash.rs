//! ArduPilot DataFlash logs (`.bin`: what an ArduPilot autopilot writes to its SD card,
//! and SITL to `logs/`) → samples for offline replay. Most ArduPilot users have these,
//! not telemetry logs.
//!
//! The format describes itself: each record is `A3 95 <type>` and its fields packed
//! little-endian; FMT records (type 128, 89 bytes) give a type its length, name, field
//! types and labels. Values are decoded as pymavlink's `DFReader` decodes them
//! (`c C e E` in hundredths, `L` in 1e-7 degrees) and found by label, so the logs of
//! every ArduPilot version read alike (`TimeUS` or the older `TimeMS`).
//!
//! | record | source | sample |
//! |--------|--------|--------|
//! | `IMU` (instance `I`), `IMU2`.. | `imu`, `imu_1`.. | [`Imu`] |
//! | `ATT` | `attitude` | [`Attitude`] (Euler angles, degrees) |
//! | `OF` | `flow` | [`OpticalFlow`]: flowX/Y the sensor's rates, bodyX/Y its gyro |
//! | `RFND` (instance, `Orient`) | `range`, `range_1`.. | [`Range`], limits from `RNGFNDn_MIN_CM`/`MAX_CM` parameters |
//! | `GPS` (instance `I`) | `gps`, `gps_1`.. | [`GnssFix`] |
//! | `BARO` (instance `I`) | `baro`, `baro_1`.. | [`Baro`] |
//! | `XKF1` core 0 / `NKF1` core 0 / `EKF1` | `ekf3` / `ekf2` / `ekf` | [`AutopilotEstimate`] (comparison only) |
//! | `VISP` | `visp` | [`Odometry`]: the external pose the autopilot was given |
//! | `SIM` | `sim_truth` | [`AutopilotEstimate`]: SITL's truth (never fused) |
//!
//! Conventions as `crate::sample` fixes them (NED/FRD in, ENU/FLU out). `OF`'s rates
//! follow MAVLink (a right-handed rotation about x is positive; EKF3 predicts
//! `flow − body = (v_y, −v_x)/range` in FRD after negating both): in FLU their y
//! changes sign, as PX4's. `stamp_us` and `arrival_us` are both the record's time.
//!
//! A stretch that is not a record (corruption, the padding of a block device) is
//! skipped to the next header and counted; an FMT that does not add up (a length its
//! types do not fill, a type character no ArduPilot writes) is refused and named, and
//! the records of its type are skipped and counted; a record cut by the end of the file
//! is reported ([`DataflashLog::cut_short`]): a flight that ended early, not a complete
//! shorter one.

use crate::sample::{
    frames, Attitude, AutopilotEstimate, Baro, GnssFix, GnssFixType, Imu, Micros, Odometry,
    OpticalFlow, Range, Sample, SensorData,
};
use nalgebra::{UnitQuaternion, Vector2, Vector3};
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::codec::dataflash::{field_size, HEAD1, HEAD2};
pub use crate::codec::dataflash::{FMT_LEN, FMT_TYPE};
/// MAV_SENSOR_ORIENTATION PITCH_270: a downward range finder.
const ORIENT_DOWN: u8 = 25;
/// RangeFinder::Status::Good in RFND's `Stat`.
const RANGE_GOOD: f64 = 4.0;
/// An OF record's interval when there is no previous one to measure it by, s.
const FLOW_DT_DEFAULT_S: f64 = 0.02;

#[derive(Debug, thiserror::Error)]
pub enum DataflashError {
    #[error("{}: cannot read: {source}", file.display())]
    Read {
        file: PathBuf,
        source: std::io::Error,
    },
    #[error("{}: no DataFlash record found (not an ArduPilot .bin log?)", file.display())]
    NoRecords { file: PathBuf },
}

/// One record type, from its FMT.
#[derive(Debug, Clone)]
pub struct Format {
    pub name: String,
    /// Record length including the 3-byte header.
    pub len: usize,
    types: Vec<u8>,
    labels: Vec<String>,
    /// Each field's offset in the payload.
    offsets: Vec<usize>,
}

impl Format {
    /// A format from an FMT payload (86 bytes), checked: every type known, the length
    /// the types fill.
    fn from_fmt(payload: &[u8]) -> Result<(u8, Format), String> {
        let text = |b: &[u8]| {
            let end = b.iter().position(|&c| c == 0).unwrap_or(b.len());
            String::from_utf8_lossy(&b[..end]).trim_end().to_string()
        };
        let (Some(&id), Some(&len)) = (payload.first(), payload.get(1)) else {
            return Err("FMT record too short".into());
        };
        let name = text(payload.get(2..6).unwrap_or_default());
        let types = text(payload.get(6..22).unwrap_or_default()).into_bytes();
        let labels: Vec<String> = text(payload.get(22..86).unwrap_or_default())
            .split(',')
            .map(str::to_string)
            .collect();
        let mut offsets = Vec::with_capacity(types.len());
        let mut at = 0;
        for &c in &types {
            let size = field_size(c).ok_or_else(|| {
                format!(
                    "FMT of {name} (type {id}): field type {:?} is not a DataFlash type",
                    c as char
                )
            })?;
            offsets.push(at);
            at += size;
        }
        if 3 + at != usize::from(len) {
            return Err(format!(
                "FMT of {name} (type {id}): length {len}, but its fields {:?} take {}",
                String::from_utf8_lossy(&types),
                3 + at
            ));
        }
        // ArduPilot's logs open with FMT's own definition: only a different one is wrong.
        if id == FMT_TYPE && (usize::from(len) != FMT_LEN || types != b"BBnNZ") {
            return Err(format!(
                "an FMT record redefines FMT as {:?}, length {len}",
                String::from_utf8_lossy(&types)
            ));
        }
        Ok((
            id,
            Format {
                name,
                len: len.into(),
                types,
                labels,
                offsets,
            },
        ))
    }

    fn index(&self, label: &str) -> Option<usize> {
        self.labels.iter().position(|l| l == label)
    }
}

/// One data record, its fields read on demand.
pub struct Record<'a> {
    pub format: &'a Format,
    payload: &'a [u8],
}

impl Record<'_> {
    pub fn name(&self) -> &str {
        &self.format.name
    }

    /// Field `label` as a number, scaled as pymavlink scales it; `None` if the record
    /// has no such field or it is text.
    pub fn get(&self, label: &str) -> Option<f64> {
        let i = self.format.index(label)?;
        self.value(i)
    }

    fn value(&self, i: usize) -> Option<f64> {
        let at = *self.format.offsets.get(i)?;
        let c = *self.format.types.get(i)?;
        let b = self.payload.get(at..at + field_size(c)?)?;
        let arr = |n: usize| b.get(..n);
        Some(match c {
            b'b' | b'M' => f64::from(b[0] as i8),
            b'B' => f64::from(b[0]),
            b'h' => f64::from(i16::from_le_bytes(arr(2)?.try_into().ok()?)),
            b'H' => f64::from(u16::from_le_bytes(arr(2)?.try_into().ok()?)),
            b'c' => f64::from(i16::from_le_bytes(arr(2)?.try_into().ok()?)) * 0.01,
            b'C' => f64::from(u16::from_le_bytes(arr(2)?.try_into().ok()?)) * 0.01,
            b'g' => half_to_f64(u16::from_le_bytes(arr(2)?.try_into().ok()?)),
            b'i' => f64::from(i32::from_le_bytes(arr(4)?.try_into().ok()?)),
            b'I' => f64::from(u32::from_le_bytes(arr(4)?.try_into().ok()?)),
            b'e' => f64::from(i32::from_le_bytes(arr(4)?.try_into().ok()?)) * 0.01,
            b'E' => f64::from(u32::from_le_bytes(arr(4)?.try_into().ok()?)) * 0.01,
            b'L' => f64::from(i32::from_le_bytes(arr(4)?.try_into().ok()?)) * 1e-7,
            b'f' => f64::from(f32::from_le_bytes(arr(4)?.try_into().ok()?)),
            b'd' => f64::from_le_bytes(arr(8)?.try_into().ok()?),
            b'q' => i64::from_le_bytes(arr(8)?.try_into().ok()?) as f64,
            b'Q' => u64::from_le_bytes(arr(8)?.try_into().ok()?) as f64,
            _ => return None,
        })
    }

    /// Field `label` as text (`n N Z` fields).
    pub fn text(&self, label: &str) -> Option<String> {
        let i = self.format.index(label)?;
        let at = *self.format.offsets.get(i)?;
        let c = *self.format.types.get(i)?;
        if !matches!(c, b'n' | b'N' | b'Z') {
            return None;
        }
        let b = self.payload.get(at..at + field_size(c)?)?;
        let end = b.iter().position(|&c| c == 0).unwrap_or(b.len());
        Some(String::from_utf8_lossy(&b[..end]).trim_end().to_string())
    }

    /// The record's time, µs since boot: `TimeUS`, or `TimeMS` (logs before 2015),
    /// where GPS's `TimeMS` is the GPS time of week and its boot time is `T`.
    pub fn time_us(&self) -> Option<Micros> {
        if let Some(us) = self.get("TimeUS") {
            return Some(us as Micros);
        }
        if self.format.index("Week").is_some() {
            return self.get("T").map(|ms| (ms * 1000.0) as Micros);
        }
        self.get("TimeMS").map(|ms| (ms * 1000.0) as Micros)
    }
}

/// IEEE half precision (`g`) → f64.
fn half_to_f64(h: u16) -> f64 {
    let sign = if h & 0x8000 != 0 { -1.0 } else { 1.0 };
    let exp = i32::from((h >> 10) & 0x1F);
    let frac = f64::from(h & 0x3FF);
    sign * match exp {
        0 => frac * 2f64.powi(-24),
        31 if frac == 0.0 => f64::INFINITY,
        31 => f64::NAN,
        e => (1.0 + frac / 1024.0) * 2f64.powi(e - 15),
    }
}

/// What a walk over the bytes found besides the records.
#[derive(Debug, Default, Clone, PartialEq)]
pub struct Scan {
    /// Data records read (FMT records not counted).
    pub records: u64,
    /// Record types defined.
    pub formats: usize,
    /// Bytes that were not part of a record (corruption, padding), skipped.
    pub skipped_bytes: u64,
    /// Records of a type no (valid) FMT defined, skipped.
    pub undefined_records: u64,
    /// FMT records refused, and why the first was.
    pub bad_formats: u64,
    pub first_error: Option<String>,
    /// The offset of a record the end of the file cuts in two, if one is.
    pub cut_short: Option<u64>,
}

/// Walks every record of a DataFlash log in file order: the pure codec under
/// [`parse`]. `progress(done, total)` counts bytes.
pub fn walk(
    bytes: &[u8],
    on_record: &mut dyn FnMut(&Record<'_>),
    progress: &mut dyn FnMut(u64, u64),
) -> Scan {
    let mut formats: HashMap<u8, Format> = HashMap::new();
    let mut scan = Scan::default();
    let total = bytes.len() as u64;
    let mut i = 0usize;
    let mut last_report = 0usize;
    while i < bytes.len() {
        if i - last_report > 1 << 20 {
            progress(i as u64, total);
            last_report = i;
        }
        let rest = &bytes[i..];
        let is_header = rest.first() == Some(&HEAD1) && rest.get(1).is_none_or(|&b| b == HEAD2);
        if !is_header {
            i += 1;
            scan.skipped_bytes += 1;
            continue;
        }
        let Some(&id) = rest.get(2) else {
            scan.cut_short = Some(i as u64);
            break;
        };
        let len = if id == FMT_TYPE {
            FMT_LEN
        } else if let Some(f) = formats.get(&id) {
            f.len
        } else {
            // Not a type we know: a false header inside corruption, or the records of a
            // refused FMT. Either way, on to the next header.
            scan.undefined_records += 1;
            i += 1;
            scan.skipped_bytes += 1;
            continue;
        };
        if rest.len() < len {
            scan.cut_short = Some(i as u64);
            break;
        }
        let payload = &rest[3..len];
        if id == FMT_TYPE {
            match Format::from_fmt(payload) {
                Ok((FMT_TYPE, _)) => {}
                Ok((t, f)) => {
                    formats.insert(t, f);
                }
                Err(e) => {
                    scan.bad_formats += 1;
                    scan.first_error.get_or_insert(e);
                }
            }
        } else if let Some(format) = formats.get(&id) {
            scan.records += 1;
            on_record(&Record { format, payload });
        }
        i += len;
    }
    progress(total, total);
    scan.formats = formats.len();
    scan
}

/// A replayable DataFlash log.
#[derive(Debug)]
pub struct DataflashLog {
    /// Time-ordered samples.
    pub samples: Vec<Sample>,
    /// Records mapped to samples, by record name.
    pub messages: BTreeMap<String, u64>,
    /// Records of a mapped type that made no sample (a field missing, a value out of
    /// range), by record name, and the first reason.
    pub unusable: BTreeMap<String, u64>,
    pub first_unusable: Option<String>,
    pub scan: Scan,
}

/// Reads a DataFlash log; `progress(done, total)` counts bytes.
pub fn read_dataflash(
    file: &Path,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<DataflashLog, DataflashError> {
    let bytes = std::fs::read(file).map_err(|source| DataflashError::Read {
        file: file.to_path_buf(),
        source,
    })?;
    let log = parse(&bytes, progress);
    if log.scan.records == 0 {
        return Err(DataflashError::NoRecords {
            file: file.to_path_buf(),
        });
    }
    Ok(log)
}

/// Whether `bytes` begin as a DataFlash log does (an FMT record first).
pub fn looks_like_dataflash(bytes: &[u8]) -> bool {
    bytes.starts_with(&[HEAD1, HEAD2, FMT_TYPE])
}

/// The pure part of [`read_dataflash`]: bytes → samples.
pub fn parse(bytes: &[u8], progress: &mut dyn FnMut(u64, u64)) -> DataflashLog {
    let mut m = Mapper::default();
    let scan = walk(bytes, &mut |r| m.record(r), progress);
    let mut samples = m.samples;
    super::sort_by_stamp(&mut samples);
    DataflashLog {
        samples,
        messages: m.messages,
        unusable: m.unusable,
        first_unusable: m.first_unusable,
        scan,
    }
}

/// Records → samples, with what it needs from earlier records (parameters, the last
/// flow time).
#[derive(Default)]
struct Mapper {
    samples: Vec<Sample>,
    messages: BTreeMap<String, u64>,
    unusable: BTreeMap<String, u64>,
    first_unusable: Option<String>,
    /// PARM values by name (range finder limits).
    params: HashMap<String, f64>,
    last_flow_us: Option<Micros>,
    names: HashMap<(&'static str, u32), Arc<str>>,
}

impl Mapper {
    /// `base` for instance 0, `base_i` for the others; interned.
    fn source(&mut self, base: &'static str, instance: u32) -> Arc<str> {
        self.names
            .entry((base, instance))
            .or_insert_with(|| match instance {
                0 => Arc::from(base),
                i => Arc::from(format!("{base}_{i}")),
            })
            .clone()
    }

    fn record(&mut self, r: &Record<'_>) {
        let name = r.name();
        if name == "PARM" {
            if let (Some(p), Some(v)) = (r.text("Name"), r.get("Value")) {
                self.params.insert(p, v);
            }
            return;
        }
        let mapped = match name {
            "IMU" | "IMU2" | "IMU3" => self.imu(r),
            "ATT" => attitude(r).map(|d| Some(("attitude", 0, d))),
            "OF" => self.flow(r),
            "RFND" => self.range(r),
            "GPS" | "GPS2" => gps(r),
            "BARO" | "BAR2" | "BAR3" => baro(r),
            "XKF1" | "NKF1" | "EKF1" => ekf(r),
            "VISP" => visp(r).map(|d| Some(("visp", 0, d))),
            "SIM" => sim_truth(r).map(|d| Some(("sim_truth", 0, d))),
            _ => return,
        };
        let out = mapped.and_then(|m| {
            let Some(t) = r.time_us() else {
                return Err("no TimeUS or TimeMS".to_string());
            };
            Ok(m.map(|m| (t, m)))
        });
        match out {
            Ok(Some((t, (base, instance, data)))) => {
                let source = self.source(base, instance);
                let s = Sample {
                    source,
                    stamp_us: Some(t),
                    arrival_us: t,
                    data,
                };
                match s.data.validate() {
                    Ok(()) => {
                        // Counted by name without a new String per record (most are).
                        match self.messages.get_mut(name) {
                            Some(n) => *n += 1,
                            None => {
                                self.messages.insert(name.to_string(), 1);
                            }
                        }
                        self.samples.push(s);
                    }
                    Err(e) => self.unusable(name, e),
                }
            }
            // A record that is not a sample by design (another EKF core, a sideways
            // range finder): nothing to say.
            Ok(None) => {}
            Err(e) => self.unusable(name, e),
        }
    }

    fn unusable(&mut self, name: &str, why: String) {
        *self.unusable.entry(name.to_string()).or_default() += 1;
        self.first_unusable
            .get_or_insert_with(|| format!("{name}: {why}"));
    }

    fn imu(&mut self, r: &Record<'_>) -> Result<Option<Mapped>, String> {
        let instance = match (r.name(), r.get("I")) {
            (_, Some(i)) => i as u32,
            ("IMU2", None) => 1,
            ("IMU3", None) => 2,
            _ => 0,
        };
        let gyro = v3(r, ["GyrX", "GyrY", "GyrZ"])?;
        let accel = v3(r, ["AccX", "AccY", "AccZ"])?;
        Ok(Some((
            "imu",
            instance,
            SensorData::Imu(Imu::from_rates(
                Some(frames::frd_to_flu(gyro)),
                Some(frames::frd_to_flu(accel)),
            )),
        )))
    }

    fn flow(&mut self, r: &Record<'_>) -> Result<Option<Mapped>, String> {
        let t = r.time_us().ok_or("no time")?;
        let dt = self
            .last_flow_us
            .map(|last| (t - last) as f64 * 1e-6)
            .filter(|dt| *dt > 0.0 && *dt < 0.5)
            .unwrap_or(FLOW_DT_DEFAULT_S);
        self.last_flow_us = Some(t);
        let flow = Vector2::new(field(r, "flowX")?, field(r, "flowY")?);
        let body = Vector2::new(field(r, "bodyX")?, field(r, "bodyY")?);
        let quality = field(r, "Qual")?.clamp(0.0, 255.0) as u8;
        Ok(Some((
            "flow",
            0,
            SensorData::Flow(OpticalFlow {
                rate: Some(Vector2::new(flow.x, -flow.y)),
                // No body rate logged (NaN): the estimator compensates with the IMU.
                gyro: Some(Vector3::new(body.x, -body.y, 0.0))
                    .filter(|g| g.iter().all(|v| v.is_finite())),
                velocity: None,
                integration_s: Some(dt),
                quality,
                status: None,
                tof: None,
            }),
        )))
    }

    fn range(&mut self, r: &Record<'_>) -> Result<Option<Mapped>, String> {
        // Logs before 2016: one RFND record for two sensors (Dist1, Dist2), no status.
        let (instance, dist) = match (r.get("Instance"), r.get("Dist"), r.get("Dist1")) {
            (i, Some(d), _) => (i.unwrap_or(0.0) as u32, d),
            (_, None, Some(d)) => (0, d),
            _ => return Err("no Dist".into()),
        };
        let orientation = r.get("Orient").map(|o| o as u8);
        if orientation.is_some_and(|o| o != ORIENT_DOWN) {
            return Ok(None);
        }
        let n = instance + 1;
        let param = |p: &str| self.params.get(&format!("RNGFND{n}_{p}")).copied();
        let min_m = param("MIN_CM").map(|cm| cm * 0.01).or_else(|| param("MIN"));
        let max_m = param("MAX_CM").map(|cm| cm * 0.01).or_else(|| param("MAX"));
        // Status Good → no verdict from the sensor (MAVLink's 0 = unknown); anything
        // else (no data, out of range low/high) → invalid.
        let signal_quality = r
            .get("Stat")
            .map(|s| if s == RANGE_GOOD { None } else { Some(1) })
            .unwrap_or(None);
        Ok(Some((
            "range",
            instance,
            SensorData::Range(Range {
                distance_m: dist,
                min_m,
                max_m,
                signal_quality,
                variance: None,
                orientation: Some(orientation.unwrap_or(ORIENT_DOWN)),
            }),
        )))
    }
}

/// A record's sample: its source base name, instance and data; `None` when the record
/// is not one by design.
type Mapped = (&'static str, u32, SensorData);

fn field(r: &Record<'_>, label: &str) -> Result<f64, String> {
    r.get(label).ok_or_else(|| format!("no field {label}"))
}

fn v3(r: &Record<'_>, labels: [&str; 3]) -> Result<Vector3<f64>, String> {
    Ok(Vector3::new(
        field(r, labels[0])?,
        field(r, labels[1])?,
        field(r, labels[2])?,
    ))
}

fn attitude(r: &Record<'_>) -> Result<SensorData, String> {
    let rpy = v3(r, ["Roll", "Pitch", "Yaw"])?.map(f64::to_radians);
    Ok(SensorData::Attitude(Attitude {
        orientation: frames::euler_ned_to_enu_flu(rpy.x, rpy.y, rpy.z),
        rates: None,
    }))
}

fn gps(r: &Record<'_>) -> Result<Option<Mapped>, String> {
    let instance = match (r.name(), r.get("I")) {
        (_, Some(i)) => i as u32,
        ("GPS2", None) => 1,
        _ => 0,
    };
    let fix = match field(r, "Status")? as i64 {
        ..=1 => GnssFixType::NoFix,
        2 => GnssFixType::Fix2d,
        3 => GnssFixType::Fix3d,
        4 => GnssFixType::Dgps,
        5 => GnssFixType::RtkFloat,
        _ => GnssFixType::RtkFixed,
    };
    let velocity = match (r.get("Spd"), r.get("GCrs"), r.get("VZ")) {
        (Some(s), Some(c), Some(vz)) => {
            let c = c.to_radians();
            Some(Vector3::new(s * c.sin(), s * c.cos(), -vz))
        }
        _ => None,
    };
    Ok(Some((
        "gps",
        instance,
        SensorData::Gnss(GnssFix {
            lat_deg: field(r, "Lat")?,
            lon_deg: field(r, "Lng")?,
            alt_m: field(r, "Alt")?,
            fix,
            position_cov: None,
            satellites: r.get("NSats").map(|n| n.clamp(0.0, 255.0) as u8),
            hdop: r.get("HDop"),
            vdop: None,
            velocity,
            velocity_up_known: true,
        }),
    )))
}

fn baro(r: &Record<'_>) -> Result<Option<Mapped>, String> {
    let instance = match (r.name(), r.get("I")) {
        (_, Some(i)) => i as u32,
        ("BAR2", None) => 1,
        ("BAR3", None) => 2,
        _ => 0,
    };
    Ok(Some((
        "baro",
        instance,
        SensorData::Baro(Baro {
            pressure_pa: field(r, "Press")?,
            temperature_c: r.get("Temp"),
            variance: None,
        }),
    )))
}

/// The autopilot's EKF: core 0 only (every core logs its own estimate).
fn ekf(r: &Record<'_>) -> Result<Option<Mapped>, String> {
    if r.get("C").is_some_and(|c| c != 0.0) {
        return Ok(None);
    }
    let base = match r.name() {
        "XKF1" => "ekf3",
        "NKF1" => "ekf2",
        _ => "ekf",
    };
    let p = v3(r, ["PN", "PE", "PD"])?;
    let v = v3(r, ["VN", "VE", "VD"]).ok();
    let yaw = r.get("Yaw").map(|y| frames::yaw_ned_to_enu(y.to_radians()));
    Ok(Some((
        base,
        0,
        SensorData::AutopilotEstimate(AutopilotEstimate {
            local_position: Some(frames::ned_to_enu(p)),
            geodetic: None,
            velocity: v.map(frames::ned_to_enu),
            yaw,
        }),
    )))
}

/// VISP: the external navigation pose the autopilot received (NED, degrees).
fn visp(r: &Record<'_>) -> Result<SensorData, String> {
    let p = v3(r, ["PX", "PY", "PZ"])?;
    let rpy = v3(r, ["Roll", "Pitch", "Yaw"])?.map(f64::to_radians);
    Ok(SensorData::Odometry(Box::new(Odometry {
        position: frames::ned_to_enu(p),
        orientation: frames::euler_ned_to_enu_flu(rpy.x, rpy.y, rpy.z),
        velocity: None,
        angular_velocity: None,
        pose_cov: None,
        twist_cov: None,
        frame_id: "odom".into(),
        child_frame_id: "base_link".into(),
        reset_counter: r.get("RstCnt").map(|c| c.clamp(0.0, 255.0) as u8),
        quality: None,
    })))
}

/// SIM: SITL's true state (geodetic position; attitude as a quaternion, or Euler
/// angles in degrees in older logs).
fn sim_truth(r: &Record<'_>) -> Result<SensorData, String> {
    let q = match (r.get("Q1"), r.get("Q2"), r.get("Q3"), r.get("Q4")) {
        (Some(w), Some(x), Some(y), Some(z)) => {
            UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z))
        }
        _ => {
            let rpy = v3(r, ["Roll", "Pitch", "Yaw"])?.map(f64::to_radians);
            UnitQuaternion::from_euler_angles(rpy.x, rpy.y, rpy.z)
        }
    };
    Ok(SensorData::AutopilotEstimate(AutopilotEstimate {
        local_position: None,
        geodetic: Some((field(r, "Lat")?, field(r, "Lng")?, field(r, "Alt")?)),
        velocity: None,
        yaw: Some(frames::q_ned_frd_to_enu_flu(q).euler_angles().2),
    }))
}

#[cfg(test)]
mod tests;
