//! Barometer: a height whose datum nobody knows and which wanders (weather, temperature,
//! the vehicle's own downwash), as EKF2 and EKF3 use it. Pressure altitude (ISA) minus
//! an offset state per barometer, an odometry-style block carrying only relative
//! information: started at zero, correlated with the position, with a random walk of
//! `baro_drift_rw`. It holds the vehicle's height where no range finder reaches (a
//! PX4Flow's sonar ends at 3.7 m), so the range finder can keep the terrain.
//!
//! Checks: finite, a plausible pressure (the sample model refuses others). Control:
//! started once the filter is; restarted (a new datum, said in an event) after
//! [`RESTART_AFTER_US`] of continuous rejection. Fuse: 1-D, `alt − origin = p_z + b_z`.

use super::ekf::{Measurement, IDX_P};
use super::{Core, Ctx, Event};
use crate::sample::Baro;

/// A barometer whose every sample failed the gate this long starts a new datum, µs.
pub const RESTART_AFTER_US: i64 = 5_000_000;
/// The offset block's name in the filter: apart from the odometry sources' blocks.
pub fn block_name(source: &str) -> String {
    format!("{BLOCK_PREFIX}{source}")
}

/// What a barometer's offset block's name starts with.
pub const BLOCK_PREFIX: &str = "baro:";

/// Per barometer: the altitude that reads as the filter's height zero, and since when
/// its samples have been rejected.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BaroState {
    pub origin: Option<f64>,
    pub rejected_since: Option<i64>,
    /// Datums started after the first.
    pub restarts: u32,
}

pub fn process(core: &mut Core, ctx: &Ctx, t: i64, source: &str, b: &Baro) {
    let cfg = ctx.cfg;
    let alt = b.altitude_m();
    if !alt.is_finite() {
        core.reject(t, source, "pressure altitude not finite", ctx);
        return;
    }
    if !core.initialised() || !core.mode_ekf_direct {
        core.mark_seen(t, source, "baro");
        return;
    }
    let name = block_name(source);
    let mut st = core.baro.get(source).cloned().unwrap_or_default();
    let restart = st.rejected_since.is_some_and(|s| t - s >= RESTART_AFTER_US);
    let Some(bank) = core.ekf.as_mut() else {
        return;
    };
    if st.origin.is_none() || restart || bank.block(&name).is_none() {
        let idx = bank.each_main(|ekf| ekf.start_block(&name));
        let z = bank.x[IDX_P + 2] + bank.x[idx + 2];
        st.origin = Some(alt - z);
        if restart {
            st.restarts += 1;
            core.event(
                t,
                Some(source),
                format!(
                    "{source}: every sample rejected for {} s: a new datum",
                    RESTART_AFTER_US / 1_000_000
                ),
                Event::Segment {
                    segment: st.restarts,
                    reason: "barometer rejected too long".into(),
                    yaw_align: 0.0,
                },
            );
        }
        st.rejected_since = None;
        core.baro.put(source, st);
        core.mark_seen(t, source, "baro");
        return;
    }
    let ekf = &**bank;
    let Some(idx) = ekf.block(&name) else { return };
    let origin = st.origin.unwrap_or(0.0);
    let noise = cfg.source(source).noise.unwrap_or(cfg.baro_noise);
    let var = noise * noise;
    let pred = ekf.x[IDX_P + 2] + ekf.x[idx + 2];
    let mut m = Measurement::new(1);
    m.set_jacobian(0, IDX_P + 2, 1.0);
    m.set_jacobian(0, idx + 2, 1.0);
    m.set_innovation(0, (alt - origin) - pred);
    m.set_noise(0, 0, var);
    let accepted = core.update(t, source, "baro", &m, ctx);
    st.rejected_since = if accepted {
        None
    } else {
        st.rejected_since.or(Some(t))
    };
    core.baro.put(source, st);
}

#[cfg(test)]
mod tests {
    use crate::sample::Baro;

    #[test]
    fn pressure_altitude_is_isa() {
        let at = |p: f64| {
            Baro {
                pressure_pa: p,
                temperature_c: None,
                variance: None,
            }
            .altitude_m()
        };
        assert!(at(101_325.0).abs() < 1e-6);
        // ISA: 1000 m at 89 874.6 Pa; near the ground 12 Pa per metre.
        assert!((at(89_874.6) - 1000.0).abs() < 0.5, "{}", at(89_874.6));
        assert!((at(101_325.0 - 120.3) - 10.0).abs() < 0.05);
    }
}
