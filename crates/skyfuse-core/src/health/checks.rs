//! Per-sample checks, one function per sensor kind. Each returns the conditions it
//! found; the memory keeps what a check needs from earlier samples (last fix, last
//! odometry pose, IMU stillness).

use super::{HealthConfig, HealthState};
use crate::geo::LocalEnu;
use crate::sample::{GnssFix, GnssFixType, Odometry, OpticalFlow, Range, SensorData};
use nalgebra::Vector3;

/// One failed check.
#[derive(Debug, Clone, PartialEq)]
pub struct Observation {
    pub code: &'static str,
    pub state: HealthState,
    pub text: String,
}

fn obs(code: &'static str, state: HealthState, text: String) -> Observation {
    Observation { code, state, text }
}

/// What the checks of one sensor remember.
#[derive(Debug, Clone, Default)]
pub struct SensorMemory {
    /// GNSS: previous good fix (time, local position) in a local frame at the first fix.
    gnss_origin: Option<LocalEnu>,
    gnss_last: Option<(i64, Vector3<f64>)>,
    /// Odometry: previous (time, position, reset counter).
    vo_last: Option<(i64, Vector3<f64>, Option<u8>)>,
    /// Odometry speed vs IMU stillness: since when they disagree.
    vo_imu_disagree_since: Option<i64>,
}

/// The checks of one decoded sample.
pub fn check_sample(
    cfg: &HealthConfig,
    mem: &mut SensorMemory,
    data: &SensorData,
    t: i64,
) -> Vec<Observation> {
    match data {
        SensorData::Flow(f) => flow(cfg, f),
        SensorData::Gnss(g) => gnss(cfg, mem, g, t),
        SensorData::Odometry(o) => odometry(cfg, mem, o, t),
        SensorData::Range(r) => range(r),
        _ => vec![],
    }
}

fn flow(cfg: &HealthConfig, f: &OpticalFlow) -> Vec<Observation> {
    let mut out = vec![];
    let height = f.tof.as_ref().map(|t| t.distance_m);
    if let Some(tof) = &f.tof {
        if tof.status.is_some_and(|s| s != 0) {
            out.push(obs(
                "tof_status",
                HealthState::Failed,
                format!("ToF status {} (not valid)", tof.status.unwrap_or(0)),
            ));
        }
        if let Some(s) = tof.strength {
            if s < cfg.tof_min_strength {
                out.push(obs(
                    "tof_weak",
                    HealthState::Failed,
                    format!("ToF signal strength {s} < {}", cfg.tof_min_strength),
                ));
            }
        }
        let grounded = tof.distance_m < cfg.flow_ground_m && tof.status.is_none_or(|s| s == 0);
        if !grounded && !(cfg.tof_min_m..=cfg.tof_max_m).contains(&tof.distance_m) {
            out.push(obs(
                "tof_out_of_range",
                HealthState::Failed,
                format!(
                    "ToF height {:.2} m outside [{}, {}] m",
                    tof.distance_m, cfg.tof_min_m, cfg.tof_max_m
                ),
            ));
        }
    }
    // On the ground the lens cannot focus and the ToF reads near zero: low quality
    // there is expected, not a fault (the estimator does not use flow that low either).
    let on_ground = height.is_some_and(|h| h < cfg.flow_ground_m)
        && f.tof
            .as_ref()
            .is_some_and(|t| t.status.is_none_or(|s| s == 0));
    if !on_ground {
        if f.quality < cfg.flow_min_quality {
            out.push(obs(
                "flow_quality_low",
                HealthState::Failed,
                format!("quality {} < {}", f.quality, cfg.flow_min_quality),
            ));
        }
        if f.status == Some(0) {
            out.push(obs(
                "flow_status",
                HealthState::Failed,
                "flow status byte says invalid".into(),
            ));
        }
    }
    if let Some(r) = f.rate {
        let m = r.x.abs().max(r.y.abs());
        if m > cfg.flow_max_rate {
            out.push(obs(
                "flow_rate_limit",
                HealthState::Degraded,
                format!("flow rate {m:.2} rad/s > {} rad/s", cfg.flow_max_rate),
            ));
        }
    }
    out
}

fn range(r: &Range) -> Vec<Observation> {
    let (lo, hi) = (r.min_m.unwrap_or(0.0), r.max_m.unwrap_or(f64::INFINITY));
    // A range finder clamps to its limits when it sees nothing: at the limit is not
    // a measurement (but the minimum on the ground is normal).
    if r.distance_m >= hi && hi.is_finite() {
        return vec![obs(
            "range_out_of_range",
            HealthState::Degraded,
            format!("range {:.2} m at the sensor's maximum {hi} m", r.distance_m),
        )];
    }
    if r.distance_m < lo * 0.5 {
        return vec![obs(
            "range_out_of_range",
            HealthState::Degraded,
            format!(
                "range {:.2} m below the sensor's minimum {lo} m",
                r.distance_m
            ),
        )];
    }
    vec![]
}

fn gnss(cfg: &HealthConfig, mem: &mut SensorMemory, g: &GnssFix, t: i64) -> Vec<Observation> {
    let mut out = vec![];
    if matches!(g.fix, GnssFixType::NoFix | GnssFixType::Fix2d) {
        out.push(obs(
            "gnss_no_fix",
            HealthState::Failed,
            format!("fix type {:?}", g.fix),
        ));
        // A fix-less position says nothing: forget the last fix for the jump check.
        mem.gnss_last = None;
        return out;
    }
    if let Some(c) = &g.position_cov {
        let h = c[(0, 0)].max(c[(1, 1)]);
        if h > cfg.gnss_failed_var {
            out.push(obs(
                "gnss_covariance",
                HealthState::Failed,
                format!("horizontal variance {h:.1} m² > {} m²", cfg.gnss_failed_var),
            ));
        } else if h > cfg.gnss_degraded_var {
            out.push(obs(
                "gnss_covariance",
                HealthState::Degraded,
                format!(
                    "horizontal variance {h:.2} m² > {} m²",
                    cfg.gnss_degraded_var
                ),
            ));
        }
    }
    if let Some(n) = g.satellites {
        if n < cfg.gnss_min_satellites {
            out.push(obs(
                "gnss_satellites",
                HealthState::Degraded,
                format!("{n} satellites < {}", cfg.gnss_min_satellites),
            ));
        }
    }
    if let Some(h) = g.hdop {
        if h > cfg.gnss_max_hdop {
            out.push(obs(
                "gnss_hdop",
                HealthState::Degraded,
                format!("HDOP {h:.1} > {}", cfg.gnss_max_hdop),
            ));
        }
    }
    let origin = *mem
        .gnss_origin
        .get_or_insert_with(|| LocalEnu::new(g.lat_deg, g.lon_deg, g.alt_m));
    let p = origin.to_enu(g.lat_deg, g.lon_deg, g.alt_m);
    if let Some((t0, p0)) = mem.gnss_last {
        let dt = (t - t0) as f64 * 1e-6;
        let step = (p - p0).xy().norm();
        // Noise allowance: a few metres whatever dt is.
        if dt > 0.0 && step > cfg.gnss_max_speed * dt + 3.0 {
            out.push(obs(
                "gnss_jump",
                HealthState::Failed,
                format!("position jumped {step:.1} m in {:.2} s", dt),
            ));
        }
    }
    mem.gnss_last = Some((t, p));
    out
}

fn odometry(cfg: &HealthConfig, mem: &mut SensorMemory, o: &Odometry, t: i64) -> Vec<Observation> {
    let mut out = vec![];
    if let Some(c) = &o.pose_cov {
        let v = c[(0, 0)].max(c[(1, 1)]).max(c[(2, 2)]);
        if v >= cfg.vo_failed_var {
            out.push(obs(
                "vo_covariance",
                HealthState::Failed,
                format!(
                    "pose variance {v:.4} ≥ {} (tracking lost)",
                    cfg.vo_failed_var
                ),
            ));
        } else if v >= cfg.vo_degraded_var {
            out.push(obs(
                "vo_covariance",
                HealthState::Degraded,
                format!(
                    "pose variance {v:.4} ≥ {} (may be drifting)",
                    cfg.vo_degraded_var
                ),
            ));
        }
    }
    if o.quality.is_some_and(|q| q < 0) {
        out.push(obs(
            "vo_quality",
            HealthState::Failed,
            "odometry quality -1 (failed)".into(),
        ));
    }
    if let Some((t0, p0, r0)) = mem.vo_last {
        if o.reset_counter != r0 && r0.is_some() {
            out.push(obs(
                "vo_reset",
                HealthState::Degraded,
                format!(
                    "odometry reset (counter {} -> {})",
                    r0.unwrap_or(0),
                    o.reset_counter.unwrap_or(0)
                ),
            ));
        }
        let dt = (t - t0) as f64 * 1e-6;
        if dt > 0.0 && dt < 0.5 {
            let step = (o.position - p0).norm();
            let speed = o.velocity.map(|v| v.norm()).unwrap_or(0.0);
            if step > cfg.vo_jump_m + speed * dt * 2.0 {
                out.push(obs(
                    "vo_jump",
                    HealthState::Degraded,
                    format!("odometry jumped {step:.2} m in {:.0} ms", dt * 1e3),
                ));
            }
        }
    }
    mem.vo_last = Some((t, o.position, o.reset_counter));
    out
}

/// The IMU-vs-odometry consistency check: odometry reports motion while the IMU is
/// still, or the reverse, for longer than the window.
pub fn vo_imu_consistency(
    cfg: &HealthConfig,
    mem: &mut SensorMemory,
    vo_speed: f64,
    imu_still: bool,
    t: i64,
) -> Option<Observation> {
    let disagree = imu_still && vo_speed > cfg.vo_imu_speed_mps;
    if !disagree {
        mem.vo_imu_disagree_since = None;
        return None;
    }
    let since = *mem.vo_imu_disagree_since.get_or_insert(t);
    if (t - since) as f64 >= cfg.vo_imu_window_ms * 1e3 {
        Some(obs(
            "vo_imu_inconsistent",
            HealthState::Failed,
            format!("odometry moves at {vo_speed:.2} m/s while the IMU is still"),
        ))
    } else {
        None
    }
}
