//! Range finder (downward): height above the terrain (a state, flat unless reset).
//!
//! Checks: finite, strictly inside (min, max) (config overrides the sample's limits; a
//! reading at a limit is a clamp, not a distance), not flagged invalid by the sensor
//! (a reading at or below the minimum still says "on the ground"), pointing down, tilt
//! below `range_max_tilt_rad`, and good for `range_quality_hold_ms` since the last
//! reading flagged invalid or at/beyond the maximum, or since a gap of as long in its
//! readings (EKF2's quality hysteresis: a sonar out of range hears stray echoes, and
//! one of them is no height). Control: kept as the flow's height; fused when the filter is
//! initialised. Terrain reset (EKF2's `resetTerrainToRng`), when the reading fails the
//! innovation gate and either follows readings at or below the minimum (the vehicle
//! left the surface it stood on; the ground constraint's height no longer applies),
//! or steps from the previous reading faster than [`RANGE_STEP_SPEED`] (no vehicle
//! climbs or sinks that fast: the edge of a table or a roof passed below), or no
//! reading of this source has passed for [`HGT_FUSION_TIMEOUT_US`] (EKF2's
//! `hgt_fusion_timeout_max`: the ground under it has changed for good). The terrain
//! moves, the vehicle does not; a lone spike resets it twice and leaves the pose alone.
//! Fuse: h = d · cos(tilt), 1-D, against z − terrain.

use super::attitude::cos_tilt;
use super::config::{DEFAULT_RANGE_MAX_M, DEFAULT_RANGE_MIN_M};
use super::ekf::Measurement;
use super::{Core, Ctx, Event};
use crate::sample::Range;

/// A range source none of whose readings passed the gate for this long resets the
/// terrain to its reading, µs (EKF2's `hgt_fusion_timeout_max`).
pub const HGT_FUSION_TIMEOUT_US: i64 = 5_000_000;
/// A change of reading faster than this, m/s, is the ground stepping, not the vehicle
/// moving (multirotors climb at 2.5–3 m/s: ArduPilot PILOT_SPEED_UP, PX4
/// MPC_Z_VEL_MAX_UP).
pub const RANGE_STEP_SPEED: f64 = 10.0;

/// Why a good reading soon after bad ones is not fused.
const RECOVERING: &str =
    "good again for less than range_quality_hold_ms after an invalid or out-of-range reading";

/// MAV_SENSOR_ROTATION_PITCH_270: downward.
const MAV_SENSOR_DOWN: u8 = 25;
/// DISTANCE_SENSOR.signal_quality: 0 unknown, 1 invalid signal, 100 perfect (PX4's
/// `distance_sensor` 0, which EKF2 does not use either).
const SIGNAL_INVALID: u8 = 1;

/// A sensor whose last bad reading was at `bad_t` is still in its quality hold of
/// `hold_us` at `t` (a reading from before the bad one, arriving late, is not).
pub(super) fn in_hold(bad_t: Option<i64>, t: i64, hold_us: i64) -> bool {
    bad_t.is_some_and(|b| t >= b && t - b < hold_us)
}

pub fn checks(r: &Range, min: f64, max: f64) -> Result<(), &'static str> {
    if !r.distance_m.is_finite() {
        return Err("distance not finite");
    }
    if r.orientation.is_some_and(|o| o != MAV_SENSOR_DOWN) {
        return Err("range finder not pointing down");
    }
    if r.distance_m <= min || r.distance_m >= max {
        return Err("distance outside the sensor's range");
    }
    if r.signal_quality == Some(SIGNAL_INVALID) {
        return Err("the sensor flags the signal invalid");
    }
    Ok(())
}

pub fn process(core: &mut Core, ctx: &Ctx, t: i64, source: &str, r: &Range) {
    let cfg = ctx.cfg;
    let sc = cfg.source(source);
    let min = sc.min_m.or(r.min_m).unwrap_or(DEFAULT_RANGE_MIN_M);
    let max = sc.max_m.or(r.max_m).unwrap_or(DEFAULT_RANGE_MAX_M);
    let hold = (cfg.range_quality_hold_ms * 1000.0) as i64;
    // A gap in its readings (a dropout, health holding it out) restarts the hysteresis
    // as a bad reading does: what a sonar above its range hears first after one is as
    // likely an echo (randomised draw 480: the first reading after a 7 s stop, 0.5 m at
    // 10.5 m, moved the terrain 10 m and scaled the flow by it; the flow, refused by
    // the main filter, was taken by the one without the camera, and the camera was
    // excluded for it).
    let gap = core
        .stats
        .get(source)
        .and_then(|st| st.last_time_us)
        .is_none_or(|last| t - last > hold);
    if gap {
        core.range_bad.put(source, t);
    }
    let down = r.orientation.is_none_or(|o| o == MAV_SENSOR_DOWN);
    if down && r.distance_m.is_finite() && r.distance_m <= min {
        // At or below its minimum a downward range finder is on its gear (or closer to
        // something than it can measure): evidence of the ground, not a height.
        super::ground::range_sample(&mut core.ground, t, r.distance_m, min, true);
        core.mark_seen(t, source, "range");
        return;
    }
    if let Err(why) = checks(r, min, max) {
        // Out of range above, or flagged bad: the hysteresis starts again.
        if r.distance_m >= max || r.signal_quality == Some(SIGNAL_INVALID) {
            *core.range_bad.get_or_insert_with(source, || t) = t;
        }
        if down && r.distance_m >= max {
            super::ground::range_high_sample(&mut core.ground, t);
        }
        core.reject(t, source, why, ctx);
        return;
    }
    if in_hold(core.range_bad.get(source).copied(), t, hold) {
        core.reject(t, source, RECOVERING, ctx);
        return;
    }
    let after_ground = core.ground.range_says_ground(t);
    super::ground::range_sample(&mut core.ground, t, r.distance_m, min, false);
    let ct = cos_tilt(&core.att.q);
    if !core.att.known() || ct < cfg.range_max_tilt_rad.cos() {
        core.reject(t, source, "tilt too large for the range finder", ctx);
        return;
    }
    // Kept as the flow's scale only when it is a distance to the ground below.
    let previous = core.range.put(source, (t, r.distance_m));
    let stepped = previous.is_some_and(|(tp, dp)| {
        let dt = (t - tp) as f64 * 1e-6;
        dt > 0.0 && dt < 1.0 && (r.distance_m - dp).abs() > RANGE_STEP_SPEED * dt
    });
    let noise = sc.noise.unwrap_or(cfg.range_noise);
    let var = r
        .variance
        .filter(|v| v.is_finite() && *v > 0.0 && sc.noise.is_none())
        .unwrap_or(noise * noise);
    let h = r.distance_m * ct;
    core.wrls.add_height(source, h, var * ct * ct);
    if core.initialised() {
        let failing = core
            .stats
            .get(source)
            .and_then(|st| st.last_fused_us)
            .is_none_or(|f| t - f > HGT_FUSION_TIMEOUT_US);
        if after_ground || stepped || failing {
            reset_terrain_if_rejected(core, ctx, t, source, r.distance_m, var);
        }
        fuse_height(core, ctx, t, source, r.distance_m, var);
    }
}

/// Start condition of a range source after the ground or a long rejection: a reading
/// the gate would refuse moves the terrain under the vehicle instead.
fn reset_terrain_if_rejected(
    core: &mut Core,
    ctx: &Ctx,
    t: i64,
    source: &str,
    slant: f64,
    var: f64,
) {
    let (h_meas, r) = height_of(core, slant, var);
    let Some(bank) = core.ekf.as_mut() else {
        return;
    };
    let before = bank.height_above_terrain();
    let ratio = bank.test_ratio(&Measurement::height(h_meas - before, r), ctx.gate(1));
    if ratio <= 1.0 {
        return;
    }
    // The terrain of every filter moves under its own height: none of them moves.
    bank.each(|ekf| ekf.reset_terrain(h_meas, r));
    core.event(
        t,
        Some(source),
        format!(
            "{source}: terrain reset, height above it {before:.2} -> {h_meas:.2} m (the ground under the vehicle changed)"
        ),
        Event::TerrainReset {
            from_m: before,
            to_m: h_meas,
            test_ratio: ratio,
        },
    );
}

/// Height above the terrain from a slant distance along the body's down axis, and its
/// variance (the reading's, and the tilt error's: d·sinθ·σθ).
fn height_of(core: &Core, slant: f64, var: f64) -> (f64, f64) {
    let ct = cos_tilt(&core.att.q);
    let tilt_var = (slant * (1.0 - ct * ct).max(0.0).sqrt()).powi(2) * core.att.cov[(0, 0)];
    (slant * ct, var * ct * ct + tilt_var)
}

/// Fuse a slant distance along the body's down axis as height (flat terrain, z = 0).
pub fn fuse_height(core: &mut Core, ctx: &Ctx, t: i64, source: &str, slant: f64, var: f64) {
    let (h, r) = height_of(core, slant, var);
    core.fuse_height(t, source, h, r, ctx);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clamped_readings_are_not_distances() {
        let mut r = Range {
            distance_m: 0.2,
            min_m: Some(0.2),
            max_m: Some(12.0),
            signal_quality: None,
            variance: None,
            orientation: Some(25),
        };
        assert!(checks(&r, 0.2, 12.0).is_err());
        r.distance_m = 2.0;
        assert!(checks(&r, 0.2, 12.0).is_ok());
        r.signal_quality = Some(SIGNAL_INVALID);
        assert_eq!(
            checks(&r, 0.2, 12.0),
            Err("the sensor flags the signal invalid")
        );
        r.signal_quality = Some(0); // unknown
        assert!(checks(&r, 0.2, 12.0).is_ok());
        r.orientation = Some(0);
        assert!(checks(&r, 0.2, 12.0).is_err());
    }
}
