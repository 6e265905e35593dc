//! Attitude: from the autopilot (Attitude samples, Imu.orientation) where given, else an
//! own complementary filter with gyro bias correction (PX4 attitude_estimator_q, seed
//! 004: δ = K_P·e + K_I·∫e, ω⁺ = ω⁻ + δ, q̇ = ½ q ⊗ ω⁺), where e comes from the
//! accelerometer (gravity direction) and, if available, an external heading.
//!
//! Checks: the quaternion is finite and normalisable. Control: the external attitude
//! is used while fresh (`attitude_timeout_ms`), else the own filter. Fuse: the chosen
//! attitude rotates the specific force in the EKF prediction.

use super::config::EstimatorConfig;
use nalgebra::{Matrix3, UnitQuaternion, Vector3};

/// Yaw (ENU, rad) of a body FLU → ENU rotation: heading of the body x axis.
pub fn yaw_of(q: &UnitQuaternion<f64>) -> f64 {
    let r = q.to_rotation_matrix();
    let m = r.matrix();
    m[(1, 0)].atan2(m[(0, 0)])
}

pub fn wrap_pi(a: f64) -> f64 {
    (a + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI) - std::f64::consts::PI
}

/// Cosine of the tilt: the world-z component of the body z axis.
pub fn cos_tilt(q: &UnitQuaternion<f64>) -> f64 {
    (q * Vector3::z()).z
}

/// PX4 attitude_estimator_q style complementary filter (FLU/ENU).
#[derive(Debug, Clone, PartialEq)]
pub struct ComplementaryAttitude {
    pub q: UnitQuaternion<f64>,
    /// Estimated gyro bias (rates = gyro - bias), rad/s.
    pub bias: Vector3<f64>,
    pub initialised: bool,
}

impl Default for ComplementaryAttitude {
    fn default() -> Self {
        Self {
            q: UnitQuaternion::identity(),
            bias: Vector3::zeros(),
            initialised: false,
        }
    }
}

impl ComplementaryAttitude {
    /// Level from the accelerometer, heading from `yaw` (or 0: free).
    pub fn init(&mut self, accel: Vector3<f64>, yaw: Option<f64>) -> bool {
        let n = accel.norm();
        if !(n.is_finite() && n > 1e-3) {
            return false;
        }
        let up = accel / n;
        let tilt = UnitQuaternion::rotation_between(&up, &Vector3::z())
            .unwrap_or_else(UnitQuaternion::identity);
        // tilt rotates the measured up (body) onto world z: it is body → world without
        // heading; add the heading about world z.
        let yaw0 = yaw_of(&tilt);
        let q =
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw.unwrap_or(0.0) - yaw0) * tilt;
        self.q = q;
        self.initialised = true;
        true
    }

    /// One step with gyro and accelerometer (body FLU) over `dt`, optionally an external
    /// heading (ENU yaw, rad).
    pub fn update(
        &mut self,
        gyro: Vector3<f64>,
        accel: Option<Vector3<f64>>,
        dt: f64,
        ext_yaw: Option<f64>,
        cfg: &EstimatorConfig,
    ) {
        if !self.initialised {
            if let Some(a) = accel {
                self.init(a, ext_yaw);
            }
            return;
        }
        if !(dt > 0.0 && dt < 1.0) {
            return;
        }
        let mut corr = Vector3::zeros();
        if let Some(yaw) = ext_yaw {
            let err = wrap_pi(yaw - yaw_of(&self.q));
            // World z in the body frame, scaled by the heading error.
            corr += self.q.inverse() * Vector3::z() * (err * cfg.att_w_ext_hdg);
        }
        if let Some(a) = accel {
            let n = a.norm();
            // Only trust the accelerometer near 1 g (PX4 subtracts the motion acceleration;
            // we have none at this level, so we skip strongly accelerated samples).
            if n.is_finite() && (n - super::ekf::GRAVITY).abs() < 0.3 * super::ekf::GRAVITY {
                let meas_up = a / n;
                let est_up = self.q.inverse() * Vector3::z();
                corr += meas_up.cross(&est_up) * cfg.att_w_acc;
            }
        }
        // Gyro bias: PI integral term (PX4 adds corr·w·dt to its negated bias).
        self.bias -= corr * (cfg.att_w_gyro_bias * dt);
        for i in 0..3 {
            self.bias[i] = self.bias[i].clamp(-cfg.att_bias_max, cfg.att_bias_max);
        }
        let rates = gyro - self.bias + corr;
        self.q *= UnitQuaternion::from_scaled_axis(rates * dt);
        self.q = UnitQuaternion::new_normalize(self.q.into_inner());
    }
}

/// Which attitude is in use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AttitudeSource {
    None,
    Imu,
    Autopilot,
    Own,
}

impl AttitudeSource {
    pub fn as_str(self) -> &'static str {
        match self {
            AttitudeSource::None => "none",
            AttitudeSource::Imu => "imu_orientation",
            AttitudeSource::Autopilot => "autopilot",
            AttitudeSource::Own => "own_filter",
        }
    }
}

/// An external attitude: (time, quaternion, covariance, body rates).
pub type ExternalAttitude = (i64, UnitQuaternion<f64>, Matrix3<f64>, Option<Vector3<f64>>);

/// The attitude the estimator uses, with its covariance and provenance.
#[derive(Debug, Clone, PartialEq)]
pub struct AttitudeState {
    pub q: UnitQuaternion<f64>,
    pub cov: Matrix3<f64>,
    pub source: AttitudeSource,
    /// External attitude: (time, quaternion, covariance, rates).
    pub ext: Option<ExternalAttitude>,
    pub own: ComplementaryAttitude,
    pub t: Option<i64>,
}

impl Default for AttitudeState {
    fn default() -> Self {
        Self {
            q: UnitQuaternion::identity(),
            cov: Matrix3::identity(),
            source: AttitudeSource::None,
            ext: None,
            own: ComplementaryAttitude::default(),
            t: None,
        }
    }
}

/// Check of an external quaternion.
pub fn check_quaternion(q: &UnitQuaternion<f64>) -> bool {
    let c = q.coords;
    c.iter().all(|v| v.is_finite()) && (c.norm() - 1.0).abs() < 1e-3
}

impl AttitudeState {
    pub fn known(&self) -> bool {
        self.source != AttitudeSource::None
    }

    /// An autopilot attitude sample.
    pub fn on_external(
        &mut self,
        t: i64,
        q: UnitQuaternion<f64>,
        cov: Matrix3<f64>,
        rates: Option<Vector3<f64>>,
        from_imu: bool,
    ) {
        self.ext = Some((t, q, cov, rates));
        self.q = q;
        self.cov = cov;
        self.t = Some(t);
        self.source = if from_imu {
            AttitudeSource::Imu
        } else {
            AttitudeSource::Autopilot
        };
        // Keep the own filter aligned so a switch-over has no jump.
        self.own.q = q;
        self.own.initialised = true;
    }

    /// Attitude at IMU time `t`: the external one propagated with the gyro while fresh,
    /// else the own filter. Returns whether the source changed.
    pub fn on_imu(
        &mut self,
        t: i64,
        gyro: Option<Vector3<f64>>,
        accel: Option<Vector3<f64>>,
        dt: f64,
        ext_yaw: Option<f64>,
        cfg: &EstimatorConfig,
    ) -> bool {
        let before = self.source;
        let timeout = (cfg.attitude_timeout_ms * 1000.0) as i64;
        let fresh = self.ext.as_ref().filter(|e| t - e.0 <= timeout);
        if let Some(&(te, qe, cov, _)) = fresh {
            let dte = (t - te) as f64 * 1e-6;
            self.q = match gyro {
                Some(w) if dte > 0.0 => qe * UnitQuaternion::from_scaled_axis(w * dte),
                _ => qe,
            };
            self.cov = cov;
            // The own filter follows so a switch-over has no jump.
            self.own.q = self.q;
        } else if let Some(w) = gyro {
            self.own.update(w, accel, dt, ext_yaw, cfg);
            if self.own.initialised {
                self.q = self.own.q;
                let s = cfg.attitude_noise_rad;
                self.cov = Matrix3::identity() * (s * s);
                self.source = AttitudeSource::Own;
            }
        }
        self.t = Some(t);
        before != self.source
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn own_filter_levels_and_learns_gyro_bias() {
        let cfg = EstimatorConfig::default();
        let mut f = ComplementaryAttitude::default();
        // Start 0.3 rad rolled although the vehicle is level; the gyro has a bias.
        f.init(Vector3::new(0.0, 0.0, 9.8), Some(0.5));
        f.q = UnitQuaternion::from_euler_angles(0.3, 0.0, 0.5);
        let bias = Vector3::new(0.01, -0.02, 0.005);
        for _ in 0..(200 * 120) {
            f.update(
                bias,
                Some(Vector3::new(0.0, 0.0, 9.8)),
                0.005,
                Some(0.5),
                &cfg,
            );
        }
        let (r, p, y) = f.q.euler_angles();
        assert!(r.abs() < 1e-3 && p.abs() < 1e-3, "{r} {p}");
        assert!((y - 0.5).abs() < 1e-2, "{y}");
        assert!((f.bias - bias).norm() < 2e-3, "{}", f.bias);
    }

    #[test]
    fn yaw_and_tilt_helpers() {
        let q = UnitQuaternion::from_euler_angles(0.1, -0.2, 1.0);
        assert!((yaw_of(&q) - 1.0).abs() < 1e-12);
        assert!((cos_tilt(&q) - 0.1f64.cos() * 0.2f64.cos()).abs() < 1e-12);
        assert!((wrap_pi(2.5 * std::f64::consts::PI) - 0.5 * std::f64::consts::PI).abs() < 1e-9);
    }
}
