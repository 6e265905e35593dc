//! The output predictor: the fused state brought from the fusion horizon to the present.
//!
//! The filter runs on a delayed time horizon (see the facade in `mod.rs`): a measurement
//! is fused when the horizon reaches its time, so one that arrives late (a GNSS fix,
//! ~100 ms) costs one update instead of a re-run of the history. An autopilot needs the
//! pose of now; PX4's EKF2 keeps an output predictor for that. This one is exact rather
//! than a complementary filter: the IMU samples between the horizon and the present are
//! pre-integrated (cumulative rotation, specific-force velocity and position increments,
//! with the accelerometer-bias terms kept apart), so the present state is the horizon's
//! state plus the increments from there, O(1) per sample and per query. The increments
//! follow the filter's own prediction model (specific force held from one sample to the
//! next and rotated by the attitude at the start of the step; the gyro integrated as the
//! own attitude filter does it), so with no measurement in the span the result equals
//! the filter run up to the present.

use super::ekf::GRAVITY;
use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use std::collections::VecDeque;

/// The cumulative sums are re-based on the oldest kept sample this often, µs (their
/// second integrals grow with the square of the span).
const REBASE_EVERY_US: i64 = 1_000_000;

/// One IMU sample ahead of the horizon, with the increments from the anchor to it.
#[derive(Debug, Clone)]
struct Node {
    t: i64,
    /// Bias-corrected body rate, integrated over the step that ends at this sample.
    rate: Vector3<f64>,
    /// Specific force held from this sample to the next (None: the sample has none).
    accel: Option<Vector3<f64>>,
    sums: Sums,
}

/// Increments from the anchor, in the anchor's body frame: rotation `q`; Σ R f dt (`v1`),
/// Σ R dt (`m1`, the bias term) and Σ dt (`g1`, the gravity term) over the steps with a
/// specific force; `p1`, `m2`, `g2` their integrals once more.
#[derive(Debug, Clone)]
struct Sums {
    q: UnitQuaternion<f64>,
    v1: Vector3<f64>,
    m1: Matrix3<f64>,
    g1: f64,
    p1: Vector3<f64>,
    m2: Matrix3<f64>,
    g2: f64,
}

impl Sums {
    fn zero() -> Self {
        Self {
            q: UnitQuaternion::identity(),
            v1: Vector3::zeros(),
            m1: Matrix3::zeros(),
            g1: 0.0,
            p1: Vector3::zeros(),
            m2: Matrix3::zeros(),
            g2: 0.0,
        }
    }

    /// One step of `dt` s holding `accel` (None: no specific force, the filter's
    /// gravity-cancelling model), then the rotation by `rate` over `rot_dt`.
    fn step(&self, dt: f64, accel: Option<Vector3<f64>>, rate: Vector3<f64>, rot_dt: f64) -> Self {
        let mut s = self.clone();
        s.p1 += self.v1 * dt;
        s.m2 += self.m1 * dt;
        s.g2 += self.g1 * dt;
        if let Some(f) = accel {
            let r = *self.q.to_rotation_matrix().matrix();
            let half = 0.5 * dt * dt;
            s.p1 += r * f * half;
            s.m2 += r * half;
            s.g2 += half;
            s.v1 += r * f * dt;
            s.m1 += r * dt;
            s.g1 += dt;
        }
        s.q = self.q * UnitQuaternion::from_scaled_axis(rate * rot_dt);
        s
    }

    /// The increments from `self` (at `t0`) to `later` (at `t1`), in the body frame at `t0`.
    fn between(&self, later: &Sums, span: f64) -> Sums {
        let inv = self.q.inverse();
        let r = *inv.to_rotation_matrix().matrix();
        Sums {
            q: inv * later.q,
            v1: r * (later.v1 - self.v1),
            m1: r * (later.m1 - self.m1),
            g1: later.g1 - self.g1,
            p1: r * (later.p1 - self.p1 - self.v1 * span),
            m2: r * (later.m2 - self.m2 - self.m1 * span),
            g2: later.g2 - self.g2 - self.g1 * span,
        }
    }
}

/// The filter's state at the horizon, as the predictor starts from it.
#[derive(Debug, Clone)]
pub(crate) struct Base {
    pub t: i64,
    pub p: Vector3<f64>,
    pub v: Vector3<f64>,
    pub q: UnitQuaternion<f64>,
    /// Accelerometer bias (body frame).
    pub accel_bias: Vector3<f64>,
    /// The IMU sample the filter holds: (time, specific force); None without one.
    pub held: Option<(i64, Option<Vector3<f64>>)>,
    /// False without an attitude: the filter then predicts at constant velocity.
    pub attitude_known: bool,
}

/// The present state.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Present {
    pub p: Vector3<f64>,
    pub v: Vector3<f64>,
    pub q: UnitQuaternion<f64>,
    /// The newest bias-corrected body rate ahead of the horizon.
    pub rate: Option<Vector3<f64>>,
}

/// IMU samples ahead of the horizon and their cumulative increments.
#[derive(Debug, Clone)]
pub(crate) struct OutputPredictor {
    nodes: VecDeque<Node>,
    /// Time the sums start from (the first node after the last re-base).
    anchor_t: i64,
    imu_timeout_us: i64,
}

/// The own attitude filter's step length for a sample `dt_us` after the previous one.
fn rot_dt(dt_us: i64) -> f64 {
    (dt_us as f64 * 1e-6).clamp(1e-4, 0.1)
}

impl OutputPredictor {
    pub fn new(imu_timeout_us: i64) -> Self {
        Self {
            nodes: VecDeque::new(),
            anchor_t: 0,
            imu_timeout_us,
        }
    }

    /// The specific force a step from `from` to `to` holds, as the filter would.
    fn held(&self, accel: Option<Vector3<f64>>, from: i64, to: i64) -> Option<Vector3<f64>> {
        accel.filter(|_| to - from <= self.imu_timeout_us)
    }

    /// An IMU sample the filter will fuse (checked, from a usable source).
    pub fn push(&mut self, t: i64, rate: Vector3<f64>, accel: Option<Vector3<f64>>) {
        let node = Node {
            t,
            rate,
            accel,
            sums: Sums::zero(),
        };
        match self.nodes.back() {
            Some(last) if last.t <= t => {
                let sums = last.sums.step(
                    ((t - last.t) as f64) * 1e-6,
                    self.held(last.accel, last.t, t),
                    rate,
                    rot_dt(t - last.t),
                );
                self.nodes.push_back(Node { sums, ..node });
            }
            Some(_) => {
                // Out of order (a second IMU, or jitter): insert and re-integrate.
                let pos = self.nodes.partition_point(|n| n.t <= t);
                self.nodes.insert(pos, node);
                self.rebase();
            }
            None => {
                self.anchor_t = t;
                self.nodes.push_back(node);
            }
        }
    }

    /// The filter has fused everything up to `t`: its samples are no longer ahead.
    pub fn drop_through(&mut self, t: i64) {
        while self.nodes.front().is_some_and(|n| n.t <= t) {
            self.nodes.pop_front();
        }
        if self
            .nodes
            .front()
            .is_some_and(|n| n.t - self.anchor_t > REBASE_EVERY_US)
        {
            self.rebase();
        }
    }

    /// Re-integrate every node from the first one.
    fn rebase(&mut self) {
        let Some(first) = self.nodes.front_mut() else {
            return;
        };
        first.sums = Sums::zero();
        self.anchor_t = first.t;
        for i in 1..self.nodes.len() {
            let (prev, cur) = (&self.nodes[i - 1], &self.nodes[i]);
            let dt_us = cur.t - prev.t;
            let sums = prev.sums.step(
                dt_us as f64 * 1e-6,
                self.held(prev.accel, prev.t, cur.t),
                cur.rate,
                rot_dt(dt_us),
            );
            self.nodes[i].sums = sums;
        }
    }

    /// The state at `present` (≥ the base's time): the base, one step to the first IMU
    /// sample ahead with the specific force the filter holds, the pre-integrated steps
    /// between the samples ahead, and a last step to `present`.
    pub fn predict(&self, base: &Base, present: i64) -> Present {
        let gravity = Vector3::new(0.0, 0.0, GRAVITY);
        let mut p = base.p;
        let mut v = base.v;
        let mut q = base.q;
        let first = self.nodes.iter().position(|n| n.t > base.t);
        // A step of `dt_us` holding `accel` at attitude `q` (world frame).
        let step = |p: &mut Vector3<f64>,
                    v: &mut Vector3<f64>,
                    q: &UnitQuaternion<f64>,
                    dt_us: i64,
                    accel: Option<Vector3<f64>>| {
            let dt = dt_us as f64 * 1e-6;
            let a = match accel {
                Some(f) if base.attitude_known => q * (f - base.accel_bias) - gravity,
                _ => Vector3::zeros(),
            };
            *p += *v * dt + a * (0.5 * dt * dt);
            *v += a * dt;
        };
        // First, to the first sample ahead (or to `present` before it) holding the
        // specific force the filter holds.
        let held = base.held.and_then(|(t, f)| f.map(|f| (t, f)));
        let to = first
            .map_or(present, |i| self.nodes[i].t.min(present))
            .max(base.t);
        step(
            &mut p,
            &mut v,
            &q,
            to - base.t,
            held.and_then(|(t, f)| self.held(Some(f), t, to)),
        );
        let Some(i) = first.filter(|&i| self.nodes[i].t <= present) else {
            return Present {
                p,
                v,
                q,
                rate: None,
            };
        };
        let n0 = &self.nodes[i];
        let end = self.nodes.partition_point(|n| n.t <= present);
        let last = end.checked_sub(1).map_or(n0, |j| &self.nodes[j.max(i)]);
        let since = base.held.map_or(n0.t - base.t, |(t, _)| n0.t - t);
        q *= UnitQuaternion::from_scaled_axis(n0.rate * rot_dt(since));
        // The pre-integrated steps from the first sample ahead to the last.
        let span = (last.t - n0.t) as f64 * 1e-6;
        let d = n0.sums.between(&last.sums, span);
        if base.attitude_known {
            let r = *q.to_rotation_matrix().matrix();
            let b = base.accel_bias;
            p += v * span + r * (d.p1 - d.m2 * b) - gravity * d.g2;
            v += r * (d.v1 - d.m1 * b) - gravity * d.g1;
        } else {
            p += v * span;
        }
        q *= d.q;
        step(
            &mut p,
            &mut v,
            &q,
            present - last.t,
            self.held(last.accel, last.t, present),
        );
        Present {
            p,
            v,
            q,
            rate: Some(last.rate),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The filter's model stepped sample by sample, for comparison.
    fn direct(
        base: &Base,
        samples: &[(i64, Vector3<f64>, Vector3<f64>)],
        present: i64,
        timeout: i64,
    ) -> Present {
        let g = Vector3::new(0.0, 0.0, GRAVITY);
        let (mut p, mut v, mut q) = (base.p, base.v, base.q);
        let (mut t, mut held, mut last_imu) = (
            base.t,
            base.held.and_then(|h| h.1.map(|f| (h.0, f))),
            base.held.map(|h| h.0),
        );
        let mut rate = None;
        // One step to `to` holding the last specific force (none after the timeout).
        let step = |p: &mut Vector3<f64>,
                    v: &mut Vector3<f64>,
                    q: &UnitQuaternion<f64>,
                    held: Option<(i64, Vector3<f64>)>,
                    t: i64,
                    to: i64| {
            let dt = (to - t) as f64 * 1e-6;
            let a = held
                .filter(|(th, _)| to - th <= timeout)
                .map_or(Vector3::zeros(), |(_, f)| q * (f - base.accel_bias) - g);
            *p += *v * dt + a * (0.5 * dt * dt);
            *v += a * dt;
        };
        for &(ts, w, f) in samples.iter().filter(|s| s.0 > base.t && s.0 <= present) {
            step(&mut p, &mut v, &q, held, t, ts);
            q *= UnitQuaternion::from_scaled_axis(w * rot_dt(ts - last_imu.unwrap_or(base.t)));
            t = ts;
            held = Some((ts, f));
            last_imu = Some(ts);
            rate = Some(w);
        }
        step(&mut p, &mut v, &q, held, t, present);
        Present { p, v, q, rate }
    }

    fn samples(n: i64, every: i64) -> Vec<(i64, Vector3<f64>, Vector3<f64>)> {
        (1..=n)
            .map(|k| {
                let s = k as f64 * 0.01;
                (
                    k * every,
                    Vector3::new(0.3 * s.sin(), -0.2, 0.5 * s.cos()),
                    Vector3::new(1.0 + s.cos(), -0.5 * s, GRAVITY + 0.3 * s.sin()),
                )
            })
            .collect()
    }

    fn base(t: i64) -> Base {
        Base {
            t,
            p: Vector3::new(1.0, -2.0, 3.0),
            v: Vector3::new(0.5, 0.2, -0.1),
            q: UnitQuaternion::from_euler_angles(0.1, -0.05, 1.2),
            accel_bias: Vector3::new(0.02, -0.01, 0.03),
            held: Some((t - 1_500, Some(Vector3::new(0.1, 0.2, GRAVITY)))),
            attitude_known: true,
        }
    }

    fn close(a: &Present, b: &Present) {
        assert!((a.p - b.p).norm() < 1e-9, "{} vs {}", a.p, b.p);
        assert!((a.v - b.v).norm() < 1e-9, "{} vs {}", a.v, b.v);
        assert!(a.q.angle_to(&b.q) < 1e-9);
        assert_eq!(a.rate, b.rate);
    }

    #[test]
    fn pre_integration_equals_stepping_the_model() {
        let s = samples(400, 2_500);
        let mut out = OutputPredictor::new(100_000);
        for &(t, w, f) in &s {
            out.push(t, w, Some(f));
        }
        // From several horizons (between samples and on one), to several present times,
        // across re-bases.
        for &(bt, present) in &[
            (0, 1_000_000),
            (101_000, 700_300),
            (500_000, 1_000_000),
            (999_000, 1_003_000),
        ] {
            let mut o = out.clone();
            o.drop_through(bt);
            close(
                &o.predict(&base(bt), present),
                &direct(&base(bt), &s, present, 100_000),
            );
        }
    }

    #[test]
    fn out_of_order_samples_and_gaps_follow_the_model() {
        let mut s = samples(200, 5_000);
        // A gap longer than the IMU timeout: that step holds no specific force.
        s.retain(|x| !(300_000..=500_000).contains(&x.0));
        let mut out = OutputPredictor::new(100_000);
        let mut order: Vec<usize> = (0..s.len()).collect();
        order.swap(10, 11);
        order.swap(50, 52);
        for i in order {
            out.push(s[i].0, s[i].1, Some(s[i].2));
        }
        let b = base(20_000);
        out.drop_through(b.t);
        close(
            &out.predict(&b, 1_000_000),
            &direct(&b, &s, 1_000_000, 100_000),
        );
    }

    #[test]
    fn without_attitude_or_samples_it_is_constant_velocity() {
        let mut b = base(0);
        b.attitude_known = false;
        let out = OutputPredictor::new(100_000);
        let got = out.predict(&b, 2_000_000);
        assert!((got.p - (b.p + b.v * 2.0)).norm() < 1e-12);
        assert_eq!(got.v, b.v);
    }
}
