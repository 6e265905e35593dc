//! An MCAP file → samples, through the same ingest as live input.
//!
//! Which input a channel feeds:
//! 1. skyfuse's own recordings name it (channel metadata `skyfuse.input`): that input,
//!    if the config (perhaps another one, `-c other.toml`) has it and its key still
//!    matches the recorded key;
//! 2. otherwise every enabled input of the config whose key expression matches the
//!    channel's topic (a ROS topic `/imu/data` is the bridge's key `imu/data`) and whose
//!    format reads the channel's encoding;
//! 3. otherwise, for a ROS 2 CDR channel of a type skyfuse decodes (a rosbag2 bag), a new
//!    input named after the topic, its kind that of the first message.
//!
//! Channels skyfuse wrote as outputs (`/skyfuse/...`, `/tf`, the ROS 2 outputs of the
//! config's `[output]`, in a bag recorded beside it too) are never inputs. The log time
//! is the arrival time: ingest's checks (clock restarts, floods, stamps) see what they
//! saw live, and the same recording replays to the same bytes every time.

use crate::codec::{Format, RosType};
use crate::config::{Config, InputConfig};
use crate::ingest::Ingest;
use crate::replay::mcap::{McapLog, RecordedChannel};
use crate::sample::Sample;
use std::collections::BTreeMap;
use std::sync::Arc;

/// How one channel of the file was used.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelUse {
    pub topic: String,
    pub encoding: String,
    pub schema: Option<String>,
    pub messages: u64,
    /// The inputs it fed, or why none.
    pub inputs: Vec<String>,
    pub skipped: Option<String>,
}

/// The samples of a recording, and what it recorded as the live output.
#[derive(Debug)]
pub struct McapReplay {
    pub samples: Vec<Sample>,
    pub channels: Vec<ChannelUse>,
    /// The config the samples went through (with inputs added for bag topics).
    pub config: Config,
    pub ingest: Arc<Ingest>,
    /// The fused poses skyfuse sent live (`/skyfuse/pose_json`): (time µs, ENU position, valid).
    pub live_poses: Vec<(i64, [f64; 3], bool)>,
    /// The first sample's arrival, µs: time zero of the replay's files.
    pub t0_us: Option<i64>,
}

fn is_output(topic: &str) -> bool {
    topic.starts_with("/skyfuse/") || topic == super::TOPIC_TF
}

fn key_matches(input: &InputConfig, topic: &str) -> bool {
    let key = topic.trim_start_matches('/');
    let Ok(k) = zenoh::key_expr::KeyExpr::try_from(key) else {
        return false;
    };
    input
        .key_exprs()
        .iter()
        .any(|e| zenoh::key_expr::KeyExpr::try_from(e.as_str()).is_ok_and(|e| e.intersects(&k)))
}

/// A config input for a bag topic nobody configured: `/camera/odom/sample` →
/// `camera_odom_sample`, its kind from its first message, its rate from the bag.
fn input_for_topic(
    topic: &str,
    ros_type: RosType,
    channel: &RecordedChannel,
    first: &[u8],
    span_s: f64,
) -> Result<InputConfig, String> {
    let mut decoded = Vec::new();
    crate::codec::decode(Format::Ros2, Some(ros_type), first, &mut decoded)
        .map_err(|e| format!("its first message does not decode: {e}"))?;
    let kind = decoded
        .first()
        .map(|d| d.data.kind())
        .ok_or("its first message holds nothing skyfuse uses")?;
    Ok(InputConfig {
        id: super::name_safe(topic.trim_matches('/')),
        kind,
        key: topic.trim_start_matches('/').to_string(),
        format: Format::Ros2,
        ros_type: Some(ros_type),
        rate_hz: (channel.messages as f64 / span_s.max(1e-3)).max(0.1),
        enabled: true,
        auto_type: false,
        transport: Default::default(),
        domain_id: 0,
    })
}

/// Route the file's channels to inputs and run every message through ingest.
pub fn samples(config: &Config, log: &McapLog) -> McapReplay {
    let mut config = config.clone();
    let first_of = |id: u16| log.messages.iter().find(|m| m.channel == id);
    let span_s = match (log.messages.first(), log.messages.last()) {
        (Some(a), Some(b)) => (b.log_time_ns.saturating_sub(a.log_time_ns)) as f64 * 1e-9,
        _ => 0.0,
    };
    // Channel → input ids (by config index, fixed once the added inputs are in).
    let mut routes: BTreeMap<u16, Vec<String>> = BTreeMap::new();
    let mut uses = Vec::new();
    // skyfuse's own ROS 2 outputs (a bag recorded with `ros2 bag record -a` beside it
    // holds them): never fed back in as inputs.
    let own_outputs: Vec<String> = config
        .output
        .announced_outputs()
        .into_iter()
        .map(|(k, _)| k.trim_start_matches('/').to_string())
        .collect();
    for (&id, ch) in &log.channels {
        let mut use_ = ChannelUse {
            topic: ch.topic.clone(),
            encoding: ch.message_encoding.clone(),
            schema: ch.schema_name.clone(),
            messages: ch.messages,
            inputs: Vec::new(),
            skipped: None,
        };
        if is_output(&ch.topic) || ch.metadata.contains_key(super::META_OUTPUT) {
            use_.skipped = Some("an output of the recorded run".into());
            uses.push(use_);
            continue;
        }
        if own_outputs
            .iter()
            .any(|k| k == ch.topic.trim_start_matches('/'))
        {
            use_.skipped = Some("one of skyfuse's own ROS 2 outputs ([output])".into());
            uses.push(use_);
            continue;
        }
        let usable = |i: &InputConfig| {
            i.enabled
                && super::channel_encoding(i.format) == ch.message_encoding
                && key_matches(i, &ch.topic)
        };
        let named = ch
            .metadata
            .get(super::META_INPUT)
            .and_then(|n| config.inputs.iter().find(|i| &i.id == n))
            .filter(|i| usable(i));
        let mut ids: Vec<String> = match named {
            Some(i) => vec![i.id.clone()],
            None => config
                .inputs
                .iter()
                .filter(|i| usable(i))
                .map(|i| i.id.clone())
                .collect(),
        };
        if ids.is_empty() {
            let ros_type = ch.schema_name.as_deref().and_then(RosType::from_name);
            match (ch.message_encoding.as_str(), ros_type, first_of(id)) {
                ("cdr", Some(t), Some(first)) => {
                    match input_for_topic(&ch.topic, t, ch, &first.data, span_s) {
                        Ok(mut input) => {
                            while config.inputs.iter().any(|i| i.id == input.id) {
                                input.id.push('_');
                            }
                            ids.push(input.id.clone());
                            config.inputs.push(input);
                        }
                        Err(why) => use_.skipped = Some(why),
                    }
                }
                ("cdr", None, _) => {
                    use_.skipped = Some(format!(
                        "type {} is not one skyfuse decodes",
                        ch.schema_name.as_deref().unwrap_or("(no schema)")
                    ))
                }
                _ => {
                    use_.skipped = Some(format!(
                        "no enabled input of the config has key {:?} and reads {:?}",
                        ch.topic.trim_start_matches('/'),
                        ch.message_encoding
                    ))
                }
            }
        }
        use_.inputs = ids.clone();
        routes.insert(id, ids);
        uses.push(use_);
    }
    let ingest = Arc::new(Ingest::new(&config));
    // Types as the bag's schemas give them, for `type = "auto"` inputs (live, the
    // bridge's liveliness tokens say it).
    {
        let mut table = crate::sync::lock(&ingest.ros_topics);
        for ch in log.channels.values() {
            if let (Some(name), "cdr") = (&ch.schema_name, ch.message_encoding.as_str()) {
                let key = ch.topic.trim_start_matches('/').to_string();
                table.insert(
                    ("recording".into(), key.clone()),
                    crate::ros_graph::TopicEntry {
                        key,
                        topic: ch.topic.clone(),
                        ros_type: name.clone(),
                        qos: String::new(),
                        zid: "recording".into(),
                        alive: true,
                        since_us: 0,
                    },
                );
            }
        }
    }
    let index: BTreeMap<&str, usize> = ingest
        .inputs
        .iter()
        .enumerate()
        .map(|(i, s)| (s.config.id.as_str(), i))
        .collect();
    let routes: BTreeMap<u16, Vec<usize>> = routes
        .into_iter()
        .map(|(ch, ids)| {
            let idx = ids
                .iter()
                .filter_map(|id| index.get(id.as_str()).copied())
                .collect();
            (ch, idx)
        })
        .collect();
    let pose_channel = log
        .channels
        .iter()
        .find(|(_, c)| c.topic == super::TOPIC_POSE_JSON)
        .map(|(&id, _)| id);
    let mut samples = Vec::new();
    let mut live_poses = Vec::new();
    for m in &log.messages {
        let arrival_us = (m.log_time_ns / 1000) as i64;
        if Some(m.channel) == pose_channel {
            if let Ok(p) = serde_json::from_slice::<RecordedPose>(&m.data) {
                live_poses.push((p.time_us, p.position, p.valid));
            }
            continue;
        }
        let Some(targets) = routes.get(&m.channel) else {
            continue;
        };
        let topic = log
            .channels
            .get(&m.channel)
            .map(|c| c.topic.trim_start_matches('/'))
            .unwrap_or_default();
        for &i in targets {
            if let Some(input) = ingest.inputs.get(i) {
                samples.extend(ingest.accept(input, topic, &m.data, arrival_us));
            }
        }
    }
    McapReplay {
        t0_us: samples.first().map(|s: &Sample| s.arrival_us),
        samples,
        channels: uses,
        config,
        ingest,
        live_poses,
    }
}

/// The fields of a recorded `/skyfuse/pose_json` message the replay compares against.
#[derive(serde::Deserialize)]
struct RecordedPose {
    time_us: i64,
    position: [f64; 3],
    valid: bool,
}
