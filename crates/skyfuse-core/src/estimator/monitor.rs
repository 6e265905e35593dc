//! Divergence monitors (seed 002, "滤波监测"): two complementary filters run beside the
//! main filter.
//!
//! - GPS + IMU (outdoors): position/velocity integrated from the IMU and pulled to each
//!   GNSS fix with fixed gains (absolute).
//! - Flow + IMU (indoors): horizontal velocity integrated from the IMU and pulled to the
//!   flow velocity (seed 001's flow/accelerometer complementary filter); its position
//!   integrates that velocity and follows the main filter slowly (time constant
//!   `monitor_track_tau_s`), so only a departure faster than that counts.
//!
//! The applicable monitor is GPS while fixes arrive, else flow. When the main filter
//! departs from it by more than `monitor_pos_bound_m` (or the velocity by
//! `monitor_vel_bound_mps`) for `monitor_time_s`, the core resets the main filter to
//! the monitor's state with inflated covariance.

use super::config::EstimatorConfig;
use nalgebra::{Vector2, Vector3};

/// How long a monitor's input stays current, µs.
const GPS_FRESH_US: i64 = 1_000_000;
const FLOW_FRESH_US: i64 = 500_000;

#[derive(Debug, Clone, PartialEq)]
pub struct Cf {
    pub p: Vector3<f64>,
    pub v: Vector3<f64>,
    pub t: i64,
}

/// A reset the core must apply.
#[derive(Debug, Clone, PartialEq)]
pub struct MonitorReset {
    pub monitor: &'static str,
    pub position: Vector3<f64>,
    /// Which axes the monitor knows (flow: horizontal only).
    pub horizontal_only: bool,
    pub velocity: Vector3<f64>,
    pub reason: String,
    pub pos_err: f64,
    pub vel_err: f64,
}

#[derive(Debug, Clone, PartialEq, Default)]
pub struct Monitors {
    pub gps: Option<Cf>,
    pub flow: Option<Cf>,
    pub diverge_since: Option<i64>,
    /// (monitor, position departure, velocity departure) of the last check.
    pub last: Option<(&'static str, f64, f64)>,
    /// The last prediction was driven by an IMU. Without one the flow monitor is only a
    /// lagging copy of the flow: no reference for the main filter.
    pub imu: bool,
}

impl Monitors {
    /// Propagate both with the world acceleration (`imu`: measured by an IMU, not the
    /// constant-velocity stand-in).
    pub fn predict(&mut self, a_world: Vector3<f64>, dt: f64, imu: bool) {
        self.imu = imu;
        for cf in [self.gps.as_mut(), self.flow.as_mut()]
            .into_iter()
            .flatten()
        {
            cf.p += cf.v * dt + a_world * (0.5 * dt * dt);
            cf.v += a_world * dt;
        }
    }

    /// A fix at `z` with its velocity, whose up component is a measurement only when
    /// `up_known` (GPS_RAW_INT has none: the position's change steers it, as with no
    /// velocity at all).
    pub fn gps_fix(
        &mut self,
        t: i64,
        z: Vector3<f64>,
        vel: Option<Vector3<f64>>,
        up_known: bool,
        cfg: &EstimatorConfig,
    ) {
        match self.gps.as_mut() {
            Some(cf) if t - cf.t < GPS_FRESH_US * 5 => {
                let dt = ((t - cf.t) as f64 * 1e-6).max(0.0);
                let e = z - cf.p;
                cf.p += e * (cfg.monitor_gps_k_pos * dt).min(1.0);
                let from_position = e * (cfg.monitor_gps_k_vel * dt).min(1.0);
                match vel {
                    Some(v) => {
                        let mut dv = (v - cf.v) * (cfg.monitor_gps_k_vel * 3.0 * dt).min(1.0);
                        if !up_known {
                            dv.z = from_position.z;
                        }
                        cf.v += dv;
                    }
                    None => cf.v += from_position,
                }
                cf.t = t;
            }
            _ => {
                self.gps = Some(Cf {
                    p: z,
                    v: vel.unwrap_or_else(Vector3::zeros),
                    t,
                });
            }
        }
    }

    pub fn flow_velocity(
        &mut self,
        t: i64,
        v_nav: Vector2<f64>,
        main_p: Option<Vector3<f64>>,
        cfg: &EstimatorConfig,
    ) {
        let Some(main_p) = main_p else { return };
        match self.flow.as_mut() {
            Some(cf) if t - cf.t < FLOW_FRESH_US * 4 => {
                let dt = ((t - cf.t) as f64 * 1e-6).max(0.0);
                let k = (cfg.monitor_flow_k_vel * dt).min(1.0);
                cf.v.x += (v_nav.x - cf.v.x) * k;
                cf.v.y += (v_nav.y - cf.v.y) * k;
                let kp = (dt / cfg.monitor_track_tau_s.max(1e-3)).min(1.0);
                cf.p += (main_p - cf.p) * kp;
                cf.p.z = main_p.z;
                cf.v.z = 0.0;
                cf.t = t;
            }
            _ => {
                self.flow = Some(Cf {
                    p: main_p,
                    v: Vector3::new(v_nav.x, v_nav.y, 0.0),
                    t,
                });
            }
        }
    }

    /// Compare the main filter with the applicable monitor. A position departure counts
    /// only beyond `monitor_pos_bound_m` and three times the filter's own horizontal 1σ
    /// (`std_h`): within what the filter already says it may be off, it is no sign of
    /// divergence.
    pub fn check(
        &mut self,
        t: i64,
        p: Vector3<f64>,
        v: Vector3<f64>,
        std_h: f64,
        cfg: &EstimatorConfig,
    ) -> Option<MonitorReset> {
        if !cfg.monitor_enabled {
            return None;
        }
        let (name, cf, horizontal) = match (&self.gps, &self.flow) {
            (Some(g), _) if t - g.t < GPS_FRESH_US => ("gps_imu", g.clone(), false),
            (_, Some(f)) if t - f.t < FLOW_FRESH_US && self.imu => ("flow_imu", f.clone(), true),
            _ => {
                self.diverge_since = None;
                self.last = None;
                return None;
            }
        };
        let (pe, ve) = if horizontal {
            ((p - cf.p).xy().norm(), (v - cf.v).xy().norm())
        } else {
            ((p - cf.p).norm(), (v - cf.v).norm())
        };
        self.last = Some((name, pe, ve));
        if !cfg.monitor_reset {
            // Watched and shown, not acted on (see `DEFAULT_MONITOR_RESET`).
            self.diverge_since = None;
            return None;
        }
        let pos_bound = cfg.monitor_pos_bound_m.max(3.0 * std_h);
        if pe <= pos_bound && ve <= cfg.monitor_vel_bound_mps {
            self.diverge_since = None;
            return None;
        }
        let since = *self.diverge_since.get_or_insert(t);
        if (t - since) as f64 * 1e-6 < cfg.monitor_time_s {
            return None;
        }
        self.diverge_since = None;
        let reason = if pe > pos_bound {
            format!(
                "position departs from the {name} monitor by {pe:.2} m (> {pos_bound:.2} m) for {} s",
                cfg.monitor_time_s
            )
        } else {
            format!(
                "velocity departs from the {name} monitor by {ve:.2} m/s (> {} m/s) for {} s",
                cfg.monitor_vel_bound_mps, cfg.monitor_time_s
            )
        };
        Some(MonitorReset {
            monitor: name,
            position: cf.p,
            horizontal_only: horizontal,
            velocity: cf.v,
            reason,
            pos_err: pe,
            vel_err: ve,
        })
    }

    pub fn shift(&mut self, d: Vector3<f64>) {
        for cf in [self.gps.as_mut(), self.flow.as_mut()]
            .into_iter()
            .flatten()
        {
            cf.p += d;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn by_default_a_monitor_watches_and_resets_nothing() {
        let cfg = EstimatorConfig::default();
        let mut m = Monitors::default();
        for i in 0..40 {
            let t = i * 100_000;
            m.gps_fix(t, Vector3::new(1.0, 2.0, 3.0), None, true, &cfg);
            let r = m.check(t, Vector3::new(11.0, 2.0, 3.0), Vector3::zeros(), 0.5, &cfg);
            assert!(r.is_none(), "reset at {t}");
        }
        let (name, departure, _) = m.last.expect("watched");
        assert_eq!(name, "gps_imu");
        assert!((departure - 10.0).abs() < 1e-9, "{departure}");
    }

    #[test]
    fn departure_must_last_before_a_reset() {
        let cfg = EstimatorConfig {
            monitor_reset: true,
            ..EstimatorConfig::default()
        };
        let mut m = Monitors::default();
        for i in 0..40 {
            let t = i * 100_000;
            m.gps_fix(t, Vector3::new(1.0, 2.0, 3.0), None, true, &cfg);
            let r = m.check(t, Vector3::new(11.0, 2.0, 3.0), Vector3::zeros(), 0.5, &cfg);
            if t < 2_000_000 {
                assert!(r.is_none(), "too early at {t}");
            } else {
                let r = r.expect("reset after 2 s");
                assert_eq!(r.monitor, "gps_imu");
                assert!((r.position - Vector3::new(1.0, 2.0, 3.0)).norm() < 1e-9);
                return;
            }
        }
        panic!("no reset");
    }

    /// GPS_RAW_INT's velocity has no up component: in a 2 m/s climb the monitor's
    /// vertical speed follows the positions, not the 0 in the message's place.
    #[test]
    fn an_unmeasured_up_velocity_is_not_taken_for_zero() {
        let cfg = EstimatorConfig::default();
        let climb = |up_known: bool| {
            let mut m = Monitors::default();
            for i in 0..100_i64 {
                let t = i * 100_000;
                // A steady climb: the IMU measures no acceleration.
                m.predict(Vector3::zeros(), 0.1, true);
                let z = Vector3::new(0.0, 0.0, 2.0 * t as f64 * 1e-6);
                m.gps_fix(t, z, Some(Vector3::zeros()), up_known, &cfg);
            }
            m.gps.map(|cf| cf.v.z).unwrap_or(f64::NAN)
        };
        let (unknown, as_zero) = (climb(false), climb(true));
        assert!((unknown - 2.0).abs() < 0.5, "{unknown}");
        assert!(as_zero < unknown - 0.5, "{as_zero} vs {unknown}");
    }

    /// A departure within three times the filter's own 1σ is no divergence; the flow
    /// monitor is no reference without an IMU driving it.
    #[test]
    fn a_departure_the_filter_allows_for_or_an_unaided_flow_monitor_resets_nothing() {
        let cfg = EstimatorConfig {
            monitor_reset: true,
            ..EstimatorConfig::default()
        };
        let mut m = Monitors::default();
        for i in 0..40 {
            let t = i * 100_000;
            m.gps_fix(t, Vector3::new(1.0, 2.0, 3.0), None, true, &cfg);
            // 10 m off, but the filter says 1σ 4 m.
            let r = m.check(t, Vector3::new(11.0, 2.0, 3.0), Vector3::zeros(), 4.0, &cfg);
            assert!(r.is_none(), "reset at {t} within 3σ");
        }
        let mut m = Monitors::default();
        for i in 0..40 {
            let t = i * 100_000;
            m.predict(Vector3::zeros(), 0.1, false);
            m.flow_velocity(t, Vector2::new(1.0, 0.0), Some(Vector3::zeros()), &cfg);
            let r = m.check(t, Vector3::new(10.0, 0.0, 0.0), Vector3::zeros(), 0.1, &cfg);
            assert!(r.is_none(), "reset to a flow monitor without an IMU at {t}");
        }
        // The same with an IMU: it resets.
        let mut m = Monitors::default();
        let mut reset = false;
        for i in 0..40 {
            let t = i * 100_000;
            m.predict(Vector3::zeros(), 0.1, true);
            m.flow_velocity(t, Vector2::new(1.0, 0.0), Some(Vector3::zeros()), &cfg);
            reset |= m
                .check(t, Vector3::new(10.0, 0.0, 0.0), Vector3::zeros(), 0.1, &cfg)
                .is_some();
        }
        assert!(reset, "no reset with an IMU");
    }
}
