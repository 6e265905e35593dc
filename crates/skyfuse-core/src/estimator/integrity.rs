//! The integrity monitor: what "valid" promises an autopilot, checked by construction
//! rather than per fault (ARAIM's solution separation, over aiding sources; DESIGN.md,
//! Estimator, "Integrity").
//!
//! - **Tests.** For each sub-filter k of the [`bank`](super::bank) (all sources but k),
//!   the separation `d = x₀ − x_k` of the position against its covariance
//!   `P_d = P_k − P₀` (the sub-filter's measurements are a subset of the main's, on one
//!   prediction), per axis: `|d| ≤ T = K_fa·σ_d`. A test counts on a channel
//!   (horizontal, vertical) only where another source also measures that channel: a
//!   source alone on its channel has nothing to be compared with (its faults are the
//!   unmonitored ones, bounded by the innovation gate against the IMU's prediction and
//!   by its own σ).
//! - **Exclusion.** When a test fails, the source whose sub-filter departs most is
//!   excluded: its solution becomes the main one, the event names the source and the
//!   figures, and the source's samples are only tested, not fused, until they have
//!   agreed with the estimate for `readmit_s`. The test says that the two solutions
//!   depart, not which one is wrong (a solution without the only GNSS whose heading
//!   the linearisation made sure of, randomised draw 488): the main solution is set
//!   aside, not dropped, and goes on with the excluded source; until it is fused again
//!   the protection level and the covariance sent cover the case that it was right.
//!   An excluded liar then shows what it claims in the bound, as a refused one does.
//!   One such solution stays per source out (a later exclusion, decided without the
//!   earlier source, says nothing of its case).
//! - **The only receiver is not excluded on the horizontal.** Without it the
//!   sub-filter is dead reckoning, and its departure says the two disagree, not
//!   which is wrong: the bound takes the whole separation instead (and the receiver's
//!   unreported error, `gnss_fault_horizontal_m`), and the sub-filter starts again
//!   once it has been held for `restart_s`. Excluded, the receiver could agree again
//!   only with an estimate that had drifted away from it: the lock-out.
//! - **Protection levels**, per axis `PL = max_k (T_k + K_md·σ_k)` over the monitored
//!   sub-filters; horizontal `HPL = max(K_H·d_major, √(PL_E² + PL_N²))`, where the
//!   fault-free term is the SBAS one (RTCA DO-229): `d_major` the error ellipse's
//!   semi-major axis and `K_H` the radius a 2-D Gaussian exceeds as rarely as one axis
//!   exceeds `K_ffmd·σ` ([`horizontal_k`]); vertical `max(K_ffmd·σ_U, PL_U)`. The pose
//!   is valid only with `HPL ≤ horizontal_alert_m` and `VPL ≤ vertical_alert_m`. An
//!   integrity failure is a valid pose whose true error exceeds its protection level.
//! - **A refusal is an exclusion too.** While the innovation gate refuses every
//!   measurement of a channel (nothing accepted there since), the estimate and the
//!   refused measurements disagree and nothing has said which is wrong: the protection
//!   level covers the case that the measurement is right (where the estimate would go
//!   if it were exact, plus what the refused velocities add up to since), and so does
//!   the covariance sent. A filter that leaves its only height source on a wrong
//!   acceleration bias shows its bound growing with the runaway instead of σz 0.1 m.
//!   A refused position stands until a position is accepted: a velocity that passes
//!   (the same receiver's) bounds the drift, not the offset. A refused velocity is
//!   answered by a velocity that passes: a noisy sample refused is not a position.
//! - **The σ sent is not below a lone receiver's slow error.** The filter learns a
//!   GNSS's slow error only through its assumed correlation time; with one receiver on
//!   a channel, the covariance sent keeps at least the slow error's spread there.
//! - **Relative navigation re-anchors.** In a frame of its own (no GNSS), a bound that
//!   has grown to [`DEFAULT_REANCHOR_FRACTION`] of the alert limit while a source
//!   measures the motion is restarted: the frame moves to where the estimate is and
//!   turns to its heading, every filter takes that as exact, the reset counter steps,
//!   and the pose's `anchored_us` says when (`reanchor`).
//! - **Sub-filters start again** from the main filter once they have been quiet (test
//!   ratio under [`RESTART_QUIET_RATIO`]) for `restart_s`: a sub-filter left to run
//!   forever drifts as far as its remaining sources let it (a flow without its GNSS),
//!   and its protection level with it; a fault must show within that window. So does
//!   one whose left-out source held a channel alone when another starts to share it:
//!   there it has been on the IMU alone, no solution to test against.

use super::ekf::{IDX_P, IDX_TERRAIN, IDX_V};
use super::measurement::Measurement;
use super::status::Protection;
use super::{Core, Ctx, Event};
use crate::source_map::SourceMap;
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

/// Detection threshold of a separation, in its own σ (ARAIM's K_fa): 5σ, a false
/// alert about once in 1.7 million independent tests.
pub const DEFAULT_K_FA: f64 = 5.0;
/// Missed-detection multiplier of a sub-filter's own σ in the protection level.
pub const DEFAULT_K_MD: f64 = 3.5;
/// Fault-free multiplier of the main filter's σ in the protection level: vertically;
/// horizontally through [`horizontal_k`], on the error ellipse's major axis.
pub const DEFAULT_K_FFMD: f64 = 5.5;
/// Alert limits: the largest protection level a valid pose may carry, m. An autopilot
/// weighs our pose by the σ it comes with, so a pose whose bound is metres still
/// holds a position and flies a mission; silence (no pose) leaves it nothing. Sized so
/// that a multicopter on optical flow alone, whose compass wanders by degrees, keeps a
/// pose over most of a flight within a few hundred metres of its start (randomised
/// flights: see BENCHMARKS.md); lower them where the vehicle flies close to obstacles.
pub const DEFAULT_HORIZONTAL_ALERT_M: f64 = 50.0;
pub const DEFAULT_VERTICAL_ALERT_M: f64 = 20.0;
/// What a GNSS receiver's error can be beyond the accuracy it reports (multipath, a
/// bad fix), horizontal and vertical, m. Relative sources (a flow, an odometry
/// segment) see it come and go, not an offset already in the estimate: at the origin,
/// or in the fix a reset takes after an outage. Unless a second receiver checks it,
/// the protection level carries it. Horizontal: 200 randomised flights (seed 1), the
/// poses outside their bound 5 011 → 1 303 at 98.5 % airborne availability (98.7 %
/// without). Vertical: none by default — 10 m caught no failure there and, against the
/// 20 m vertical alert limit, cut the median availability to 94.4 %.
pub const DEFAULT_GNSS_FAULT_HORIZONTAL_M: f64 = 10.0;
pub const DEFAULT_GNSS_FAULT_VERTICAL_M: f64 = 0.0;
/// An excluded source agrees again for this long before it is fused again, s.
pub const DEFAULT_READMIT_S: f64 = 10.0;
/// A sub-filter quiet this long starts again from the main filter, s.
pub const DEFAULT_RESTART_S: f64 = 30.0;
/// In a frame of its own, the frame is re-anchored where the horizontal protection
/// level passes this fraction of the alert limit (0: never). Without anything that
/// measures where the vehicle is (a GNSS), its position is relative navigation: what
/// the flow or the odometry measures is the motion, and the drift since take-off grows
/// with the distance flown, however well the motion is measured (a flow off 3 % in
/// scale under a compass that wanders by degrees, over a kilometre: tens of metres).
/// Such a position is sent as the motion since the last anchor, as ArduPilot's EKF
/// calls a flow's position relative: the estimate does not move, the frame does (the
/// reset counter steps, as for any discontinuity), and the bound is on the position
/// relative to where the estimate had the vehicle, and at the heading it had, at the
/// anchor. Randomised climbs on a flow and a barometer (seed 2) were valid a median
/// 68 % of the airborne time, the rest over the alert limit on the drift since
/// take-off alone. Late rather than early (0.8, not 0.5): right after an anchor the
/// bound is centimetres, and what the filter's model of a real flow leaves out shows
/// there first (the PX4 flow flight in `../shared/data`, anchored at 0.5 after the
/// carry by hand: 98.7 % of its poses within 3σ north of the camera's track; at 0.8,
/// anchored once in flight, and unanchored: 100 %).
pub const DEFAULT_REANCHOR_FRACTION: f64 = 0.8;
/// Anchors at most this often, µs: a motion that is barely measured (a velocity σ of
/// metres per second) regains its bound in seconds, and an anchor that follows the
/// estimate around would make the bound say nothing.
const REANCHOR_EVERY_US: i64 = 30_000_000;
/// Nor while the velocity is this uncertain, m/s (1σ, horizontal): the motion is not
/// measured yet (a flow back after minutes of nothing, its first samples settling the
/// velocity), and a bound started from nil would rest on the velocity's σ alone.
const ANCHOR_VELOCITY_STD_MPS: f64 = 0.5;
/// Nor before the motion has been measured without a break for this long, µs: a
/// velocity back after a spell without one still corrects the position it left behind
/// (through their correlation), and an anchor would freeze that position where it
/// was (a vehicle held on its side by hand for 4.5 s: anchored 40 ms after the flow
/// came back, 0.31 m off where the filter would have brought it back to).
const ANCHOR_SETTLE_US: i64 = 10_000_000;
/// The tests run at most this often (filter time), µs.
const CHECK_EVERY_US: i64 = 50_000;
/// "Quiet": a separation under this fraction of its threshold.
pub const RESTART_QUIET_RATIO: f64 = 0.3;
/// A separation's σ is taken as at least this, m: a source that moved the estimate
/// by millimetres on an axis it barely informs (a flow's velocity on the height, by
/// the tilt) is no fault, however small its own σ there.
const SIGMA_D_FLOOR: f64 = 0.2;
/// A Jacobian entry this large (of a unit one) makes a measurement inform a channel:
/// a body-frame velocity's vertical part through a tilt of a few degrees does not.
const CHANNEL_WEIGHT: f64 = 0.3;
/// A source counts as measuring a channel this long after it last did, at least, µs.
const CHANNEL_RECENT_US: i64 = 2_000_000;

/// `[integrity]`: the tests, the protection levels and the alert limits.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IntegrityConfig {
    /// Run the bank of sub-filters and the separation tests. Off: the protection level
    /// is the main filter's `K_ffmd·σ` alone.
    pub enabled: bool,
    pub k_fa: f64,
    pub k_md: f64,
    pub k_ffmd: f64,
    pub horizontal_alert_m: f64,
    pub vertical_alert_m: f64,
    pub readmit_s: f64,
    pub restart_s: f64,
    pub gnss_fault_horizontal_m: f64,
    pub gnss_fault_vertical_m: f64,
    pub reanchor_fraction: f64,
}

impl Default for IntegrityConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            k_fa: DEFAULT_K_FA,
            k_md: DEFAULT_K_MD,
            k_ffmd: DEFAULT_K_FFMD,
            horizontal_alert_m: DEFAULT_HORIZONTAL_ALERT_M,
            vertical_alert_m: DEFAULT_VERTICAL_ALERT_M,
            readmit_s: DEFAULT_READMIT_S,
            restart_s: DEFAULT_RESTART_S,
            gnss_fault_horizontal_m: DEFAULT_GNSS_FAULT_HORIZONTAL_M,
            gnss_fault_vertical_m: DEFAULT_GNSS_FAULT_VERTICAL_M,
            reanchor_fraction: DEFAULT_REANCHOR_FRACTION,
        }
    }
}

impl IntegrityConfig {
    pub fn validate(&self) -> Result<(), String> {
        for (name, v) in [
            ("k_fa", self.k_fa),
            ("k_md", self.k_md),
            ("k_ffmd", self.k_ffmd),
            ("horizontal_alert_m", self.horizontal_alert_m),
            ("vertical_alert_m", self.vertical_alert_m),
            ("readmit_s", self.readmit_s),
            ("restart_s", self.restart_s),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!(
                    "integrity.{name} must be a positive number, got {v}"
                ));
            }
        }
        for (name, v) in [
            ("gnss_fault_horizontal_m", self.gnss_fault_horizontal_m),
            ("gnss_fault_vertical_m", self.gnss_fault_vertical_m),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!(
                    "integrity.{name} must be a number of metres, 0 or more, got {v}"
                ));
            }
        }
        let f = self.reanchor_fraction;
        if !(f.is_finite() && (0.0..=1.0).contains(&f)) {
            return Err(format!(
                "integrity.reanchor_fraction must be a fraction of the alert limit from 0 (never) to 1, got {f}"
            ));
        }
        Ok(())
    }
}

/// The channels a measurement informs.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Channels {
    pub horizontal: bool,
    pub vertical: bool,
    /// Per channel (horizontal, vertical): whether it reads the position there, not
    /// only the velocity. Only such a measurement, accepted, answers a refused position.
    pub position: [bool; 2],
}

impl Channels {
    /// From the core states its Jacobian reads (position, velocity, terrain). In a row
    /// that reads a horizontal velocity the height states are a scale (a flow's, by the
    /// height above the terrain), not a height measured: the vertical channel stays the
    /// range finder's and the barometer's.
    pub fn of(m: &Measurement) -> Self {
        let mut c = Channels::default();
        for row in 0..m.rows() {
            let reads_horizontal_velocity = m
                .jacobian_row(row)
                .entries()
                .any(|(k, h)| (k == IDX_V || k == IDX_V + 1) && h.abs() >= CHANNEL_WEIGHT);
            for (k, h) in m.jacobian_row(row).entries() {
                if h.abs() < CHANNEL_WEIGHT
                    || (reads_horizontal_velocity && (k == IDX_P + 2 || k == IDX_TERRAIN))
                {
                    continue;
                }
                match k {
                    k if k == IDX_P || k == IDX_P + 1 => {
                        c.horizontal = true;
                        c.position[0] = true;
                    }
                    k if k == IDX_V || k == IDX_V + 1 => c.horizontal = true,
                    k if k == IDX_P + 2 => {
                        c.vertical = true;
                        c.position[1] = true;
                    }
                    k if k == IDX_V + 2 || k == IDX_TERRAIN => c.vertical = true,
                    _ => {}
                }
            }
        }
        c
    }
}

/// When a source last informed each channel (fused into the main filter).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SourceChannels {
    pub horizontal: Option<i64>,
    pub vertical: Option<i64>,
}

/// A source taken out by a failed separation test.
#[derive(Debug, Clone, PartialEq)]
pub struct Excluded {
    pub since: i64,
    /// Since when its samples have agreed with the estimate (innovation test passed).
    pub agreeing_since: Option<i64>,
}

/// One sub-filter's test, as the status shows it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SeparationTest {
    /// The source the sub-filter leaves out.
    pub source: String,
    /// x₀ − x_k, ENU, m.
    pub separation: [f64; 3],
    /// σ of the separation per axis, m.
    pub sigma: [f64; 3],
    /// The largest |d| / T over the channels it is tested on (> 1: failed).
    pub ratio: f64,
    /// Tested on (another source shares the channel).
    pub horizontal: bool,
    pub vertical: bool,
    /// The only GNSS receiver, failed on the horizontal: not excluded there (see
    /// `check`), the bound covers the separation instead.
    pub lone_receiver_held: bool,
    /// Since when it has been held, µs (filter time).
    #[serde(skip)]
    pub held_since: Option<i64>,
    /// The source itself informed the channel (horizontal, vertical), shared or not.
    #[serde(skip)]
    pub informs: [bool; 2],
    /// Seconds since the sub-filter started.
    pub age_s: f64,
}

/// The monitor's state (part of the core: snapshotted and re-run with it).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct IntegrityState {
    pub channels: SourceMap<SourceChannels>,
    pub excluded: SourceMap<Excluded>,
    pub last_check: Option<i64>,
    /// The reset counter at the last check.
    pub checked_reset: u8,
    pub tests: Vec<SeparationTest>,
    /// Protection levels of the last check (horizontal, vertical), m.
    pub hpl: f64,
    pub vpl: f64,
    /// Per axis (ENU), the largest separation of a tested sub-filter beyond its 1σ,
    /// squared, m²: a disagreement between solutions that no test has resolved, added
    /// to the covariance sent so that an autopilot weighs what it cannot see.
    pub unresolved_var: [f64; 3],
    pub exclusions: u64,
    /// Per channel (horizontal, vertical): the measurements refused since the last
    /// one accepted there.
    pub refused: [Option<RefusedStreak>; 2],
    /// Per channel: what a long refusal said when a position ended it, and when (µs):
    /// fading over [`RELEASE_TAU_S`] (see [`IntegrityState::held`]).
    pub released: [Option<(i64, Vector3<f64>)>; 2],
    /// Per channel: the mean normalised innovation (yᵢ²/Sᵢ) of the last accepted rows,
    /// about [`MISFIT_ROWS`] of them (see [`IntegrityState::misfit_factor`]).
    pub misfit: [f64; 2],
    /// When the frame of its own was last re-anchored, µs (filter time; see
    /// [`DEFAULT_REANCHOR_FRACTION`]): the horizontal bound is relative to it.
    pub anchored: Option<i64>,
    /// Since when a source has measured the motion without a break (see
    /// [`ANCHOR_SETTLE_US`]), µs.
    pub motion_since: Option<i64>,
    /// The anchors made so far, and the last one: (its ordinal, time, E, N).
    pub anchor_count: usize,
    pub last_anchor: Option<(usize, i64, [f64; 2])>,
}

/// How much wider than a lone receiver's slow error (its stationary 1σ) the σ sent on
/// the channels it holds is. A slowly varying error is a handful of draws over a
/// flight, so a flight's share of poses within 3σ is not 99.7 % but as its few draws
/// fell: sampled over flights of 2-15 min with correlation times of 30 s-5 min, an
/// error sent at exactly its own σ leaves 12 % of flights under 99 % within 3σ on some
/// axis, at 1.3× 0.6 % (`a_slow_error_needs_its_sigma_overbounded`).
/// The Gaussian sent overbounds the error's distribution over a flight, as aviation's
/// integrity σ overbounds a range error's.
pub const GNSS_SLOW_OVERBOUND: f64 = 1.3;

/// Rows the misfit averages over: half a second of a 10 Hz GNSS's two axes.
pub const MISFIT_ROWS: f64 = 10.0;
/// A mean normalised innovation up to this is a consistent filter's (the mean of 10
/// χ²₁ exceeds 2 one time in 30); beyond it, what is sent is widened by the excess.
pub const MISFIT_OK: f64 = 2.0;
/// One row counts at most this much (the gate's 5σ).
const MISFIT_ROW_CAP: f64 = 25.0;

/// A refusal that lasted this long is not resolved by the measurement that ends it, µs.
pub const LONG_REFUSAL_US: i64 = 3_000_000;
/// Its disagreement fades over this time once a position ended it, s: a receiver's
/// multipath lasts seconds to a minute.
pub const RELEASE_TAU_S: f64 = 60.0;

/// What the refused measurements of a channel say the estimate may be wrong by.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RefusedStreak {
    /// The first and the latest refusal, µs.
    pub since: i64,
    pub last: i64,
    /// The largest |shift| of the position, per axis, were a refused measurement
    /// exact (m): of the refused positions, and of the refused velocity-only
    /// measurements (through the position's correlation with the velocity); and the
    /// refused velocity shifts integrated over time (m).
    pub shift: Vector3<f64>,
    pub velocity_shift: Vector3<f64>,
    pub drift: Vector3<f64>,
}

impl RefusedStreak {
    /// Per axis, what the streak says the estimate may be wrong by, m.
    fn extent(&self) -> Vector3<f64> {
        self.shift + self.velocity_shift + self.drift
    }
}

/// A refused velocity counts for at most this long since the previous refusal, µs.
const DRIFT_STEP_MAX_US: i64 = 1_000_000;

impl IntegrityState {
    /// `source` informed these channels of the main filter at `t`.
    pub fn fused(&mut self, source: &str, ch: Channels, t: i64) {
        let c = self
            .channels
            .get_or_insert_with(source, SourceChannels::default);
        if ch.horizontal {
            c.horizontal = Some(t);
        }
        if ch.vertical {
            c.vertical = Some(t);
        }
    }

    /// An aiding measurement of these channels was accepted at `t`: they are held
    /// again. A velocity answers what the refused velocities said (their drift, and
    /// the position they would have moved through its correlation with the velocity:
    /// one noisy flow sample refused over dark ground, taken as exact, put 57 m into
    /// the bound of a climb with no position source, for good; randomised draw 744:
    /// 15.5 % valid airborne, the error under 2 m), not a refused position: a GNSS
    /// whose velocity passed while its positions were refused for a minute (its
    /// multipath over, the estimate 4.3 m off on its last fixes) had the
    /// covariance sent claim 0.7 m all along (randomised draw 74: 2 595 poses beyond
    /// 5σ). A position that ends a refusal of [`LONG_REFUSAL_US`] or more does not
    /// settle it either: it may be the liar passing the gate at its edge (draw 55: a fix
    /// after 24 s of refused multipath moved the estimate 1.7 m onto it and σ fell to
    /// 0.67 m), so what the refusal said fades over [`RELEASE_TAU_S`] instead.
    pub fn held(&mut self, ch: Channels, t: i64) {
        for (c, on) in [ch.horizontal, ch.vertical].into_iter().enumerate() {
            if !on {
                continue;
            }
            match self.refused[c].as_mut() {
                Some(streak) if !ch.position[c] && streak.shift != Vector3::zeros() => {
                    streak.drift = Vector3::zeros();
                    streak.velocity_shift = Vector3::zeros();
                }
                Some(streak) if streak.last - streak.since >= LONG_REFUSAL_US => {
                    let extent = streak.extent().sup(&self.released_at(c, t));
                    self.released[c] = Some((t, extent));
                    self.refused[c] = None;
                }
                _ => self.refused[c] = None,
            }
        }
    }

    /// What a long refusal of channel `c` still says at `t`.
    fn released_at(&self, c: usize, t: i64) -> Vector3<f64> {
        self.released[c].map_or(Vector3::zeros(), |(since, e)| {
            e * (-((t - since).max(0) as f64 * 1e-6) / RELEASE_TAU_S).exp()
        })
    }

    /// An aiding measurement of these channels was refused at `t`; were it exact the
    /// position would move by `dp` and the velocity by `dv`.
    pub fn refused(&mut self, ch: Channels, t: i64, dp: Vector3<f64>, dv: Vector3<f64>) {
        for (c, on) in [ch.horizontal, ch.vertical].into_iter().enumerate() {
            if !on {
                continue;
            }
            let axes = if c == 0 { 0..2 } else { 2..3 };
            let streak = self.refused[c].get_or_insert(RefusedStreak {
                since: t,
                last: t,
                shift: Vector3::zeros(),
                velocity_shift: Vector3::zeros(),
                drift: Vector3::zeros(),
            });
            let shift = if ch.position[c] {
                &mut streak.shift
            } else {
                &mut streak.velocity_shift
            };
            let dt = ((t - streak.last).clamp(0, DRIFT_STEP_MAX_US)) as f64 * 1e-6;
            for a in axes {
                shift[a] = shift[a].max(dp[a].abs());
                streak.drift[a] += dv[a].abs() * dt;
            }
            streak.last = t;
        }
    }

    /// An accepted row of a measurement of this channel: innovation `y`, variance `s`.
    pub fn observe_misfit(&mut self, horizontal: bool, y: f64, s: f64) {
        if !(y.is_finite() && s.is_finite() && s > 0.0) {
            return;
        }
        let m = &mut self.misfit[usize::from(!horizontal)];
        *m += ((y * y / s).min(MISFIT_ROW_CAP) - *m) / MISFIT_ROWS;
    }

    /// How much wider than the filter's own the variance sent is, per channel
    /// (horizontal, vertical): the accepted measurements themselves say the estimate is
    /// that much less certain than the filter thinks. Whatever misleads the model (an
    /// accelerometer that stepped 1 m/s² in a hard step, a delay nobody configured),
    /// the fixes it still passes show it first: on PX4's square with the accelerometer
    /// off, fixes 0.44 m off passed the gate while the filter claimed 4 cm.
    pub fn misfit_factor(&self) -> [f64; 2] {
        self.misfit.map(|m| (m / MISFIT_OK).max(1.0))
    }

    /// Per axis (ENU), what the refused measurements say the estimate may be wrong by
    /// at `t`, m: the open refusals and what the long ones that ended still say.
    pub fn refused_extent(&self, t: i64) -> Vector3<f64> {
        let mut e = Vector3::zeros();
        for s in self.refused.iter().flatten() {
            e += s.extent();
        }
        for c in 0..2 {
            e = e.sup(&self.released_at(c, t));
        }
        e
    }

    pub fn is_excluded(&self, source: &str) -> bool {
        self.excluded.get(source).is_some()
    }

    /// Another source than `source` informed the channel recently.
    fn shared(&self, source: &str, t: i64, horizontal: bool, window: i64) -> bool {
        self.channels.iter().any(|(s, c)| {
            s != source
                && !self.is_excluded(s)
                && if horizontal { c.horizontal } else { c.vertical }
                    .is_some_and(|l| t - l <= window)
        })
    }
}

/// An excluded source's sample was tested against the estimate (`agrees`: its
/// innovation passed the gate). Re-admits it after `readmit_s` of agreement.
pub(super) fn excluded_sample(core: &mut Core, ctx: &Ctx, t: i64, source: &str, agrees: bool) {
    let readmit = (ctx.cfg.integrity.readmit_s * 1e6) as i64;
    let Some(x) = core.integrity.excluded.get_mut(source) else {
        return;
    };
    if !agrees {
        x.agreeing_since = None;
        return;
    }
    let since = *x.agreeing_since.get_or_insert(t);
    if t - since < readmit {
        return;
    }
    let excluded_s = (t - x.since) as f64 * 1e-6;
    core.integrity.excluded.retain(|s, _| s != source);
    if let Some(bank) = core.ekf.as_mut() {
        bank.drop_shadow(source);
    }
    core.event(
        t,
        Some(source),
        format!(
            "integrity: {source} agrees again ({:.0} s): fused again after {excluded_s:.1} s excluded",
            ctx.cfg.integrity.readmit_s
        ),
        Event::IntegrityReadmit { excluded_s },
    );
}

/// Run the tests (at most every [`CHECK_EVERY_US`]): exclude a faulty source, restart
/// quiet sub-filters, and set the protection levels.
pub(super) fn check(core: &mut Core, ctx: &Ctx, t: i64) {
    // Not held back after a reset: the protection level of the estimate before it is
    // not this one's (randomised draw 334: a pose sent valid 14 m off, on the level of
    // 20 ms before the reset that moved it there).
    if core.integrity.checked_reset == core.reset_counter
        && core
            .integrity
            .last_check
            .is_some_and(|l| t - l < CHECK_EVERY_US && t >= l)
    {
        return;
    }
    core.integrity.last_check = Some(t);
    core.integrity.checked_reset = core.reset_counter;
    let cfg = &ctx.cfg.integrity;
    let window = channel_window(ctx.cfg);
    let Some(bank) = core.ekf.as_ref() else {
        core.integrity.tests.clear();
        return;
    };
    let main = bank.main();
    let p0 = main.cov3(IDX_P);
    let x0 = main.pos();
    let sigma0 = axis_sigma(&p0);
    // The fault-free bounds, widened by what the accepted measurements say of the
    // filter's own σ: horizontally the error ellipse's, vertically the up axis's.
    let misfit = core.integrity.misfit_factor();
    let fault_free_h = fault_free_hpl(&p0, cfg.k_ffmd) * misfit[0].sqrt();
    // Per axis, the faults' (below) beside the fault-free vertical one.
    let mut pl = Vector3::new(0.0, 0.0, sigma0.z * misfit[1].sqrt() * cfg.k_ffmd);
    // Kept from one check to the next (the figures are written in place, the names
    // cloned only when the bank changed): this runs 20 times a second.
    let mut tests = std::mem::take(&mut core.integrity.tests);
    tests.truncate(bank.subs().len());
    let mut worst: Option<(usize, f64)> = None;
    let mut unresolved = [0.0f64; 3];
    let mut restart: Vec<String> = Vec::new();
    for (i, sub) in bank.subs().iter().enumerate() {
        let d = x0 - sub.ekf.pos();
        let pk = sub.ekf.cov3(IDX_P);
        let sigma_k = axis_sigma(&pk);
        // Var(x0 − xk) = Pk − P0 holds while the sub-filter's information is a part of
        // the main filter's. A sub-filter surer than the main one on an axis has learnt
        // something the main one refused (a GNSS fix that an unaided sub-filter took
        // after an outage while the main one, held by the flow, gated it out): there the
        // two are taken as independent, Pk + P0. With the difference, floored, a flow
        // was excluded for disagreeing with a GNSS that was 4.7 m off (draw 74). So is
        // one that fused anything the main one refused, whatever its σ: a camera was
        // excluded for disagreeing with a GNSS back from an outage 3 m off (draw 127).
        let sigma_d = Vector3::from_fn(|a, _| {
            let (k, z) = (pk[(a, a)].max(0.0), p0[(a, a)].max(0.0));
            let var = if k >= z && !sub.took_refused {
                k - z
            } else {
                k + z
            };
            var.sqrt().max(SIGMA_D_FLOOR)
        });
        // Tested on a channel the source informs and another source shares.
        let own = core
            .integrity
            .channels
            .get(&sub.without)
            .copied()
            .unwrap_or_default();
        let informs = |c: Option<i64>| c.is_some_and(|l| t - l <= window);
        let own_informs = [informs(own.horizontal), informs(own.vertical)];
        let horizontal = own_informs[0] && core.integrity.shared(&sub.without, t, true, window);
        let vertical = own_informs[1] && core.integrity.shared(&sub.without, t, false, window);
        // A channel that another source starts to share, the left-out one informing it
        // all along: there the sub-filter has been without its left-out source and
        // without anything else, on the IMU alone, and what it is there is no solution
        // to test against. It starts again from the main filter (randomised draw 860:
        // the filter without the camera, 7.5 m and 0.8 m off on the IMU alone when a
        // flow joined, excluded the camera 1.2 s later and kept the estimate 1.3–3 m
        // under the truth). Not when the left-out source itself comes back: the one
        // without it is what it is tested against (draw 659: a GNSS back 4.4 m off).
        let newly_tested = tests
            .get(i)
            .filter(|old| old.source == sub.without)
            .is_some_and(|old| {
                (horizontal && !old.horizontal && old.informs[0])
                    || (vertical && !old.vertical && old.informs[1])
            });
        if newly_tested {
            restart.push(sub.without.clone());
        }
        // The only GNSS receiver on the horizontal is the only thing that measures
        // where the vehicle is; the sub-filter without it is dead reckoning, whose
        // drift under a compass off by degrees or a flow off its scale the model
        // bounds no better than the receiver's. Their departure says that the two
        // disagree, not that the receiver is wrong, and excluding it leaves the dead
        // reckoning, which nothing checks any more, and a receiver that can agree
        // again only with an estimate that has drifted away from it: the lock-out.
        // Randomised flights: seed 3 draw 445 (a flow 8 % off its scale under a
        // compass swinging ±14°: the receiver excluded, the estimate 8.8 m off), seed 2
        // draw 138 (a receiver excluded at take-off, never fused again). Held, its
        // case is covered instead: the bound takes the whole separation (were the
        // receiver wrong, the truth is with the dead reckoning), and the receiver's
        // own unreported error is on top (`gnss_fault_horizontal_m`).
        let lone_receiver = core
            .stats
            .get(sub.without.as_str())
            .is_some_and(|st| st.kind == "gnss")
            && gnss_receivers(core, t, true, window, Some(&sub.without)) == 0;
        let mut ratio = 0.0f64;
        let mut excludable = 0.0f64;
        let mut held = false;
        for a in 0..3 {
            let tested = if a < 2 { horizontal } else { vertical };
            if !tested || newly_tested {
                continue;
            }
            let threshold = cfg.k_fa * sigma_d[a];
            let r = d[a].abs() / threshold;
            ratio = ratio.max(r);
            unresolved[a] = unresolved[a].max((d[a].abs() - sigma_d[a]).max(0.0).powi(2));
            if a < 2 && lone_receiver {
                held |= r > 1.0;
                pl[a] = pl[a].max(threshold.max(d[a].abs()) + cfg.k_md * sigma_k[a]);
            } else {
                excludable = excludable.max(r);
                pl[a] = pl[a].max(threshold + cfg.k_md * sigma_k[a]);
            }
        }
        if excludable > 1.0 && worst.is_none_or(|(_, r)| excludable > r) {
            worst = Some((i, excludable));
        }
        let held_since = held.then(|| {
            tests
                .get(i)
                .filter(|old| old.source == sub.without)
                .and_then(|old| old.held_since)
                .unwrap_or(t)
        });
        let test = SeparationTest {
            source: String::new(),
            separation: [d.x, d.y, d.z],
            sigma: [sigma_d.x, sigma_d.y, sigma_d.z],
            ratio,
            horizontal,
            vertical,
            lone_receiver_held: held,
            held_since,
            informs: own_informs,
            age_s: (t - sub.since) as f64 * 1e-6,
        };
        match tests.get_mut(i) {
            Some(old) => {
                let name = std::mem::take(&mut old.source);
                *old = test;
                old.source = name;
            }
            None => tests.push(test),
        }
        if tests[i].source != sub.without {
            tests[i].source = sub.without.clone();
        }
    }
    // The solutions the exclusions set aside (see `bank::Shadow`): were an excluded
    // source right, the estimate is off by the separation from its solution.
    for shadow in bank.shadows() {
        let d = x0 - shadow.ekf.pos();
        let sigma_s = axis_sigma(&shadow.ekf.cov3(IDX_P));
        for a in 0..3 {
            pl[a] = pl[a].max(d[a].abs() + cfg.k_md * sigma_s[a]);
            unresolved[a] = unresolved[a].max(d[a] * d[a]);
        }
    }
    // What the accepted measurements say of the filter's own σ, in the σ sent.
    for a in 0..3 {
        let f = misfit[usize::from(a == 2)];
        if f > 1.0 {
            unresolved[a] = unresolved[a].max((f - 1.0) * p0[(a, a)].max(0.0));
        }
    }
    // The refused measurements' case (see the module's docs).
    let refused = core.integrity.refused_extent(t);
    for a in 0..3 {
        if refused[a] > 0.0 {
            pl[a] = pl[a].max(refused[a] + cfg.k_md * sigma0[a]);
            unresolved[a] = unresolved[a].max(refused[a] * refused[a]);
        }
    }
    // A GNSS that no second receiver checks, per channel (horizontal, vertical).
    let receivers =
        [true, false].map(|horizontal| gnss_receivers(core, t, horizontal, window, None));
    let lone = receivers.map(|n| n == 1);
    // Its slow error is learnt only through its correlation time, which nobody knows:
    // receivers wander over half a minute to many minutes. The filter's σ falls below
    // the slow error's own spread only by taking it to average out over
    // `gnss_bias_tau_s`; where it does not, the σ sent lies (randomised draw 326: 6 m
    // under the truth for 460 s, sent with σ 1.3 m). The σ sent does not go below it,
    // overbounded (see [`GNSS_SLOW_OVERBOUND`]), on every channel whose estimate one
    // receiver set and none checks: while it informs the channel, and after it went
    // quiet too, since what it left in the estimate stays there (draw 206: 5.4 m off
    // north, sent with σ 1.7 m in a 5 s outage, the floor gone with the fixes).
    // The protection level is the integrity bound, not the accuracy (as ARAIM keeps one
    // covariance for each): it keeps the filter's own σ, with the receiver's unreported
    // error on top (below), and holds the truth on every randomised flight; taken to
    // the floor too, the vertical one of receivers reporting 3-5 m passed the 20 m
    // alert limit and flights valid 95 % fell to 0-10 %.
    // Anchored: no second receiver now, and one ever (a window of `i64::MAX`).
    let ever = [true, false].map(|horizontal| gnss_receivers(core, t, horizontal, i64::MAX, None));
    let anchored = [0, 1].map(|c| receivers[c] <= 1 && ever[c] >= 1);
    for a in 0..3 {
        if !anchored[usize::from(a == 2)] {
            continue;
        }
        let var0 = p0[(a, a)].max(0.0);
        let floor = (GNSS_SLOW_OVERBOUND * main.gnss_bias_std[a]).powi(2) - var0;
        if floor > 0.0 {
            unresolved[a] = unresolved[a].max(floor);
        }
    }
    // Its unreported error (see `DEFAULT_GNSS_FAULT_HORIZONTAL_M`) on the channels it
    // holds, on top of the rest.
    let unchecked_h = if lone[0] {
        cfg.gnss_fault_horizontal_m
    } else {
        0.0
    };
    if lone[1] {
        pl.z += cfg.gnss_fault_vertical_m;
    }
    if !restart.is_empty() {
        if let Some(bank) = core.ekf.as_mut() {
            for source in &restart {
                bank.restart_sub(source, t);
            }
        }
    }
    core.integrity.hpl = fault_free_h.max(pl.x.hypot(pl.y)) + unchecked_h;
    core.integrity.vpl = pl.z;
    core.integrity.unresolved_var = unresolved;
    // Not while carried by hand: nothing is sent then (the pose is invalid until set
    // down), and a hand tilts a range finder at anything, so the sources disagree in
    // ways a flight does not. Measured on the real PX4 flight: a camera excluded in
    // (or just after) the hand for a range finder's steps left the main filter with
    // the flow's uncorrected drift for the whole flight after.
    // The sub-filters follow the main one meanwhile: what they made of the hand's
    // motion is no test of anything once it is set down.
    if core.ground.handled(t) {
        if let Some(bank) = core.ekf.as_mut() {
            for s in &tests {
                bank.restart_sub(&s.source, t);
            }
        }
        core.integrity.tests = tests;
        return;
    }
    if let Some((i, ratio)) = worst {
        let test = tests[i].clone();
        core.integrity.tests = tests;
        exclude(core, t, &test, ratio);
        return;
    }
    if reanchor_due(core, cfg, t, window) {
        reanchor(core, ctx, t);
    }
    // Quiet sub-filters start again from the main one (see the module's docs), and
    // so does one held for a lone receiver for as long: its dead reckoning drifts on,
    // and the bound with it, to silence (a receiver's fault shows within the window;
    // randomised seed 3 draw 173: 30 s of multipath 9 m out, covered all along).
    let restart = (cfg.restart_s * 1e6) as i64;
    if let Some(bank) = core.ekf.as_mut() {
        for s in &tests {
            let quiet = match s.held_since {
                Some(since) => t - since >= restart,
                None => s.ratio < RESTART_QUIET_RATIO && s.age_s * 1e6 >= restart as f64,
            };
            if quiet {
                bank.restart_sub(&s.source, t);
            }
        }
    }
    core.integrity.tests = tests;
}

/// Relative navigation starts again (the frame is re-anchored) from a bound of up to
/// this many alert limits once the motion is measured again. A flow dark for 20 s
/// just as the bound neared the anchoring fraction took it past the limit, and the
/// frame was never anchored again: invalid for the rest of the flight while the error
/// was a metre (randomised seed 2 draw 228, 38 % valid airborne instead of 86 %; seed 3
/// draw 104, 66 % instead of 93 %). Beyond it the estimate had lost where it was
/// (minutes on the IMU alone above a range finder, 100 m off with a bound of 1 km, seed
/// 2 draw 287), no place to start from, though a bound from there would hold: the
/// valid poses' RMSE over the flight went 0.12 → 24 m.
pub const RESUME_BOUND_FACTOR: f64 = 2.0;

/// A frame of its own whose horizontal bound has grown past the anchoring fraction
/// of the alert limit while a source measures the motion (see
/// [`DEFAULT_REANCHOR_FRACTION`]). Not in a frame a GNSS set: there the position is
/// where the vehicle is on Earth, and its bound is what it is. Nor once the bound has
/// passed [`RESUME_BOUND_FACTOR`] alert limits. Keeps `motion_since` as it goes.
fn reanchor_due(core: &mut Core, cfg: &IntegrityConfig, t: i64, window: i64) -> bool {
    let measured = core.ground.hold.is_none()
        && core.integrity.channels.iter().any(|(s, c)| {
            !core.integrity.is_excluded(s) && c.horizontal.is_some_and(|l| t - l <= window)
        });
    core.integrity.motion_since = if measured {
        core.integrity.motion_since.or(Some(t))
    } else {
        None
    };
    let settled = core
        .integrity
        .motion_since
        .is_some_and(|since| t - since >= ANCHOR_SETTLE_US);
    let velocity_known = core.ekf.as_ref().is_some_and(|b| {
        let v = b.main().cov3(IDX_V);
        v[(0, 0)].max(v[(1, 1)]).sqrt() <= ANCHOR_VELOCITY_STD_MPS
    });
    cfg.reanchor_fraction > 0.0
        && core.gnss.origin.is_none()
        && settled
        && velocity_known
        && core.integrity.hpl > cfg.reanchor_fraction * cfg.horizontal_alert_m
        && core.integrity.hpl <= RESUME_BOUND_FACTOR * cfg.horizontal_alert_m
        && core
            .integrity
            .anchored
            .is_none_or(|a| t - a >= REANCHOR_EVERY_US || t < a)
}

/// Re-anchor the frame horizontally where the main filter has the vehicle, and at
/// the heading it has, in every filter of the bank: each sub-filter's separation from
/// the main one starts again with the bound (it was a drift since the old anchor,
/// which the frame leaves). The heading too: in a frame of its own the compass's
/// error counts from the take-off heading, and a compass that swings ±13° over minutes
/// is off it by 25° for as long, where the position since the anchor turns by the
/// whole of it (randomised draw 370 of seed 2: 604 poses beyond 5σ on laps of 20 m
/// anchored in position alone); from the anchor's heading it is off by what it moved
/// since, which the heading's model bounds (`yaw_error_std`, `yaw_error_tau_s`).
/// A re-run of the history anchors where the first run did (see `Ctx::anchors`), if
/// within the history's reach of it.
fn reanchor(core: &mut Core, ctx: &Ctx, t: i64) {
    let Some(bank) = core.ekf.as_mut() else {
        return;
    };
    let k = core.integrity.anchor_count;
    let reach = (ctx.cfg.history_ms * 1000.0) as i64;
    let at = match ctx.anchors.get(k) {
        Some(&(first, at)) if (t - first).abs() <= reach => Vector3::new(at[0], at[1], 0.0),
        _ => bank.main().pos(),
    };
    bank.anchor([at.x, at.y], t);
    core.integrity.anchored = Some(t);
    core.integrity.anchor_count = k + 1;
    core.integrity.last_anchor = Some((k, t, [at.x, at.y]));
    core.reset_counter = core.reset_counter.wrapping_add(1);
    let hpl = core.integrity.hpl;
    core.event(
        t,
        None,
        format!(
            "frame re-anchored at ({:.2}, {:.2}) m: nothing measures where the vehicle is, and the drift bound since the last anchor had reached {hpl:.1} m; the position is relative navigation from here",
            at.x, at.y
        ),
        Event::Reset(crate::event::Reset::Anchor {
            reset_counter: core.reset_counter,
            hpl_m: hpl,
        }),
    );
}

/// Per axis, the 1σ of a position covariance, m.
fn axis_sigma(p: &nalgebra::Matrix3<f64>) -> Vector3<f64> {
    p.diagonal().map(|v| v.max(0.0).sqrt())
}

/// How long a source counts as informing a channel after it last did, µs.
pub(super) fn channel_window(cfg: &super::config::EstimatorConfig) -> i64 {
    ((cfg.aiding_timeout_ms * 1000.0) as i64).max(CHANNEL_RECENT_US)
}

/// The GNSS receivers (other than `except`) not excluded that informed the channel
/// (horizontal, else vertical) within `window` of `t`, µs.
pub(super) fn gnss_receivers(
    core: &Core,
    t: i64,
    horizontal: bool,
    window: i64,
    except: Option<&str>,
) -> usize {
    core.integrity
        .channels
        .iter()
        .filter(|(s, c)| {
            except != Some(s.as_str())
                && !core.integrity.is_excluded(s)
                && core
                    .stats
                    .get(s.as_str())
                    .is_some_and(|st| st.kind == "gnss")
                && if horizontal { c.horizontal } else { c.vertical }
                    .is_some_and(|l| t - l <= window)
        })
        .count()
}

/// Exclude the source of the failed `test`: its sub-filter's solution becomes the main
/// one (every other sub-filter starts again from it).
fn exclude(core: &mut Core, t: i64, test: &SeparationTest, ratio: f64) {
    let source = test.source.as_str();
    let Some(bank) = core.ekf.as_mut() else {
        return;
    };
    if !bank.exclude(source, t) {
        return;
    }
    core.integrity.excluded.put(
        source,
        Excluded {
            since: t,
            agreeing_since: None,
        },
    );
    core.integrity.exclusions += 1;
    core.reset_counter = core.reset_counter.wrapping_add(1);
    let [e, n, u] = test.separation;
    let [se, sn, su] = test.sigma;
    core.event(
        t,
        Some(source),
        format!(
            "integrity: {source} excluded: the estimate with it departs from the one without it by ({e:.2}, {n:.2}, {u:.2}) m ENU against σ ({se:.2}, {sn:.2}, {su:.2}) m, {ratio:.1}× the threshold; the solution without it is the estimate now, the one with it is kept beside and bounds what is sent until {source} agrees again"
        ),
        Event::IntegrityExclusion {
            separation: test.separation,
            sigma: test.sigma,
            test_ratio: ratio,
            reset_counter: core.reset_counter,
        },
    );
}

/// The radius a horizontal error of unit covariance (a circular 2-D Gaussian) exceeds
/// as rarely as one axis exceeds `k` (its tail `2·Q(k)`): `√(−2·ln(2·Q(k)))`, 5.85 for
/// k = 5.5 (SBAS flies precision approaches on 6.0). `Q` by its asymptotic series,
/// low by 0.1 % at k = 4 and 0.01 % at 5.5 (so the radius is, if anything, wider); a
/// smaller `k` is taken as 4 (a wider bound).
pub fn horizontal_k(k: f64) -> f64 {
    let k = k.max(4.0);
    let density = (-0.5 * k * k).exp() / (2.0 * std::f64::consts::PI).sqrt();
    let k2 = k * k;
    let tail = density / k * (1.0 - 1.0 / k2 + 3.0 / (k2 * k2) - 15.0 / (k2 * k2 * k2));
    (-2.0 * (2.0 * tail).ln()).sqrt()
}

/// The fault-free horizontal protection level of position covariance `p`: `K_H` times
/// the semi-major axis of its horizontal error ellipse (DO-229's `d_major`). The root
/// sum of two per-axis `K_ffmd·σ` bounds a circular error at 7.8σ, a third wider than
/// the same risk needs, and that third was availability on flights whose only
/// horizontal source is a flow (their σ grows with the distance flown).
pub fn fault_free_hpl(p: &Matrix3<f64>, k_ffmd: f64) -> f64 {
    let (e, n, en) = (p[(0, 0)].max(0.0), p[(1, 1)].max(0.0), p[(0, 1)]);
    let half_diff = 0.5 * (e - n);
    let major = 0.5 * (e + n) + (half_diff * half_diff + en * en).sqrt();
    horizontal_k(k_ffmd) * major.max(0.0).sqrt()
}

/// The protection levels of the estimate now, and the alert limits: the bank's when it
/// runs, else the main filter's fault-free bound alone.
pub(super) fn protection(core: &Core, cfg: &IntegrityConfig) -> Protection {
    let (hpl, vpl) = if cfg.enabled && core.ekf.is_some() && core.integrity.last_check.is_some() {
        (core.integrity.hpl, core.integrity.vpl)
    } else {
        let p = match core.ekf.as_ref() {
            Some(e) => e.cov3(IDX_P),
            None => Matrix3::from_diagonal(&core.wrls.var),
        };
        (
            fault_free_hpl(&p, cfg.k_ffmd),
            axis_sigma(&p).z * cfg.k_ffmd,
        )
    };
    Protection {
        horizontal_m: hpl,
        vertical_m: vpl,
        horizontal_alert_m: cfg.horizontal_alert_m,
        vertical_alert_m: cfg.vertical_alert_m,
        anchored_us: core.integrity.anchored,
    }
}

/// The protection levels of a pose at `present`, whose velocity has covariance
/// `velocity_cov`: the last check's, widened by what the velocity's uncertainty moves
/// the position since (the check's age and the horizon's delay together), which shows
/// where the check's bound is nil (a frame just re-anchored: 0.6 cm off 16 ms later).
pub(super) fn protection_at(
    core: &Core,
    cfg: &IntegrityConfig,
    present: i64,
    velocity_cov: &Matrix3<f64>,
) -> Protection {
    let mut p = protection(core, cfg);
    let since = core.integrity.last_check.or(core.pred_t).unwrap_or(present);
    let span = (present - since).max(0) as f64 * 1e-6;
    p.horizontal_m += fault_free_hpl(velocity_cov, cfg.k_ffmd) * span;
    p.vertical_m += axis_sigma(velocity_cov).z * cfg.k_ffmd * span;
    p
}

#[cfg(test)]
mod tests {
    use super::*;

    /// K_H from the one-axis multiplier: exp(−K_H²/2) is the 2-D tail, 2·Q(k) the
    /// one-axis one (Q(4) = 3.167e-5, Q(5.5) = 1.899e-8).
    #[test]
    fn the_horizontal_multiplier_has_the_one_axis_risk() {
        let tail = |k: f64| (-0.5 * horizontal_k(k).powi(2)).exp();
        assert!(
            (tail(4.0) / (2.0 * 3.167e-5) - 1.0).abs() < 2e-3,
            "{}",
            tail(4.0)
        );
        assert!(
            (tail(5.5) / (2.0 * 1.899e-8) - 1.0).abs() < 3e-4,
            "{}",
            tail(5.5)
        );
        assert!((horizontal_k(5.5) - 5.846).abs() < 1e-3);
    }

    /// Of `flights` flights (2-15 min, sampled at 2 Hz) whose slow error is a
    /// Gauss-Markov error (correlation time 30 s-5 min) on three axes, sent with `k`
    /// times its own σ: how many have under 99 % of their samples within 3σ on some axis.
    fn flights_under_99_within_3_sigma(k: f64, flights: usize, seed: u64) -> usize {
        use rand::{Rng, SeedableRng};
        use rand_distr::StandardNormal;
        const DT_S: f64 = 0.5;
        let mut rng = rand::rngs::SmallRng::seed_from_u64(seed);
        (0..flights)
            .filter(|_| {
                let tau = rng.gen_range(30.0..300.0);
                let n = (rng.gen_range(120.0..900.0) / DT_S) as usize;
                let phi = (-DT_S / tau).exp();
                let q = (1.0 - phi * phi).sqrt();
                (0..3).any(|_| {
                    let mut x: f64 = rng.sample(StandardNormal);
                    let mut within = 0usize;
                    for _ in 0..n {
                        within += usize::from(x.abs() <= 3.0 * k);
                        x = phi * x + q * rng.sample::<f64, _>(StandardNormal);
                    }
                    (within as f64) < 0.99 * n as f64
                })
            })
            .count()
    }

    /// Why the σ sent overbounds a lone receiver's slow error: sent at exactly its own
    /// σ, a calibrated slow error leaves one flight in eight under 99 % within 3σ (121
    /// of 1 000); at [`GNSS_SLOW_OVERBOUND`] times it, 6.
    #[test]
    fn a_slow_error_needs_its_sigma_overbounded() {
        let at_own = flights_under_99_within_3_sigma(1.0, 1000, 1);
        let overbounded = flights_under_99_within_3_sigma(GNSS_SLOW_OVERBOUND, 1000, 1);
        println!("of 1 000 flights: {at_own} at its own σ, {overbounded} overbounded");
        assert!(at_own > 100, "{at_own}");
        assert!(overbounded < 20, "{overbounded}");
    }

    /// The fault-free bound is K_H times the ellipse's semi-major axis: a circular σ of
    /// 1 m is bounded at 5.85 m, not the 7.78 m of two per-axis 5.5σ; an ellipse
    /// turned off the axes is bounded by its major axis, not by its E and N spreads.
    #[test]
    fn the_fault_free_bound_is_the_error_ellipse_s() {
        let k = horizontal_k(5.5);
        let circle = Matrix3::identity();
        assert!((fault_free_hpl(&circle, 5.5) - k).abs() < 1e-12);
        assert!(fault_free_hpl(&circle, 5.5) < (5.5f64).hypot(5.5));
        // σ 2 m along the north-east diagonal, 0.1 m across: E and N 1.415 m each.
        let (a, b) = (4.0, 0.01);
        let turned = Matrix3::new(
            0.5 * (a + b),
            0.5 * (a - b),
            0.0,
            0.5 * (a - b),
            0.5 * (a + b),
            0.0,
            0.0,
            0.0,
            1.0,
        );
        assert!((fault_free_hpl(&turned, 5.5) - 2.0 * k).abs() < 1e-9);
    }

    #[test]
    fn a_measurement_says_which_channels_it_informs() {
        // A horizontal velocity, nothing more.
        let horizontal_velocity = Channels {
            horizontal: true,
            vertical: false,
            position: [false, false],
        };
        let m = Measurement::height(0.1, 0.01);
        assert_eq!(
            Channels::of(&m),
            Channels {
                horizontal: false,
                vertical: true,
                position: [false, true],
            }
        );
        let r = nalgebra::Matrix3::identity();
        let m = Measurement::of_states(IDX_V, 2, &Vector3::zeros(), &r);
        assert_eq!(Channels::of(&m), horizontal_velocity);
        // A flow scaled by the filter's own height reads the height states as its
        // scale: still a horizontal velocity, not a height.
        let mut m = Measurement::of_states(IDX_V, 2, &Vector3::zeros(), &r);
        for row in 0..2 {
            m.set_jacobian(row, IDX_P + 2, -0.5);
            m.set_jacobian(row, IDX_TERRAIN, 0.5);
        }
        assert_eq!(Channels::of(&m), horizontal_velocity);
        let m = Measurement::of_states(IDX_P, 3, &Vector3::zeros(), &r);
        assert!(Channels::of(&m).horizontal && Channels::of(&m).vertical);
    }

    /// A refused velocity's shift (the position it would have moved, were it exact) is
    /// answered by a velocity accepted on its channel; a refused position's is not.
    #[test]
    fn a_refused_velocity_is_answered_by_an_accepted_one() {
        let h_velocity = Channels {
            horizontal: true,
            vertical: false,
            position: [false, false],
        };
        let h_position = Channels {
            position: [true, false],
            ..h_velocity
        };
        let mut st = IntegrityState::default();
        st.refused(
            h_velocity,
            0,
            Vector3::new(57.0, -3.0, 0.0),
            Vector3::zeros(),
        );
        assert_eq!(st.refused_extent(0), Vector3::new(57.0, 3.0, 0.0));
        st.held(h_velocity, 100_000);
        assert_eq!(st.refused_extent(100_000), Vector3::zeros());
        // Beside a refused position, the velocity's part goes and the position's stays.
        st.refused(
            h_position,
            200_000,
            Vector3::new(2.0, 1.0, 0.0),
            Vector3::zeros(),
        );
        st.refused(
            h_velocity,
            300_000,
            Vector3::new(9.0, 9.0, 0.0),
            Vector3::zeros(),
        );
        assert_eq!(st.refused_extent(300_000), Vector3::new(11.0, 10.0, 0.0));
        st.held(h_velocity, 400_000);
        assert_eq!(st.refused_extent(400_000), Vector3::new(2.0, 1.0, 0.0));
    }

    /// A channel whose every measurement is refused carries the largest shift a
    /// refused one would have made plus the refused velocities integrated over the
    /// time refused (each step at most [`DRIFT_STEP_MAX_US`]); one accepted
    /// measurement of that channel's position ends it (a velocity only the drift),
    /// a long refusal fading rather than gone, and the other channel keeps its own.
    #[test]
    fn refused_measurements_bound_the_estimate_until_one_is_accepted() {
        let (h, v) = (
            Channels {
                horizontal: true,
                vertical: false,
                position: [true, false],
            },
            Channels {
                horizontal: false,
                vertical: true,
                position: [false, true],
            },
        );
        let h_velocity = Channels {
            position: [false, false],
            ..h
        };
        let mut st = IntegrityState::default();
        assert_eq!(st.refused_extent(0), Vector3::zeros());
        let dv = Vector3::new(0.5, -0.2, 9.0);
        st.refused(h, 0, Vector3::new(2.0, -1.0, 7.0), dv);
        st.refused(h, 500_000, Vector3::new(-1.0, 3.0, 0.0), dv);
        // 10 s later: counted as 1 s.
        st.refused(h, 10_500_000, Vector3::zeros(), dv);
        let e = st.refused_extent(0);
        assert!((e.x - (2.0 + 0.5 * 1.5)).abs() < 1e-12, "{e}");
        assert!((e.y - (3.0 + 0.2 * 1.5)).abs() < 1e-12, "{e}");
        assert_eq!(e.z, 0.0, "a horizontal refusal says nothing of the height");
        st.refused(v, 0, Vector3::new(0.0, 0.0, -4.0), Vector3::zeros());
        assert_eq!(st.refused_extent(0).z, 4.0);
        // A velocity accepted: the refused position still stands, its drift does not.
        st.held(h_velocity, 0);
        let e = st.refused_extent(0);
        assert_eq!((e.x, e.y, e.z), (2.0, 3.0, 4.0));
        // A position ends the horizontal refusal, which lasted 10.5 s: what it said
        // fades over RELEASE_TAU_S. The vertical one, a moment long, is settled.
        let t = 10_600_000;
        st.held(h, t);
        let e = st.refused_extent(t);
        assert_eq!((e.x, e.y, e.z), (2.0, 3.0, 4.0));
        st.held(v, t);
        let e = st.refused_extent(t + 60_000_000);
        let fade = (-1.0f64).exp();
        assert!(
            (e.x - 2.0 * fade).abs() < 1e-12 && (e.y - 3.0 * fade).abs() < 1e-12,
            "{e}"
        );
        assert_eq!(e.z, 0.0);
        assert!(st.refused.iter().all(Option::is_none));
    }

    #[test]
    fn the_config_refuses_nonsense() {
        assert!(IntegrityConfig::default().validate().is_ok());
        let bad = IntegrityConfig {
            horizontal_alert_m: 0.0,
            ..IntegrityConfig::default()
        };
        assert!(bad
            .validate()
            .unwrap_err()
            .contains("integrity.horizontal_alert_m"));
        for f in [-0.1, 1.5, f64::NAN] {
            let bad = IntegrityConfig {
                reanchor_fraction: f,
                ..IntegrityConfig::default()
            };
            assert!(bad
                .validate()
                .unwrap_err()
                .contains("integrity.reanchor_fraction"));
        }
    }
}
