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

/// The pure part of [`read_mcap`]: bytes → channels and messages. Reads with the `mcap`
/// crate's sans-I/O linear reader, records longer than [`MAX_RECORD`] refused (a
/// damaged length would otherwise be allocated whole, and a failed allocation aborts).
pub fn parse(bytes: &[u8], progress: &mut dyn FnMut(u64, u64)) -> Result<McapLog, ParseError> {
    if !bytes.starts_with(::mcap::MAGIC) {
        return Err(ParseError::NotMcap(
            "it does not start with MCAP's magic bytes".into(),
        ));
    }
    // A damaged chunk (too large, or records running past it) ends the file there.
    let (bytes, damaged) = cut_at_damaged_chunk(bytes);
    let total = bytes.len() as u64;
    let mut log = McapLog::default();
    // The `mcap` crate's reader can still panic on a damaged file (0.26: a record longer
    // than what is left of its chunk underflows a counter; debug builds panic, release
    // builds read on from a wrapped count): what was read before stays, the rest is cut.
    let stop = match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        read_records(bytes, &mut log, &mut *progress)
    })) {
        Ok(stop) => stop,
        Err(panic) => {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "a panic".into());
            Some(format!(
                "the MCAP reader failed on a damaged record ({what})"
            ))
        }
    };
    progress(total, total);
    if let Some(why) = stop.or(damaged) {
        if log.messages.is_empty() {
            return Err(ParseError::Empty(why));
        }
        log.truncated = Some(format!(
            "reading stopped after {} messages: {why}",
            log.messages.len()
        ));
    }
    if log.messages.is_empty() {
        return Err(ParseError::Empty("the file holds no messages".into()));
    }
    log.messages.sort_by_key(|m| m.log_time_ns);
    Ok(log)
}

/// The records of `bytes` into `log`; why reading stopped early, if it did.
fn read_records(
    bytes: &[u8],
    log: &mut McapLog,
    progress: &mut dyn FnMut(u64, u64),
) -> Option<String> {
    use ::mcap::records::Record;
    use ::mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
    let total = bytes.len() as u64;
    // A file cut short has no end magic; read what is there.
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_skip_end_magic(true)
            .with_record_length_limit(MAX_RECORD),
    );
    // Schema id → (name, encoding); channel id → its record, until its first message.
    let mut schemas: BTreeMap<u16, (String, String)> = BTreeMap::new();
    let mut pending: BTreeMap<u16, RecordedChannel> = BTreeMap::new();
    let mut pos = 0usize;
    let mut stop: Option<String> = None;
    while let Some(event) = reader.next_event() {
        let record = match event {
            Ok(LinearReadEvent::ReadRequest(want)) => {
                let n = want.min(bytes.len() - pos);
                reader.insert(n).copy_from_slice(&bytes[pos..pos + n]);
                reader.notify_read(n);
                pos += n;
                if log.messages.len().is_multiple_of(8192) {
                    progress(pos as u64, total);
                }
                continue;
            }
            // Only the records read here are parsed: the crate's parsers of the others
            // (attachments, metadata, indexes, statistics) never see a damaged file
            // (libFuzzer's third finding: a short Attachment record panics one of them).
            Ok(LinearReadEvent::Record { data, opcode }) => {
                use ::mcap::records::op;
                if !matches!(opcode, op::SCHEMA | op::CHANNEL | op::MESSAGE) {
                    continue;
                }
                ::mcap::parse_record(opcode, data)
            }
            Err(e) => {
                stop = Some(e.to_string());
                break;
            }
        };
        match record {
            Ok(Record::Schema { header, .. }) => {
                schemas.insert(header.id, (header.name, header.encoding));
            }
            Ok(Record::Channel(c)) => {
                let schema = schemas.get(&c.schema_id);
                pending.insert(
                    c.id,
                    RecordedChannel {
                        topic: c.topic,
                        message_encoding: c.message_encoding,
                        schema_name: schema.map(|s| s.0.clone()),
                        schema_encoding: schema.map(|s| s.1.clone()),
                        metadata: c.metadata,
                        messages: 0,
                    },
                );
            }
            Ok(Record::Message { header, data }) => {
                let id = header.channel_id;
                let channel = match log.channels.entry(id) {
                    std::collections::btree_map::Entry::Occupied(e) => e.into_mut(),
                    std::collections::btree_map::Entry::Vacant(e) => match pending.get(&id) {
                        Some(c) => e.insert(c.clone()),
                        None => {
                            stop = Some(format!(
                                "a message on channel {id}, which no Channel record declared"
                            ));
                            break;
                        }
                    },
                };
                channel.messages += 1;
                log.messages.push(RecordedMessage {
                    channel: id,
                    log_time_ns: header.log_time,
                    data: data.into_owned(),
                });
            }
            Ok(_) => {}
            Err(e) => {
                stop = Some(e.to_string());
                break;
            }
        }
    }
    stop
}

/// No record of a real recording is near this (a message is at most a camera frame).
pub const MAX_RECORD: usize = 256 * 1024 * 1024;

/// No chunk of a real recording is near this (rosbag2 and Foxglove write under 1 MiB).
pub const MAX_CHUNK_UNCOMPRESSED: u64 = 256 * 1024 * 1024;

const OP_CHUNK: u8 = 0x06;

/// The little-endian u64 at `at`, if `bytes` holds it.
fn le_u64(bytes: &[u8], at: usize) -> Option<u64> {
    Some(u64::from_le_bytes(
        bytes.get(at..at.checked_add(8)?)?.try_into().ok()?,
    ))
}

/// `bytes` up to the first damaged chunk record, and why it was cut: one claiming more
/// than [`MAX_CHUNK_UNCOMPRESSED`] bytes uncompressed, or an uncompressed one whose
/// records do not fit it (see [`uncompressed_records_overrun`]). Walks the top-level
/// records (opcode, u64 length, body); a Chunk body starts with start time, end time,
/// uncompressed size.
fn cut_at_damaged_chunk(bytes: &[u8]) -> (&[u8], Option<String>) {
    let mut at = ::mcap::MAGIC.len();
    while let (Some(&op), Some(len)) = (bytes.get(at), le_u64(bytes, at + 1)) {
        let body = at + 9;
        let declared_end = usize::try_from(len).ok().and_then(|l| body.checked_add(l));
        let complete = declared_end.is_some_and(|e| e <= bytes.len());
        if op == OP_CHUNK {
            if let Some(size) = le_u64(bytes, body + 16) {
                if size > MAX_CHUNK_UNCOMPRESSED {
                    return (
                        &bytes[..at],
                        Some(format!(
                            "a chunk at byte {at} claims {size} bytes uncompressed (at most {MAX_CHUNK_UNCOMPRESSED} are read): a damaged file"
                        )),
                    );
                }
            }
            let end = declared_end.map_or(bytes.len(), |e| e.min(bytes.len()));
            if uncompressed_records_overrun(&bytes[body.min(end)..end], complete) {
                return (
                    &bytes[..at],
                    Some(format!(
                        "a record in the chunk at byte {at} runs past the chunk's end: a damaged file"
                    )),
                );
            }
        }
        match declared_end {
            Some(next) if complete => at = next,
            _ => break,
        }
    }
    (bytes, None)
}

/// An uncompressed chunk (its body: start and end time, uncompressed size and CRC,
/// compression, records; `complete`: all of it is in the file) whose records do not fit
/// its records section, or whose records section does not fit the chunk: the `mcap`
/// crate's reader would underflow its count of what is left (a panic in a debug build,
/// a wrapped count in release), so such a chunk ends the file instead. Compressed
/// chunks are checked by the crate against their uncompressed size.
fn uncompressed_records_overrun(chunk: &[u8], complete: bool) -> bool {
    let u32_at = |i: usize| -> Option<usize> {
        let b: [u8; 4] = chunk.get(i..i + 4)?.try_into().ok()?;
        usize::try_from(u32::from_le_bytes(b)).ok()
    };
    let u64_at = |i: usize| le_u64(chunk, i);
    // 8 + 8 + 8 + 4 bytes of times, size and CRC, then the compression string.
    let Some(name_len) = u32_at(28) else {
        return false;
    };
    if name_len != 0 {
        return false;
    }
    let Some(records_len) = u64_at(32) else {
        return false;
    };
    if complete && records_len > (chunk.len() as u64).saturating_sub(40) {
        return true;
    }
    let mut left = records_len;
    let mut at = 40usize;
    while left > 0 {
        if left < 9 {
            // Not even a record's opcode and length fit in what is left.
            return true;
        }
        let Some(len) = u64_at(at + 1) else {
            // The chunk ends with the file (cut short): the reader stops there. A whole
            // chunk whose records leave it is damaged.
            return complete;
        };
        let Some(record) = len.checked_add(9).filter(|r| *r <= left) else {
            return true;
        };
        left -= record;
        at = match usize::try_from(record).ok().and_then(|r| at.checked_add(r)) {
            Some(next) => next,
            None => return true,
        };
    }
    false
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::borrow::Cow;
    use std::sync::Arc;

    /// An MCAP file written by the `mcap` crate's writer: two channels, `n` messages
    /// each, small chunks.
    fn file(n: u64) -> Vec<u8> {
        file_with(n, Some(::mcap::Compression::Zstd))
    }

    fn file_with(n: u64, compression: Option<::mcap::Compression>) -> Vec<u8> {
        let mut out = std::io::Cursor::new(Vec::new());
        {
            let mut w = ::mcap::WriteOptions::new()
                .compression(compression)
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

    /// Where the file's Chunk records start, walking the top-level records.
    fn chunk_offsets(file: &[u8]) -> Vec<usize> {
        let mut at = ::mcap::MAGIC.len();
        let mut chunks = vec![];
        while at + 9 <= file.len() {
            let len = u64::from_le_bytes(file[at + 1..at + 9].try_into().expect("8 bytes"));
            if file[at] == OP_CHUNK {
                chunks.push(at);
            }
            at += 9 + len as usize;
        }
        chunks
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
    fn a_chunk_claiming_terabytes_ends_the_file_there_instead_of_the_process() {
        let mut whole = file(50);
        // The second chunk's uncompressed size: find the chunks by walking the records.
        let chunks = chunk_offsets(&whole);
        assert!(chunks.len() > 2, "{} chunks", chunks.len());
        let size_at = chunks[1] + 9 + 16;
        whole[size_at..size_at + 8].copy_from_slice(&(1u64 << 42).to_le_bytes());
        let log = parse(&whole, &mut |_, _| {}).expect("the part before it");
        assert!(!log.messages.is_empty());
        assert!(log
            .truncated
            .as_deref()
            .is_some_and(|t| t.contains("claims 4398046511104 bytes")));
    }

    /// Found by libFuzzer: in an uncompressed chunk, a record longer than what is left
    /// of the chunk made the crate's reader underflow a counter (a panic in debug
    /// builds). Such a chunk now ends the file, before the crate reads it.
    #[test]
    fn a_record_running_past_its_uncompressed_chunk_ends_the_file_there() {
        let mut whole = file_with(50, None);
        let chunks = chunk_offsets(&whole);
        assert!(chunks.len() > 2, "{} chunks", chunks.len());
        let body = chunks[1] + 9;
        assert_eq!(&whole[body + 28..body + 32], &[0, 0, 0, 0], "uncompressed");
        // The first record inside the second chunk claims 100 bytes more than its chunk.
        let records_len = u64::from_le_bytes(whole[body + 32..body + 40].try_into().expect("8"));
        let first = body + 40;
        whole[first + 1..first + 9].copy_from_slice(&(records_len + 100).to_le_bytes());
        let log = parse(&whole, &mut |_, _| {}).expect("the part before it");
        assert!(!log.messages.is_empty());
        assert!(
            log.truncated
                .as_deref()
                .is_some_and(|t| t.contains("runs past the chunk's end")),
            "{:?}",
            log.truncated
        );
        // Undamaged, the same file reads whole.
        let log = parse(&file_with(50, None), &mut |_, _| {}).expect("parse");
        assert_eq!((log.messages.len(), log.truncated), (100, None));
    }

    /// The inputs libFuzzer found (`fuzz/`, target `mcap`): each reaches no panic in the
    /// crate's reader (which `parse` would catch and report as below) any more.
    #[test]
    fn the_fuzzers_findings_are_cut_before_the_crate_reads_them() {
        let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/fuzz");
        let mut n = 0;
        for entry in std::fs::read_dir(dir).expect("tests/data/fuzz") {
            let path = entry.expect("entry").path();
            let bytes = std::fs::read(&path).expect("read");
            let said = match parse(&bytes, &mut |_, _| {}) {
                Ok(log) => log.truncated.unwrap_or_default(),
                Err(e) => e.to_string(),
            };
            assert!(
                !said.contains("failed on a damaged record"),
                "{}: {said}",
                path.display()
            );
            n += 1;
        }
        assert!(n >= 3);
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
