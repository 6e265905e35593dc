//! Throughput benchmark (a bench binary, `cargo bench --bench throughput`):
//! - decode rate per wire format and message (samples/s), payloads made by our encoders
//!   from simulated samples (the encoders are round-trip tested against rosbags and
//!   pymavlink);
//! - estimator cost per sample kind (IMU prediction, each update) over a simulated flight;
//! - the bank of filters against the main filter alone, per sample;
//! - whole-run throughput (samples/s) of a simulated scenario and of the real PX4 flight
//!   replay, through the same `Fusion` core the service runs.
//!
//! Every figure is the median of 7 repetitions; the spread (min–max) is printed beside it.

use skyfuse::codec::{self, Format, MavIdentity, RosType};
use skyfuse::estimator::EstimatorConfig;
use skyfuse::fusion::Fusion;
use skyfuse::health::HealthConfig;
use skyfuse::sample::{Decoded, Sample, SensorData, SensorKind};
use skyfuse::sim::sensors::{StreamSpec, DEMO_STREAMS};
use skyfuse::sim::Simulator;
use std::collections::BTreeMap;
use std::hint::black_box;
use std::time::Instant;

const REPS: usize = 7;

fn median(mut v: Vec<f64>) -> (f64, f64, f64) {
    v.sort_by(f64::total_cmp);
    (v[v.len() / 2], v[0], v[v.len() - 1])
}

/// One simulated sample of each kind (taken mid-flight).
fn sample_of(kind: SensorKind) -> SensorData {
    Simulator::new(DEMO_STREAMS, 1, 40.0)
        .skip_while(|e| e.measured_t < 30.0)
        .find(|e| e.data.kind() == kind)
        .map(|e| e.data)
        .expect("the simulator has every kind")
}

fn decode_bench() {
    println!("## Decode throughput (samples/s, median of {REPS}; min–max)\n");
    println!("| format | message | bytes | samples/s | spread |");
    println!("|---|---|---|---|---|");
    let cases: Vec<(Format, Option<RosType>, SensorKind, &str)> = vec![
        (
            Format::Ros2,
            Some(RosType::Imu),
            SensorKind::Imu,
            "sensor_msgs/Imu",
        ),
        (
            Format::Ros2,
            Some(RosType::NavSatFix),
            SensorKind::Gnss,
            "sensor_msgs/NavSatFix",
        ),
        (
            Format::Ros2,
            Some(RosType::Odometry),
            SensorKind::Odometry,
            "nav_msgs/Odometry",
        ),
        (
            Format::Ros2,
            Some(RosType::FlowTof),
            SensorKind::Flow,
            "skyfuse_msgs/FlowTof",
        ),
        (
            Format::Ros1,
            Some(RosType::Imu),
            SensorKind::Imu,
            "sensor_msgs/Imu",
        ),
        (
            Format::Ros1,
            Some(RosType::Odometry),
            SensorKind::Odometry,
            "nav_msgs/Odometry",
        ),
        (Format::MavlinkJson, None, SensorKind::Imu, "HIGHRES_IMU"),
        (
            Format::MavlinkJson,
            None,
            SensorKind::Flow,
            "OPTICAL_FLOW_RAD",
        ),
        (
            Format::MavlinkJson,
            None,
            SensorKind::Attitude,
            "ATTITUDE_QUATERNION",
        ),
        (Format::MavlinkRaw, None, SensorKind::Imu, "HIGHRES_IMU"),
        (
            Format::MavlinkRaw,
            None,
            SensorKind::Flow,
            "OPTICAL_FLOW_RAD",
        ),
        (Format::Json, None, SensorKind::Imu, "imu"),
        (Format::Json, None, SensorKind::Odometry, "odometry"),
    ];
    let mav = MavIdentity {
        system_id: 1,
        component_id: 1,
        sequence: 7,
    };
    for (format, ty, kind, name) in cases {
        let data = sample_of(kind);
        // ROS stamps are wall-clock; MAVLink's are time since the autopilot booted.
        let stamp = match format {
            Format::MavlinkJson | Format::MavlinkRaw => 123_456_000,
            _ => 1_700_000_000_000_000,
        };
        let enc = match codec::encode_sample(format, ty, stamp, &data, mav) {
            Ok(e) => e,
            Err(e) => {
                println!(
                    "| {} | {name} | – | cannot encode: {e} | |",
                    format.as_str()
                );
                continue;
            }
        };
        let payload = enc.payload;
        let mut out: Vec<Decoded> = Vec::with_capacity(4);
        let n = 20_000;
        let rates: Vec<f64> = (0..REPS)
            .map(|_| {
                let t = Instant::now();
                for _ in 0..n {
                    out.clear();
                    let r = codec::decode(format, ty, black_box(&payload), &mut out);
                    black_box(&r);
                }
                n as f64 / t.elapsed().as_secs_f64()
            })
            .collect();
        let (m, lo, hi) = median(rates);
        println!(
            "| {} | {name} | {} | {:.0} | {:.0}–{:.0} |",
            format.as_str(),
            payload.len(),
            m,
            lo,
            hi
        );
    }
    println!();
}

fn inputs_of(streams: &[skyfuse::sim::sensors::StreamSpec]) -> skyfuse::fusion::InputList {
    streams
        .iter()
        .map(|s| skyfuse::fusion::InputSpec::new(s.input_id, s.kind, s.rate_hz))
        .collect()
}

fn sim_samples(streams: &[StreamSpec], duration_s: f64) -> Vec<Sample> {
    Simulator::new(streams, 1, duration_s)
        .map(|e| Sample {
            source: streams[e.stream].input_id.into(),
            stamp_us: Some((e.measured_t * 1e6) as i64),
            arrival_us: (e.publish_t * 1e6) as i64,
            data: e.data,
        })
        .collect()
}

/// The samples in the order the filter fuses them (host time as the estimator maps it,
/// prediction inputs first at equal times). Fed so, nothing waits for the horizon and
/// each arrival fuses exactly itself: this prices what fusing each kind costs.
fn fusion_order(samples: &[Sample], cfg: &EstimatorConfig) -> Vec<Sample> {
    let mut clocks = skyfuse::estimator::timing::SourceClocks::default();
    let mut keyed: Vec<(i64, u8, usize)> = samples
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let t = clocks.host_time(cfg, s);
            (t, skyfuse::estimator::rank(s.data.kind()), i)
        })
        .collect();
    keyed.sort();
    keyed
        .into_iter()
        .map(|(_, _, i)| samples[i].clone())
        .collect()
}

/// µs per sample by kind, median over `REPS` runs; and samples/s of the whole run.
fn cost_per_kind(
    streams: &[StreamSpec],
    samples: &[Sample],
) -> (BTreeMap<&'static str, Vec<f64>>, Vec<f64>) {
    let mut per_kind: BTreeMap<&'static str, Vec<f64>> = BTreeMap::new();
    let mut totals = Vec::new();
    for _ in 0..REPS {
        let mut f = Fusion::new(
            EstimatorConfig::default(),
            HealthConfig::default(),
            &inputs_of(streams),
        );
        let mut sums: BTreeMap<&'static str, (f64, usize)> = BTreeMap::new();
        let t0 = Instant::now();
        for s in samples {
            let t = Instant::now();
            black_box(f.process(s, s.arrival_us));
            let e = sums.entry(s.data.kind().as_str()).or_default();
            e.0 += t.elapsed().as_secs_f64();
            e.1 += 1;
        }
        totals.push(samples.len() as f64 / t0.elapsed().as_secs_f64());
        for (k, (sum, n)) in sums {
            per_kind.entry(k).or_default().push(sum / n as f64 * 1e6);
        }
    }
    (per_kind, totals)
}

/// Per-kind cost over `SIM_SECONDS` of the demo flight on `streams`: fed in fusion order
/// (*fusing it*) and as published (*on arrival*), with samples/s of the latter.
struct FlightCosts {
    samples: usize,
    fusing: BTreeMap<&'static str, Vec<f64>>,
    arrival: BTreeMap<&'static str, Vec<f64>>,
    totals: Vec<f64>,
}

const SIM_SECONDS: f64 = 140.0;

fn flight_costs(streams: &[StreamSpec]) -> FlightCosts {
    let samples = sim_samples(streams, SIM_SECONDS);
    let (fusing, _) = cost_per_kind(
        streams,
        &fusion_order(&samples, &EstimatorConfig::default()),
    );
    let (arrival, totals) = cost_per_kind(streams, &samples);
    FlightCosts {
        samples: samples.len(),
        fusing,
        arrival,
        totals,
    }
}

impl FlightCosts {
    /// The whole flight as published: samples/s and its speed against real time.
    fn print_as_published(self, what: &str) {
        let (m, lo, hi) = median(self.totals);
        println!(
            "\n{what}: {} samples, {m:.0} samples/s ({lo:.0}–{hi:.0}), {:.0}× real time.\n",
            self.samples,
            m / (self.samples as f64 / SIM_SECONDS)
        );
    }
}

fn estimator_bench() {
    println!("## Estimator cost per sample (µs, `Fusion::process`: checks + estimator + health; median of {REPS} runs of 140 s of the demo flight)\n");
    println!("*Fusing it*: the samples fed in the order the filter fuses them, so each call fuses");
    println!(
        "exactly its own sample. *On arrival*: fed as published (the GNSS fix 100 ms after the"
    );
    println!("IMU of the same moment): a call fuses whatever its arrival moved past the horizon,");
    println!("so the IMU, the newest sample most of the time, carries the others' fusing.\n");
    let costs = flight_costs(DEMO_STREAMS);
    println!("| sample kind (what fusing it does) | fusing it | spread | on arrival | spread |");
    println!("|---|---|---|---|---|");
    let what = |k: &str| match k {
        "imu" => "imu (EKF prediction)",
        "attitude" => "attitude (attitude update)",
        "gnss" => "gnss (position + velocity update)",
        "odometry" => "odometry (position + velocity update)",
        "flow" => "flow (compensation + velocity update)",
        "range" => "range (height update)",
        _ => "other",
    };
    for (k, v) in &costs.fusing {
        let (m, lo, hi) = median(v.clone());
        let (am, alo, ahi) = costs
            .arrival
            .get(k)
            .cloned()
            .map_or((0.0, 0.0, 0.0), median);
        println!(
            "| {} | {m:.2} | {lo:.2}–{hi:.2} | {am:.2} | {alo:.2}–{ahi:.2} |",
            what(k)
        );
    }
    costs.print_as_published("Whole simulated flight as published");
}

/// The bank of filters (issue 44): the demo flight as published, fused by the main
/// filter alone (`[integrity] enabled = false`: no sub-filters) and by the bank (one
/// sub-filter per aiding source beside it), samples/s median of `REPS` each, the same
/// samples; the cost ratio is per sample.
fn bank_bench() {
    let samples = sim_samples(DEMO_STREAMS, SIM_SECONDS);
    let rate = |enabled: bool| {
        let mut cfg = EstimatorConfig::default();
        cfg.integrity.enabled = enabled;
        let mut rates = Vec::new();
        let mut subs = 0;
        for _ in 0..REPS {
            let mut f = Fusion::new(
                cfg.clone(),
                HealthConfig::default(),
                &inputs_of(DEMO_STREAMS),
            );
            let t0 = Instant::now();
            for s in &samples {
                black_box(f.process(s, s.arrival_us));
            }
            rates.push(samples.len() as f64 / t0.elapsed().as_secs_f64());
            subs = f.est.state_summary().integrity.tests.len();
        }
        (median(rates), subs)
    };
    let ((single, slo, shi), _) = rate(false);
    let ((bank, blo, bhi), subs) = rate(true);
    println!(
        "## The bank of filters: the demo flight as published ({} samples, median of {REPS})\n",
        samples.len()
    );
    println!("| estimator | samples/s | spread | µs per sample |");
    println!("|---|---|---|---|");
    println!(
        "| main filter alone | {single:.0} | {slo:.0}–{shi:.0} | {:.2} |",
        1e6 / single
    );
    println!(
        "| bank: main + {subs} sub-filters | {bank:.0} | {blo:.0}–{bhi:.0} | {:.2} |",
        1e6 / bank
    );
    println!(
        "\nThe bank costs {:.2}× the main filter alone per sample.\n",
        single / bank
    );
}

/// The demo flight with its IMU at 1 kHz (a flight controller's full rate): the IMU is
/// then three quarters of the samples, so this prices what a high-rate log costs.
fn imu_1khz_bench() {
    let costs = flight_costs(&skyfuse::sim::sensors::with_imu_rate(DEMO_STREAMS, 1000.0));
    println!("## The demo flight with a 1 kHz IMU (µs per sample, fusing it; median of {REPS})\n");
    println!("| sample kind | fusing it | spread |");
    println!("|---|---|---|");
    for (k, v) in &costs.fusing {
        let (m, lo, hi) = median(v.clone());
        println!("| {k} | {m:.2} | {lo:.2}–{hi:.2} |");
    }
    costs.print_as_published("As published");
}

/// `skyfuse replay` of a simulated PX4 ULog with a 1 kHz IMU, the whole command as a
/// user runs it (reading, the estimator and health, the evaluation, every output file),
/// after `skyfuse sim --ulog` wrote the log: samples per second end to end, median of 3.
fn ulog_replay_bench() {
    let bin = env!("CARGO_BIN_EXE_skyfuse");
    let dir = std::env::temp_dir().join(format!("skyfuse-ulog-bench-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    println!("## `skyfuse replay` of a 1 kHz ULog, end to end (median of {ULOG_REPS}; min–max)\n");
    println!("| log | samples | s | samples/s |");
    println!("|---|---|---|---|");
    for (scenario, seconds) in [("outdoor", 600), ("demo", 600)] {
        let log = dir.join(format!("{scenario}.ulg"));
        let wrote = std::process::Command::new(bin)
            .args(["sim", "--ulog"])
            .arg(&log)
            .args(["--scenario", scenario, "--imu-hz", "1000", "--duration"])
            .arg(seconds.to_string())
            .output();
        let Some(line) = wrote.ok().filter(|o| o.status.success()).and_then(|o| {
            String::from_utf8_lossy(&o.stdout)
                .lines()
                .find(|l| l.starts_with("wrote "))
                .map(str::to_string)
        }) else {
            println!("| {scenario} | (sim --ulog failed) | | |");
            continue;
        };
        // "wrote FILE (N messages, ...": every message is a sample.
        let samples: f64 = line
            .split('(')
            .nth(1)
            .and_then(|r| r.split_whitespace().next())
            .and_then(|n| n.parse().ok())
            .unwrap_or(f64::NAN);
        let mut times = Vec::new();
        for _ in 0..ULOG_REPS {
            let t = Instant::now();
            let ok = std::process::Command::new(bin)
                .arg("replay")
                .arg(&log)
                .arg("--out")
                .arg(dir.join(scenario))
                .output()
                .is_ok_and(|o| o.status.success());
            if ok {
                times.push(t.elapsed().as_secs_f64());
            }
        }
        if times.is_empty() {
            println!("| {scenario} | (replay failed) | | |");
            continue;
        }
        let (m, lo, hi) = median(times);
        println!(
            "| {scenario}, {seconds} s | {samples:.0} | {m:.2} ({lo:.2}–{hi:.2}) | {:.0} |",
            samples / m
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
    println!();
}

const ULOG_REPS: usize = 3;

fn replay_bench() {
    let Some(dir) =
        skyfuse_core::shared_data::shared_data("px4-flow-vio-7c824ee5", "throughput replay_bench")
    else {
        println!("(PX4 replay skipped: ../shared/data/px4-flow-vio-7c824ee5 is absent)");
        return;
    };
    let t = Instant::now();
    let log = match skyfuse::replay::px4log::read_dir(&dir) {
        Ok(l) => l,
        Err(e) => {
            println!("(PX4 replay skipped: {e})");
            return;
        }
    };
    let read_s = t.elapsed().as_secs_f64();
    let mut rates = Vec::new();
    for _ in 0..REPS {
        let mut cfg = EstimatorConfig::default();
        for id in [
            "flow_1",
            "range_1",
            "vio",
            "imu",
            "imu_1",
            "attitude_states",
        ] {
            cfg.sources.entry(id.into()).or_default().fuse = false;
        }
        let inputs: skyfuse::fusion::InputList = vec![
            skyfuse::fusion::InputSpec::new("flow", SensorKind::Flow, 60.0),
            skyfuse::fusion::InputSpec::new("range", SensorKind::Range, 50.0),
            skyfuse::fusion::InputSpec::new("attitude", SensorKind::Attitude, 10.0),
        ];
        let mut f = Fusion::new(cfg, HealthConfig::default(), &inputs);
        let t0 = Instant::now();
        for s in &log.samples {
            black_box(f.process(s, s.arrival_us));
        }
        rates.push(log.samples.len() as f64 / t0.elapsed().as_secs_f64());
    }
    let (m, lo, hi) = median(rates);
    println!(
        "## Real PX4 flight replay (307 s, {} samples)\n",
        log.samples.len()
    );
    let n = log.samples.len() as f64;
    println!(
        "CSV read: {read_s:.3} s. Fusion (flow + range + attitude): {m:.0} samples/s ({lo:.0}–{hi:.0}). Read and fused: {:.0} samples/s.\n",
        n / (read_s + n / m)
    );
}

/// The whole ingest path of one ROS 2 sample (`Ingest::accept`: counters, the announced
/// type looked up in the bridge-topic table, decode, validation, time checks), with the
/// table empty and holding 100 bridge topics, beside the bare decode of the same bytes.
fn ingest_bench() {
    use skyfuse::ingest::Ingest;
    use skyfuse::ros_graph::TopicEntry;
    println!("## Ingest path, ROS 2 sensor_msgs/Imu (samples/s, median of {REPS}; min–max)\n");
    println!("| path | samples/s | spread |");
    println!("|---|---|---|");
    let config = skyfuse::config::Config::load(None, Vec::new()).expect("default config");
    let mav = MavIdentity {
        system_id: 1,
        component_id: 1,
        sequence: 0,
    };
    let data = sample_of(SensorKind::Imu);
    let n = 20_000;
    // Stamps must increase (time going backwards is rejected): one payload per call.
    let payloads: Vec<Vec<u8>> = (0..n * REPS as i64)
        .map(|i| {
            let stamp = 1_700_000_000_000_000 + i * 5_000;
            codec::encode_sample(Format::Ros2, Some(RosType::Imu), stamp, &data, mav)
                .expect("encode")
                .payload
        })
        .collect();
    // One repetition per chunk of fresh payloads: samples/s, median and spread. `f`
    // gets each payload's index in the whole run.
    let per_chunk = |f: &mut dyn FnMut(usize, &[u8])| {
        median(
            payloads
                .chunks(n as usize)
                .enumerate()
                .map(|(c, chunk)| {
                    let t = Instant::now();
                    for (i, p) in chunk.iter().enumerate() {
                        f(c * n as usize + i, black_box(p));
                    }
                    chunk.len() as f64 / t.elapsed().as_secs_f64()
                })
                .collect(),
        )
    };
    let mut out: Vec<Decoded> = Vec::with_capacity(4);
    let decode = per_chunk(&mut |_, p| {
        out.clear();
        black_box(codec::decode(Format::Ros2, Some(RosType::Imu), p, &mut out).is_ok());
    });
    let mut rows = vec![("bare decode".to_string(), decode)];
    for topics in [0usize, 100] {
        let ingest = Ingest::new(&config);
        {
            let mut t = skyfuse::sync::lock(&ingest.ros_topics);
            for k in 0..topics {
                let key = if k == topics - 1 {
                    "mavros/imu/data".to_string()
                } else {
                    format!("robot{k}/some/topic")
                };
                let entry = TopicEntry {
                    key: key.clone(),
                    topic: format!("/{key}"),
                    ros_type: "sensor_msgs/msg/Imu".into(),
                    qos: ":1::0,10".into(),
                    zid: format!("{k:032x}"),
                    alive: true,
                    since_us: 0,
                };
                t.insert((entry.zid.clone(), key), entry);
            }
        }
        let input = ingest
            .inputs
            .iter()
            .find(|i| i.config.id == "imu")
            .expect("imu input")
            .clone();
        // Arriving at the pace of their stamps: ingest refuses a sensor clock that
        // runs faster than the host's (a restart or a wrong unit).
        let rates = per_chunk(&mut |i, p| {
            black_box(ingest.accept(&input, "mavros/imu/data", p, i as i64 * 5_000));
        });
        let accepted = input
            .counters
            .accepted
            .load(std::sync::atomic::Ordering::Relaxed);
        assert_eq!(accepted, (n * REPS as i64) as u64, "every sample accepted");
        rows.push((format!("Ingest::accept, {topics} bridge topics"), rates));
    }
    for (name, (m, lo, hi)) in rows {
        println!("| {name} | {m:.0} | {lo:.0}–{hi:.0} |");
    }
    println!();
}

fn main() {
    // `cargo test --benches` runs bench binaries with --bench absent: keep it quick.
    let quick = !std::env::args().any(|a| a == "--bench");
    if quick {
        println!("(quick mode: run with `cargo bench --bench throughput` for figures)");
        return;
    }
    // `cargo bench --bench throughput -- ingest` runs one section.
    let only = std::env::args().skip(1).find(|a| !a.starts_with('-'));
    let sections: [(&str, fn()); 7] = [
        ("decode", decode_bench),
        ("ingest", ingest_bench),
        ("estimator", estimator_bench),
        ("bank", bank_bench),
        ("imu1k", imu_1khz_bench),
        ("replay", replay_bench),
        ("ulog", ulog_replay_bench),
    ];
    for (name, run) in sections {
        if only.as_deref().is_none_or(|o| o == name) {
            run();
        }
    }
}
