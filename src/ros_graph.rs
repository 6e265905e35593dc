//! ROS 2 graph presence over zenoh-bridge-ros2dds's liveliness tokens.
//!
//! The bridge declares `@/<zid>/@ros2_lv/MP/<key>/<type>/<qos>` for every ROS publisher
//! it routes (`/` written `§` in key and type; see zenoh-plugin-ros2dds
//! `liveliness_mgt.rs`), and a bridge that sees such a token from another Zenoh node
//! creates a DDS writer for it, so ROS 2 tools see the topic with its type before anyone
//! subscribes. skyfuse announces its ROS 2 outputs that way ([`announce`]) and watches
//! the tokens of others ([`discover`]) to list the ROS topics on the network.
//! [`token_key`] and [`parse_token_key`] are the pure codec.

use serde::Serialize;
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

pub use crate::config::DEFAULT_QOS;
/// Key expression matching every bridge publisher token.
pub const PUBLISHER_TOKENS: &str = "@/*/@ros2_lv/MP/**";

/// A publisher token, parsed.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct PublisherToken {
    pub zid: String,
    /// The Zenoh key the data is published on (ROS topic without its leading `/`).
    pub key: String,
    /// ROS type, e.g. `sensor_msgs/msg/NavSatFix`.
    pub ros_type: String,
    pub qos: String,
}

/// `@/<zid>/@ros2_lv/MP/<key §>/<type §>/<qos>`.
pub fn token_key(zid: &str, key: &str, ros_type: &str, qos: &str) -> String {
    format!(
        "@/{zid}/@ros2_lv/MP/{}/{}/{qos}",
        key.trim_start_matches('/').replace('/', "§"),
        ros_type.replace('/', "§")
    )
}

/// The inverse of [`token_key`]; `None` for anything that is not a publisher token.
pub fn parse_token_key(k: &str) -> Option<PublisherToken> {
    let rest = k.strip_prefix("@/")?;
    let (zid, rest) = rest.split_once('/')?;
    let rest = rest.strip_prefix("@ros2_lv/MP/")?;
    // key and type have no '/' (they are §-escaped); the QoS part may contain none
    // either in the bridge's form, but take everything after the second chunk.
    let mut parts = rest.splitn(3, '/');
    let key = parts.next()?.replace('§', "/");
    let ros_type = parts.next()?.replace('§', "/");
    let qos = parts.next().unwrap_or("").to_string();
    if zid.is_empty() || key.is_empty() || ros_type.is_empty() {
        return None;
    }
    Some(PublisherToken {
        zid: zid.to_string(),
        key,
        ros_type,
        qos,
    })
}

/// A field of a ROS type description (REP 2011): name, rosidl type id, nested type.
type FieldDesc = (&'static str, u8, &'static str);

/// The type descriptions skyfuse publishes, field for field as the `.msg` files
/// (type ids from rosidl: 1 nested, 6 int32, 7 uint32, 11 float64, 17 string).
const TYPE_DESCRIPTIONS: &[(&str, &[FieldDesc])] = &[
    (
        "builtin_interfaces/msg/Time",
        &[("sec", 6, ""), ("nanosec", 7, "")],
    ),
    (
        "std_msgs/msg/Header",
        &[
            ("stamp", 1, "builtin_interfaces/msg/Time"),
            ("frame_id", 17, ""),
        ],
    ),
    (
        "geometry_msgs/msg/Point",
        &[("x", 11, ""), ("y", 11, ""), ("z", 11, "")],
    ),
    (
        "geometry_msgs/msg/Quaternion",
        &[("x", 11, ""), ("y", 11, ""), ("z", 11, ""), ("w", 11, "")],
    ),
    (
        "geometry_msgs/msg/Pose",
        &[
            ("position", 1, "geometry_msgs/msg/Point"),
            ("orientation", 1, "geometry_msgs/msg/Quaternion"),
        ],
    ),
    (
        "geometry_msgs/msg/PoseStamped",
        &[
            ("header", 1, "std_msgs/msg/Header"),
            ("pose", 1, "geometry_msgs/msg/Pose"),
        ],
    ),
    (
        "geometry_msgs/msg/PointStamped",
        &[
            ("header", 1, "std_msgs/msg/Header"),
            ("point", 1, "geometry_msgs/msg/Point"),
        ],
    ),
];

fn describe(name: &str) -> Option<&'static [FieldDesc]> {
    TYPE_DESCRIPTIONS
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, f)| *f)
}

/// The JSON of one type description, formatted as Python's `json.dumps` does (the
/// hash is over these exact bytes).
fn struct_json(name: &str, fields: &[FieldDesc]) -> String {
    let fields: Vec<String> = fields
        .iter()
        .map(|(n, id, nested)| {
            format!(
                "{{\"name\": \"{n}\", \"type\": {{\"type_id\": {id}, \"capacity\": 0, \"string_capacity\": 0, \"nested_type_name\": \"{nested}\"}}}}"
            )
        })
        .collect();
    format!(
        "{{\"type_name\": \"{name}\", \"fields\": [{}]}}",
        fields.join(", ")
    )
}

/// The REP 2011 type hash (`RIHS01_<sha256 hex>`) of a type skyfuse publishes.
pub fn rihs01(name: &str) -> Option<String> {
    use sha2::{Digest, Sha256};
    // px4_msgs: the hashes of PX4's own definitions (the 1.16 layout we write).
    if let Some(t) = crate::codec::ros::px4::Px4Type::from_name(name) {
        return Some(crate::codec::ros::px4::type_hash(
            t,
            crate::codec::ros::px4::Px4Version::V1_16,
        ));
    }
    let fields = describe(name)?;
    // Every type it refers to, directly or not, sorted by name.
    let mut refs = std::collections::BTreeSet::new();
    let mut todo = vec![fields];
    while let Some(f) = todo.pop() {
        for (_, _, nested) in f.iter().filter(|f| !f.2.is_empty()) {
            if refs.insert(*nested) {
                todo.push(describe(nested)?);
            }
        }
    }
    let referenced: Vec<String> = refs
        .iter()
        .map(|r| describe(r).map(|f| struct_json(r, f)))
        .collect::<Option<_>>()?;
    let text = format!(
        "{{\"type_description\": {}, \"referenced_type_descriptions\": [{}]}}",
        struct_json(name, fields),
        referenced.join(", ")
    );
    let digest = Sha256::digest(text.as_bytes());
    let hex: String = digest.iter().map(|b| format!("{b:02x}")).collect();
    Some(format!("RIHS01_{hex}"))
}

/// The QoS part of a token for `ros_distro`: Humble has none; Iron and later end it
/// with the type hash.
pub fn qos_part(qos: &str, ros_distro: &str, ros_type: &str) -> String {
    match (ros_distro, rihs01(ros_type)) {
        ("humble", _) | (_, None) => qos.to_string(),
        (_, Some(h)) => format!("{qos}:typehash={h};"),
    }
}

/// A ROS topic offered on the network.
#[derive(Debug, Clone, Serialize)]
pub struct TopicEntry {
    pub key: String,
    pub topic: String,
    pub ros_type: String,
    pub qos: String,
    pub zid: String,
    pub alive: bool,
    /// Host time, µs, of the last change.
    pub since_us: i64,
}

/// The topics bridges announce, keyed by (zid, key).
pub type TopicTable = Arc<Mutex<BTreeMap<(String, String), TopicEntry>>>;

/// Declare a publisher token for each `(key, ROS type)`; they live until dropped.
pub async fn announce(
    session: &zenoh::Session,
    outputs: &[(String, &'static str)],
    qos: &str,
    ros_distro: &str,
) -> Vec<zenoh::liveliness::LivelinessToken> {
    let zid = session.zid().to_string();
    let mut tokens = Vec::new();
    for (key, ty) in outputs {
        let k = token_key(&zid, key, ty, &qos_part(qos, ros_distro, ty));
        match session.liveliness().declare_token(&k).await {
            Ok(t) => {
                tracing::info!(token = %k, "announced ROS 2 publisher");
                tokens.push(t);
            }
            Err(e) => tracing::warn!(token = %k, "cannot declare liveliness token: {e}"),
        }
    }
    tokens
}

/// Watch bridge publisher tokens (current ones first) into `table`, skipping our own.
pub async fn discover(
    session: &zenoh::Session,
    table: TopicTable,
) -> Option<zenoh::pubsub::Subscriber<()>> {
    let own = session.zid().to_string();
    let sub = session
        .liveliness()
        .declare_subscriber(PUBLISHER_TOKENS)
        .history(true)
        .callback(move |s| {
            let Some(tok) = parse_token_key(s.key_expr().as_str()) else {
                return;
            };
            if tok.zid == own {
                return;
            }
            let alive = s.kind() == zenoh::sample::SampleKind::Put;
            let mut t = crate::sync::lock(&table);
            let e = t
                .entry((tok.zid.clone(), tok.key.clone()))
                .or_insert_with(|| TopicEntry {
                    topic: format!("/{}", tok.key),
                    key: tok.key.clone(),
                    ros_type: tok.ros_type.clone(),
                    qos: tok.qos.clone(),
                    zid: tok.zid.clone(),
                    alive,
                    since_us: crate::clock::now_us(),
                });
            if e.alive != alive || e.ros_type != tok.ros_type {
                e.since_us = crate::clock::now_us();
            }
            e.alive = alive;
            e.ros_type = tok.ros_type;
            e.qos = tok.qos;
            tracing::info!(topic = %e.topic, ros_type = %e.ros_type, zid = %e.zid, alive, "ROS 2 topic on the network");
        })
        .await;
    match sub {
        Ok(s) => Some(s),
        Err(e) => {
            tracing::warn!("cannot watch ROS 2 liveliness tokens: {e}");
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn token_keys_as_the_bridge_writes_them() {
        let k = token_key(
            "1f2e3d",
            "/gps/fix",
            "sensor_msgs/msg/NavSatFix",
            DEFAULT_QOS,
        );
        assert_eq!(
            k,
            "@/1f2e3d/@ros2_lv/MP/gps§fix/sensor_msgs§msg§NavSatFix/:1::0,10"
        );
        let t = parse_token_key(&k).expect("parses");
        assert_eq!(t.key, "gps/fix");
        assert_eq!(t.ros_type, "sensor_msgs/msg/NavSatFix");
        assert_eq!(t.qos, ":1::0,10");
        assert_eq!(t.zid, "1f2e3d");
        assert!(parse_token_key("@/x/@ros2_lv/MS/a/b/c").is_none());
        assert!(parse_token_key("mavlink/1/1/HEARTBEAT").is_none());
    }

    /// The hashes equal what `rosbags` computes (get_typestore(Stores.ROS2_JAZZY)
    /// .hash_rihs01(name)), printed by tests/py/rihs01.py; the e2e test also checks the
    /// announced tokens against rosbags live.
    #[test]
    fn type_hashes_match_rosbags() {
        let a = rihs01("geometry_msgs/msg/PoseStamped").expect("known");
        let b = rihs01("geometry_msgs/msg/PointStamped").expect("known");
        assert!(a.starts_with("RIHS01_") && a.len() == 7 + 64, "{a}");
        assert_ne!(a, b);
        assert!(rihs01("acme_msgs/msg/Gizmo").is_none());
        // rosbags 0.11.9, Stores.ROS2_JAZZY (tests/py/rihs01.py).
        assert_eq!(
            a,
            "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8"
        );
        assert_eq!(
            b,
            "RIHS01_4c0296af86e01e562e9e0405d138a01537247580076c58ea38d7923ac1045897"
        );
        assert_eq!(
            qos_part(":1::0,10", "humble", "geometry_msgs/msg/PoseStamped"),
            ":1::0,10"
        );
        assert_eq!(
            qos_part(":1::0,10", "jazzy", "geometry_msgs/msg/PoseStamped"),
            format!(":1::0,10:typehash={a};")
        );
    }
}
