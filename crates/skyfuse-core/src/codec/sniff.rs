//! What a Zenoh payload is, from its key and bytes alone: the format, the ROS type or
//! MAVLink message, the kinds of sample it gives. Discovery uses it for the keys seen on
//! the network, so a user is told what an unread key would be read as. Pure; the
//! decoders themselves decide (a payload is only called a type it decodes as, whole).
//!
//! Order: MAVLink per-message keys (`mavlink/<sys>/<comp>/<NAME>`, mavlink-server) by
//! their name; ROS 1 keys (`<hex(type)>/<md5>/<topic>`, zenoh-plugin-ros1) by their type;
//! then the payload: JSON (mavlink-server's or skyfuse's), raw MAVLink frames, CDR.

use super::{json, mavlink, ros, Format, RosType};
use crate::sample::{Decoded, SensorKind};

/// What a payload was recognised as.
#[derive(Debug, Clone, PartialEq)]
pub struct Sniffed {
    pub format: Format,
    /// The kinds of sample it gives, in order; empty for a message skyfuse does not read.
    pub kinds: Vec<SensorKind>,
    /// ROS formats: the type.
    pub ros_type: Option<RosType>,
    /// MAVLink per-message keys: the message.
    pub message: Option<String>,
    /// Several ROS types fit the bytes (no bridge announces which): the candidates.
    pub ambiguous: Vec<RosType>,
}

impl Sniffed {
    fn new(format: Format, kinds: Vec<SensorKind>) -> Sniffed {
        Sniffed {
            format,
            kinds,
            ros_type: None,
            message: None,
            ambiguous: Vec::new(),
        }
    }
}

/// mavlink-server's per-message key: `mavlink/<sys>/<comp>/<NAME>` → NAME. Its per-field
/// keys (`…/<NAME>/<field>`) are not message keys.
pub fn mavlink_message_of_key(key: &str) -> Option<&str> {
    let parts: Vec<&str> = key.split('/').collect();
    match parts[..] {
        ["mavlink", sys, comp, name]
            if sys.parse::<u8>().is_ok()
                && comp.parse::<u8>().is_ok()
                && name.starts_with(|c: char| c.is_ascii_uppercase()) =>
        {
            Some(name)
        }
        _ => None,
    }
}

/// Whether `key` is one of mavlink-server's per-field keys (`mavlink/1/1/ATTITUDE/roll`):
/// every message's fields again, one key each, which nothing reads.
pub fn is_mavlink_field_key(key: &str) -> bool {
    let mut parts = key.split('/');
    parts.next() == Some("mavlink")
        && parts.clone().count() >= 4
        && parts.next().is_some_and(|s| s.parse::<u8>().is_ok())
}

/// zenoh-plugin-ros1's key → the ROS type it names.
fn ros1_type_of_key(key: &str) -> Option<RosType> {
    let hex = key.split('/').next()?;
    if hex.len() % 2 != 0 || hex.is_empty() {
        return None;
    }
    let bytes: Option<Vec<u8>> = (0..hex.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(hex.get(i..i + 2)?, 16).ok())
        .collect();
    RosType::from_name(std::str::from_utf8(&bytes?).ok()?)
}

fn kinds_of(decoded: &[Decoded]) -> Vec<SensorKind> {
    let mut kinds: Vec<SensorKind> = Vec::new();
    for d in decoded {
        if !kinds.contains(&d.data.kind()) {
            kinds.push(d.data.kind());
        }
    }
    kinds
}

/// The payload on `key`, recognised; `None` when it is nothing skyfuse can read.
pub fn sniff(key: &str, payload: &[u8]) -> Option<Sniffed> {
    if let Some(name) = mavlink_message_of_key(key) {
        let mut out = Vec::new();
        mavlink::decode_json_into(payload, &mut out).ok()?;
        let kinds = match mavlink::message_kind(name) {
            mavlink::MessageKind::Read(k) => k.to_vec(),
            _ => Vec::new(),
        };
        let mut s = Sniffed::new(Format::MavlinkJson, kinds);
        s.message = Some(name.to_string());
        return Some(s);
    }
    if let Some(ty) = ros1_type_of_key(key) {
        ros::decode_ros1(ty, payload).ok()?;
        let mut s = Sniffed::new(Format::Ros1, vec![ty.kind()]);
        s.ros_type = Some(ty);
        return Some(s);
    }
    match payload.first()? {
        b'{' => {
            if let Ok(d) = json::decode(payload) {
                return Some(Sniffed::new(Format::Json, vec![d.data.kind()]));
            }
            // mavlink-server's JSON on another key (`mavlink/out`: every message).
            let mut out = Vec::new();
            mavlink::decode_json_into(payload, &mut out).ok()?;
            Some(Sniffed::new(Format::MavlinkJson, kinds_of(&out)))
        }
        // MAVLink 2 and 1 start-of-frame bytes.
        0xFD | 0xFE => {
            let mut out = Vec::new();
            let ok = mavlink::decode_raw(payload, &mut out).is_ok();
            (ok || !out.is_empty()).then(|| Sniffed::new(Format::MavlinkRaw, kinds_of(&out)))
        }
        // CDR encapsulation header: plain CDR, big- or little-endian.
        0 if payload.len() >= 4 && payload[1] <= 1 && payload[2..4] == [0, 0] => {
            match ros::cdr_types(payload)[..] {
                [] => None,
                [ty] => {
                    let mut s = Sniffed::new(Format::Ros2, vec![ty.kind()]);
                    s.ros_type = Some(ty);
                    Some(s)
                }
                ref several => {
                    let mut s = Sniffed::new(Format::Ros2, Vec::new());
                    s.ambiguous = several.to_vec();
                    Some(s)
                }
            }
        }
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::{encode_sample, MavIdentity};
    use crate::sample::{GnssFix, GnssFixType, Imu, Range, SensorData};
    use nalgebra::Vector3;

    const MAV: MavIdentity = MavIdentity {
        system_id: 1,
        component_id: 1,
        sequence: 0,
    };

    fn imu() -> SensorData {
        SensorData::Imu(Imu {
            gyro: Some(Vector3::new(0.01, 0.02, 0.03)),
            accel: Some(Vector3::new(0.1, 0.2, 9.8)),
            orientation: None,
            gyro_cov: None,
            accel_cov: None,
            orientation_cov: None,
        })
    }

    fn fix() -> SensorData {
        SensorData::Gnss(GnssFix {
            lat_deg: 47.39,
            lon_deg: 8.54,
            alt_m: 488.0,
            fix: GnssFixType::Fix3d,
            position_cov: None,
            satellites: None,
            hdop: None,
            vdop: None,
            velocity: None,
            velocity_up_known: false,
        })
    }

    fn range() -> SensorData {
        SensorData::Range(Range {
            distance_m: 2.5,
            min_m: Some(0.1),
            max_m: Some(8.0),
            signal_quality: None,
            variance: None,
            orientation: None,
        })
    }

    /// Each format the simulator and the bridges publish is recognised as what it is:
    /// the ROS 2 type from the bytes alone, the MAVLink message from mavlink-server's
    /// key, the ROS 1 type from zenoh-plugin-ros1's key, raw frames and skyfuse JSON.
    #[test]
    fn every_format_is_recognised_from_its_key_and_bytes() {
        let t = 1_700_000_000_000_000;
        for (ty, data) in [
            (RosType::Imu, imu()),
            (RosType::NavSatFix, fix()),
            (RosType::Range, range()),
        ] {
            let cdr = encode_sample(Format::Ros2, Some(ty), t, &data, MAV)
                .unwrap()
                .payload;
            let s = sniff("some/topic", &cdr).unwrap_or_else(|| panic!("{ty}"));
            assert_eq!((s.format, s.ros_type), (Format::Ros2, Some(ty)), "{s:?}");
            assert_eq!(s.kinds, vec![ty.kind()]);
            // Cut short or padded beyond a writer's padding, it is not that type.
            assert!(
                sniff("some/topic", &cdr[..cdr.len() - 8]).is_none_or(|s| s.ros_type != Some(ty))
            );
            let mut long = cdr.clone();
            long.extend_from_slice(&[0; 8]);
            assert!(sniff("some/topic", &long).is_none_or(|s| s.ros_type != Some(ty)));

            let ros1 = encode_sample(Format::Ros1, Some(ty), t, &data, MAV)
                .unwrap()
                .payload;
            let key = format!(
                "{}/{}/robot/imu",
                ty.ros1_name()
                    .bytes()
                    .map(|b| format!("{b:02x}"))
                    .collect::<String>(),
                ty.ros1_md5()
            );
            let s = sniff(&key, &ros1).unwrap();
            assert_eq!((s.format, s.ros_type), (Format::Ros1, Some(ty)));
        }
        let json = encode_sample(Format::MavlinkJson, None, 5_000, &imu(), MAV).unwrap();
        let name = json.mavlink_name.unwrap();
        let s = sniff(&format!("mavlink/1/1/{name}"), &json.payload).unwrap();
        assert_eq!(s.format, Format::MavlinkJson);
        assert_eq!(s.message.as_deref(), Some(name));
        assert_eq!(
            s.kinds,
            vec![SensorKind::Imu, SensorKind::Baro],
            "HIGHRES_IMU"
        );
        // The same JSON on mavlink-server's all-messages key.
        let s = sniff("mavlink/out", &json.payload).unwrap();
        assert_eq!(
            (s.format, s.kinds),
            (Format::MavlinkJson, vec![SensorKind::Imu])
        );
        let raw = encode_sample(Format::MavlinkRaw, None, 5_000, &range(), MAV).unwrap();
        let s = sniff("mavlink_raw/out", &raw.payload).unwrap();
        assert_eq!(
            (s.format, s.kinds),
            (Format::MavlinkRaw, vec![SensorKind::Range])
        );
        let js = encode_sample(Format::Json, None, t, &fix(), MAV).unwrap();
        let s = sniff("my/gps", &js.payload).unwrap();
        assert_eq!((s.format, s.kinds), (Format::Json, vec![SensorKind::Gnss]));
        // Text, an image's bytes, an empty payload: nothing skyfuse reads.
        for other in [&b"hello"[..], &[0x89, b'P', b'N', b'G'], &[]] {
            assert_eq!(sniff("x", other), None);
        }
    }

    #[test]
    fn mavlink_server_keys() {
        assert_eq!(
            mavlink_message_of_key("mavlink/1/1/ATTITUDE"),
            Some("ATTITUDE")
        );
        assert_eq!(mavlink_message_of_key("mavlink/1/1/ATTITUDE/roll"), None);
        assert_eq!(mavlink_message_of_key("mavlink/out"), None);
        assert!(is_mavlink_field_key("mavlink/1/1/ATTITUDE/roll"));
        assert!(!is_mavlink_field_key("mavlink/1/1/ATTITUDE"));
        assert!(!is_mavlink_field_key("mavlink/out"));
    }
}
