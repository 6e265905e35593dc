//! `skyfuse sim --monte-carlo N --seed S`: randomised vehicles and flights through one
//! configuration, on every core, with a progress bar; the integrity table by scenario
//! family on stdout, each run's figures in `runs.jsonl` with `--out`.

use super::runs::Progress;
use crate::config::Config;
use crate::offline::{self, DrawResult, FamilyRow};
use crate::sim::monte_carlo::Stress;
use std::io::Write;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{mpsc, Arc};

pub(super) fn run(
    c: &Config,
    seed: u64,
    first: u64,
    n: u64,
    stress: Stress,
    jobs: Option<usize>,
    out: Option<&std::path::Path>,
) -> Result<(), String> {
    if n == 0 {
        return Err("--monte-carlo needs at least one run".into());
    }
    // One flight with a place to put it: every file of a scenario run, to look at.
    if let (1, Some(dir)) = (n, out) {
        let summary = offline::run_draw_files(
            seed,
            first,
            stress,
            c.estimator.clone(),
            c.health.clone(),
            dir,
        )
        .map_err(|e| e.to_string())?;
        println!("{}", summary.input);
        println!(
            "{}",
            serde_json::to_string_pretty(&summary.consistency).unwrap_or_default()
        );
        println!("files in {}", dir.display());
        return Ok(());
    }
    let jobs = jobs
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |p| p.get()))
        .clamp(1, 256);
    let mut runs_file = match out {
        Some(dir) => {
            std::fs::create_dir_all(dir)
                .map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
            let path = dir.join("runs.jsonl");
            Some((
                std::fs::File::create(&path)
                    .map_err(|e| format!("cannot write {}: {e}", path.display()))?,
                path,
            ))
        }
        None => None,
    };
    let next = Arc::new(AtomicU64::new(first));
    let end = first + n;
    let (tx, rx) = mpsc::channel::<DrawResult>();
    let workers: Vec<_> = (0..jobs)
        .map(|_| {
            let (next, tx) = (next.clone(), tx.clone());
            let (est, health) = (c.estimator.clone(), c.health.clone());
            std::thread::spawn(move || loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                if i >= end {
                    break;
                }
                let r = offline::run_draw_stressed(seed, i, stress, est.clone(), health.clone());
                if tx.send(r).is_err() {
                    break;
                }
            })
        })
        .collect();
    drop(tx);
    let stressed = if stress.accel_steps {
        ", accelerometer steps"
    } else {
        ""
    };
    let mut progress = Progress::new(format!(
        "{n} flights, seed {seed}{stressed}, {jobs} at a time"
    ));
    let mut results = Vec::with_capacity(n as usize);
    for r in rx {
        if let Some((f, path)) = runs_file.as_mut() {
            let line = serde_json::to_string(&r).unwrap_or_default();
            writeln!(f, "{line}").map_err(|e| format!("cannot write {}: {e}", path.display()))?;
        }
        if r.integrity_failures() > 0 {
            eprintln!(
                "\ndraw {} (seed {seed}): {} integrity failures, worst error {:.2}× its protection level at {:.1} s: {}",
                r.index,
                r.integrity_failures(),
                r.consistency.as_ref().map_or(0.0, |c| c.worst_pl_ratio),
                r.consistency.as_ref().map_or(0.0, |c| c.worst_pl_t),
                r.description
            );
        }
        results.push(r);
        progress.update(results.len() as f64 / n as f64);
    }
    for w in workers {
        w.join().map_err(|_| "a Monte Carlo worker panicked")?;
    }
    results.sort_by_key(|r| r.index);
    let rows = offline::family_rows(&results);
    print_table(&rows);
    if let Some(dir) = out {
        let path = dir.join("families.json");
        let text = serde_json::to_string_pretty(&rows).unwrap_or_default() + "\n";
        std::fs::write(&path, text).map_err(|e| format!("cannot write {}: {e}", path.display()))?;
        println!("\neach run: {}", dir.join("runs.jsonl").display());
    }
    Ok(())
}

fn opt(v: Option<f64>) -> String {
    v.map_or_else(|| "-".into(), |x| format!("{x:.2}"))
}

/// The table, as Markdown (it goes into BENCHMARKS.md as it is).
pub(super) fn print_table(rows: &[FamilyRow]) {
    println!(
        "| family | runs | integrity failures (runs) | beyond 5σ | within 3σ E/N/U, worst run % | NEES E/N/U median [p5-p95] | valid airborne % median (min) | fused RMSE m median | best single | flow DR | fused best |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for r in rows {
        let nees: Vec<String> = (0..3)
            .map(|a| {
                format!(
                    "{:.2} [{:.2}-{:.2}]",
                    r.nees_axis_median[a], r.nees_axis_p5[a], r.nees_axis_p95[a]
                )
            })
            .collect();
        println!(
            "| {} | {} | {} ({}) | {} | {:.1} / {:.1} / {:.1} | {} | {:.1} ({:.1}) | {} | {} | {} | {}/{} |",
            r.family,
            r.runs,
            r.integrity_failures,
            r.runs_with_failures,
            r.beyond_5_sigma,
            r.within_3_sigma_min[0] * 100.0,
            r.within_3_sigma_min[1] * 100.0,
            r.within_3_sigma_min[2] * 100.0,
            nees.join(" / "),
            r.availability_median * 100.0,
            r.availability_min * 100.0,
            opt(r.fused_rmse_median),
            opt(r.best_single_median),
            opt(r.flow_dr_median),
            r.fused_best,
            r.runs,
        );
    }
}
