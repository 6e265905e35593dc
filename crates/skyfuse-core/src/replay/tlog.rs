//! MAVLink telemetry logs (`.tlog`, as QGroundControl, MAVProxy and pymavlink write
//! them) → samples for offline replay: each record is an 8-byte big-endian timestamp
//! (µs since the Unix epoch, when the ground station received it) followed by one
//! MAVLink v1 or v2 frame. Frames are decoded by the same MAVLink mapping as live input
//! ([`crate::codec::mavlink::decode_raw_filtered`], CRC-checked), so a replay sees
//! exactly what `skyfuse run` would have seen on that link. This is the log ArduPilot
//! users have.
//!
//! Sources are named after the sensor kind (`imu`, `attitude`, `flow`, `range`, `gps`,
//! `vehicle_state`, `autopilot`), the first message type of a kind taking the plain
//! name and any other the kind plus the message name (`imu_scaled_imu2`); a simulator's
//! SIM_STATE (ArduPilot SITL's truth, never fused) is `sim_truth`; messages of
//! our own component (197) are skipped, as live. Both `stamp_us` and `arrival_us` are
//! the record's timestamp: one clock for everything offline, as for PX4 logs.
//!
//! A record that is not a frame (a corrupt or truncated log) is skipped byte by byte
//! until the next plausible record, and counted; a bad frame costs only itself.

use crate::codec::mavlink::decode_raw_filtered;
use crate::sample::{Decoded, Micros, Sample, SensorKind};
use std::cell::RefCell;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

const STX_V1: u8 = 0xFE;
const STX_V2: u8 = 0xFD;
/// Our own MAVLink component (VISION_POSITION_ESTIMATE sender): skipped.
const OWN_COMPONENT: u8 = 197;

#[derive(Debug, thiserror::Error)]
pub enum TlogError {
    #[error("{}: cannot read: {source}", file.display())]
    Read {
        file: PathBuf,
        source: std::io::Error,
    },
    #[error("{}: no MAVLink frame found (not a telemetry log?)", file.display())]
    NoFrames { file: PathBuf },
}

/// A replayable telemetry log.
#[derive(Debug)]
pub struct TlogLog {
    /// Time-ordered samples.
    pub samples: Vec<Sample>,
    /// Frames found (decodable or not).
    pub frames: u64,
    /// Frames whose message skyfuse maps to a sample, by message name.
    pub messages: BTreeMap<String, u64>,
    /// Bytes skipped between records (corruption, truncation).
    pub skipped_bytes: u64,
    /// Frames that failed to decode (bad CRC, out-of-range values), and the first error.
    pub bad_frames: u64,
    pub first_error: Option<String>,
}

/// Length of the MAVLink frame starting at `buf[0]`, if its header is there.
fn frame_len(buf: &[u8]) -> Option<usize> {
    match *buf.first()? {
        STX_V1 => Some(6 + usize::from(*buf.get(1)?) + 2),
        STX_V2 => {
            let signed = buf.get(2)? & 0x01 != 0;
            Some(10 + usize::from(*buf.get(1)?) + 2 + if signed { 13 } else { 0 })
        }
        _ => None,
    }
}

/// Reads a telemetry log; `progress(done, total)` counts bytes.
pub fn read_tlog(file: &Path, progress: &mut dyn FnMut(u64, u64)) -> Result<TlogLog, TlogError> {
    let read_err = |source| TlogError::Read {
        file: file.to_path_buf(),
        source,
    };
    let mut bytes = std::fs::read(file).map_err(read_err)?;
    // `.tlog.gz`: a compressed log (how a test or an archive keeps one).
    if file.extension().is_some_and(|e| e == "gz") {
        let mut plain = Vec::new();
        std::io::Read::read_to_end(&mut flate2::read::GzDecoder::new(&bytes[..]), &mut plain)
            .map_err(read_err)?;
        bytes = plain;
    }
    let parsed = parse(&bytes, progress);
    if parsed.frames == 0 {
        return Err(TlogError::NoFrames {
            file: file.to_path_buf(),
        });
    }
    Ok(parsed)
}

/// The pure part of [`read_tlog`]: bytes → samples.
pub fn parse(bytes: &[u8], progress: &mut dyn FnMut(u64, u64)) -> TlogLog {
    let total = bytes.len() as u64;
    let mut out = TlogLog {
        samples: Vec::new(),
        frames: 0,
        messages: BTreeMap::new(),
        skipped_bytes: 0,
        bad_frames: 0,
        first_error: None,
    };
    // (kind, message name) → source name.
    let mut names: BTreeMap<(SensorKind, String), Arc<str>> = BTreeMap::new();
    let mut kinds_taken: BTreeMap<SensorKind, String> = BTreeMap::new();
    let mut decoded: Vec<Decoded> = Vec::new();
    let mut i = 0usize;
    let mut last_report = 0usize;
    while i + 8 < bytes.len() {
        let rest = &bytes[i + 8..];
        let Some(len) = frame_len(rest).filter(|&l| l <= rest.len()) else {
            i += 1;
            out.skipped_bytes += 1;
            continue;
        };
        let mut stamp = [0u8; 8];
        stamp.copy_from_slice(&bytes[i..i + 8]);
        let t = Micros::try_from(u64::from_be_bytes(stamp)).unwrap_or(Micros::MAX);
        let name = RefCell::new(String::new());
        decoded.clear();
        let keep = |n: &str| {
            n.clone_into(&mut name.borrow_mut());
            true
        };
        match decode_raw_filtered(&rest[..len], &keep, &mut decoded) {
            Ok(()) => {
                out.frames += 1;
                i += 8 + len;
            }
            Err(e) => {
                // Not a frame after all (or a corrupt one): look for the next record.
                out.bad_frames += 1;
                out.first_error.get_or_insert_with(|| e.to_string());
                i += 1;
                out.skipped_bytes += 1;
                continue;
            }
        }
        let name = name.into_inner();
        // One frame, one message counted, whatever number of samples it carries.
        let mut counted = false;
        for d in decoded.drain(..) {
            if d.mav_origin.is_some_and(|(_, c)| c == OWN_COMPONENT) {
                continue;
            }
            let kind = d.data.kind();
            let source = names
                .entry((kind, name.clone()))
                .or_insert_with(|| {
                    let base = match kind {
                        SensorKind::Imu => "imu",
                        SensorKind::Attitude => "attitude",
                        SensorKind::Gnss => "gps",
                        SensorKind::Flow => "flow",
                        SensorKind::Range => "range",
                        SensorKind::Odometry => "odometry",
                        SensorKind::AutopilotEstimate => "autopilot",
                        SensorKind::VehicleState => "vehicle_state",
                        SensorKind::Baro => "baro",
                    };
                    // A simulator's truth is named for what it is.
                    if name == "SIM_STATE" {
                        return Arc::from("sim_truth");
                    }
                    let owner = kinds_taken.entry(kind).or_insert_with(|| name.clone());
                    // Both state messages feed one vehicle state.
                    if *owner == name || kind == SensorKind::VehicleState {
                        Arc::from(base)
                    } else {
                        Arc::from(format!("{base}_{}", name.to_ascii_lowercase()))
                    }
                })
                .clone();
            if !std::mem::replace(&mut counted, true) {
                *out.messages.entry(name.clone()).or_default() += 1;
            }
            out.samples.push(Sample {
                source,
                stamp_us: Some(t),
                arrival_us: t,
                data: d.data,
            });
        }
        if i - last_report >= 1 << 18 {
            last_report = i;
            progress(i as u64, total);
        }
    }
    out.skipped_bytes += bytes.len().saturating_sub(i) as u64;
    // Ground stations log in arrival order; keep it stable for equal stamps.
    super::sort_by_stamp(&mut out.samples);
    progress(total, total);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::mavlink::encode_raw_v2;
    use crate::sample::SensorData;
    use ::mavlink::dialects::common::{self, MavMessage};
    use ::mavlink::MavHeader;

    fn record(t_us: u64, sys: u8, comp: u8, msg: &MavMessage) -> Vec<u8> {
        let header = MavHeader {
            system_id: sys.into(),
            component_id: comp,
            sequence: 0,
        };
        let mut v = t_us.to_be_bytes().to_vec();
        v.extend(encode_raw_v2(header, msg).expect("encodes"));
        v
    }

    fn attitude(ms: u32) -> MavMessage {
        MavMessage::ATTITUDE(common::ATTITUDE_DATA {
            time_boot_ms: ms,
            roll: 0.1,
            ..Default::default()
        })
    }

    #[test]
    fn records_decode_and_garbage_costs_only_itself() {
        let mut log = Vec::new();
        log.extend(record(1_700_000_000_000_000, 1, 1, &attitude(1000)));
        log.extend([0x55; 7]); // stray bytes
        log.extend(record(1_700_000_000_020_000, 1, 1, &attitude(1020)));
        // Our own VPE component is skipped, as live.
        log.extend(record(1_700_000_000_030_000, 1, 197, &attitude(1030)));
        let mut truncated = record(1_700_000_000_040_000, 1, 1, &attitude(1040));
        truncated.truncate(20);
        log.extend(truncated);
        let parsed = parse(&log, &mut |_, _| {});
        assert_eq!(parsed.frames, 3);
        assert_eq!(parsed.samples.len(), 2);
        assert!(parsed.skipped_bytes >= 7 + 20, "{}", parsed.skipped_bytes);
        let s = &parsed.samples[1];
        assert_eq!(s.stamp_us, Some(1_700_000_000_020_000));
        assert_eq!(s.source.as_ref(), "attitude");
        let SensorData::Attitude(a) = &s.data else {
            panic!("{:?}", s.data)
        };
        // Roll right 0.1 rad in NED/FRD is a roll about the forward axis in FLU too.
        let (roll, _, _) = a.orientation.euler_angles();
        assert!((roll - 0.1).abs() < 1e-6, "{roll}");
        assert_eq!(parsed.messages.get("ATTITUDE"), Some(&2));
    }

    #[test]
    fn a_second_message_of_a_kind_gets_its_own_source() {
        let q = MavMessage::ATTITUDE_QUATERNION(common::ATTITUDE_QUATERNION_DATA {
            time_boot_ms: 5,
            q1: 1.0,
            ..Default::default()
        });
        let mut log = record(10, 1, 1, &attitude(1));
        log.extend(record(20, 1, 1, &q));
        let parsed = parse(&log, &mut |_, _| {});
        let sources: Vec<&str> = parsed.samples.iter().map(|s| s.source.as_ref()).collect();
        assert_eq!(sources, ["attitude", "attitude_attitude_quaternion"]);
    }
}
