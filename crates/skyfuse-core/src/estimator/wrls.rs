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

use crate::source_map::SourceMap;
use nalgebra::{Matrix3, Vector3};

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

/// An absolute position and its per-axis variance (NaN where it says nothing).
type Absolute = (Vector3<f64>, Vector3<f64>);

/// Per source, keyed by its id: the entries stay once a source has been seen, and a
/// tick empties their values, so a tick allocates nothing (a source's first sample
/// does, once).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Wrls {
    pub x: Option<Vector3<f64>>,
    /// Per-axis variance of x.
    pub var: Vector3<f64>,
    /// Time of the last tick, µs.
    pub t: Option<i64>,
    pub last_delta: Vector3<f64>,
    pub last_delta_var: Vector3<f64>,
    /// Weights of the last tick per relative source and axis.
    pub weights: SourceMap<[f64; 3]>,
    /// Height of the ground in the frame (0 at the take-off pose; uncertain once GNSS
    /// anchors the frame) and its variance: range heights are `z − terrain`.
    pub terrain: f64,
    pub terrain_var: f64,
    /// Displacements accumulated in this tick (zero `covered`: none).
    rel: SourceMap<RelAcc>,
    /// Latest absolute position (z, var) per source in this tick.
    abs: SourceMap<Option<Absolute>>,
    /// Latest height above the terrain (h, var) per range source in this tick.
    heights: SourceMap<Option<(f64, f64)>>,
}

/// Σσ⁻² of some estimates: the inverse-variance weights a_i = σ_i⁻² / Σσ⁻² and the
/// fused variance 1 / Σσ⁻² (a non-positive or non-finite variance gets weight 0).
#[derive(Clone, Copy)]
struct Fused {
    inverse_sum: f64,
}

impl Fused {
    fn of(vars: impl Iterator<Item = f64>) -> Self {
        Self {
            inverse_sum: vars.map(inverse).sum(),
        }
    }

    /// 1/Σσ⁻² (infinite when none has a weight).
    fn variance(self) -> f64 {
        if self.inverse_sum <= 0.0 {
            f64::INFINITY
        } else {
            1.0 / self.inverse_sum
        }
    }

    /// σ⁻² / Σσ⁻² of the estimate of variance `v` (0 when none has a weight).
    fn weight(self, v: f64) -> f64 {
        if self.inverse_sum <= 0.0 {
            0.0
        } else {
            inverse(v) / self.inverse_sum
        }
    }
}

fn inverse(v: f64) -> f64 {
    if v.is_finite() && v > 0.0 {
        1.0 / v
    } else {
        0.0
    }
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

    /// Add a relative displacement (already in the world frame) covering `dt` seconds.
    pub fn add_relative(&mut self, source: &str, delta: Vector3<f64>, var: Vector3<f64>, dt: f64) {
        if self.x.is_none() || !delta.iter().all(|v| v.is_finite()) {
            return;
        }
        let acc = self.rel.get_or_insert_with(source, RelAcc::default);
        acc.delta += delta;
        acc.var += var;
        acc.covered += dt;
    }

    /// Add an absolute position (world). NaN components (e.g. a height-only source) are
    /// ignored on that axis.
    pub fn add_absolute(&mut self, source: &str, z: Vector3<f64>, var: Vector3<f64>) {
        if self.x.is_none() {
            return;
        }
        *self.abs.get_or_insert_with(source, || None) = Some((z, var));
    }

    /// A height above the terrain (range finder), variance `var`.
    pub fn add_height(&mut self, source: &str, h: f64, var: f64) {
        if self.x.is_none() || !h.is_finite() {
            return;
        }
        *self.heights.get_or_insert_with(source, || None) = Some((h, var));
    }

    /// The frame moved by an uncertain amount (covariance `s`): the position and the
    /// terrain share the error.
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

    /// The absolute measurements of this tick, by source: the absolute positions, and
    /// each range height as a z of terrain + h (in place of an absolute position of the
    /// same source id).
    fn absolutes(&self) -> impl Iterator<Item = Absolute> + '_ {
        let heights = self.heights.iter().filter_map(|(src, h)| {
            h.map(|(h, hv)| {
                let z = Vector3::new(f64::NAN, f64::NAN, h + self.terrain);
                let var = Vector3::new(f64::INFINITY, f64::INFINITY, hv + self.terrain_var);
                (src.as_str(), (z, var))
            })
        });
        let abs = self
            .abs
            .iter()
            .filter(|(src, _)| !self.heights.get(src).is_some_and(Option::is_some))
            .filter_map(|(src, a)| a.map(|a| (src.as_str(), a)));
        MergeBySource {
            a: abs.peekable(),
            b: heights.peekable(),
        }
    }

    /// Run every tick that ends before `now`, appending each one's result to `out`.
    pub fn tick(&mut self, now: i64, period_us: i64, no_delta_var: f64, out: &mut Vec<WrlsOutput>) {
        let period_us = period_us.max(1);
        while let (Some(t0), Some(x)) = (self.t, self.x) {
            let t1 = t0 + period_us;
            if t1 >= now {
                break;
            }
            let period = period_us as f64 * 1e-6;
            // Terrain from each range height against each absolute z.
            for (h, hv) in self.heights.values().flatten() {
                for (z, var) in self.abs.values().flatten() {
                    if z[2].is_finite() && var[2].is_finite() && var[2] > 0.0 {
                        let f = Fused::of([self.terrain_var, var[2] + hv].into_iter());
                        if f.variance().is_finite() {
                            self.terrain = f.weight(self.terrain_var) * self.terrain
                                + f.weight(var[2] + hv) * (z[2] - h);
                            self.terrain_var = f.variance();
                        }
                    }
                }
            }
            // The relative sources' displacements, each scaled to the tick.
            let scaled = |axis: usize| {
                self.rel
                    .iter()
                    .filter(|(_, a)| a.covered > 0.0)
                    .map(move |(s, a)| {
                        let k = period / a.covered;
                        (s, a.delta[axis] * k, a.var[axis] * k * k)
                    })
            };
            // Every relative source of this tick gets a weight on each axis; the others
            // are dropped.
            let rel = &self.rel;
            self.weights
                .retain(|s, _| rel.get(s).is_some_and(|a| a.covered > 0.0));
            let mut delta = Vector3::zeros();
            let mut dvar = Vector3::zeros();
            for axis in 0..3 {
                let f = Fused::of(scaled(axis).map(|i| i.2));
                if f.variance().is_finite() {
                    delta[axis] = scaled(axis).map(|i| i.1 * f.weight(i.2)).sum();
                    dvar[axis] = f.variance();
                } else {
                    dvar[axis] = no_delta_var * period;
                }
                for (s, _, var) in scaled(axis) {
                    let ws = self.weights.get_or_insert_with(s, || [0.0; 3]);
                    ws[axis] = f.weight(var);
                }
            }
            // The prediction and the absolute measurements, by the same rule.
            let mut xp = x + delta;
            let mut vp = self.var + dvar;
            for axis in 0..3 {
                let predicted = (xp[axis], vp[axis]);
                let usable = |(z, var): Absolute| {
                    (z[axis].is_finite() && var[axis].is_finite() && var[axis] > 0.0)
                        .then_some((z[axis], var[axis]))
                };
                let items =
                    || std::iter::once(predicted).chain(self.absolutes().filter_map(usable));
                let f = Fused::of(items().map(|i| i.1));
                if f.variance().is_finite() {
                    xp[axis] = items().map(|(z, var)| z * f.weight(var)).sum();
                    vp[axis] = f.variance();
                }
            }
            // This tick's measurements are used: the sources stay, empty.
            for acc in self.rel.values_mut() {
                *acc = RelAcc::default();
            }
            for a in self.abs.values_mut() {
                *a = None;
            }
            for h in self.heights.values_mut() {
                *h = None;
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
    }
}

/// Two iterators sorted by source id, merged in that order (the order a map of both
/// would iterate; ids do not repeat between them).
struct MergeBySource<'a, A, B, T>
where
    A: Iterator<Item = (&'a str, T)>,
    B: Iterator<Item = (&'a str, T)>,
{
    a: std::iter::Peekable<A>,
    b: std::iter::Peekable<B>,
}

impl<'a, A, B, T> Iterator for MergeBySource<'a, A, B, T>
where
    A: Iterator<Item = (&'a str, T)>,
    B: Iterator<Item = (&'a str, T)>,
{
    type Item = T;

    fn next(&mut self) -> Option<T> {
        let take_a = match (self.a.peek(), self.b.peek()) {
            (Some((sa, _)), Some((sb, _))) => sa < sb,
            (Some(_), None) => true,
            (None, _) => false,
        };
        if take_a { self.a.next() } else { self.b.next() }.map(|(_, t)| t)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_variance_weights() {
        let f = Fused::of([1.0, 4.0].into_iter());
        assert!((f.weight(1.0) - 0.8).abs() < 1e-12 && (f.weight(4.0) - 0.2).abs() < 1e-12);
        assert!((f.variance() - 0.8).abs() < 1e-12);
        let vars = [2.0, f64::INFINITY, 2.0];
        let f = Fused::of(vars.into_iter());
        assert_eq!(vars.map(|v| f.weight(v)), [0.5, 0.0, 0.5]);
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
        let mut out = Vec::new();
        f.tick(20_001, 20_000, 1.0, &mut out);
        assert_eq!(out.len(), 1);
        assert!((out[0].delta.x - (0.8 * 0.02 + 0.2 * 0.04)).abs() < 1e-12);
        assert!((out[0].var.x - (1e-4 + 0.8e-6)).abs() < 1e-15);
        let weight_a = f.weights.get("a").expect("a weighed")[0];
        assert!((weight_a - 0.8).abs() < 1e-12);
        // An absolute fix with equal variance pulls halfway.
        let v = f.var.x;
        let x = f.x.expect("initialised").x;
        f.add_absolute("gps", Vector3::new(1.0, 0.0, 0.0), Vector3::repeat(v));
        f.tick(40_001, 20_000, 0.0, &mut out);
        let x2 = f.x.expect("initialised").x;
        assert!((x2 - (x + 1.0) / 2.0).abs() < 1e-9, "{x2}");
    }
}
