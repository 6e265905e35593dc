//! IMU: drives the prediction. Checks (finite, plausible), control (attitude source,
//! gyro bias from the autopilot's rates), fuse (= the EKF/monitor prediction step,
//! done by the core when time advances).

use super::attitude::check_quaternion;
use super::config::EstimatorConfig;
use super::{Core, Ctx, DebugTopic, Event};
use crate::sample::{Attitude, Imu};
use nalgebra::{Matrix3, Vector3};

/// Largest plausible specific force, m/s², and rate, rad/s.
const MAX_ACCEL: f64 = 160.0;
const MAX_GYRO: f64 = 35.0;

/// The IMU sample the prediction holds until the next one.
#[derive(Debug, Clone, PartialEq)]
pub struct ImuInput {
    pub t: i64,
    pub gyro: Option<Vector3<f64>>,
    pub accel: Option<Vector3<f64>>,
    /// Specific-force variance per axis for one sample, (m/s²)².
    pub accel_var: f64,
}

/// First-order low-pass of a vector (seed 001's LPF_1_, with the proper 2π).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Lpf3 {
    pub y: Option<Vector3<f64>>,
    pub t: Option<i64>,
}

impl Lpf3 {
    pub fn update(&mut self, x: Vector3<f64>, t: i64, hz: f64) -> Vector3<f64> {
        let y = match (self.y, self.t) {
            (Some(y), Some(t0)) if hz > 0.0 && t > t0 => {
                let dt = (t - t0) as f64 * 1e-6;
                let alpha = dt / (dt + 1.0 / (2.0 * std::f64::consts::PI * hz));
                y + (x - y) * alpha.min(1.0)
            }
            (Some(y), Some(t0)) if hz > 0.0 && t <= t0 => y,
            _ => x,
        };
        self.y = Some(y);
        self.t = Some(t);
        y
    }
}

#[derive(Debug, Clone, PartialEq, Default)]
pub struct ImuState {
    pub last: Option<ImuInput>,
    /// Gyro bias estimated against the autopilot's (bias-corrected) rates.
    pub gyro_bias: Vector3<f64>,
    pub bias_from_rates: bool,
    /// Latest bias-corrected body rate, rad/s.
    pub rate: Option<(i64, Vector3<f64>)>,
}

fn finite3(v: &Vector3<f64>) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// Checks: reject non-finite or implausible values.
pub fn checks(imu: &Imu) -> Result<(), &'static str> {
    if let Some(g) = imu.gyro {
        if !finite3(&g) || g.norm() > MAX_GYRO {
            return Err("gyro not finite or out of range");
        }
    }
    if let Some(a) = imu.accel {
        if !finite3(&a) || a.norm() > MAX_ACCEL {
            return Err("accel not finite or out of range");
        }
    }
    if let Some(q) = &imu.orientation {
        if !check_quaternion(q) {
            return Err("orientation not a unit quaternion");
        }
    }
    if imu.gyro.is_none() && imu.accel.is_none() && imu.orientation.is_none() {
        return Err("empty IMU sample");
    }
    Ok(())
}

/// Per-sample specific-force variance: the message's covariance, else the density.
fn accel_var(imu: &Imu, dt: f64, cfg: &EstimatorConfig) -> f64 {
    match imu.accel_cov {
        Some(c) if c.trace().is_finite() && c.trace() > 0.0 => c.trace() / 3.0,
        _ => cfg.accel_noise_density.powi(2) / dt.max(1e-3),
    }
}

/// Process one IMU sample at host time `t` (the core has already predicted to `t`
/// with the previous sample).
pub fn process(core: &mut Core, ctx: &Ctx, t: i64, source: &str, imu: &Imu) {
    if let Err(why) = checks(imu) {
        core.reject(t, source, why, ctx);
        return;
    }
    let cfg = ctx.cfg;
    let dt = core
        .imu
        .last
        .as_ref()
        .map_or(0.005, |l| ((t - l.t) as f64 * 1e-6).clamp(1e-4, 0.1));
    // Control: attitude. An orientation in the message is an external attitude.
    if let Some(q) = imu.orientation {
        let cov = imu
            .orientation_cov
            .filter(|c| c.iter().all(|v| v.is_finite()) && c.trace() > 0.0)
            .unwrap_or_else(|| Matrix3::identity() * cfg.attitude_noise_rad.powi(2));
        core.att.on_external(t, q, cov, None, true);
    }
    let ext_yaw = core.odometry_heading();
    if core.att.on_imu(t, imu.gyro, imu.accel, dt, ext_yaw, cfg) {
        let src = core.att.source.as_str();
        core.event(
            t,
            Some(source),
            format!("attitude source is now {src}"),
            Event::SourceSwitch(crate::event::SourceSwitch::Attitude { attitude: src }),
        );
    }
    if core.att.source == super::attitude::AttitudeSource::Own {
        core.imu.gyro_bias = core.att.own.bias;
    }
    super::ground::imu_sample(&mut core.ground, t, imu.gyro, imu.accel);
    let rate = imu.gyro.map(|g| g - core.imu.gyro_bias);
    if let Some(w) = rate {
        core.imu.rate = Some((t, w));
        core.flow_gyro_sample(t, w, ctx);
        core.debug_point(t, DebugTopic::ImuAngularVelocity, source, w);
    }
    core.imu.last = Some(ImuInput {
        t,
        gyro: imu.gyro,
        accel: imu.accel,
        accel_var: accel_var(imu, dt, cfg),
    });
    core.mark_used(t, source);
}

/// An autopilot attitude sample.
pub fn process_attitude(core: &mut Core, ctx: &Ctx, t: i64, source: &str, a: &Attitude) {
    if !check_quaternion(&a.orientation) {
        core.reject(t, source, "attitude not a unit quaternion", ctx);
        return;
    }
    let cfg = ctx.cfg;
    let cov = Matrix3::identity() * cfg.attitude_noise_rad.powi(2);
    // Keep the IMU's own orientation when it has one (same clock as the prediction).
    if core.att.source != super::attitude::AttitudeSource::Imu
        || core
            .att
            .ext
            .as_ref()
            .is_none_or(|e| t - e.0 > (cfg.attitude_timeout_ms * 1000.0) as i64)
    {
        core.att.on_external(t, a.orientation, cov, a.rates, false);
    }
    // Gyro bias against the autopilot's rates (they are bias-corrected by its filter).
    if let (Some(rates), Some(last)) = (a.rates, core.imu.last.as_ref()) {
        if let Some(g) = last.gyro {
            if rates.iter().all(|v| v.is_finite()) && (t - last.t).abs() < 20_000 {
                let k = (0.02 / cfg.gyro_bias_tau_s.max(0.02)).min(1.0);
                core.imu.gyro_bias += ((g - rates) - core.imu.gyro_bias) * k;
                core.imu.bias_from_rates = true;
            }
        }
    }
    if core.imu.last.is_none() {
        // No IMU: the autopilot's rates feed the flow compensation.
        if let Some(w) = a.rates.filter(|r| r.iter().all(|v| v.is_finite())) {
            core.imu.rate = Some((t, w));
            core.flow_gyro_sample(t, w, ctx);
        }
    }
    core.mark_used(t, source);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lpf_converges_and_lags() {
        let mut f = Lpf3::default();
        let mut y = Vector3::zeros();
        for i in 0..400 {
            y = f.update(Vector3::new(1.0, 0.0, 0.0), i * 5_000, 3.0);
        }
        assert!((y.x - 1.0).abs() < 1e-6);
        let mut f = Lpf3::default();
        f.update(Vector3::zeros(), 0, 3.0);
        let y = f.update(Vector3::new(1.0, 0.0, 0.0), 5_000, 3.0);
        // α = dt / (dt + 1/(2π·3)) ≈ 0.086.
        assert!((y.x - 0.0861).abs() < 1e-3, "{}", y.x);
    }

    #[test]
    fn implausible_imu_is_rejected() {
        let imu = Imu {
            gyro: Some(Vector3::new(f64::NAN, 0.0, 0.0)),
            accel: None,
            orientation: None,
            gyro_cov: None,
            accel_cov: None,
            orientation_cov: None,
        };
        assert!(checks(&imu).is_err());
    }
}
