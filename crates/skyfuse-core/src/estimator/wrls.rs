//! Weighted recursive least squares (seed 002).
//!
//! Every `wrls_period_ms` (a tick) the frame-to-frame displacements each relative
//! source produced in the tick (T265/VO, flow) are combined per axis with the
//! minimum-variance weights a_i = σ_i⁻² / Σσ⁻² (the seed's Lagrange result), after
//! normalising each to the tick length (sources cover slightly different intervals).
//! The fused displacement is accumulated (the seed's `fusion_displace` summed into
//! `pose_msg`); its variance 1/Σσ⁻² adds to the position variance. Absolute sources
//! (GNSS position, range height) are then combined with that prediction by the same
//! inverse-variance rule, which is what makes it *recursive*: without them it is exactly
//! the seed's accumulated displacement.

use nalgebra::{Matrix3, Vector3};
use std::collections::BTreeMap;

#[derive(Debug, Clone, PartialEq, Default)]
struct RelAcc {
    delta: Vector3<f64>,
    var: Vector3<f64>,
    covered: f64,
}

/// One tick's result.
#[derive(Debug, Clone, PartialEq)]
pub struct WrlsOutput {
    pub t: i64,
    pub x: Vector3<f64>,
    pub var: Vector3<f64>,
    pub delta: Vector3<f64>,
}

#[derive(Debug, Clone, PartialEq, Default)]
pub struct Wrls {
    pub x: Option<Vector3<f64>>,
    /// Per-axis variance of x.
    pub var: Vector3<f64>,
    /// Time of the last tick, µs.
    pub t: Option<i64>,
    pub last_delta: Vector3<f64>,
    pub last_delta_var: Vector3<f64>,
    /// Weights of the last tick per source (x axis; y, z alike unless a source lacks one).
    pub weights: BTreeMap<String, [f64; 3]>,
    /// Height of the ground in the frame (0 at the take-off pose; uncertain once GNSS
    /// anchors the frame) and its variance: range heights are `z − terrain`.
    pub terrain: f64,
    pub terrain_var: f64,
    rel: BTreeMap<String, RelAcc>,
    abs: BTreeMap<String, (Vector3<f64>, Vector3<f64>)>,
    heights: BTreeMap<String, (f64, f64)>,
}

/// Inverse-variance weights a_i = σ_i⁻² / Σσ⁻² and the fused variance 1 / Σσ⁻².
pub fn weights(vars: &[f64]) -> (Vec<f64>, f64) {
    let inv: Vec<f64> = vars
        .iter()
        .map(|&v| {
            if v.is_finite() && v > 0.0 {
                1.0 / v
            } else {
                0.0
            }
        })
        .collect();
    let sum: f64 = inv.iter().sum();
    if sum <= 0.0 {
        return (vec![0.0; vars.len()], f64::INFINITY);
    }
    (inv.iter().map(|w| w / sum).collect(), 1.0 / sum)
}

impl Wrls {
    pub fn init(&mut self, t: i64, x: Vector3<f64>, var: Vector3<f64>) {
        self.x = Some(x);
        self.var = var;
        self.t = Some(t);
        self.terrain = 0.0;
        self.terrain_var = var.z;
        self.rel.clear();
        self.abs.clear();
        self.heights.clear();
    }

    pub fn add_relative(&mut self, source: &str, delta: Vector3<f64>, var: Vector3<f64>, dt: f64) {
        if self.x.is_none() || !delta.iter().all(|v| v.is_finite()) {
            return;
        }
        let acc = self.rel.entry(source.to_string()).or_default();
        acc.delta += delta;
        acc.var += var;
        acc.covered += dt;
    }

    pub fn add_absolute(&mut self, source: &str, z: Vector3<f64>, var: Vector3<f64>) {
        if self.x.is_none() {
            return;
        }
        self.abs.insert(source.to_string(), (z, var));
    }

    /// A height above the terrain (range finder), variance `var`.
    pub fn add_height(&mut self, source: &str, h: f64, var: f64) {
        if self.x.is_none() || !h.is_finite() {
            return;
        }
        self.heights.insert(source.to_string(), (h, var));
    }

    pub fn add_frame_uncertainty(&mut self, s: &Matrix3<f64>) {
        if self.x.is_some() {
            self.var += s.diagonal();
            self.terrain_var += s[(2, 2)];
        }
    }

    pub fn shift(&mut self, d: Vector3<f64>) {
        if let Some(x) = self.x.as_mut() {
            *x += d;
        }
    }

    pub fn reset(&mut self, x: Vector3<f64>, var: Vector3<f64>) {
        if self.x.is_some() {
            self.x = Some(x);
            self.var = var;
        }
    }

    /// Run every tick that ends before `now`.
    pub fn tick(&mut self, now: i64, period_us: i64, no_delta_var: f64) -> Vec<WrlsOutput> {
        let mut out = vec![];
        let period_us = period_us.max(1);
        while let (Some(t0), Some(x)) = (self.t, self.x) {
            let t1 = t0 + period_us;
            if t1 >= now {
                break;
            }
            let period = period_us as f64 * 1e-6;
            let rel = std::mem::take(&mut self.rel);
            let mut abs = std::mem::take(&mut self.abs);
            let heights = std::mem::take(&mut self.heights);
            // Terrain datum: an absolute height (GNSS) and a height above ground together
            // measure the ground's height in the frame.
            for (h, hv) in heights.values() {
                for (z, var) in abs.values() {
                    if z[2].is_finite() && var[2].is_finite() && var[2] > 0.0 {
                        let (w, v) = weights(&[self.terrain_var, var[2] + hv]);
                        if v.is_finite() {
                            self.terrain = w[0] * self.terrain + w[1] * (z[2] - h);
                            self.terrain_var = v;
                        }
                    }
                }
            }
            for (src, (h, hv)) in &heights {
                abs.insert(
                    src.clone(),
                    (
                        Vector3::new(f64::NAN, f64::NAN, h + self.terrain),
                        Vector3::new(f64::INFINITY, f64::INFINITY, hv + self.terrain_var),
                    ),
                );
            }
            let mut delta = Vector3::zeros();
            let mut dvar = Vector3::zeros();
            self.weights.clear();
            for axis in 0..3 {
                let items: Vec<(&String, f64, f64)> = rel
                    .iter()
                    .filter(|(_, a)| a.covered > 0.0)
                    .map(|(s, a)| {
                        let k = period / a.covered;
                        (s, a.delta[axis] * k, a.var[axis] * k * k)
                    })
                    .collect();
                let vars: Vec<f64> = items.iter().map(|i| i.2).collect();
                let (w, v) = weights(&vars);
                if v.is_finite() {
                    delta[axis] = items.iter().zip(&w).map(|(i, w)| i.1 * w).sum();
                    dvar[axis] = v;
                } else {
                    dvar[axis] = no_delta_var * period;
                }
                for (i, w) in items.iter().zip(&w) {
                    self.weights.entry(i.0.clone()).or_insert([0.0; 3])[axis] = *w;
                }
            }
            let mut xp = x + delta;
            let mut vp = self.var + dvar;
            for axis in 0..3 {
                let mut vars = vec![vp[axis]];
                let mut vals = vec![xp[axis]];
                for (z, var) in abs.values() {
                    if z[axis].is_finite() && var[axis].is_finite() && var[axis] > 0.0 {
                        vars.push(var[axis]);
                        vals.push(z[axis]);
                    }
                }
                let (w, v) = weights(&vars);
                if v.is_finite() {
                    xp[axis] = vals.iter().zip(&w).map(|(z, w)| z * w).sum();
                    vp[axis] = v;
                }
            }
            self.x = Some(xp);
            self.var = vp;
            self.t = Some(t1);
            self.last_delta = delta;
            self.last_delta_var = dvar;
            out.push(WrlsOutput {
                t: t1,
                x: xp,
                var: vp,
                delta,
            });
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_variance_weights() {
        let (w, v) = weights(&[1.0, 4.0]);
        assert!((w[0] - 0.8).abs() < 1e-12 && (w[1] - 0.2).abs() < 1e-12);
        assert!((v - 0.8).abs() < 1e-12);
        let (w, _) = weights(&[2.0, f64::INFINITY, 2.0]);
        assert_eq!(w, vec![0.5, 0.0, 0.5]);
    }

    #[test]
    fn fuses_displacements_and_absolute_fixes() {
        let mut f = Wrls::default();
        f.init(0, Vector3::zeros(), Vector3::repeat(1e-4));
        // Two sources over one 20 ms tick: 0.02 m (σ² 1e-6) and 0.04 m (σ² 4e-6).
        f.add_relative(
            "a",
            Vector3::new(0.02, 0.0, 0.0),
            Vector3::repeat(1e-6),
            0.02,
        );
        f.add_relative(
            "b",
            Vector3::new(0.04, 0.0, 0.0),
            Vector3::repeat(4e-6),
            0.02,
        );
        let out = f.tick(20_001, 20_000, 1.0);
        assert_eq!(out.len(), 1);
        assert!((out[0].delta.x - (0.8 * 0.02 + 0.2 * 0.04)).abs() < 1e-12);
        assert!((out[0].var.x - (1e-4 + 0.8e-6)).abs() < 1e-15);
        assert!((f.weights["a"][0] - 0.8).abs() < 1e-12);
        // An absolute fix with equal variance pulls halfway.
        let v = f.var.x;
        let x = f.x.expect("initialised").x;
        f.add_absolute("gps", Vector3::new(1.0, 0.0, 0.0), Vector3::repeat(v));
        f.tick(40_001, 20_000, 0.0);
        let x2 = f.x.expect("initialised").x;
        assert!((x2 - (x + 1.0) / 2.0).abs() < 1e-9, "{x2}");
    }
}
