//! GNSS: position (and velocity) in local ENU relative to the origin.
//!
//! Checks: a 3D fix (or better), finite coordinates, a usable accuracy (the message's
//! covariance, else HDOP/VDOP × UERE), not worse than `gnss_max_var`. Control: the first
//! good fix sets the origin; if the filter already runs (indoor start) the origin is
//! placed so that the fix lands on the current estimate (no jump) and the frame's
//! uncertainty is added to the covariance. Fuse: 3D position with the full covariance,
//! velocity where the message has one.

use super::config::EstimatorConfig;
use super::ekf::IDX_P;
use super::integrity;
use super::{Core, Ctx, DebugTopic, Event};
use crate::geo::LocalEnu;
use crate::sample::{GnssFix, GnssFixType};
use crate::source_map::SourceMap;
use nalgebra::{Matrix3, Vector3};

#[derive(Debug, Clone, PartialEq, Default)]
pub struct GnssState {
    pub origin: Option<LocalEnu>,
    /// Last ENU position per source (for the frame deltas).
    pub last: SourceMap<(i64, Vector3<f64>)>,
    /// Last time a GNSS fix was fused, µs.
    pub last_fused: Option<i64>,
    /// Per source, since when its positions have been refused (none accepted since), µs:
    /// by the gate, or by the innovation test while health held it out.
    pub refused_since: SourceMap<Option<i64>>,
    /// Per source, how far off it may be beyond what it reports, 1σ per axis (m), and
    /// since when (µs): set when it was reset to after a long refusal, fading over the
    /// slow error's correlation time (see [`GnssState::doubt_at`]).
    pub doubt: SourceMap<Option<(i64, Vector3<f64>)>>,
}

impl GnssState {
    /// A position of `source` was fused: its refusals are over.
    fn passed(&mut self, source: &str) {
        if let Some(since) = self.refused_since.get_mut(source) {
            *since = None;
        }
    }

    /// A position of `source` was refused at `t` (by the gate, or by the test while
    /// health held it out): its refusals run from the first of them.
    fn refused(&mut self, source: &str, t: i64) {
        self.refused_since
            .get_or_insert_with(source, || None)
            .get_or_insert(t);
    }

    /// The doubt on `source`'s slow error at `t`: as large as it was found off, fading
    /// with the slow error's own correlation time `tau_s`.
    pub fn doubt_at(&self, source: &str, t: i64, tau_s: f64) -> Vector3<f64> {
        match self.doubt.get(source).copied().flatten() {
            Some((since, d)) => d * (-((t - since).max(0) as f64 * 1e-6) / tau_s.max(1.0)).exp(),
            None => Vector3::zeros(),
        }
    }
}

/// Checks of one fix; returns the ENU covariance.
pub fn checks(fix: &GnssFix, cfg: &EstimatorConfig) -> Result<Matrix3<f64>, &'static str> {
    match fix.fix {
        GnssFixType::NoFix => return Err("no fix"),
        GnssFixType::Fix2d => return Err("2D fix only"),
        _ => {}
    }
    if !(fix.lat_deg.is_finite() && fix.lon_deg.is_finite() && fix.alt_m.is_finite())
        || fix.lat_deg.abs() > 90.0
        || fix.lon_deg.abs() > 180.0
    {
        return Err("coordinates not finite or out of range");
    }
    let cov = match fix.position_cov.as_deref().copied() {
        Some(c) if c.iter().all(|v| v.is_finite()) && (0..3).all(|i| c[(i, i)] > 0.0) => c,
        _ => {
            let Some(hdop) = fix.hdop.filter(|h| h.is_finite() && *h > 0.0) else {
                return Err("no accuracy (covariance or HDOP)");
            };
            let vdop = fix
                .vdop
                .filter(|v| v.is_finite() && *v > 0.0)
                .unwrap_or(1.5 * hdop);
            let h = (hdop * cfg.gnss_uere_m).powi(2);
            let v = (vdop * cfg.gnss_uere_m).powi(2);
            Matrix3::from_diagonal(&Vector3::new(h, h, v))
        }
    };
    if cov[(0, 0)].max(cov[(1, 1)]) > cfg.gnss_max_var {
        return Err("accuracy worse than gnss_max_var");
    }
    Ok(cov)
}

pub fn process(core: &mut Core, ctx: &Ctx, t: i64, source: &str, fix: &GnssFix) {
    let cfg = ctx.cfg;
    let cov = match checks(fix, cfg) {
        Ok(c) => c,
        Err(why) => {
            core.reject(t, source, why, ctx);
            return;
        }
    };
    let bias_std = bias_std(&cov, cfg);
    // Control: origin.
    let origin = match core.gnss.origin {
        Some(o) => o,
        None => {
            let at_fix = LocalEnu::new(fix.lat_deg, fix.lon_deg, fix.alt_m);
            let origin = match core.position() {
                Some(p) => {
                    // Place the origin so that this fix is where we already are.
                    let (lat, lon, alt) = at_fix.to_geodetic(-p);
                    if let Some(bank) = core.ekf.as_mut() {
                        let yaw_var = cfg.yaw_error_std * cfg.yaw_error_std;
                        bank.each(|ekf| {
                            ekf.add_frame_uncertainty(&cov);
                            ekf.add_heading_uncertainty(yaw_var);
                            ekf.end_drift();
                        });
                    }
                    core.wrls.add_frame_uncertainty(&cov);
                    LocalEnu::new(lat, lon, alt)
                }
                None => at_fix,
            };
            core.gnss.origin = Some(origin);
            // Where the vehicle is on Earth from here: no anchor of relative
            // navigation (see `integrity::DEFAULT_REANCHOR_FRACTION`) bounds it.
            core.integrity.anchored = None;
            core.event(
                t,
                Some(source),
                format!(
                    "ENU origin set from GNSS at {:.7}, {:.7}, {:.2} m",
                    origin.origin_lat_deg, origin.origin_lon_deg, origin.origin_alt_m
                ),
                Event::OriginSet {
                    lat: origin.origin_lat_deg,
                    lon: origin.origin_lon_deg,
                    alt: origin.origin_alt_m,
                },
            );
            origin
        }
    };
    let enu = origin.to_enu(fix.lat_deg, fix.lon_deg, fix.alt_m);
    core.debug_point(t, DebugTopic::OriUavGps, source, enu);
    if let Some((_, last)) = core.gnss.last.get(source) {
        core.debug_point(t, DebugTopic::OriginDgps, source, enu - last);
    }
    core.gnss.last.put(source, (t, enu));
    let vel = fix
        .velocity
        .filter(|v| cfg.gnss_fuse_velocity && v.iter().all(|x| x.is_finite()));
    let vel_noise = cfg.source(source).vel_noise.unwrap_or(cfg.gnss_vel_noise);
    // The slow part of the error: a fraction of the variance the receiver reports (at
    // most the configured 1σ), a state of the filter; the rest is white. A configured
    // noise is the white part (1σ horizontal; vertical keeps the message's ratio).
    let white = match cfg.source(source).noise {
        Some(s) => {
            let ratio = (cov[(2, 2)] / cov[(0, 0)].max(1e-12)).max(1.0);
            Matrix3::from_diagonal(&Vector3::new(s * s, s * s, s * s * ratio))
        }
        None => {
            let mut w = cov;
            for i in 0..3 {
                w[(i, i)] = (cov[(i, i)] - bias_std[i] * bias_std[i]).max(0.05 * cov[(i, i)]);
            }
            w
        }
    };
    // The slow error's model is at least what the receiver was found off by lately: a
    // Gauss-Markov error of its reported size cannot be metres off, and the filter,
    // told so, learnt within 2 s that the reset position was not that uncertain.
    let model_std = bias_std.sup(&core.gnss.doubt_at(source, t, cfg.gnss_bias_tau_s));
    if let Some(bank) = core.ekf.as_mut() {
        bank.each(|e| e.gnss_bias_std = model_std);
    }
    core.wrls.add_absolute(source, enu, cov.diagonal());
    core.monitors
        .gps_fix(t, enu, vel, fix.velocity_up_known, cfg);
    if !core.initialised() {
        core.gnss_bias_prior = Some(bias_std);
        if core.att.known() {
            let v_var = vel.map(|_| Vector3::repeat(vel_noise * vel_noise));
            core.initialise(t, source, enu, cov.diagonal(), vel, v_var, ctx);
            // Started at this fix: its error is the fix's, whose slow part the bias
            // states hold (a source's kind is known only once it has been fused).
            let slow_var = bias_std.component_mul(&bias_std);
            if let Some(bank) = core.ekf.as_mut() {
                bank.each(|e| e.tie_to_gnss_bias(slow_var));
            }
        }
        return;
    }
    // What this fix teaches the estimate of where it is, it teaches unchecked: with no
    // second receiver, nothing else measures the absolute position, and the error the
    // receiver does not report (multipath; `[integrity] gnss_fault_horizontal_m`) rides
    // in with it and stays until it changes. A fix after an outage, onto an estimate
    // metres uncertain, carries that allowance as doubt on its slow error, so that the
    // σ sent says it (randomised draws 785 and 659: reset onto 14 m of multipath, and
    // fused 3.5 m off after a 75 s outage, both sent with σ 0.5-1.6 m); a fix onto an
    // estimate that already knew where it was teaches it nothing, and adds nothing.
    let lost = lost(core, cfg, t);
    let taught = unchecked_doubt(core, ctx, t, source, &cov, &enu, lost);
    if taught != Vector3::zeros() {
        carry_doubt(core, source, t, &taught, cfg.gnss_bias_tau_s);
    }
    // Control: after a spell without any position source the estimate has drifted by an
    // unknown amount; the first fix resets the position to it (PX4's reset_pos_to_gps)
    // rather than being gated out, and the reset counter tells the autopilot (`lost`).
    // A receiver whose positions the gate refused for `reject_reset_s` (multipath coming
    // in looks exactly so; or the estimate drifted) and that is reset to after an
    // outage: which of the two was wrong nobody knows.
    let reject_reset = (cfg.reject_reset_s * 1e6) as i64;
    let refused_since = core.gnss.refused_since.get(source).copied().flatten();
    let excluded = core.integrity.is_excluded(source);
    // Excluded by the integrity monitor is refused too: it disagreed with the rest.
    let refused_long = excluded || refused_since.is_some_and(|since| t - since >= reject_reset);
    // A receiver the estimate was refusing while another source held the horizontal is
    // not reset to a moment after that source is gone: the IMU has barely moved the
    // estimate since, and what said the receiver was wrong still stands; after
    // `reject_reset_s` without that source it is. Randomised draws 334 and 238: a flow
    // gone for 1.2 s, the estimate (1.4 m off, σ 2 m) was reset 14 m and 10 m onto the
    // receiver's multipath that the gate, and the separation test, had refused for
    // seconds (integrity failures, 4 poses). A receiver alone all along is reset to as
    // before: its refusals are the estimate's own drift as likely (the lock-out).
    let others = core
        .integrity
        .channels
        .iter()
        .filter(|(s, _)| s.as_str() != source)
        .filter_map(|(_, c)| c.horizontal)
        .max();
    let spell = others.map_or(i64::MAX, |l| t - l);
    let short_spell = (refused_since.is_some() || excluded) && spell < reject_reset;
    if lost && !short_spell && core.mode_ekf_direct {
        if let Some(jump) = core.ekf.as_ref().map(|b| enu - b.gnss_bias() - b.pos()) {
            let v_var = vel_noise * vel_noise;
            if refused_long {
                // Refused up to the outage (by the gate, or by the test while health
                // held it out): its slow error may be the whole jump, and the position
                // taken through it is that uncertain (randomised draw 86: reset 10.7 m
                // onto a multipath offset with σ 1 m).
                carry_doubt(core, source, t, &jump.abs(), cfg.gnss_bias_tau_s);
            }
            if let Some(bank) = core.ekf.as_mut() {
                bank.each(|ekf| ekf.reset_pos_vel_through_bias(enu, vel, cov.diagonal(), v_var));
            }
            for st in core.odom.values_mut() {
                st.align = None;
            }
            core.reset_counter = core.reset_counter.wrapping_add(1);
            let gap_s = core
                .unaided_since
                .or(core.last_aiding)
                .map(|l| (t - l) as f64 * 1e-6);
            let jump = jump.norm();
            core.event(
                t,
                Some(source),
                format!(
                    "position reset to {source} after {} without position sources (moved {jump:.2} m)",
                    gap_s.map(|g| format!("{g:.1} s")).unwrap_or_else(|| "a spell".into())
                ),
                Event::Reset(crate::event::Reset::Gnss {
                    reset_counter: core.reset_counter,
                    jump_m: jump,
                    gap_s,
                }),
            );
            core.aided(t, "gnss");
            core.unaided_since = None;
            core.gnss.last_fused = Some(t);
            core.gnss.passed(source);
            return;
        }
    }
    // Fuse: the slow part of the error is the bias state, the rest is white.
    let accepted = core.fuse_position(t, source, "gnss", enu, &white, None, ctx);
    if accepted {
        core.gnss.last_fused = Some(t);
        core.unaided_since = None;
        core.gnss.passed(source);
    } else if core.initialised() {
        core.gnss.refused(source, t);
    }
    if let Some(v) = vel {
        let r = Matrix3::identity() * (vel_noise * vel_noise);
        // Only what was measured: GPS_RAW_INT's velocity has no up component.
        let rows = if fix.velocity_up_known { 3 } else { 2 };
        core.fuse_world_velocity(t, source, v, &r, rows, ctx);
    }
}

/// `source`'s slow error is at least `at_least` uncertain (1σ per axis, m), or what its
/// doubt still says: in every filter's bias state and its model, and remembered to fade
/// over `tau_s` (see [`GnssState::doubt_at`]).
fn carry_doubt(core: &mut Core, source: &str, t: i64, at_least: &Vector3<f64>, tau_s: f64) {
    let doubt = at_least.sup(&core.gnss.doubt_at(source, t, tau_s));
    if let Some(bank) = core.ekf.as_mut() {
        bank.each(|ekf| {
            ekf.gnss_bias_std = ekf.gnss_bias_std.sup(&doubt);
            ekf.widen_gnss_bias(&doubt);
        });
    }
    *core.gnss.doubt.get_or_insert_with(source, || None) = Some((t, doubt));
}

/// The doubt a fix of `source` (covariance `cov`) brings in unchecked, 1σ per axis (m):
/// on the horizontal axes, the part of the estimate's uncertainty it removes, at most the
/// fault allowance as a 2σ bound per axis; none while another receiver checks it, nor
/// while GNSS positions are being fused.
fn unchecked_doubt(
    core: &Core,
    ctx: &Ctx,
    t: i64,
    source: &str,
    cov: &Matrix3<f64>,
    enu: &Vector3<f64>,
    lost: bool,
) -> Vector3<f64> {
    let cfg = ctx.cfg;
    let Some(bank) = core.ekf.as_ref() else {
        return Vector3::zeros();
    };
    // Only a receiver back from an outage (or its first fix): one fused all along holds
    // what the estimate knows, and its slow error is the bias state's to track.
    let timeout = (cfg.aiding_timeout_ms * 1000.0) as i64;
    let window = integrity::channel_window(cfg);
    if core.gnss.last_fused.is_some_and(|l| t - l <= timeout)
        || integrity::gnss_receivers(core, t, true, window, Some(source)) > 0
    {
        return Vector3::zeros();
    }
    let cap = cfg.integrity.gnss_fault_horizontal_m / (2.0 * std::f64::consts::SQRT_2);
    let prior = bank.main().cov3(IDX_P);
    // Lost, the fix resets the position, and the σ the estimate had is the no-aiding
    // hold's, which says nothing of where the vehicle is: what the fix teaches is
    // the jump it makes (randomised seed 3, draw 19: a 1 Hz receiver back from a 2.8 s
    // outage 8.5 m into multipath, reset onto while the hold said σ 1.3 m: 2 182 poses
    // beyond 5σ). The whole allowance on every reset, tried, cost flights reset after
    // 1 s outages up to 8 points of validity for nothing (seed 1, draws 110 and 227).
    let jump = if lost {
        (enu - bank.gnss_bias() - bank.pos()).abs()
    } else {
        Vector3::zeros()
    };
    // Of the jump, what the dead reckoning could have carried the estimate since the
    // last fix on an accelerometer off by the fault allowance is the estimate's (½·a·T²,
    // `dead_reckoning_fault_mps2`; a velocity fused since does not place it). The
    // rest, past the cap, is the receiver's, 1σ: no IMU explains it. A GNSS-only
    // vehicle whose receiver stepped 40 m was reset onto it a second after its last
    // fix and sent valid 39 m off the truth with σ 3.9 m; 30 s of a 2° tilt error carry
    // the IMU's own 135 m.
    let gap_s = core
        .gnss
        .last_fused
        .map_or(f64::INFINITY, |l| (t - l) as f64 * 1e-6);
    let carried = 0.5 * cfg.dead_reckoning_fault_mps2 * gap_s * gap_s;
    let size = jump.xy().norm();
    let receivers = if size > carried {
        jump * ((size - carried) / size)
    } else {
        Vector3::zeros()
    };
    let taught = |a: usize| {
        (prior[(a, a)] - cov[(a, a)])
            .max(0.0)
            .sqrt()
            .max(jump[a])
            .min(cap)
            .max(receivers[a])
    };
    Vector3::new(taught(0), taught(1), 0.0)
}

/// Whether the estimate no longer knows where it is: no horizontal position source for
/// `aiding_timeout_ms`, or held by the no-aiding constraints (the hold is not where the
/// vehicle is). The next fix resets the position to it.
fn lost(core: &Core, cfg: &EstimatorConfig, t: i64) -> bool {
    let timeout = (cfg.aiding_timeout_ms * 1000.0) as i64;
    core.unaided_since.is_some() || core.ground.last_h_aiding.is_none_or(|l| t - l > timeout)
}

/// 1σ per axis of the slow part of a fix's error whose covariance is `cov`.
pub fn bias_std(cov: &Matrix3<f64>, cfg: &EstimatorConfig) -> Vector3<f64> {
    let f = cfg.gnss_bias_fraction.clamp(0.0, 1.0);
    let cap = [
        cfg.gnss_bias_std_m,
        cfg.gnss_bias_std_m,
        cfg.gnss_bias_std_v_m,
    ];
    Vector3::from_fn(|i, _| (f * cov[(i, i)].max(0.0)).sqrt().min(cap[i]))
}

/// A fix from a GNSS the health layer took out: only its innovation test, on a copy
/// of the filter (see [`Core::probe_position`]).
pub fn probe(core: &mut Core, ctx: &Ctx, t: i64, source: &str, fix: &GnssFix) {
    let (Ok(cov), Some(origin)) = (checks(fix, ctx.cfg), core.gnss.origin) else {
        return;
    };
    if core.ekf.is_none() || !core.mode_ekf_direct {
        return;
    }
    let enu = origin.to_enu(fix.lat_deg, fix.lon_deg, fix.alt_m);
    // Beyond the gate while held out is a refusal like the gate's own: a reset onto
    // it later cannot tell multipath from drift (randomised draw 967: held out 17 s
    // while multipath ran in to 14 m, then reset onto with σ 0.6 m).
    if core
        .probe_position(t, source, "gnss", enu, &cov, ctx)
        .is_some_and(|ratio| ratio > 1.0)
    {
        core.gnss.refused(source, t);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fix(kind: GnssFixType) -> GnssFix {
        GnssFix {
            lat_deg: 47.0,
            lon_deg: 8.0,
            alt_m: 400.0,
            fix: kind,
            position_cov: None,
            satellites: Some(10),
            hdop: Some(0.8),
            vdop: None,
            velocity: None,
            velocity_up_known: false,
        }
    }

    #[test]
    fn no_fix_is_skipped_and_hdop_gives_the_variance() {
        let cfg = EstimatorConfig::default();
        assert!(checks(&fix(GnssFixType::NoFix), &cfg).is_err());
        let c = checks(&fix(GnssFixType::Fix3d), &cfg).expect("3d fix");
        assert!((c[(0, 0)] - (0.8f64 * 2.5).powi(2)).abs() < 1e-12);
        assert!((c[(2, 2)] - (1.2f64 * 2.5).powi(2)).abs() < 1e-12);
        let mut bad = fix(GnssFixType::Fix3d);
        bad.hdop = Some(5.0);
        assert!(checks(&bad, &cfg).is_err());
    }
}
