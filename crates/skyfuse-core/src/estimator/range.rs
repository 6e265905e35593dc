//! Range finder (downward): height above a flat terrain at z = 0 of the origin.
//!
//! Checks: finite, strictly inside (min, max) (config overrides the sample's limits; a
//! reading at a limit is a clamp, not a distance), pointing down, tilt below
//! `range_max_tilt_rad`. Control: kept as the flow's height; fused when the filter is
//! initialised. Fuse: z = d · cos(tilt), 1-D.

use super::attitude::cos_tilt;
use super::config::{DEFAULT_RANGE_MAX_M, DEFAULT_RANGE_MIN_M};
use super::{Core, Ctx};
use crate::sample::Range;

/// MAV_SENSOR_ROTATION_PITCH_270: downward.
const MAV_SENSOR_DOWN: u8 = 25;

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
    Ok(())
}

pub fn process(core: &mut Core, ctx: &Ctx, t: i64, source: &str, r: &Range) {
    let cfg = ctx.cfg;
    let sc = cfg.source(source);
    let min = sc.min_m.or(r.min_m).unwrap_or(DEFAULT_RANGE_MIN_M);
    let max = sc.max_m.or(r.max_m).unwrap_or(DEFAULT_RANGE_MAX_M);
    let down = r.orientation.is_none_or(|o| o == MAV_SENSOR_DOWN);
    if down && r.distance_m.is_finite() && r.distance_m <= min {
        // At or below its minimum a downward range finder is on its gear (or closer to
        // something than it can measure): evidence of the ground, not a height.
        super::ground::range_sample(&mut core.ground, t, r.distance_m, min, true);
        core.mark_seen(t, source, "range");
        return;
    }
    if let Err(why) = checks(r, min, max) {
        core.reject(t, source, why, ctx);
        return;
    }
    super::ground::range_sample(&mut core.ground, t, r.distance_m, min, false);
    core.range.insert(source.to_string(), (t, r.distance_m));
    let ct = cos_tilt(&core.att.q);
    if !core.att.known() || ct < cfg.range_max_tilt_rad.cos() {
        core.reject(t, source, "tilt too large for the range finder", ctx);
        return;
    }
    let noise = sc.noise.unwrap_or(cfg.range_noise);
    let var = r
        .variance
        .filter(|v| v.is_finite() && *v > 0.0 && sc.noise.is_none())
        .unwrap_or(noise * noise);
    let h = r.distance_m * ct;
    core.wrls.add_height(source, h, var * ct * ct);
    if core.initialised() {
        fuse_height(core, ctx, t, source, r.distance_m, var);
    }
}

/// Fuse a slant distance along the body's down axis as height (flat terrain, z = 0).
pub fn fuse_height(core: &mut Core, ctx: &Ctx, t: i64, source: &str, slant: f64, var: f64) {
    let ct = cos_tilt(&core.att.q);
    let h = slant * ct;
    // Attitude error moves the tilt cosine: d·sinθ·σθ.
    let tilt_var = (slant * (1.0 - ct * ct).max(0.0).sqrt()).powi(2) * core.att.cov[(0, 0)];
    let r = var * ct * ct + tilt_var;
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
        r.orientation = Some(0);
        assert!(checks(&r, 0.2, 12.0).is_err());
    }
}
