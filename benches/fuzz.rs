//! Mutation fuzzing of every decoder the service exposes to the outside, from real seeds
//! (the golden vectors and the payloads captured from the real bridges in tests/data):
//! ROS 2 CDR (each supported type, both byte orders), ROS 1, mavlink-server JSON, raw
//! MAVLink frames (v1 and v2, several per payload), PX4's px4_msgs (every layout, XCDR1
//! and XCDR2), skyfuse JSON, the TOML config, the
//! websocket client message, the fault-control body and MCAP files (`skyfuse replay
//! FILE.mcap`: recordings as the recorder writes them, chunked and not, zstd and lz4).
//!
//! Each input is a seed mutated 1–8 times (bit flips, random bytes, interesting values,
//! truncation, extension, duplication and deletion of runs, splices with another seed,
//! pure random bytes now and then). A panic is caught, counted and reported with the
//! input; memory is read before and after (resident set) to show it stays bounded.
//!
//! `cargo bench --bench fuzz -- --iters 10000000` (per target; BENCHMARKS.md has the
//! figures); `cargo bench --bench fuzz -- mavlink_raw` runs one target. Under
//! `cargo test` (no `--bench`) every target runs 20 000 inputs and any panic fails.
//! The decoders are `fuzz/targets.rs`, shared with the coverage-guided libFuzzer targets
//! in `fuzz/`; `cargo bench --bench fuzz -- --write-seeds DIR` writes these seeds as
//! their starting corpus (DIR/<target>/).

use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use skyfuse::codec::{self, Format, RosType};

#[path = "../fuzz/targets.rs"]
mod decoders;
use decoders::Target as Decoder;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::time::Instant;

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data");

fn hex(s: &str) -> Vec<u8> {
    (0..s.len() / 2)
        .filter_map(|i| u8::from_str_radix(s.get(2 * i..2 * i + 2)?, 16).ok())
        .collect()
}

fn read_json(name: &str) -> serde_json::Value {
    let text = std::fs::read_to_string(format!("{DATA}/{name}"))
        .unwrap_or_else(|e| panic!("{DATA}/{name}: {e}"));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{name}: {e}"))
}

/// Captures of the real bridges, from ../shared/data (other projects' output is not kept
/// in the repository): the seeds they give are left out, saying so, when it is absent.
fn read_shared_jsonl(name: &str) -> Vec<serde_json::Value> {
    let Some(path) =
        skyfuse_core::shared_data::shared_data(name, "fuzz bench (its real-bridge seeds)")
    else {
        return Vec::new();
    };
    std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

/// One fuzz target: its seeds and what it decodes (true: accepted).
/// A decoder and the real seeds its mutants start from.
struct Target {
    decoder: Decoder,
    seeds: Vec<Vec<u8>>,
}

fn ros_seeds(ros2: bool) -> Vec<(RosType, Vec<u8>)> {
    let v = read_json("ros_vectors.json");
    let mut out = vec![];
    for vec in v["vectors"].as_array().into_iter().flatten() {
        let Some(ty) = vec["type"].as_str().and_then(RosType::from_name) else {
            continue;
        };
        let keys: &[&str] = if ros2 {
            &["cdr_le", "cdr_be"]
        } else {
            &["ros1"]
        };
        for k in keys {
            if let Some(h) = vec[*k].as_str() {
                out.push((ty, hex(h)));
            }
        }
    }
    if ros2 {
        for s in read_shared_jsonl("bridges/ros2dds-samples.jsonl") {
            let ty = s["ros_type"].as_str().and_then(RosType::from_name);
            if let (Some(ty), Some(h)) = (ty, s["payload_hex"].as_str()) {
                out.push((ty, hex(h)));
            }
        }
    }
    out
}

fn targets() -> Vec<Target> {
    let ros = |ros2: bool| -> Vec<Vec<u8>> {
        ros_seeds(ros2)
            .iter()
            .map(|(ty, b)| {
                std::iter::once(Decoder::ros_type_byte(*ty))
                    .chain(b.iter().copied())
                    .collect()
            })
            .collect()
    };
    let mav_json: Vec<Vec<u8>> = read_shared_jsonl("bridges/mavlink-server-samples.jsonl")
        .iter()
        .filter_map(|s| s["payload"].as_str().map(|p| p.as_bytes().to_vec()))
        .chain(
            read_json("mavlink_vectors.json")["vectors"]
                .as_array()
                .into_iter()
                .flatten()
                .filter_map(|v| v["json"].as_str().map(|p| p.as_bytes().to_vec())),
        )
        .collect();
    let frames: Vec<Vec<u8>> = read_json("mavlink_vectors.json")["vectors"]
        .as_array()
        .into_iter()
        .flatten()
        .flat_map(|v| ["v2_hex", "v1_hex"].map(|k| v[k].as_str().map(hex)))
        .flatten()
        .collect();
    // Several frames per payload, as mavlink-server's raw keys carry them.
    let mut raw = frames.clone();
    for w in frames.windows(3) {
        raw.push(w.concat());
    }
    let config =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/default.toml"))
            .unwrap_or_default();
    let sitl: Vec<Vec<u8>> = [
        "skyfuse-gps.toml",
        "skyfuse-nogps.toml",
        "skyfuse-gps-raw.toml",
    ]
    .iter()
    .filter_map(|n| std::fs::read(format!("{DATA}/sitl/{n}")).ok())
    .collect();
    Decoder::ALL
        .into_iter()
        .map(|decoder| {
            let seeds = match decoder {
                Decoder::Ros2Cdr => ros(true),
                Decoder::Ros1 => ros(false),
                Decoder::MavlinkJson => mav_json.clone(),
                Decoder::MavlinkRaw => raw.clone(),
                Decoder::SkyfuseJson => skyfuse_json_seeds(),
                Decoder::ConfigToml => std::iter::once(config.clone().into_bytes())
                    .chain(sitl.iter().cloned())
                    .collect(),
                Decoder::WsClient => vec![
                    br#"{"type": "subscribe", "max_rate_hz": 5}"#.to_vec(),
                    br#"{"type":"subscribe","max_rate_hz":50.0}"#.to_vec(),
                ],
                Decoder::Mcap => mcap_seeds(),
                Decoder::Dataflash => dataflash_seeds(),
                Decoder::Timesync => timesync_seeds(),
                Decoder::Px4Msgs => px4_seeds(),
                Decoder::ControlBody => vec![
                    br#"{"sensor": "gps", "fault": "stop", "duration_s": 10}"#.to_vec(),
                    br#"{"sensor":"flow","fault":"dark-floor"}"#.to_vec(),
                    br#"{"sensor":"t265","fault":"clear"}"#.to_vec(),
                ],
            };
            Target { decoder, seeds }
        })
        .collect()
}

/// px4_msgs as rosbags and CycloneDDS wrote them from PX4's definitions (every type
/// and release, XCDR1, and XCDR2 as PX4 1.16's zenoh module sends it), each with the
/// prefix byte naming its type: once found from the payload, once named.
fn px4_seeds() -> Vec<Vec<u8>> {
    use skyfuse::codec::ros::px4::{Px4Type, Px4Version};
    let v = read_json("px4_vectors.json");
    let mut out = vec![];
    for vec in v["vectors"].as_array().into_iter().flatten() {
        let Some(ty) = vec["type"]
            .as_str()
            .and_then(|n| Px4Type::ALL.into_iter().find(|t| t.ros2_name() == n))
        else {
            continue;
        };
        let version = Px4Version::ALL
            .into_iter()
            .find(|r| vec["version"].as_str() == Some(r.as_str()));
        let mut add = |version, xcdr2, bytes: Vec<u8>| {
            out.push(
                std::iter::once(Decoder::px4_byte(ty, version, xcdr2))
                    .chain(bytes)
                    .collect(),
            );
        };
        if let Some(h) = vec["xcdr1"].as_str() {
            add(None, false, hex(h));
            add(version, false, hex(h));
        }
        if let Some(h) = vec["px4_zenoh_1_16"].as_str() {
            add(Some(Px4Version::V1_16), true, hex(h));
        }
    }
    out
}

/// TIMESYNC frames as an autopilot sends them: a request, an answer, both in one read;
/// and clock triples for the estimate.
fn timesync_seeds() -> Vec<Vec<u8>> {
    use mavlink::dialects::common::{MavMessage, TIMESYNC_DATA};
    let frame = |tc1: i64, ts1: i64| {
        let header = mavlink::MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: 7,
        };
        let msg = MavMessage::TIMESYNC(TIMESYNC_DATA {
            tc1,
            ts1,
            target_system: 0,
            target_component: 0,
        });
        skyfuse::codec::mavlink::encode_raw_v2(header, &msg).unwrap_or_default()
    };
    let request = frame(0, 1_000_000_000_123);
    let answer = frame(1_000_000_000_500, 1_700_000_000_000_000_000);
    // The same answer signed, as a link with signing required reads it.
    let signed = skyfuse::codec::mavlink::encode_raw_v2_signed(
        mavlink::MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: 8,
        },
        &MavMessage::TIMESYNC(TIMESYNC_DATA {
            tc1: 1_000_000_000_500,
            ts1: 1_700_000_000_000_000_000,
            target_system: 0,
            target_component: 0,
        }),
        &skyfuse::codec::mavlink::signing_data([7; 32], 1, false),
    )
    .unwrap_or_default();
    let triples: Vec<u8> = (0..8i64)
        .flat_map(|i| {
            let local = 1_700_000_000_000_000_000 + i * 500_000_000;
            [1_000_000_000 + i * 500_000_000, local, local + 300_000]
        })
        .flat_map(i64::to_le_bytes)
        .collect();
    vec![
        request.clone(),
        answer.clone(),
        [request, answer].concat(),
        signed,
        triples,
    ]
}

/// Short simulated flights as DataFlash logs (every record type the reader maps).
fn dataflash_seeds() -> Vec<Vec<u8>> {
    [0.2, 1.0]
        .into_iter()
        .map(|seconds| {
            let events =
                skyfuse::sim::Simulator::new(skyfuse::sim::sensors::DEMO_STREAMS, 3, seconds);
            let mut bytes = Vec::new();
            skyfuse::sim::dataflash::write_flight(events, &mut bytes).expect("in memory");
            bytes
        })
        .collect()
}

/// Small recordings as the recorder writes them (the Foxglove SDK's MCAP writer): a CDR
/// channel with its ros2msg schema and a JSON one, chunked with zstd or lz4, or not.
fn mcap_seeds() -> Vec<Vec<u8>> {
    use foxglove::{McapCompression, McapWriteOptions, PartialMetadata};
    let cdr: Vec<Vec<u8>> = ros_seeds(true)
        .into_iter()
        .map(|(_, b)| b)
        .take(6)
        .collect();
    let mut out = vec![];
    for (chunked, compression) in [
        (true, Some(McapCompression::Zstd)),
        (true, Some(McapCompression::Lz4)),
        (true, None),
        (false, None),
    ] {
        let ctx = foxglove::Context::new();
        let options = McapWriteOptions::new()
            .use_chunks(chunked)
            .chunk_size(Some(256))
            .compression(compression);
        let Ok(writer) = ctx
            .mcap_writer_with_options(options)
            .create(std::io::Cursor::new(Vec::new()))
        else {
            continue;
        };
        let imu = ctx
            .channel_builder("mavros/imu/data")
            .message_encoding("cdr")
            .schema(skyfuse::record::ros2msg::schema(RosType::Imu))
            .add_metadata(skyfuse::record::META_INPUT, "imu")
            .build_raw();
        let json = ctx
            .channel_builder("/skyfuse/events")
            .message_encoding("json")
            .build_raw();
        if let (Ok(imu), Ok(json)) = (imu, json) {
            for (i, b) in cdr.iter().enumerate() {
                let t = PartialMetadata {
                    log_time: Some(1_000_000 * i as u64),
                };
                imu.log_with_meta(b, t);
                json.log_with_meta(br#"{"kind":"health","message":"ok"}"#, t);
            }
        }
        if let Ok(cursor) = writer.close() {
            out.push(cursor.into_inner());
        }
    }
    out
}

/// skyfuse's own JSON, as the simulator publishes it: one sample of each kind.
fn skyfuse_json_seeds() -> Vec<Vec<u8>> {
    use skyfuse::sim::sensors::DEMO_STREAMS;
    use skyfuse::sim::Simulator;
    let mut seen = std::collections::BTreeSet::new();
    let mut out = vec![];
    for e in Simulator::new(DEMO_STREAMS, 1, 5.0) {
        let stream = &DEMO_STREAMS[e.stream];
        if !seen.insert(stream.input_id) {
            continue;
        }
        let mav = codec::MavIdentity {
            system_id: 1,
            component_id: 1,
            sequence: 0,
        };
        let t = (e.measured_t * 1e6) as i64;
        if let Ok(enc) = codec::encode_sample(Format::Json, None, t, &e.data, mav) {
            out.push(enc.payload);
        }
    }
    out
}

const INTERESTING: [u8; 10] = [0, 1, 0x7f, 0x80, 0xff, 0xfe, b'"', b'{', b'}', b'\\'];

fn mutate(rng: &mut SmallRng, seeds: &[Vec<u8>], buf: &mut Vec<u8>) {
    buf.clear();
    if rng.gen_ratio(1, 64) {
        let n = rng.gen_range(0..256);
        buf.extend((0..n).map(|_| rng.gen::<u8>()));
        return;
    }
    buf.extend_from_slice(&seeds[rng.gen_range(0..seeds.len())]);
    for _ in 0..rng.gen_range(1..=8) {
        let len = buf.len();
        match rng.gen_range(0..9) {
            0 if len > 0 => {
                let i = rng.gen_range(0..len);
                buf[i] ^= 1 << rng.gen_range(0..8);
            }
            1 if len > 0 => {
                let i = rng.gen_range(0..len);
                buf[i] = rng.gen();
            }
            2 if len > 0 => {
                let i = rng.gen_range(0..len);
                buf[i] = INTERESTING[rng.gen_range(0..INTERESTING.len())];
            }
            3 if len > 0 => buf.truncate(rng.gen_range(0..len)),
            4 => {
                let n = rng.gen_range(1..32);
                buf.extend((0..n).map(|_| rng.gen::<u8>()));
            }
            5 if len > 1 => {
                // Delete a run.
                let a = rng.gen_range(0..len);
                let b = rng.gen_range(a..len.min(a + 16) + 1).min(len);
                buf.drain(a..b);
            }
            6 if len > 1 => {
                // Duplicate a run in place.
                let a = rng.gen_range(0..len);
                let b = (a + rng.gen_range(1..16)).min(len);
                let run: Vec<u8> = buf[a..b].to_vec();
                let at = rng.gen_range(0..=buf.len());
                buf.splice(at..at, run);
            }
            7 => {
                // Splice: this seed's head, another seed's tail.
                let other = &seeds[rng.gen_range(0..seeds.len())];
                let cut = rng.gen_range(0..=len);
                let from = rng.gen_range(0..=other.len());
                buf.truncate(cut);
                buf.extend_from_slice(&other[from..]);
            }
            8 if len >= 4 => {
                // A 16- or 32-bit length/count field set to an extreme.
                let i = rng.gen_range(0..len - 3);
                let v: [u8; 4] = match rng.gen_range(0..4) {
                    0 => [0xff; 4],
                    1 => [0; 4],
                    2 => 0x7fff_ffffu32.to_le_bytes(),
                    _ => 0x8000_0000u32.to_be_bytes(),
                };
                buf[i..i + 4].copy_from_slice(&v);
            }
            _ => {}
        }
    }
}

fn rss_kib() -> u64 {
    std::fs::read_to_string("/proc/self/statm")
        .ok()
        .and_then(|s| s.split_whitespace().nth(1)?.parse::<u64>().ok())
        .map_or(0, |pages| pages * 4)
}

struct Outcome {
    inputs: u64,
    accepted: u64,
    panics: u64,
    first_panic: Option<Vec<u8>>,
    secs: f64,
    rss_before_kib: u64,
    rss_after_kib: u64,
}

fn run(target: &Target, iters: u64, seed: u64) -> Outcome {
    let mut rng = SmallRng::seed_from_u64(seed);
    let mut buf = Vec::with_capacity(4096);
    let (mut accepted, mut panics, mut first_panic) = (0, 0, None);
    // Warm up before measuring memory: the allocator's first arenas are not growth.
    for _ in 0..iters.min(10_000) {
        mutate(&mut rng, &target.seeds, &mut buf);
        let _ = catch_unwind(AssertUnwindSafe(|| target.decoder.decode(&buf)));
    }
    let rss_before_kib = rss_kib();
    let start = Instant::now();
    for _ in 0..iters {
        mutate(&mut rng, &target.seeds, &mut buf);
        match catch_unwind(AssertUnwindSafe(|| target.decoder.decode(&buf))) {
            Ok(true) => accepted += 1,
            Ok(false) => {}
            Err(_) => {
                panics += 1;
                first_panic.get_or_insert_with(|| buf.clone());
            }
        }
    }
    Outcome {
        inputs: iters,
        accepted,
        panics,
        first_panic,
        secs: start.elapsed().as_secs_f64(),
        rss_before_kib,
        rss_after_kib: rss_kib(),
    }
}

/// The seeds as a libFuzzer corpus: one file per seed under `dir/<target>/`.
fn write_seeds(dir: &std::path::Path) {
    for t in targets() {
        let sub = dir.join(t.decoder.name());
        if let Err(e) = std::fs::create_dir_all(&sub) {
            panic!("cannot create {}: {e}", sub.display());
        }
        for (i, seed) in t.seeds.iter().enumerate() {
            let path = sub.join(format!("seed-{i:03}"));
            if let Err(e) = std::fs::write(&path, seed) {
                panic!("cannot write {}: {e}", path.display());
            }
        }
        println!(
            "{:<14} {:>4} seeds → {}",
            t.decoder.name(),
            t.seeds.len(),
            sub.display()
        );
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let bench = args.iter().any(|a| a == "--bench");
    let iters = args
        .iter()
        .position(|a| a == "--iters")
        .and_then(|i| args.get(i + 1)?.parse().ok())
        .unwrap_or(if bench { 10_000_000 } else { 20_000 });
    let value = |flag: &str| {
        let i = args.iter().position(|a| a == flag)?;
        args.get(i + 1)
    };
    if let Some(dir) = value("--write-seeds") {
        write_seeds(std::path::Path::new(dir));
        return;
    }
    // The one positional argument: a target name (not a flag, nor a flag's value).
    let only = args
        .iter()
        .enumerate()
        .skip(1)
        .find(|(i, a)| !a.starts_with('-') && !matches!(args[i - 1].as_str(), "--iters"))
        .map(|(_, a)| a);
    // Panics are caught and counted; their messages would flood the output.
    let quiet = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    println!(
        "target          seeds      inputs   accepted  panics   inputs/s  RSS before→after KiB"
    );
    let mut failed = vec![];
    for t in targets() {
        if only.is_some_and(|o| o != t.decoder.name()) {
            continue;
        }
        assert!(!t.seeds.is_empty(), "{}: no seeds read", t.decoder.name());
        let o = run(&t, iters, 0x5eed);
        println!(
            "{:<14} {:>6} {:>11} {:>10} {:>7} {:>10.0}   {} → {}",
            t.decoder.name(),
            t.seeds.len(),
            o.inputs,
            o.accepted,
            o.panics,
            o.inputs as f64 / o.secs,
            o.rss_before_kib,
            o.rss_after_kib
        );
        if let Some(p) = o.first_panic {
            failed.push(format!(
                "{}: {} panics, first on {:02x?}",
                t.decoder.name(),
                o.panics,
                p
            ));
        }
        // Every target must accept some of its mutants (else the seeds or the harness are
        // wrong and nothing deep is reached) and reject some.
        if o.accepted == 0 || o.accepted == o.inputs {
            failed.push(format!(
                "{}: accepted {} of {}",
                t.decoder.name(),
                o.accepted,
                o.inputs
            ));
        }
    }
    std::panic::set_hook(quiet);
    assert!(failed.is_empty(), "{}", failed.join("\n"));
}
