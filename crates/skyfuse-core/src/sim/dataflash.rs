//! A simulated flight written as an ArduPilot DataFlash log (`.bin`): the records
//! [`crate::replay::dataflash`] reads, in ArduCopter 4.x layouts (`IMU` and `BARO` with
//! only the fields the simulator has), each defined by its FMT record before its first
//! use, as ArduPilot's logger does. A flight of any length with a known truth, in the
//! log most ArduPilot users have, for the replay tests and the corpus.
//!
//! Conventions inverted from the reader: ENU/FLU → NED/FRD; `OF` as MAVLink's rates
//! (flow y and body y change sign); the range finder's limits as `RNGFND1_MIN_CM` /
//! `MAX_CM` parameters, logged before its first record; times as `TimeUS` since boot
//! (the simulator's start at [`BOOT_OFFSET_US`]). The truth is logged as SITL logs its
//! own (`SIM`, 10 Hz), so a replay can be scored against it (`--reference sim_truth`).

use super::sensors::{HOME_ALT, HOME_LAT, HOME_LON};
use super::truth::TruthState;
use super::ulog::put_f32s;
use super::SimEvent;
use crate::codec::dataflash::{field_size, FMT_LEN, FMT_TYPE, HEAD1, HEAD2};
use crate::geo::LocalEnu;
use crate::sample::{frames, GnssFixType, SensorData};
use std::io::{self, Write};

/// The simulator's time 0 in the log's clock (ArduPilot logs start after boot).
pub const BOOT_OFFSET_US: u64 = 10_000_000;

/// A record type: its id, name, field types and labels (as ArduPilot's LogStructure).
struct RecordType {
    id: u8,
    name: &'static str,
    types: &'static str,
    labels: &'static str,
}

const PARM: RecordType = RecordType {
    id: 64,
    name: "PARM",
    types: "QNf",
    labels: "TimeUS,Name,Value",
};
const IMU: RecordType = RecordType {
    id: 65,
    name: "IMU",
    types: "QBffffff",
    labels: "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ",
};
const ATT: RecordType = RecordType {
    id: 66,
    name: "ATT",
    types: "QccccCCCC",
    labels: "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw",
};
const OF: RecordType = RecordType {
    id: 67,
    name: "OF",
    types: "QBffff",
    labels: "TimeUS,Qual,flowX,flowY,bodyX,bodyY",
};
const RFND: RecordType = RecordType {
    id: 68,
    name: "RFND",
    types: "QBCBB",
    labels: "TimeUS,Instance,Dist,Stat,Orient",
};
const GPS: RecordType = RecordType {
    id: 69,
    name: "GPS",
    types: "QBBIHBcLLeffffB",
    labels: "TimeUS,I,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,Yaw,U",
};
const BARO: RecordType = RecordType {
    id: 70,
    name: "BARO",
    types: "QBffc",
    labels: "TimeUS,I,Alt,Press,Temp",
};
const VISP: RecordType = RecordType {
    id: 71,
    name: "VISP",
    types: "QQIffffffffB",
    labels: "TimeUS,RTimeUS,CTimeMS,PX,PY,PZ,Roll,Pitch,Yaw,PErr,AErr,RstCnt",
};
#[cfg(test)]
const TYPES: [&RecordType; 9] = [&PARM, &IMU, &ATT, &OF, &RFND, &GPS, &BARO, &VISP, &SIM];

/// The simulator's truth, as SITL logs its own (`replay` reads it as `sim_truth`).
const SIM: RecordType = RecordType {
    id: 72,
    name: "SIM",
    types: "QccCfLLffff",
    labels: "TimeUS,Roll,Pitch,Yaw,Alt,Lat,Lng,Q1,Q2,Q3,Q4",
};
/// How often the truth is logged, s (SITL: 10 Hz).
const TRUTH_PERIOD_S: f64 = 0.1;

/// RangeFinder::Status as RFND's `Stat` logs it.
const RANGE_NO_DATA: u8 = 1;
const RANGE_LOW: u8 = 2;
const RANGE_HIGH: u8 = 3;
const RANGE_GOOD: u8 = 4;

/// What was written.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DataflashSummary {
    /// Data records (FMT and PARM not counted).
    pub records: u64,
    pub bytes: u64,
    /// Samples of a kind with no record here.
    pub skipped: u64,
}

/// Writes DataFlash records to `out`.
pub struct DataflashWriter<W: Write> {
    out: W,
    buf: Vec<u8>,
    defined: [bool; 256],
    range_params_written: bool,
    /// The vehicle's latest body rates (IMU gyro, else the autopilot's), FLU: what
    /// ArduPilot logs as OF's bodyX/Y when the flow sensor has no gyro of its own.
    body_rates: Option<nalgebra::Vector3<f64>>,
    summary: DataflashSummary,
}

impl<W: Write> DataflashWriter<W> {
    pub fn new(out: W) -> Self {
        Self {
            out,
            buf: Vec::with_capacity(128),
            defined: [false; 256],
            range_params_written: false,
            body_rates: None,
            summary: DataflashSummary::default(),
        }
    }

    /// The FMT record of `t`, once, before its first record.
    fn define(&mut self, t: &RecordType) -> io::Result<()> {
        if self.defined[usize::from(t.id)] {
            return Ok(());
        }
        self.defined[usize::from(t.id)] = true;
        let mut b = Vec::with_capacity(FMT_LEN);
        b.extend_from_slice(&[HEAD1, HEAD2, FMT_TYPE, t.id, record_len(t)]);
        for (text, width) in [(t.name, 4), (t.types, 16), (t.labels, 64)] {
            let mut field = text.as_bytes().to_vec();
            field.resize(width, 0);
            b.extend_from_slice(&field);
        }
        debug_assert_eq!(b.len(), FMT_LEN);
        self.out.write_all(&b)?;
        self.summary.bytes += b.len() as u64;
        Ok(())
    }

    /// Writes the record in `self.buf` (its payload after the time) as type `t`.
    fn emit(&mut self, t: &RecordType, time_us: u64, payload: &[u8]) -> io::Result<()> {
        self.define(t)?;
        let mut b = std::mem::take(&mut self.buf);
        b.clear();
        b.extend_from_slice(&[HEAD1, HEAD2, t.id]);
        b.extend_from_slice(&time_us.to_le_bytes());
        b.extend_from_slice(payload);
        debug_assert_eq!(b.len(), usize::from(record_len(t)), "{}", t.name);
        let r = self.out.write_all(&b);
        self.summary.bytes += b.len() as u64;
        self.buf = b;
        r
    }

    fn param(&mut self, time_us: u64, name: &str, value: f64) -> io::Result<()> {
        let mut p = name.as_bytes().to_vec();
        p.resize(16, 0);
        p.extend_from_slice(&(value as f32).to_le_bytes());
        self.emit(&PARM, time_us, &p)
    }

    /// Logs one simulated measurement at `t_us` (µs since the simulator's start).
    pub fn sample(&mut self, t_us: u64, data: &SensorData) -> io::Result<()> {
        let t = t_us + BOOT_OFFSET_US;
        let mut p: Vec<u8> = Vec::with_capacity(64);
        let record = match data {
            SensorData::Imu(imu) => {
                let (Some(g), Some(a)) = (imu.gyro, imu.accel) else {
                    self.summary.skipped += 1;
                    return Ok(());
                };
                self.body_rates = Some(g);
                p.push(0);
                let (g, a) = (frames::frd_to_flu(g), frames::frd_to_flu(a));
                put_f32s(&mut p, &[g.x, g.y, g.z, a.x, a.y, a.z]);
                &IMU
            }
            SensorData::Attitude(att) => {
                if let Some(w) = att.rates {
                    self.body_rates = Some(w);
                }
                let (r, pi, y) = frames::q_ned_frd_to_enu_flu(att.orientation).euler_angles();
                let yaw = y.to_degrees().rem_euclid(360.0);
                put_centi_i16(&mut p, &[0.0, r.to_degrees(), 0.0, pi.to_degrees()]);
                put_centi_u16(&mut p, &[0.0, yaw, 0.0, 0.0]);
                &ATT
            }
            SensorData::Flow(f) => {
                let Some(rate) = f.rate else {
                    self.summary.skipped += 1;
                    return Ok(());
                };
                let body = f
                    .gyro
                    .or(self.body_rates)
                    .map_or([f64::NAN; 2], |g| [g.x, -g.y]);
                p.push(f.quality);
                put_f32s(&mut p, &[rate.x, -rate.y, body[0], body[1]]);
                &OF
            }
            SensorData::Range(r) => {
                if !self.range_params_written {
                    self.range_params_written = true;
                    if let Some(min) = r.min_m {
                        self.param(t, "RNGFND1_MIN_CM", (min * 100.0).round())?;
                    }
                    if let Some(max) = r.max_m {
                        self.param(t, "RNGFND1_MAX_CM", (max * 100.0).round())?;
                    }
                }
                let stat = match r.signal_quality {
                    Some(1) if r.max_m.is_some_and(|m| r.distance_m >= m) => RANGE_HIGH,
                    Some(1) if r.min_m.is_some_and(|m| r.distance_m <= m) => RANGE_LOW,
                    Some(1) => RANGE_NO_DATA,
                    _ => RANGE_GOOD,
                };
                p.push(0);
                put_centi_u16(&mut p, &[r.distance_m]);
                p.extend_from_slice(&[stat, r.orientation.unwrap_or(25)]);
                &RFND
            }
            SensorData::Gnss(g) => {
                let status = match g.fix {
                    GnssFixType::NoFix => 1,
                    GnssFixType::Fix2d => 2,
                    GnssFixType::Fix3d => 3,
                    GnssFixType::Dgps => 4,
                    GnssFixType::RtkFloat => 5,
                    GnssFixType::RtkFixed => 6,
                };
                let v = g.velocity.unwrap_or_default();
                p.extend_from_slice(&[0, status]);
                p.extend_from_slice(&0u32.to_le_bytes()); // GMS
                p.extend_from_slice(&0u16.to_le_bytes()); // GWk
                p.push(g.satellites.unwrap_or(0));
                put_centi_i16(&mut p, &[g.hdop.unwrap_or(99.99)]);
                for deg in [g.lat_deg, g.lon_deg] {
                    p.extend_from_slice(&((deg * 1e7).round() as i32).to_le_bytes());
                }
                p.extend_from_slice(&((g.alt_m * 100.0).round() as i32).to_le_bytes());
                let course = v.x.atan2(v.y).to_degrees().rem_euclid(360.0);
                put_f32s(&mut p, &[v.xy().norm(), course, -v.z, 0.0]);
                p.push(0);
                &GPS
            }
            SensorData::Baro(b) => {
                p.push(0);
                put_f32s(&mut p, &[b.altitude_m(), b.pressure_pa]);
                put_centi_i16(&mut p, &[b.temperature_c.unwrap_or(25.0)]);
                &BARO
            }
            SensorData::Odometry(o) => {
                let pos = frames::ned_to_enu(o.position);
                let (r, pi, y) = frames::q_ned_frd_to_enu_flu(o.orientation).euler_angles();
                p.extend_from_slice(&t.to_le_bytes()); // RTimeUS
                p.extend_from_slice(&((t / 1000) as u32).to_le_bytes()); // CTimeMS
                let deg = |a: f64| a.to_degrees();
                put_f32s(
                    &mut p,
                    &[pos.x, pos.y, pos.z, deg(r), deg(pi), deg(y), 0.0, 0.0],
                );
                p.push(o.reset_counter.unwrap_or(0));
                &VISP
            }
            _ => {
                self.summary.skipped += 1;
                return Ok(());
            }
        };
        self.emit(record, t, &p)?;
        self.summary.records += 1;
        Ok(())
    }

    /// Logs the true state `s` at `t_us` as a SIM record (geodetic about `origin`).
    pub fn truth(&mut self, t_us: u64, s: &TruthState, origin: &LocalEnu) -> io::Result<()> {
        let (lat, lon, alt) = origin.to_geodetic(s.position);
        let q = frames::q_ned_frd_to_enu_flu(s.attitude);
        let (r, pi, y) = q.euler_angles();
        let mut p = Vec::with_capacity(40);
        put_centi_i16(&mut p, &[r.to_degrees(), pi.to_degrees()]);
        put_centi_u16(&mut p, &[y.to_degrees().rem_euclid(360.0)]);
        put_f32s(&mut p, &[alt]);
        for deg in [lat, lon] {
            p.extend_from_slice(&((deg * 1e7).round() as i32).to_le_bytes());
        }
        put_f32s(&mut p, &[q.w, q.i, q.j, q.k]);
        self.emit(&SIM, t_us + BOOT_OFFSET_US, &p)
    }

    /// Flushes and returns what was written.
    pub fn finish(mut self) -> io::Result<DataflashSummary> {
        self.out.flush()?;
        Ok(self.summary)
    }
}

/// A record type's length: the header and its fields.
fn record_len(t: &RecordType) -> u8 {
    let fields: usize = t.types.bytes().filter_map(field_size).sum();
    u8::try_from(3 + fields).unwrap_or(u8::MAX)
}

/// Writes the simulated flight `events` to `out`, each at its measurement time, and the
/// truth every [`TRUTH_PERIOD_S`] as SITL does (about the simulator's default home).
pub fn write_flight(
    events: impl Iterator<Item = SimEvent>,
    out: impl Write,
) -> io::Result<DataflashSummary> {
    let origin = LocalEnu::new(HOME_LAT, HOME_LON, HOME_ALT);
    let mut w = DataflashWriter::new(out);
    let mut next_truth = 0.0;
    for e in events {
        let t = (e.measured_t.max(0.0) * 1e6).round() as u64;
        if e.measured_t >= next_truth {
            w.truth(t, &e.truth, &origin)?;
            next_truth = e.measured_t + TRUTH_PERIOD_S;
        }
        w.sample(t, &e.data)?;
    }
    w.finish()
}

/// `c` fields: hundredths in an i16.
fn put_centi_i16(b: &mut Vec<u8>, v: &[f64]) {
    for x in v {
        let c = (x * 100.0).round().clamp(i16::MIN.into(), i16::MAX.into()) as i16;
        b.extend_from_slice(&c.to_le_bytes());
    }
}

/// `C` fields: hundredths in a u16.
fn put_centi_u16(b: &mut Vec<u8>, v: &[f64]) {
    for x in v {
        let c = (x * 100.0).round().clamp(0.0, u16::MAX.into()) as u16;
        b.extend_from_slice(&c.to_le_bytes());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_record_type_fits_a_byte_and_names_each_field() {
        for t in TYPES {
            let n = t.types.len();
            assert_eq!(t.labels.split(',').count(), n, "{}", t.name);
            assert!(
                t.types.bytes().all(|c| field_size(c).is_some()),
                "{}",
                t.name
            );
            assert!(usize::from(record_len(t)) < 255, "{}", t.name);
            assert!(t.name.len() <= 4 && t.types.len() <= 16 && t.labels.len() <= 64);
        }
        let mut ids: Vec<u8> = TYPES.iter().map(|t| t.id).collect();
        ids.dedup();
        assert_eq!(ids.len(), TYPES.len());
    }
}
