//! The bank of filters: the main filter, fed by every usable source, and one
//! sub-filter per aiding source that is fed by all the others (solution separation, as
//! ARAIM does it over satellites and ArduPilot's EKF3 over IMU lanes). They share
//! everything but the measurements they leave out: the same prediction, the same
//! states added and reset at the same moments, so that the difference between the main
//! solution and a sub-solution is exactly what its left-out source did to the estimate
//! since the sub-filter started, and its covariance is the difference of theirs
//! (`integrity` tests it).
//!
//! A measurement is linearised once, about the main filter's state. A sub-filter's
//! innovation is taken about its own state to first order, `y_k = y − H (x_k − x_0)`:
//! the models are smooth and the states close (when they are not, the test has already
//! said so), and it costs a sparse row product instead of rebuilding the measurement.
//!
//! Reads go to the main filter ([`std::ops::Deref`]); every change goes through the
//! bank, so no filter can be changed alone by mistake.

use super::ekf::{Ekf, Measurement, UpdateOutcome};
use nalgebra::DVector;
use std::ops::Deref;

/// Most sub-filters the bank keeps (one per aiding source): beyond, the rest share the
/// main filter's fate unmonitored (a vehicle with more than eight aiding sources is
/// not one this is built for).
pub const MAX_SUBS: usize = 8;

/// A filter without one source.
#[derive(Debug, Clone, PartialEq)]
pub struct Sub {
    /// The source it leaves out.
    pub without: String,
    pub ekf: Ekf,
    /// When it was started as a copy of the main filter, µs (host clock): what it
    /// separates is what the source did since.
    pub since: i64,
    /// It fused a measurement the main filter refused since it started: its
    /// information is no longer a part of the main filter's (see `integrity`).
    pub took_refused: bool,
}

impl Sub {
    /// Start again from the main filter at `t`.
    fn restart(&mut self, main: &Ekf, t: i64) {
        self.ekf = main.clone();
        self.since = t;
        self.took_refused = false;
    }
}

/// The solution an exclusion set aside: the filter that kept the excluded source, fed
/// everything, the excluded source included, while it stays out. The test that
/// excluded it said only that the two solutions departed beyond their threshold, not
/// which is wrong; until the source agrees again, what is sent covers both.
///
/// One per excluded source. A later exclusion was decided against a solution without
/// the earlier one, so it says nothing of the world where the earlier one was right:
/// that solution takes the later source too, and stays (randomised draw 21 of seed 2:
/// a GNSS excluded on the height, then the barometer against the range finder's
/// dead reckoning; the set-aside solution with the GNSS was replaced by the one with
/// the barometer, and poses were sent valid 12 m above the truth with σz 3-4 m).
#[derive(Debug, Clone, PartialEq)]
pub struct Shadow {
    /// The excluded source whose exclusion set it aside.
    pub with: String,
    /// The excluded sources it still takes: its own, and those excluded after it.
    takes: Vec<String>,
    pub ekf: Ekf,
}

impl Shadow {
    /// It takes the excluded `source`'s measurements.
    pub fn takes(&self, source: &str) -> bool {
        self.takes.iter().any(|s| s == source)
    }
}

/// The main filter and its sub-filters.
#[derive(Debug, Clone, PartialEq)]
pub struct Bank {
    main: Ekf,
    subs: Vec<Sub>,
    shadows: Vec<Shadow>,
}

impl Deref for Bank {
    type Target = Ekf;
    fn deref(&self) -> &Ekf {
        &self.main
    }
}

impl Bank {
    pub fn new(main: Ekf) -> Self {
        Self {
            main,
            subs: Vec::new(),
            shadows: Vec::new(),
        }
    }

    pub fn main(&self) -> &Ekf {
        &self.main
    }

    pub fn subs(&self) -> &[Sub] {
        &self.subs
    }

    /// The solutions the exclusions set aside, one per excluded source, oldest first.
    pub fn shadows(&self) -> &[Shadow] {
        &self.shadows
    }

    /// The sub-filter without `source`, if there is one.
    pub fn sub(&self, source: &str) -> Option<&Sub> {
        self.subs.iter().find(|s| s.without == source)
    }

    /// The same change to every filter (a prediction, a state added, a reset): each
    /// gets it on its own state.
    pub fn each(&mut self, mut f: impl FnMut(&mut Ekf)) {
        f(&mut self.main);
        self.others().for_each(f);
    }

    /// The same change to every filter, returning the main filter's result.
    pub fn each_main<R>(&mut self, mut f: impl FnMut(&mut Ekf) -> R) -> R {
        for ekf in self.others() {
            f(ekf);
        }
        f(&mut self.main)
    }

    /// Every filter but the main one: the sub-filters and the set-aside solution.
    fn others(&mut self) -> impl Iterator<Item = &mut Ekf> {
        let subs = self.subs.iter_mut().map(|s| &mut s.ekf);
        subs.chain(self.shadows.iter_mut().map(|s| &mut s.ekf))
    }

    /// A measurement from `source` (None: a constraint every filter takes, such as
    /// the ground's), linearised about the main filter: the main filter and every
    /// sub-filter but the one without `source` take it, each gating it on its own.
    /// Returns the main filter's outcome.
    pub fn update(&mut self, m: &Measurement, gate: f64, source: Option<&str>) -> UpdateOutcome {
        let main_x = &self.main.x;
        let mut accepted = [false; MAX_SUBS];
        for (s, took) in self.subs.iter_mut().zip(accepted.iter_mut()) {
            if source.is_some_and(|src| s.without == src) {
                continue;
            }
            *took = update_about(&mut s.ekf, m, main_x, gate);
        }
        for s in &mut self.shadows {
            update_about(&mut s.ekf, m, main_x, gate);
        }
        let out = self.main.update(m, gate, false);
        if !out.accepted {
            for (s, took) in self.subs.iter_mut().zip(accepted) {
                s.took_refused |= took;
            }
        }
        out
    }

    /// A measurement of the excluded `source`: only the solutions that keep it take it.
    pub fn update_shadow(&mut self, m: &Measurement, gate: f64, source: &str) {
        let main_x = &self.main.x;
        for s in self.shadows.iter_mut().filter(|s| s.takes(source)) {
            update_about(&mut s.ekf, m, main_x, gate);
        }
    }

    /// `source` is fused again (or gone): its set-aside solution with it; the others
    /// take it as every filter does.
    pub fn drop_shadow(&mut self, source: &str) {
        self.shadows.retain(|s| s.with != source);
        for s in &mut self.shadows {
            s.takes.retain(|x| x != source);
        }
    }

    /// A reset to the measurement `m` (every filter): the states in `states` forget
    /// what they knew (variance `var`, uncorrelated), then take `m` ungated. Every
    /// sub-filter starts again from the main filter afterwards: they all agree now.
    pub fn reset_to(&mut self, m: &Measurement, states: &[usize], var: f64, t: i64) {
        self.main.forget(states, var);
        let out = self.main.update(m, 0.0, true);
        debug_assert!(out.accepted || !out.nis.is_finite());
        for s in &mut self.subs {
            s.ekf = self.main.clone();
            s.since = t;
            s.took_refused = false;
        }
        self.shadows.clear();
    }

    /// Start the sub-filter without `source` as a copy of the main filter at `t`
    /// (nothing if it runs, or the bank is full). Returns whether one runs now.
    pub fn ensure_sub(&mut self, source: &str, t: i64) -> bool {
        if self.sub(source).is_some() {
            return true;
        }
        if self.subs.len() >= MAX_SUBS {
            return false;
        }
        self.subs.push(Sub {
            without: source.to_string(),
            ekf: self.main.clone(),
            since: t,
            took_refused: false,
        });
        true
    }

    /// Start the sub-filter without `source` again from the main filter at `t`.
    pub fn restart_sub(&mut self, source: &str, t: i64) {
        if let Some(s) = self.subs.iter_mut().find(|s| s.without == source) {
            s.restart(&self.main, t);
        }
    }

    /// The frame re-anchored at `at` (E, N) and the main filter's heading (see
    /// [`Ekf::anchor_frame`]) at `t`: the sub-filters start again from the main one
    /// (their headings apart, with the heading's uncertainty gone, would part them
    /// with nothing to say why), the set-aside solutions keep theirs and part as they
    /// do, in the bound.
    pub fn anchor(&mut self, at: [f64; 2], t: i64) {
        self.main.anchor_frame(at);
        for s in &mut self.subs {
            s.restart(&self.main, t);
        }
        for s in &mut self.shadows {
            s.ekf.anchor_frame(at);
        }
    }

    /// Drop the sub-filter without `source`.
    pub fn remove_sub(&mut self, source: &str) {
        self.subs.retain(|s| s.without != source);
    }

    /// Fault exclusion: the solution without `source` becomes the main one, and every
    /// other sub-filter starts again from it (they all had the faulty source in them).
    /// Returns false (and changes nothing) without such a sub-filter.
    pub fn exclude(&mut self, source: &str, t: i64) -> bool {
        let Some(i) = self.subs.iter().position(|s| s.without == source) else {
            return false;
        };
        let clean = self.subs.swap_remove(i);
        let kept = std::mem::replace(&mut self.main, clean.ekf);
        for s in &mut self.shadows {
            s.takes.push(source.to_string());
        }
        self.shadows.push(Shadow {
            with: source.to_string(),
            takes: vec![source.to_string()],
            ekf: kept,
        });
        for s in &mut self.subs {
            s.ekf = self.main.clone();
            s.since = t;
            s.took_refused = false;
        }
        true
    }
}

/// `m`, linearised about the main filter's state `main_x`, into another filter of the
/// bank (see the module's docs). Returns whether it was accepted.
fn update_about(ekf: &mut Ekf, m: &Measurement, main_x: &DVector<f64>, gate: f64) -> bool {
    let mk = m.about(main_x, &ekf.x);
    ekf.update(&mk, gate, false).accepted
}

#[cfg(test)]
mod tests {
    use super::super::ekf::IDX_P;
    use super::*;
    use nalgebra::{Matrix3, Vector3};

    fn bank() -> Bank {
        Bank::new(Ekf::new(
            Vector3::zeros(),
            Vector3::zeros(),
            Vector3::repeat(1.0),
            Vector3::repeat(1.0),
            0.01,
        ))
    }

    fn position(z: Vector3<f64>, at: &Ekf, var: f64) -> Measurement {
        Measurement::of_states(IDX_P, 3, &(z - at.pos()), &(Matrix3::identity() * var))
    }

    /// Five positions `z` of `source` fused, then `source` excluded at `t`: the main
    /// solution as it was with it.
    fn fused_then_excluded(b: &mut Bank, source: &str, z: Vector3<f64>, t: i64) -> Vector3<f64> {
        for _ in 0..5 {
            let m = position(z, b.main(), 0.1);
            b.update(&m, 1e9, Some(source));
        }
        let with = b.main().pos();
        assert!(b.exclude(source, t));
        with
    }

    /// A sub-filter fed all but one source ends exactly where a filter fed only the
    /// others would: the linearisation about the main filter costs nothing for a
    /// linear measurement.
    #[test]
    fn a_sub_filter_is_the_filter_without_its_source() {
        let mut b = bank();
        b.ensure_sub("gps", 0);
        let mut alone = b.main().clone();
        for i in 0..20 {
            let gps = Vector3::new(5.0, 0.0, 0.0);
            let flow = Vector3::new(1.0 + f64::from(i) * 0.01, 0.0, 0.0);
            let m = position(gps, b.main(), 0.5);
            b.update(&m, 1e9, Some("gps"));
            let m = position(flow, b.main(), 0.5);
            b.update(&m, 1e9, Some("flow"));
            alone.update(&position(flow, &alone, 0.5), 1e9, false);
        }
        let sub = b.sub("gps").expect("sub");
        assert!((sub.ekf.pos() - alone.pos()).norm() < 1e-9);
        assert!((sub.ekf.p.clone() - alone.p.clone()).abs().max() < 1e-9);
        // The main filter has both, and is between them.
        assert!(b.pos().x > alone.pos().x && b.pos().x < 5.0);
        // Excluding the GNSS makes the clean solution the main one.
        assert!(b.exclude("gps", 1));
        assert!((b.pos() - alone.pos()).norm() < 1e-9);
        assert!(b.sub("gps").is_none());
    }

    /// A sub-filter that fused what the main filter refused says so (its separation is
    /// then no longer tested against the difference of the covariances), until it
    /// starts again from the main filter.
    #[test]
    fn a_sub_filter_that_took_a_refused_measurement_says_so() {
        let mut b = bank();
        b.ensure_sub("camera", 0);
        b.ensure_sub("gps", 0);
        // The camera holds the main filter tight; the sub-filter without it is loose.
        for _ in 0..20 {
            let m = position(Vector3::zeros(), b.main(), 0.001);
            b.update(&m, 5.0, Some("camera"));
        }
        let m = position(Vector3::new(2.0, 0.0, 0.0), b.main(), 0.01);
        assert!(
            !b.update(&m, 5.0, Some("gps")).accepted,
            "the main filter refuses it"
        );
        let took = |b: &Bank, s: &str| b.sub(s).expect("sub").took_refused;
        assert!(
            took(&b, "camera"),
            "the sub-filter without the camera took it"
        );
        assert!(!took(&b, "gps"), "the one without the GNSS never saw it");
        b.restart_sub("camera", 1);
        assert!(!took(&b, "camera"));
    }

    /// An exclusion sets the main solution aside instead of dropping it: it goes on
    /// with the excluded source (and every other), so that what is sent can cover the
    /// case that the source was right, until it is fused again or a reset makes every
    /// filter agree.
    #[test]
    fn an_exclusion_keeps_the_solution_it_set_aside() {
        let mut b = bank();
        b.ensure_sub("gps", 0);
        let with_gps = fused_then_excluded(&mut b, "gps", Vector3::new(3.0, 0.0, 0.0), 7);
        let shadow = b.shadows().first().expect("the set-aside solution");
        assert_eq!(shadow.with, "gps");
        assert_eq!(shadow.ekf.pos(), with_gps);
        assert!(
            (b.main().pos() - with_gps).norm() > 2.0,
            "the main is without it"
        );
        // Only the set-aside solution takes the excluded source; every filter takes
        // the others.
        let m = position(Vector3::new(3.0, 0.0, 0.0), b.main(), 0.1);
        b.update_shadow(&m, 1e9, "gps");
        assert!((b.main().pos() - with_gps).norm() > 2.0);
        let before = b.shadows()[0].ekf.pos();
        let m = position(Vector3::new(0.0, 1.0, 0.0), b.main(), 0.1);
        b.update(&m, 1e9, Some("flow"));
        assert!(b.shadows()[0].ekf.pos().y > before.y);
        b.update_shadow(&m, 1e9, "flow");
        b.drop_shadow("flow");
        assert!(!b.shadows().is_empty(), "only its own source drops it");
        b.drop_shadow("gps");
        assert!(b.shadows().is_empty());
        // A reset makes every filter agree: nothing is left aside.
        b.ensure_sub("gps", 8);
        assert!(b.exclude("gps", 9));
        let m = position(Vector3::zeros(), b.main(), 0.1);
        b.reset_to(&m, &[IDX_P, IDX_P + 1, IDX_P + 2], 1.0, 10);
        assert!(b.shadows().is_empty());
    }

    /// A second exclusion keeps the solution the first set aside: it was decided
    /// against a solution without the first source, and says nothing of the case that
    /// the first was right. That solution takes the second source too, and goes when
    /// its own source is fused again, not before.
    #[test]
    fn a_second_exclusion_keeps_the_first_solution_set_aside() {
        let mut b = bank();
        b.ensure_sub("gps", 0);
        b.ensure_sub("baro", 0);
        let with_gps = fused_then_excluded(&mut b, "gps", Vector3::new(0.0, 0.0, 3.0), 7);
        for _ in 0..5 {
            let m = position(Vector3::new(0.0, 0.0, 3.0), b.main(), 0.1);
            b.update_shadow(&m, 1e9, "gps");
            let m = position(Vector3::new(0.0, 0.0, -3.0), b.main(), 0.1);
            b.update(&m, 1e9, Some("baro"));
        }
        assert!(b.exclude("baro", 8));
        let with: Vec<&str> = b.shadows().iter().map(|s| s.with.as_str()).collect();
        assert_eq!(with, ["gps", "baro"]);
        let (z_gps, z_baro) = (b.shadows()[0].ekf.pos().z, b.shadows()[1].ekf.pos().z);
        assert!(
            z_gps > z_baro + 1.0 && with_gps.z > z_gps,
            "the solution with the GNSS still has it ({z_gps:.2} m, {:.2} m before the barometer), above the barometer's ({z_baro:.2} m)",
            with_gps.z
        );
        // The barometer, out now, still reaches the solution with the GNSS (its
        // exclusion was decided without the GNSS), and the one with itself.
        assert!(b.shadows()[0].takes("baro") && b.shadows()[1].takes("baro"));
        assert!(
            !b.shadows()[1].takes("gps"),
            "set aside after the GNSS went"
        );
        let before = b
            .shadows()
            .iter()
            .map(|s| s.ekf.pos().z)
            .collect::<Vec<_>>();
        let m = position(Vector3::new(0.0, 0.0, -3.0), b.main(), 0.1);
        b.update_shadow(&m, 1e9, "baro");
        let main_z = b.main().pos().z;
        for (s, z) in b.shadows().iter().zip(before) {
            assert!(s.ekf.pos().z < z, "{} took the barometer", s.with);
        }
        b.drop_shadow("baro");
        assert_eq!(b.shadows().len(), 1, "the GNSS's case stays");
        assert!(
            !b.shadows()[0].takes("baro"),
            "fused again: every filter takes it"
        );
        assert_eq!(b.main().pos().z, main_z);
        b.drop_shadow("gps");
        assert!(b.shadows().is_empty());
    }
}
