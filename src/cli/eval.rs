//! `skyfuse eval`: the corpus. Every flight log found under the paths given (and, with
//! `--scenarios`, every simulator scenario) replayed with one configuration, and one
//! table: the fused track beside each single source, plain flow dead reckoning, the
//! autopilot's own EKF where the log has it, against the log's reference (the truth in
//! a simulation), whole log; valid fraction and whether the valid poses kept the σ
//! they were sent with.
//!
//! Source sets per flight: `flow` (flow, range finders, attitude and barometers: what a
//! flow-only vehicle has) where the log has flow, and `all` (every sensor but the
//! reference and the autopilot's estimates). The reference is never fused.

use super::runs::{load_flight, Flight};
use crate::config::Config;
use crate::offline::{self, ReplayOptions, Summary};
use crate::sample::SensorKind;
use std::path::{Path, PathBuf};

/// One replay of one flight with one source set.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Row {
    pub flight: String,
    pub set: String,
    pub reference: String,
    /// Fused, valid poses only: RMSE SE(3)-aligned and origin-aligned, m.
    pub fused: Option<f64>,
    pub fused_origin: Option<f64>,
    /// Each single source (not fused-from-everything, not dead reckoning), RMSE m.
    pub sources: Vec<(String, f64)>,
    /// Plain flow dead reckoning per flow source, RMSE m.
    pub dead_reckoning: Vec<(String, f64)>,
    /// The autopilot's own estimate(s) where logged, RMSE m.
    pub autopilot: Vec<(String, f64)>,
    pub valid_fraction: f64,
    /// The valid poses kept their σ ([`offline::Consistency::kept`]).
    pub consistent: bool,
    pub within_3_sigma: Option<[f64; 3]>,
    pub beyond_5_sigma: Option<usize>,
    pub nees_mean: Option<f64>,
}

impl Row {
    fn of(flight: &str, set: &str, s: &Summary, kinds: &[(String, SensorKind)]) -> Self {
        let kind = |n: &str| kinds.iter().find(|(id, _)| id == n).map(|(_, k)| *k);
        let mut row = Row {
            flight: flight.to_string(),
            set: set.to_string(),
            reference: s.reference.clone(),
            fused: None,
            fused_origin: None,
            sources: vec![],
            dead_reckoning: vec![],
            autopilot: vec![],
            valid_fraction: s.availability.valid_fraction,
            consistent: s
                .consistency
                .as_ref()
                .is_some_and(offline::Consistency::kept),
            within_3_sigma: s.consistency.as_ref().map(|c| c.within_3_sigma),
            beyond_5_sigma: s.consistency.as_ref().map(|c| c.beyond_5_sigma),
            nees_mean: s.consistency.as_ref().map(|c| c.nees_mean),
        };
        for sc in &s.scores {
            let Some(rmse) = sc.ape.as_ref().map(|a| a.rmse) else {
                continue;
            };
            let entry = (sc.name.clone(), rmse);
            if sc.name == "fused" {
                row.fused = Some(rmse);
                row.fused_origin = sc.ape_origin.as_ref().map(|a| a.rmse);
            } else if sc.name.ends_with("_dr") && kind(&sc.name).is_none() {
                row.dead_reckoning.push(entry);
            } else if kind(&sc.name) == Some(SensorKind::AutopilotEstimate) {
                row.autopilot.push(entry);
            } else if !republished(&sc.name, kinds) {
                row.sources.push(entry);
            }
        }
        row
    }

    /// Fused no worse than every comparison in the row.
    pub fn fused_best(&self) -> bool {
        let Some(f) = self.fused else {
            return false;
        };
        self.sources
            .iter()
            .chain(&self.dead_reckoning)
            .chain(&self.autopilot)
            .all(|(_, r)| f <= *r)
    }
}

/// Flight logs under `path`: files `skyfuse replay` reads, and directories that are a
/// flight themselves (a PX4 CSV export, a rosbag2 bag), not looked into further.
pub fn find_flights(path: &Path) -> Vec<PathBuf> {
    let is_log = |p: &Path| {
        let n = p.to_string_lossy().to_ascii_lowercase();
        [".ulg", ".bin", ".tlog", ".tlog.gz", ".mcap"]
            .iter()
            .any(|e| n.ends_with(e))
    };
    if path.is_file() {
        return vec![path.to_path_buf()];
    }
    let Ok(entries) = std::fs::read_dir(path) else {
        return vec![];
    };
    let mut entries: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
    entries.sort();
    let is_flight_dir = path.join("metadata.yaml").is_file()
        || entries.iter().any(|p| {
            let n = p.to_string_lossy();
            n.ends_with("_0.csv") || n.ends_with("_0.csv.gz")
        });
    if is_flight_dir {
        return vec![path.to_path_buf()];
    }
    let mut out = vec![];
    for p in entries {
        if p.is_dir() {
            out.extend(find_flights(&p));
        } else if is_log(&p) {
            out.push(p);
        }
    }
    out
}

/// A short name for a flight: its path as given, `/` as `_`.
fn flight_name(path: &Path) -> String {
    let s = path.to_string_lossy();
    s.trim_start_matches("./")
        .trim_start_matches("../")
        .replace('/', "_")
}

/// Whether `id` is an autopilot's re-publication of a sensor the log also has raw
/// (PX4's `vehicle_gps_position` beside `sensor_gps`, `vehicle_imu` beside
/// `sensor_combined`, EKF2's `estimator_states` quaternions beside `vehicle_attitude`):
/// fusing both would count one sensor twice, and scoring one against the other
/// compares a receiver with itself.
fn republished(id: &str, sources: &[(String, SensorKind)]) -> bool {
    let has = |n: &str| sources.iter().any(|(s, _)| s == n);
    (id.starts_with("vehicle_gps_position") && has("gps"))
        || (id.starts_with("vehicle_imu") && has("imu"))
        || (id.starts_with("attitude_states") && has("attitude"))
}

/// The source sets replayed for a log with these sources.
fn source_sets(
    sources: &[(String, SensorKind)],
    reference: &str,
) -> Vec<(&'static str, Vec<String>)> {
    let of = |kinds: &[SensorKind]| -> Vec<String> {
        sources
            .iter()
            .filter(|(id, k)| {
                kinds.contains(k)
                    && id != reference
                    && id != "sim_truth"
                    && !republished(id, sources)
            })
            .map(|(id, _)| id.clone())
            .collect()
    };
    let mut sets = vec![];
    if sources.iter().any(|(_, k)| *k == SensorKind::Flow) {
        sets.push((
            "flow",
            of(&[
                SensorKind::Flow,
                SensorKind::Range,
                SensorKind::Attitude,
                SensorKind::Baro,
            ]),
        ));
    }
    sets.push((
        "all",
        of(&[
            SensorKind::Imu,
            SensorKind::Attitude,
            SensorKind::Flow,
            SensorKind::Range,
            SensorKind::Baro,
            SensorKind::Gnss,
            SensorKind::Odometry,
        ]),
    ));
    sets
}

/// `skyfuse eval`.
pub(super) fn eval(
    c: &Config,
    paths: &[PathBuf],
    scenarios: bool,
    out: &Path,
    check: bool,
) -> Result<(), String> {
    let mut flights = vec![];
    for p in paths {
        if !p.exists() {
            return Err(format!("{}: no such file or directory", p.display()));
        }
        let found = find_flights(p);
        if found.is_empty() {
            eprintln!("{}: no flight log found", p.display());
        }
        flights.extend(found);
    }
    if flights.is_empty() && !scenarios {
        return Err("nothing to evaluate: give flight logs or directories, or --scenarios".into());
    }
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    let mut rows = vec![];
    for path in &flights {
        let name = flight_name(path);
        eprintln!("{name}");
        let flight: Flight = match load_flight(c, path) {
            Ok(f) => f,
            Err(e) => {
                eprintln!("  skipped: {e}");
                continue;
            }
        };
        let found = offline::log_sources(flight.source());
        let Some(reference) = found.auto_reference.clone() else {
            eprintln!("  skipped: no reference to score against (no camera odometry, autopilot estimate, GNSS or truth)");
            continue;
        };
        for (set, fuse) in source_sets(&found.sources, &reference) {
            if fuse.is_empty() {
                continue;
            }
            let opts = ReplayOptions {
                fuse: Some(fuse.clone()),
                reference: reference.clone(),
                window: None,
                t0_us: flight.t0_us(),
                pose_rate_hz: Some(flight.config().output.pose_rate_hz),
            };
            eprintln!("  {set}: fusing {} against {reference}", fuse.join(", "));
            let dir = out.join(&name).join(set);
            let cfg = flight.config();
            let summary = offline::run_replay(
                &path.display().to_string(),
                flight.source(),
                cfg.estimator.clone(),
                cfg.health.clone(),
                &opts,
                &dir,
                &mut |_| {},
            )
            .map_err(|e| format!("{name} ({set}): {e}"))?;
            rows.push(Row::of(&name, set, &summary, &found.sources));
        }
    }
    if scenarios {
        for (name, _) in crate::sim::scenario::NAMES {
            eprintln!("scenario {name}");
            let scn = crate::sim::scenario::scenario(name)
                .ok_or_else(|| format!("scenario {name} missing"))?;
            let dir = out.join(format!("scenario-{name}"));
            let summary = offline::run_scenario(
                &scn,
                1,
                scn.default_duration_s(),
                c.estimator.clone(),
                c.health.clone(),
                &dir,
                &mut |_| {},
            )
            .map_err(|e| format!("scenario {name}: {e}"))?;
            let kinds: Vec<(String, SensorKind)> = scn
                .streams
                .iter()
                .map(|s| (s.input_id.to_string(), s.kind))
                .collect();
            rows.push(Row::of(
                &format!("scenario {name}"),
                "scenario",
                &summary,
                &kinds,
            ));
        }
    }
    let table = markdown(&rows);
    println!("{table}");
    std::fs::write(out.join("eval.md"), &table).map_err(|e| e.to_string())?;
    let json = serde_json::to_string_pretty(&rows).map_err(|e| e.to_string())?;
    std::fs::write(out.join("eval.json"), json).map_err(|e| e.to_string())?;
    let broken: Vec<String> = rows
        .iter()
        .filter(|r| !r.consistent || !r.fused_best())
        .map(|r| format!("{} ({})", r.flight, r.set))
        .collect();
    println!(
        "{} runs; fused best and consistent in {}; files in {}",
        rows.len(),
        rows.len() - broken.len(),
        out.display()
    );
    if check && !broken.is_empty() {
        return Err(format!(
            "not fused-best or not consistent: {}",
            broken.join(", ")
        ));
    }
    Ok(())
}

/// The table, as Markdown (BENCHMARKS.md keeps it).
pub fn markdown(rows: &[Row]) -> String {
    let m = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.3}"));
    let list = |v: &[(String, f64)]| {
        if v.is_empty() {
            "-".to_string()
        } else {
            v.iter()
                .map(|(n, r)| format!("{n} {r:.3}"))
                .collect::<Vec<_>>()
                .join(", ")
        }
    };
    let mut t = String::from(
        "| flight | fused | ref | fused RMSE m (SE3 / origin) | single sources | flow dead reckoning | autopilot EKF | valid | within 3σ E/N/U % | >5σ | NEES | fused best | consistent |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let w = r.within_3_sigma.map_or("-".to_string(), |w| {
            format!(
                "{:.1}/{:.1}/{:.1}",
                100.0 * w[0],
                100.0 * w[1],
                100.0 * w[2]
            )
        });
        t.push_str(&format!(
            "| {} | {} | {} | {} / {} | {} | {} | {} | {:.1} % | {} | {} | {} | {} | {} |\n",
            r.flight,
            r.set,
            r.reference,
            m(r.fused),
            m(r.fused_origin),
            list(&r.sources),
            list(&r.dead_reckoning),
            list(&r.autopilot),
            100.0 * r.valid_fraction,
            w,
            r.beyond_5_sigma.map_or("-".into(), |n| n.to_string()),
            m(r.nees_mean),
            if r.fused_best() { "yes" } else { "no" },
            if r.consistent { "yes" } else { "no" },
        ));
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_flow_set_is_what_a_flow_vehicle_has_and_never_the_reference() {
        let s = |v: &[(&str, SensorKind)]| -> Vec<(String, SensorKind)> {
            v.iter().map(|(n, k)| (n.to_string(), *k)).collect()
        };
        let sources = s(&[
            ("imu", SensorKind::Imu),
            ("attitude", SensorKind::Attitude),
            ("flow", SensorKind::Flow),
            ("range", SensorKind::Range),
            ("baro", SensorKind::Baro),
            ("vio", SensorKind::Odometry),
            ("ekf2", SensorKind::AutopilotEstimate),
        ]);
        let sets = source_sets(&sources, "vio");
        assert_eq!(sets[0].0, "flow");
        assert_eq!(sets[0].1, ["attitude", "flow", "range", "baro"]);
        assert_eq!(sets[1].0, "all");
        assert_eq!(sets[1].1, ["imu", "attitude", "flow", "range", "baro"]);
        // An autopilot's re-publications of a sensor it also logs are not fused again.
        let px4 = s(&[
            ("gps", SensorKind::Gnss),
            ("vehicle_gps_position", SensorKind::Gnss),
            ("imu", SensorKind::Imu),
            ("vehicle_imu_1", SensorKind::Imu),
            ("attitude", SensorKind::Attitude),
            ("attitude_states_2", SensorKind::Attitude),
            ("ekf2", SensorKind::AutopilotEstimate),
        ]);
        assert_eq!(source_sets(&px4, "ekf2")[0].1, ["gps", "imu", "attitude"]);
        // No flow: only the `all` set.
        let sets = source_sets(
            &s(&[("gps", SensorKind::Gnss), ("imu", SensorKind::Imu)]),
            "ekf",
        );
        assert_eq!(sets.len(), 1);
        assert_eq!(sets[0].1, ["gps", "imu"]);
    }
}
