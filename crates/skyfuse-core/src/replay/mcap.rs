//! MCAP files (skyfuse's own flight recordings, rosbag2 bags, anything the Foxglove SDK
//! wrote) → time-ordered recorded messages, read with the format's own `mcap` crate.
//!
//! This reader knows the file format only: which channel a message is on, its encoding
//! and schema, its log time and its bytes. What a channel means (a Zenoh key skyfuse
//! recorded, a ROS 2 topic of a known type) is decided by the service, which feeds the
//! bytes through the same ingest path as live input.
//!
//! A file cut short (a killed recorder, a copy interrupted) is read up to the last
//! complete chunk: the messages before the damage are returned and `truncated` says
//! where reading stopped. Only a file with no readable message at all is an error.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum McapError {
    #[error("{}: cannot read: {source}", file.display())]
    Read {
        file: PathBuf,
        source: std::io::Error,
    },
    #[error("{}: not an MCAP file: {message}", file.display())]
    NotMcap { file: PathBuf, message: String },
    #[error("{}: no message could be read: {message}", file.display())]
    Empty { file: PathBuf, message: String },
}

/// One channel of the file, as its Channel and Schema records describe it.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedChannel {
    pub topic: String,
    pub message_encoding: String,
    /// Schema name (`sensor_msgs/msg/Imu`, `foxglove.PoseInFrame`), if the channel has one.
    pub schema_name: Option<String>,
    /// Schema encoding (`ros2msg`, `protobuf`, `jsonschema`).
    pub schema_encoding: Option<String>,
    pub metadata: BTreeMap<String, String>,
    /// Messages read on this channel.
    pub messages: u64,
}

/// One message: which channel, when it was logged (the arrival time for skyfuse's
/// recordings and rosbag2's receive time), and its bytes as they were recorded.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedMessage {
    pub channel: u16,
    pub log_time_ns: u64,
    pub data: Vec<u8>,
}

/// A read MCAP file.
#[derive(Debug, Default)]
pub struct McapLog {
    pub channels: BTreeMap<u16, RecordedChannel>,
    /// Ordered by log time (stable: equal times keep file order).
    pub messages: Vec<RecordedMessage>,
    /// Where and why reading stopped early, for a file cut short.
    pub truncated: Option<String>,
}

/// Reads an MCAP file; `progress(done, total)` counts bytes (message bytes read so far).
pub fn read_mcap(file: &Path, progress: &mut dyn FnMut(u64, u64)) -> Result<McapLog, McapError> {
    let bytes = std::fs::read(file).map_err(|source| McapError::Read {
        file: file.to_path_buf(),
        source,
    })?;
    parse(&bytes, progress).map_err(|e| match e {
        ParseError::NotMcap(message) => McapError::NotMcap {
            file: file.to_path_buf(),
            message,
        },
        ParseError::Empty(message) => McapError::Empty {
            file: file.to_path_buf(),
            message,
        },
    })
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ParseError {
    #[error("not an MCAP file: {0}")]
    NotMcap(String),
    #[error("no message could be read: {0}")]
    Empty(String),
}

/// The pure part of [`read_mcap`]: bytes → channels and messages.
pub fn parse(bytes: &[u8], progress: &mut dyn FnMut(u64, u64)) -> Result<McapLog, ParseError> {
    if !bytes.starts_with(::mcap::MAGIC) {
        return Err(ParseError::NotMcap(
            "it does not start with MCAP's magic bytes".into(),
        ));
    }
    // A file cut short has no end magic; read what is there.
    let options = ::mcap::read::Options::IgnoreEndMagic.into();
    let stream = ::mcap::MessageStream::new_with_options(bytes, options)
        .map_err(|e| ParseError::NotMcap(e.to_string()))?;
    let mut log = McapLog::default();
    let total = bytes.len() as u64;
    // Progress: message bytes so far against the file's size, every few thousand messages.
    let mut done: u64 = 0;
    for m in stream {
        match m {
            Ok(m) => {
                let ch = &m.channel;
                let entry = log
                    .channels
                    .entry(ch.id)
                    .or_insert_with(|| RecordedChannel {
                        topic: ch.topic.clone(),
                        message_encoding: ch.message_encoding.clone(),
                        schema_name: ch.schema.as_ref().map(|s| s.name.clone()),
                        schema_encoding: ch.schema.as_ref().map(|s| s.encoding.clone()),
                        metadata: ch.metadata.clone(),
                        messages: 0,
                    });
                entry.messages += 1;
                let m_len = m.data.len() as u64;
                log.messages.push(RecordedMessage {
                    channel: ch.id,
                    log_time_ns: m.log_time,
                    data: m.data.into_owned(),
                });
                done += m_len;
                if log.messages.len() % 8192 == 0 {
                    progress(done.min(total), total);
                }
            }
            Err(e) => {
                if log.messages.is_empty() {
                    return Err(ParseError::Empty(e.to_string()));
                }
                log.truncated = Some(format!(
                    "reading stopped after {} messages: {e}",
                    log.messages.len()
                ));
                break;
            }
        }
    }
    progress(total, total);
    if log.messages.is_empty() && log.truncated.is_none() {
        return Err(ParseError::Empty("the file holds no messages".into()));
    }
    log.messages.sort_by_key(|m| m.log_time_ns);
    Ok(log)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::borrow::Cow;
    use std::sync::Arc;

    /// An MCAP file written by the `mcap` crate's writer: two channels, `n` messages
    /// each, small chunks.
    fn file(n: u64) -> Vec<u8> {
        let mut out = std::io::Cursor::new(Vec::new());
        {
            let mut w = ::mcap::WriteOptions::new()
                .chunk_size(Some(512))
                .create(&mut out)
                .expect("writer");
            let schema = Arc::new(::mcap::Schema {
                id: 1,
                name: "sensor_msgs/msg/Imu".into(),
                encoding: "ros2msg".into(),
                data: Cow::Borrowed(b"# definition"),
            });
            let imu = Arc::new(::mcap::Channel {
                id: 0,
                topic: "imu/data".into(),
                schema: Some(schema),
                message_encoding: "cdr".into(),
                metadata: BTreeMap::from([("k".to_string(), "v".to_string())]),
            });
            let json = Arc::new(::mcap::Channel {
                id: 1,
                topic: "/skyfuse/events".into(),
                schema: None,
                message_encoding: "json".into(),
                metadata: BTreeMap::new(),
            });
            for i in 0..n {
                for (ch, t) in [(&imu, 2 * i + 1), (&json, 2 * i)] {
                    w.write(&::mcap::Message {
                        channel: ch.clone(),
                        sequence: i as u32,
                        log_time: t * 1000,
                        publish_time: t * 1000,
                        data: Cow::Owned(vec![i as u8; 40]),
                    })
                    .expect("write");
                }
            }
            w.finish().expect("finish");
        }
        out.into_inner()
    }

    #[test]
    fn reads_channels_schemas_and_messages_in_time_order() {
        let log = parse(&file(100), &mut |_, _| {}).expect("parse");
        assert_eq!(log.messages.len(), 200);
        assert!(log.truncated.is_none());
        assert!(log
            .messages
            .windows(2)
            .all(|w| w[0].log_time_ns <= w[1].log_time_ns));
        let imu = log
            .channels
            .values()
            .find(|c| c.topic == "imu/data")
            .expect("imu channel");
        assert_eq!(imu.schema_name.as_deref(), Some("sensor_msgs/msg/Imu"));
        assert_eq!(imu.schema_encoding.as_deref(), Some("ros2msg"));
        assert_eq!(imu.message_encoding, "cdr");
        assert_eq!(imu.metadata.get("k").map(String::as_str), Some("v"));
        assert_eq!(imu.messages, 100);
    }

    #[test]
    fn a_file_cut_short_gives_what_was_written_before_the_cut() {
        let whole = file(400);
        let cut = &whole[..whole.len() * 2 / 3];
        let log = parse(cut, &mut |_, _| {}).expect("parse the cut file");
        assert!(log.truncated.is_some(), "the cut is reported");
        // Chunks of 512 bytes hold a few messages each: little is lost.
        assert!(
            log.messages.len() > 400,
            "{} of 800 messages",
            log.messages.len()
        );
        assert!(log.messages.len() < 800);
    }

    #[test]
    fn bytes_that_are_not_mcap_are_named_as_such() {
        assert!(matches!(
            parse(b"not an mcap file at all", &mut |_, _| {}),
            Err(ParseError::NotMcap(_))
        ));
        let whole = file(10);
        assert!(parse(&whole[..20], &mut |_, _| {}).is_err());
    }
}
