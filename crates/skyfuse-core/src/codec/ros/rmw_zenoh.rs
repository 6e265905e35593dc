//! ROS 2 as rmw_zenoh (ROS 2's Zenoh middleware, Tier 1 since Kilted) puts it on Zenoh,
//! with no bridge: pure functions over keys and attachment bytes. From
//! ros2/rmw_zenoh `docs/design.md` and `rmw_zenoh_cpp/src/detail/` (Jazzy 0.2.10, Kilted
//! 0.6.7; the wire files are identical in both):
//!
//! - data key `<domain>/<topic without its outer slashes>/<pkg>::msg::dds_::<Msg>_/<hash>`,
//!   the hash `RIHS01_<sha256 hex>` (Humble: `TypeHashNotSupported`);
//! - the payload is the same CDR as a DDS bridge carries (encapsulation header first);
//! - every sample carries an attachment: sequence number (i64 LE, from 1 per
//!   publisher), source timestamp (i64 LE, ns since the Unix epoch) and the publisher's
//!   16-byte GID after a LEB128 length (zenoh-ext serialisation: 33 bytes). Jazzy
//!   0.2.0–0.2.3 wrote the same three with string keys (77 bytes); both are read.

use crate::codec::error::DecodeError;

/// Humble's rmw_zenoh puts this where the type hash goes.
pub const TYPE_HASH_NOT_SUPPORTED: &str = "TypeHashNotSupported";

/// `sensor_msgs/msg/Imu` → `sensor_msgs::msg::dds_::Imu_` (the type chunk of keys).
pub fn dds_type_name(ros2_name: &str) -> Option<String> {
    let mut parts = ros2_name.split('/');
    let (Some(pkg), Some(kind), Some(name), None) =
        (parts.next(), parts.next(), parts.next(), parts.next())
    else {
        return None;
    };
    Some(format!("{pkg}::{kind}::dds_::{name}_"))
}

/// `sensor_msgs::msg::dds_::Imu_` → `sensor_msgs/msg/Imu`.
pub fn ros2_type_name(dds: &str) -> Option<String> {
    let (ns, name) = dds.split_once("::dds_::")?;
    let (pkg, kind) = ns.split_once("::")?;
    let name = name.strip_suffix('_')?;
    if pkg.is_empty() || kind.is_empty() || name.is_empty() || kind.contains(':') {
        return None;
    }
    Some(format!("{pkg}/{kind}/{name}"))
}

/// The key expression that receives `topic` in `domain` from any rmw_zenoh publisher:
/// of `ros2_type` if given (any hash: Humble's, Jazzy's, a type changed in a later
/// distribution is still seen, then refused by the decoder if its layout differs), else
/// of any type (`type = "auto"`: the type is read from each sample's key).
pub fn subscription_key(domain: u32, topic: &str, ros2_type: Option<&str>) -> String {
    let topic = topic.trim_matches('/');
    let ty = ros2_type
        .and_then(dds_type_name)
        .unwrap_or_else(|| "*".to_string());
    format!("{domain}/{topic}/{ty}/*")
}

/// The key an rmw_zenoh publisher of `topic` puts its samples on.
pub fn data_key(domain: u32, topic: &str, ros2_type: &str, type_hash: &str) -> Option<String> {
    Some(format!(
        "{domain}/{}/{}/{type_hash}",
        topic.trim_matches('/'),
        dds_type_name(ros2_type)?
    ))
}

/// The QoS field of a token for rclcpp's default profile (reliable, volatile, keep
/// last 10): rmw_zenoh leaves each field equal to its own default empty, and its
/// default depth is 42.
pub const QOS_RELIABLE_DEPTH_10: &str = "::,10:,:,:,,";

/// rmw_zenoh's names in tokens: every `/` becomes `%`.
fn mangle(name: &str) -> String {
    name.replace('/', "%")
}

/// The liveliness token of node `namespace`/`name` (enclave `/`), id `node_id`, of the
/// Zenoh session `zid`.
pub fn node_token(domain: u32, zid: &str, node_id: u32, namespace: &str, name: &str) -> String {
    format!(
        "@ros2_lv/{domain}/{zid}/{node_id}/{node_id}/NN/%/{}/{}",
        mangle(namespace),
        mangle(name)
    )
}

/// The liveliness token of a publisher (`MP`) of that node.
#[allow(clippy::too_many_arguments)]
pub fn publisher_token(
    domain: u32,
    zid: &str,
    node_id: u32,
    entity_id: u32,
    namespace: &str,
    node: &str,
    topic: &str,
    ros2_type: &str,
    type_hash: &str,
    qos: &str,
) -> Option<String> {
    Some(format!(
        "@ros2_lv/{domain}/{zid}/{node_id}/{entity_id}/MP/%/{}/{}/{}/{}/{type_hash}/{qos}",
        mangle(namespace),
        mangle(node),
        mangle(&format!("/{}", topic.trim_matches('/'))),
        dds_type_name(ros2_type)?
    ))
}

/// The ROS 2 type a data key carries (`0/imu/data/sensor_msgs::msg::dds_::Imu_/RIHS01_…`
/// → `sensor_msgs/msg/Imu`).
pub fn type_of_key(key: &str) -> Option<String> {
    let mut chunks = key.rsplit('/');
    let _hash = chunks.next()?;
    ros2_type_name(chunks.next()?)
}

/// What every rmw_zenoh sample carries beside its payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Attachment {
    /// Per publisher, from 1.
    pub sequence_number: i64,
    /// When the publisher sent it, ns since the Unix epoch.
    pub source_timestamp_ns: i64,
    /// The publisher's id.
    pub source_gid: [u8; 16],
}

/// Bytes of the attachment format before rmw_zenoh 0.2.4 (string keys).
const LEGACY_KEYS: [&str; 3] = ["sequence_number", "source_timestamp", "source_gid"];

impl Attachment {
    /// The current format (33 bytes).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(33);
        out.extend_from_slice(&self.sequence_number.to_le_bytes());
        out.extend_from_slice(&self.source_timestamp_ns.to_le_bytes());
        out.push(16);
        out.extend_from_slice(&self.source_gid);
        out
    }

    /// Either format; anything else (rmw_zenoh's reader would throw on it) is an error
    /// naming what is wrong.
    pub fn parse(bytes: &[u8]) -> Result<Attachment, DecodeError> {
        let mut r = Reader { bytes, pos: 0 };
        let legacy = bytes.first() == Some(&(LEGACY_KEYS[0].len() as u8))
            && bytes.get(1..=LEGACY_KEYS[0].len()) == Some(LEGACY_KEYS[0].as_bytes());
        let field = |r: &mut Reader, key: &str| -> Result<(), DecodeError> {
            if legacy {
                r.key(key)
            } else {
                Ok(())
            }
        };
        field(&mut r, LEGACY_KEYS[0])?;
        let sequence_number = r.i64("sequence_number")?;
        field(&mut r, LEGACY_KEYS[1])?;
        let source_timestamp_ns = r.i64("source_timestamp")?;
        field(&mut r, LEGACY_KEYS[2])?;
        let len = r.byte("source_gid length")?;
        if len != 16 {
            return Err(DecodeError::BadLength {
                field: "rmw_zenoh attachment source_gid".into(),
                len: usize::from(len),
            });
        }
        let gid = r.take(16, "source_gid")?;
        if r.pos != bytes.len() {
            return Err(DecodeError::BadLength {
                field: "rmw_zenoh attachment (bytes after the GID)".into(),
                len: bytes.len(),
            });
        }
        let mut source_gid = [0u8; 16];
        source_gid.copy_from_slice(gid);
        Ok(Attachment {
            sequence_number,
            source_timestamp_ns,
            source_gid,
        })
    }
}

struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], DecodeError> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.bytes.len());
        let Some(end) = end else {
            return Err(DecodeError::BadLength {
                field: format!("rmw_zenoh attachment {what} (cut short)"),
                len: self.bytes.len(),
            });
        };
        let out = &self.bytes[self.pos..end];
        self.pos = end;
        Ok(out)
    }

    fn byte(&mut self, what: &str) -> Result<u8, DecodeError> {
        Ok(self.take(1, what)?[0])
    }

    fn i64(&mut self, what: &str) -> Result<i64, DecodeError> {
        let b = self.take(8, what)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Ok(i64::from_le_bytes(a))
    }

    /// A legacy string key: its LEB128 length (one byte here) and text.
    fn key(&mut self, want: &str) -> Result<(), DecodeError> {
        let len = usize::from(self.byte(want)?);
        let got = self.take(len, want)?;
        if got != want.as_bytes() {
            return Err(DecodeError::BadString {
                field: format!("rmw_zenoh attachment key (expected {want:?})"),
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_as_rmw_zenoh_writes_them() {
        // docs/design.md's own examples, and the type chunk both ways.
        assert_eq!(
            dds_type_name("std_msgs/msg/String").as_deref(),
            Some("std_msgs::msg::dds_::String_")
        );
        assert_eq!(
            ros2_type_name("sensor_msgs::msg::dds_::Imu_").as_deref(),
            Some("sensor_msgs/msg/Imu")
        );
        assert_eq!(
            type_of_key("0/robot1/chatter/std_msgs::msg::dds_::String_/RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18")
                .as_deref(),
            Some("std_msgs/msg/String")
        );
        assert_eq!(
            type_of_key("0/imu/data/sensor_msgs::msg::dds_::Imu_/TypeHashNotSupported").as_deref(),
            Some("sensor_msgs/msg/Imu")
        );
        assert_eq!(
            subscription_key(0, "/imu/data", Some("sensor_msgs/msg/Imu")),
            "0/imu/data/sensor_msgs::msg::dds_::Imu_/*"
        );
        assert_eq!(
            subscription_key(7, "robot1/odom/", None),
            "7/robot1/odom/*/*"
        );
        for bad in [
            "",
            "Imu_",
            "sensor_msgs::dds_::Imu_",
            "a::b::dds_::_",
            "a::b::c::dds_::X_",
        ] {
            assert_eq!(ros2_type_name(bad), None, "{bad}");
        }
        assert_eq!(dds_type_name("sensor_msgs/Imu"), None);
    }

    /// Tokens as docs/design.md and liveliness_utils.cpp make them (the examples of the
    /// design document's graph section, with our node).
    #[test]
    fn tokens_as_rmw_zenoh_writes_them() {
        let hash = "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8";
        assert_eq!(
            node_token(0, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "/", "skyfuse"),
            "@ros2_lv/0/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/skyfuse"
        );
        assert_eq!(
            publisher_token(
                0,
                "Z",
                0,
                1,
                "/",
                "skyfuse",
                "skyfuse/pose",
                "geometry_msgs/msg/PoseStamped",
                hash,
                QOS_RELIABLE_DEPTH_10
            )
            .as_deref(),
            Some(
                "@ros2_lv/0/Z/0/1/MP/%/%/skyfuse/%skyfuse%pose/geometry_msgs::msg::dds_::PoseStamped_/RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8/::,10:,:,:,,"
            )
        );
        assert_eq!(
            data_key(2, "/data_fusion/pose_msg", "geometry_msgs/msg/PoseStamped", hash)
                .as_deref(),
            Some("2/data_fusion/pose_msg/geometry_msgs::msg::dds_::PoseStamped_/RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8")
        );
    }

    /// The 33 bytes rmw_zenoh ≥ 0.2.4 writes (zenoh-ext: i64 LE, i64 LE, LEB128 16, 16
    /// bytes), and the 77-byte keyed form of 0.2.0–0.2.3 (docs/design.md, issue #600).
    #[test]
    fn attachments_of_both_formats_are_read_and_nothing_else() {
        let a = Attachment {
            sequence_number: 1,
            source_timestamp_ns: 1_764_000_000_123_456_789,
            source_gid: *b"0123456789abcdef",
        };
        let bytes = a.to_bytes();
        assert_eq!(bytes.len(), 33);
        assert_eq!(&bytes[..8], &[1, 0, 0, 0, 0, 0, 0, 0]);
        assert_eq!(bytes[16], 0x10);
        assert_eq!(Attachment::parse(&bytes), Ok(a));
        let mut legacy = vec![15u8];
        legacy.extend_from_slice(b"sequence_number");
        legacy.extend_from_slice(&1i64.to_le_bytes());
        legacy.push(16);
        legacy.extend_from_slice(b"source_timestamp");
        legacy.extend_from_slice(&1_764_000_000_123_456_789i64.to_le_bytes());
        legacy.push(10);
        legacy.extend_from_slice(b"source_gid");
        legacy.push(16);
        legacy.extend_from_slice(b"0123456789abcdef");
        assert_eq!(legacy.len(), 77);
        assert_eq!(Attachment::parse(&legacy), Ok(a));
        // Cut anywhere, a longer GID, trailing bytes: errors, never a panic.
        for n in 0..bytes.len() {
            assert!(Attachment::parse(&bytes[..n]).is_err(), "{n}");
        }
        for n in 0..legacy.len() {
            assert!(Attachment::parse(&legacy[..n]).is_err(), "{n}");
        }
        let mut long = bytes.clone();
        long[16] = 24;
        assert!(Attachment::parse(&long).is_err());
        let mut trailing = bytes.clone();
        trailing.push(0);
        assert!(Attachment::parse(&trailing).is_err());
    }
}
