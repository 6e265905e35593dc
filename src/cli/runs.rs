//! The offline commands: `sim` scenario runs and `replay` of recorded flights, with
//! progress bars on a terminal and the scores printed as a table.

use super::*;
use crate::replay::px4log;

pub(super) fn parse_window(s: &str) -> Result<(f64, f64), String> {
    let (a, b) = s
        .split_once(':')
        .ok_or_else(|| format!("window {s:?}: expected START:END in seconds"))?;
    let a: f64 = a
        .trim()
        .parse()
        .map_err(|_| format!("window start {a:?} is not a number"))?;
    let b: f64 = b
        .trim()
        .parse()
        .map_err(|_| format!("window end {b:?} is not a number"))?;
    if !(a.is_finite() && b.is_finite() && b > a) {
        return Err(format!("window {s:?}: END must be after START"));
    }
    Ok((a, b))
}

pub(super) fn parse_fusion(s: &str) -> Result<Vec<Mode>, String> {
    match s {
        "all" => Ok(vec![Mode::Wrls, Mode::Ekf, Mode::WrlsEkf]),
        "wrls" => Ok(vec![Mode::Wrls]),
        "ekf" => Ok(vec![Mode::Ekf]),
        "wrls+ekf" => Ok(vec![Mode::WrlsEkf]),
        other => Err(format!(
            "unknown fusion mode {other:?} (wrls, ekf, wrls+ekf or all)"
        )),
    }
}

/// A progress bar on stderr: redrawn in place on a terminal, every 10 % otherwise.
pub struct Progress {
    label: String,
    tty: bool,
    last_shown: i64,
}

impl Progress {
    pub fn new(label: impl Into<String>) -> Self {
        use std::io::IsTerminal;
        Self {
            label: label.into(),
            tty: std::io::stderr().is_terminal(),
            last_shown: -1,
        }
    }

    pub fn update(&mut self, fraction: f64) {
        let pct = (fraction.clamp(0.0, 1.0) * 100.0) as i64;
        let step = if self.tty { 1 } else { 10 };
        if pct / step == self.last_shown / step && pct != 100 || pct == self.last_shown {
            return;
        }
        self.last_shown = pct;
        let filled = (pct / 4) as usize;
        let bar = format!("{}{}", "#".repeat(filled), "-".repeat(25 - filled));
        if self.tty {
            eprint!("\r{} [{bar}] {pct:>3}%", self.label);
            if pct == 100 {
                eprintln!();
            }
        } else {
            eprintln!("{} [{bar}] {pct:>3}%", self.label);
        }
    }
}

pub(super) fn fmt_rmse(v: Option<f64>) -> String {
    v.map(|x| format!("{x:.3}")).unwrap_or_else(|| "-".into())
}

/// One row of the scenario table: name, each source's APE RMSE, fused per mode.
type ScenarioRow = (String, Vec<(String, Option<f64>)>, Vec<Option<f64>>);

/// `--imu-hz`: a rate the simulator can run (1 Hz to 10 kHz).
fn checked_imu_hz(hz: f64) -> Result<f64, String> {
    if hz.is_finite() && (1.0..=10_000.0).contains(&hz) {
        Ok(hz)
    } else {
        Err(format!("--imu-hz {hz}: must be between 1 and 10000 Hz"))
    }
}

/// The scenario `name`, with its IMU at `imu_hz` if given.
pub(super) fn scenario_at(name: &str, imu_hz: Option<f64>) -> Result<scenario::Scenario, String> {
    let mut scn = scenario::scenario(name)
        .ok_or_else(|| format!("unknown scenario {name:?} (see --list)"))?;
    if let Some(hz) = imu_hz.map(checked_imu_hz).transpose()? {
        scn.streams = crate::sim::sensors::with_imu_rate(&scn.streams, hz);
    }
    Ok(scn)
}

/// The flight-log format `skyfuse sim` writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum SimLog {
    /// `--ulog`: PX4's ULog.
    Ulog,
    /// `--dataflash`: ArduPilot's DataFlash `.bin`.
    Dataflash,
}

/// `skyfuse sim --ulog FILE` / `--dataflash FILE`: one scenario's sensor samples as a
/// flight log.
pub(super) fn sim_log(
    scenario_name: &str,
    seed: u64,
    duration: Option<f64>,
    imu_hz: Option<f64>,
    file: &std::path::Path,
    format: SimLog,
) -> Result<(), String> {
    let scn = scenario_at(scenario_name, imu_hz)?;
    let duration = duration.unwrap_or_else(|| scn.default_duration_s());
    let sim = scn.simulator(seed, duration);
    let out = std::fs::File::create(file)
        .map_err(|e| format!("cannot create {}: {e}", file.display()))?;
    let mut bar = Progress::new("writing  ");
    let events = sim.inspect(|e| bar.update(e.measured_t / duration));
    let out = std::io::BufWriter::new(out);
    let written = match format {
        SimLog::Ulog => crate::sim::ulog::write_flight(events, out).map(|s| (s.messages, s.bytes)),
        SimLog::Dataflash => {
            crate::sim::dataflash::write_flight(events, out).map(|s| (s.records, s.bytes))
        }
    };
    let (messages, bytes) = written.map_err(|e| format!("writing {}: {e}", file.display()))?;
    println!(
        "wrote {} ({messages} messages, {:.1} MB, {duration} s of scenario {scenario_name})",
        file.display(),
        bytes as f64 / 1e6
    );
    Ok(())
}

/// `skyfuse sim --out`: one or all scenarios, one or all fusion modes.
pub(super) fn offline_sims(
    c: &Config,
    scenario_name: &str,
    fusion: Option<&str>,
    seed: u64,
    duration: Option<f64>,
    imu_hz: Option<f64>,
    out: &std::path::Path,
) -> Result<(), String> {
    let names: Vec<&str> = if scenario_name == "all" {
        scenario::NAMES.iter().map(|(n, _)| *n).collect()
    } else {
        vec![scenario_name]
    };
    let modes = match fusion {
        Some(f) => parse_fusion(f)?,
        None => vec![c.estimator.mode],
    };
    let many = names.len() > 1 || modes.len() > 1;
    // scenario -> (source scores from the first mode, fused score per mode)
    let mut table: Vec<ScenarioRow> = Vec::new();
    for name in &names {
        let scn = scenario_at(name, imu_hz)?;
        let duration = duration.unwrap_or_else(|| scn.default_duration_s());
        let mut sources = Vec::new();
        let mut fused = Vec::new();
        for m in &modes {
            let mut cfg = c.estimator.clone();
            cfg.mode = *m;
            let dir = if many {
                out.join(name).join(m.as_str())
            } else {
                out.to_path_buf()
            };
            let mut bar = Progress::new(format!("{name:<16} {:<8}", m.as_str()));
            let summary = offline::run_scenario(
                &scn,
                seed,
                duration,
                cfg,
                c.health.clone(),
                &dir,
                &mut |f| bar.update(f),
            )
            .map_err(|e| e.to_string())?;
            if sources.is_empty() {
                sources = summary
                    .scores
                    .iter()
                    .filter(|s| s.name != "fused")
                    .map(|s| (s.name.clone(), s.ape.as_ref().map(|a| a.rmse)))
                    .collect();
            }
            let (f, best) = summary.fused_and_best_source();
            tracing::info!(
                scenario = name,
                mode = m.as_str(),
                fused_rmse_m = fmt_rmse(f),
                best_source = best.as_ref().map(|b| format!("{} {:.3}", b.0, b.1)).unwrap_or_default(),
                events = summary.events,
                out = %dir.display(),
                "offline run done"
            );
            print_consistency(&summary);
            fused.push(f);
        }
        table.push((name.to_string(), sources, fused));
    }
    let mut md = String::from(
        "APE RMSE against truth, m (SE(3)-aligned as `evo_ape -a`); sources as the sensors report them\n\n| scenario | sources | ",
    );
    md += &modes
        .iter()
        .map(|m| m.as_str())
        .collect::<Vec<_>>()
        .join(" | ");
    md += " |\n|---|---|";
    md += &"---|".repeat(modes.len());
    md += "\n";
    for (name, sources, fused) in &table {
        let src = sources
            .iter()
            .map(|(n, r)| format!("{n} {}", fmt_rmse(*r)))
            .collect::<Vec<_>>()
            .join(", ");
        md += &format!(
            "| {name} | {src} | {} |\n",
            fused
                .iter()
                .map(|f| fmt_rmse(*f))
                .collect::<Vec<_>>()
                .join(" | ")
        );
    }
    print!("{md}");
    if many {
        std::fs::write(out.join("table.md"), &md)
            .map_err(|e| format!("cannot write {}: {e}", out.join("table.md").display()))?;
    }
    Ok(())
}

/// A flight log loaded for replay: its samples (or a ULog streamed as the replay reaches
/// them), the files' time zero, the poses sent live (a skyfuse recording) and the
/// config the recording was made with.
pub(super) struct Flight {
    samples: Vec<crate::sample::Sample>,
    streamed: Option<px4log::UlogSamples>,
    t0_us: Option<i64>,
    live_poses: Vec<(i64, [f64; 3], bool)>,
    config: Config,
}

impl Flight {
    pub(super) fn source(&self) -> &dyn offline::SampleSource {
        match &self.streamed {
            Some(log) => log,
            None => &self.samples,
        }
    }

    pub(super) fn t0_us(&self) -> Option<i64> {
        self.t0_us
    }

    pub(super) fn config(&self) -> &Config {
        &self.config
    }

    /// What a streamed ULog's topics gave, once the replay has read them.
    pub(super) fn report_streamed(&self) {
        if let Some(log) = &self.streamed {
            report_px4_read(&log.take_topics(), &log.stand_ins(), &log.missing);
        }
    }
}

/// Reads the flight log at `path` (any format `skyfuse replay` takes).
pub(super) fn load_flight(c: &Config, path: &std::path::Path) -> Result<Flight, String> {
    let mut bar = Progress::new("reading  ");
    let mut on_progress = |done: u64, total: u64| bar.update(done as f64 / total.max(1) as f64);
    let name = path.to_string_lossy().to_ascii_lowercase();
    let is_tlog = name.ends_with(".tlog") || name.ends_with(".tlog.gz");
    let is_dataflash = path.is_file() && (name.ends_with(".bin") || starts_as_dataflash(path));
    let mut t0_us = None;
    let mut live_poses = Vec::new();
    let mut streamed = None;
    let mut c = c.clone();
    let samples = if let Some(file) = mcap_file(path)? {
        let log =
            crate::replay::mcap::read_mcap(&file, &mut on_progress).map_err(|e| e.to_string())?;
        if let Some(t) = &log.truncated {
            tracing::warn!(file = %file.display(), "the file is cut short (not finished?): {t}");
        }
        let replay = crate::record::replay::samples(&c, &log);
        for ch in &replay.channels {
            match &ch.skipped {
                Some(why) => {
                    tracing::info!(topic = %ch.topic, messages = ch.messages, "not replayed: {why}")
                }
                None => {
                    tracing::info!(topic = %ch.topic, messages = ch.messages, inputs = ?ch.inputs, "replayed")
                }
            }
        }
        for st in replay.ingest.statuses(0) {
            if st.received > 0 && st.rejected > 0 {
                tracing::warn!(
                    input = %st.id,
                    received = st.received,
                    rejected = st.rejected,
                    "rejected at ingest, as live; last: {}",
                    st.last_error.as_deref().unwrap_or("-")
                );
            }
        }
        t0_us = replay.t0_us;
        live_poses = replay.live_poses;
        c = replay.config;
        replay.samples
    } else if is_dataflash {
        let log = crate::replay::dataflash::read_dataflash(path, &mut on_progress)
            .map_err(|e| e.to_string())?;
        report_dataflash_read(path, &log);
        log.samples
    } else if is_tlog {
        let log =
            crate::replay::tlog::read_tlog(path, &mut on_progress).map_err(|e| e.to_string())?;
        for (m, n) in &log.messages {
            tracing::info!(message = %m, samples = n, "read");
        }
        if log.skipped_bytes > 0 || log.bad_frames > 0 {
            tracing::warn!(
                skipped_bytes = log.skipped_bytes,
                bad_frames = log.bad_frames,
                "corrupt records skipped; first problem: {}",
                log.first_error
                    .as_deref()
                    .unwrap_or("bytes between records")
            );
        }
        log.samples
    } else if path.is_dir() {
        let log =
            px4log::read_dir_with_progress(path, &mut on_progress).map_err(|e| e.to_string())?;
        report_px4_read(&log.topics, &log.stand_ins, &log.missing);
        log.samples
    } else {
        // A cut ULog reads as a complete, shorter flight: say so.
        if let Ok(Some(at)) = px4log::ulog_cut_short(path) {
            warn_cut_short(path, "message", at);
        }
        // A ULog is streamed where it can be: its samples made as the replay reaches
        // them, never all in memory (an hour of a 1 kHz log is four million).
        match px4log::read_ulog_for_replay(path, &mut on_progress).map_err(|e| e.to_string())? {
            px4log::UlogRead::Whole(log) => {
                report_px4_read(&log.topics, &log.stand_ins, &log.missing);
                log.samples
            }
            px4log::UlogRead::Streamed(log) => {
                streamed = Some(log);
                Vec::new()
            }
        }
    };
    Ok(Flight {
        samples,
        streamed,
        t0_us,
        live_poses,
        config: c,
    })
}

/// `skyfuse replay`.
pub(super) fn replay(
    c: &Config,
    path: &std::path::Path,
    out: &std::path::Path,
    sources: Option<&[String]>,
    reference: &str,
    window: Option<(f64, f64)>,
    fusion: Option<&str>,
) -> Result<(), String> {
    let mut cfg = c.estimator.clone();
    if let Some(f) = fusion {
        match parse_fusion(f)?.as_slice() {
            [m] => cfg.mode = *m,
            _ => return Err("replay takes one fusion mode".into()),
        }
    }
    let flight = load_flight(c, path)?;
    let (t0_us, live_poses, c) = (flight.t0_us, &flight.live_poses, &flight.config);
    let source = flight.source();
    let mut bar = Progress::new("replaying");
    let opts = offline::ReplayOptions {
        fuse: sources.map(|s| s.to_vec()),
        reference: reference.to_string(),
        window,
        t0_us,
        pose_rate_hz: Some(c.output.pose_rate_hz),
    };
    let summary = offline::run_replay(
        &path.display().to_string(),
        source,
        cfg,
        c.health.clone(),
        &opts,
        out,
        &mut |f| bar.update(f),
    )
    .map_err(|e| e.to_string())?;
    flight.report_streamed();
    println!(
        "replayed {} samples ({}) -> {}",
        summary.samples,
        summary.mode,
        out.display()
    );
    let a = &summary.availability;
    println!(
        "valid {:.1} % of {:.1} s, longest invalid {:.1} s{}",
        100.0 * a.valid_fraction,
        a.span_s,
        a.longest_invalid_s,
        match (
            a.airborne_s,
            a.airborne_valid_fraction,
            a.airborne_longest_invalid_s
        ) {
            (Some(s), Some(f), Some(g)) => format!(
                "; airborne {s:.1} s: valid {:.1} %, longest invalid {g:.1} s",
                100.0 * f
            ),
            _ => String::new(),
        }
    );
    if !live_poses.is_empty() {
        let t0 = t0_us.unwrap_or(0);
        let (n, rms, max) = compare_with_live(&out.join("fused.tum"), live_poses, t0)?;
        write_live_tum(&out.join("live.tum"), live_poses, t0)?;
        println!(
            "against the poses sent live (live.tum, {} valid): {n} matched, position difference RMS {rms:.4} m, max {max:.4} m",
            live_poses.iter().filter(|p| p.2).count()
        );
    }
    println!(
        "APE against {} (fused: valid poses only), m:   RMSE / max SE(3)-aligned   RMSE / max origin-aligned",
        summary.reference
    );
    let stat = |a: &Option<crate::eval::ApeStats>| match a {
        Some(a) => format!("{:>7.3} / {:>7.3}", a.rmse, a.max),
        None => format!("{:>17}", "-"),
    };
    for s in &summary.scores {
        println!(
            "  {:<12} {}     {}   ({} poses)",
            s.name,
            stat(&s.ape),
            stat(&s.ape_origin),
            s.poses
        );
    }
    print_consistency(&summary);
    Ok(())
}

/// One line: did the valid poses hold the reference inside the σ they were sent with.
fn print_consistency(summary: &offline::Summary) {
    match &summary.consistency {
        Some(c) => println!(
            "consistency against {} ({} valid poses, alignment {}): within 3σ E {:.1} % N {:.1} % U {:.1} %, beyond 5σ {}, worst {:.1}σ ({} at {:.1} s), mean NEES {:.2}{}",
            summary.reference,
            c.poses,
            c.alignment,
            100.0 * c.within_3_sigma[0],
            100.0 * c.within_3_sigma[1],
            100.0 * c.within_3_sigma[2],
            c.beyond_5_sigma,
            c.worst_ratio,
            ["E", "N", "U"][c.worst_axis.min(2)],
            c.worst_t,
            c.nees_mean,
            if c.kept() { "" } else { "  NOT CONSISTENT" }
        ),
        None => println!(
            "consistency against {}: not measured (no valid pose matched the reference)",
            summary.reference
        ),
    }
}

/// A log whose end cuts its last `unit` (message, record) in two, at byte `at`.
fn warn_cut_short(path: &std::path::Path, unit: &str, at: u64) {
    tracing::warn!(
        file = %path.display(),
        "the file is cut short (not finished?): its last {unit}, at byte {at}, is incomplete; replaying what comes before"
    );
}

/// Whether `path` begins as a DataFlash log (whatever its name).
fn starts_as_dataflash(path: &std::path::Path) -> bool {
    let mut head = [0u8; 3];
    std::fs::File::open(path)
        .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut head))
        .is_ok_and(|()| crate::replay::dataflash::looks_like_dataflash(&head))
}

/// What a DataFlash log gave, and what it did not.
fn report_dataflash_read(path: &std::path::Path, log: &crate::replay::dataflash::DataflashLog) {
    for (m, n) in &log.messages {
        tracing::info!(record = %m, samples = n, "read");
    }
    for (m, n) in &log.unusable {
        tracing::warn!(record = %m, records = n, "not usable");
    }
    if let Some(why) = &log.first_unusable {
        tracing::warn!("first unusable record: {why}");
    }
    let s = &log.scan;
    if let Some(at) = s.cut_short {
        warn_cut_short(path, "record", at);
    }
    if s.bad_formats > 0 {
        tracing::warn!(
            refused = s.bad_formats,
            "record formats refused; first: {}",
            s.first_error.as_deref().unwrap_or("-")
        );
    }
    if s.skipped_bytes > 0 {
        tracing::warn!(
            skipped_bytes = s.skipped_bytes,
            undefined_records = s.undefined_records,
            "bytes that are not records skipped (corruption, padding)"
        );
    }
}

/// What a PX4 log's topics gave, what stood in for absent ones, what is missing.
fn report_px4_read(topics: &[px4log::TopicSummary], stand_ins: &[String], missing: &[String]) {
    for t in topics {
        match &t.first_error {
            Some(e) => {
                tracing::warn!(topic = %t.name, source = %t.source, rows = t.rows, skipped = t.skipped, "read; first problem: {e}")
            }
            None => tracing::info!(topic = %t.name, source = %t.source, rows = t.rows, "read"),
        }
    }
    for s in stand_ins {
        println!("stand-in: {s}");
    }
    for m in missing {
        println!("missing: {m}");
    }
}

/// The MCAP file to replay: `path` itself, or the one `.mcap` in a rosbag2 directory.
fn mcap_file(path: &std::path::Path) -> Result<Option<std::path::PathBuf>, String> {
    let is_mcap = |p: &std::path::Path| {
        p.extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("mcap"))
    };
    if path.is_file() {
        return Ok(is_mcap(path).then(|| path.to_path_buf()));
    }
    if path.join("metadata.yaml").is_file() {
        let files: Vec<_> = std::fs::read_dir(path)
            .map_err(|e| format!("{}: {e}", path.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| is_mcap(p))
            .collect();
        return match files.as_slice() {
            [one] => Ok(Some(one.clone())),
            [] => Err(format!(
                "{}: a rosbag2 bag without an .mcap file (sqlite3 bags: convert with `ros2 bag convert` or rosbags-convert)",
                path.display()
            )),
            _ => Err(format!(
                "{}: a bag split into {} .mcap files: replay them one by one",
                path.display(),
                files.len()
            )),
        };
    }
    Ok(None)
}

/// Positions of the valid live poses against the replayed fused.tum, matched by time
/// (within 10 ms): (matched, RMS, max) of the distance.
fn compare_with_live(
    fused_tum: &std::path::Path,
    live: &[(i64, [f64; 3], bool)],
    t0_us: i64,
) -> Result<(usize, f64, f64), String> {
    let fused = crate::eval::Trajectory::read_tum(fused_tum).map_err(|e| e.to_string())?;
    let (mut n, mut sum, mut max) = (0usize, 0.0f64, 0.0f64);
    for (t_us, p, valid) in live {
        if !valid {
            continue;
        }
        let t = (t_us - t0_us) as f64 * 1e-6;
        let i = fused.t.partition_point(|ft| *ft < t);
        let best = [i.checked_sub(1), Some(i)]
            .into_iter()
            .flatten()
            .filter(|&j| j < fused.t.len())
            .min_by(|&a, &b| (fused.t[a] - t).abs().total_cmp(&(fused.t[b] - t).abs()));
        if let Some(j) = best.filter(|&j| (fused.t[j] - t).abs() <= 0.01) {
            let d = (fused.p[j] - nalgebra::Vector3::from(*p)).norm();
            n += 1;
            sum += d * d;
            max = max.max(d);
        }
    }
    Ok((
        n,
        if n > 0 {
            (sum / n as f64).sqrt()
        } else {
            f64::NAN
        },
        max,
    ))
}

/// The valid live poses as TUM (positions; orientation identity), time from `t0_us`.
fn write_live_tum(
    file: &std::path::Path,
    live: &[(i64, [f64; 3], bool)],
    t0_us: i64,
) -> Result<(), String> {
    let mut tr = crate::eval::Trajectory::default();
    for (t_us, p, _) in live.iter().filter(|l| l.2) {
        tr.t.push((t_us - t0_us) as f64 * 1e-6);
        tr.p.push(nalgebra::Vector3::from(*p));
        tr.q.push(nalgebra::UnitQuaternion::identity());
    }
    tr.write_tum(file).map_err(|e| e.to_string())
}
