//! Optical flow (seed 001 pipeline, seed 000 calibration).
//!
//! Checks: quality, and good for `flow_quality_hold_ms` since the last reading below it
//! in the air (over poor texture what still passes reads slow), tilt below
//! `range_max_tilt_rad` (tilted further, the camera sees a wall or the horizon, not the
//! ground below: EKF2 gates flow with the range finder's tilt limit too), finite rates
//! within `max_rate`, a height. Preprocessing: per-axis scale factors; rotation
//! compensation with the flow module's own gyro (OPTICAL_FLOW_RAD style) or the IMU
//! gyro low-passed to the flow's phase (3 Hz) and clamped; scaling by the height along
//! the body's down axis (the module's ToF, else the latest range finder sample, else the
//! fused height over the tilt cosine): v_body = (-c_y·d, c_x·d) for compensated rates
//! c = scale·rate − ω (sample.rs convention: rate = ω_xy + (v_y, −v_x)/d).
//! Rotation into the navigation frame by yaw and integration into a displacement
//! (`OF_sum`). Fuse: the body-frame horizontal velocity. The calibrator (ArduPilot
//! AP_OpticalFlow_Calibrator) estimates the per-axis scale from the fused velocity.

use super::attitude::{cos_tilt, yaw_of};
use super::imu::Lpf3;
use super::{BodyVelocity, Core, Ctx, DebugTopic, Event};
use crate::event::CalibrationResult;
use crate::sample::OpticalFlow;
use nalgebra::{Matrix3, UnitQuaternion, Vector2, Vector3};
use serde::Serialize;

/// Oldest IMU gyro reading that still compensates a flow sample without a gyro of its
/// own, µs.
const MAX_GYRO_AGE_US: i64 = 100_000;

#[derive(Debug, Clone, PartialEq)]
pub struct FlowState {
    pub lpf: Lpf3,
    /// Scale factors from calibration, multiplied into the configured ones.
    pub cal_scale: Vector2<f64>,
    pub of_sum: Vector3<f64>,
    pub last_t: Option<i64>,
    /// The rate noise this sensor shows, learnt from its innovations.
    pub noise: RateNoise,
    /// The last sample below `flow_min_quality` in the air (poor texture), µs.
    pub poor_t: Option<i64>,
    /// The scale and heading errors where the current watch window started.
    pub calibration_mark: Option<CalibrationMark>,
}

/// A flow's learnt scale and heading errors (their estimates and variances in the main
/// filter) at a moment: see [`watch_calibration`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CalibrationMark {
    pub t: i64,
    pub x: [f64; 2],
    pub var: [f64; 2],
}

impl Default for FlowState {
    fn default() -> Self {
        Self {
            lpf: Lpf3::default(),
            cal_scale: Vector2::new(1.0, 1.0),
            of_sum: Vector3::zeros(),
            last_t: None,
            noise: RateNoise::default(),
            poor_t: None,
            calibration_mark: None,
        }
    }
}

/// Rows the learnt rate noise averages over (8 s of a 6 Hz flow's two axes).
const RATE_NOISE_ROWS: f64 = 100.0;
/// The learnt variance stays within these fractions of the configured one: at least
/// half its σ, and never above it (more than configured is the prediction noise's and
/// the misfit's to answer). Half, not the sensor's own: what the configured noise also
/// covers is every model error no innovation shows. Down to a fifth, 1 000 randomised
/// flights had 5 497 poses beyond 5σ instead of 1 011 (a compass heading swinging
/// faster than its model, a low-rate flow later than its delay's prior); at a half,
/// 1 091, with the climbs on flow 13 → 27 % valid.
const RATE_NOISE_MIN_FRACTION: f64 = 0.25;
const RATE_NOISE_MAX_FRACTION: f64 = 1.0;
/// Above this height the floor is the same velocity, not the same rate, m. The model
/// errors the floor covers are velocity errors whatever the height (a heading wrong by
/// a swinging compass turns the speed, a delay shows the acceleration, a mounting the
/// speed again), and a rate reads them divided by the height: a floor held in rate
/// grew the velocity noise of a flow at 20 m five times past what those errors need,
/// and on a climb above its range finder the position's σ outgrew the alert limit in
/// minutes while its error stayed metres (randomised climbs on flow with a
/// barometer: 36.6 % valid airborne at the median). Every flight that failed with a
/// lower floor flew below this height.
const RATE_NOISE_FLOOR_HEIGHT_M: f64 = 4.0;
/// The floor never falls below this fraction (a quarter of the configured σ), however
/// high the flow, for a flow sampling at [`RATE_NOISE_FULL_FLOOR_HZ`] or faster: what
/// the innovations say is trusted that far and no further. At a fifth, a climb to 27 m
/// on a 57 Hz flow 228 ms late (randomised draw 927) had 93 % of its valid poses within
/// 3σ north; at a quarter, 100 %.
const RATE_NOISE_LOWEST_FRACTION: f64 = 0.0625;
/// A slower flow's lowest fraction is in proportion to its rate, down to
/// [`RATE_NOISE_SLOW_LOWEST_FRACTION`] at [`RATE_NOISE_SLOW_HZ`] and below. The errors
/// the floor covers (a swinging heading, a delay, a mounting) last seconds: a flow
/// sampling twice as fast does not average them out, and a floor per sample let it
/// learn twice as much of them per second. In proportion to the rate, the floor is
/// one information rate. At one floor per sample, a 6 Hz flow's position σ grew as
/// if it were ten times noisier per second than a 57 Hz one at the same floor:
/// climbs on 5-35 Hz flows above 8 m were invalid on their protection level for most
/// of the flight with the error metres (1 000 randomised flights: climb / flow 66.1 %
/// valid airborne at the median; with this, 81.9 %, the same consistency). Faster
/// flows keep the quarter, whose need was measured: with 0.02 at every rate, draw
/// 801 (a 66 Hz flow) had 1 052 poses beyond 5σ, and 744 and 808 (83 and 46 Hz) fell
/// under 93 % within 3σ.
const RATE_NOISE_SLOW_LOWEST_FRACTION: f64 = 0.02;
const RATE_NOISE_SLOW_HZ: f64 = 15.0;
/// The rate from which a flow keeps [`RATE_NOISE_LOWEST_FRACTION`], Hz (46.9).
const RATE_NOISE_FULL_FLOOR_HZ: f64 =
    RATE_NOISE_SLOW_HZ * RATE_NOISE_LOWEST_FRACTION / RATE_NOISE_SLOW_LOWEST_FRACTION;
/// Sample intervals the flow's rate averages over.
const RATE_NOISE_RATE_SAMPLES: f64 = 20.0;
/// One row counts at most this many configured variances (an outlier).
const RATE_NOISE_ROW_CAP: f64 = 25.0;

/// A flow sensor's rate noise as its innovations show it (covariance matching: the
/// innovation's square, less what the filter's own uncertainty and the other terms of
/// the noise explain, is the rate noise the sample had), as a fraction of the
/// configured variance (`flow_rate_noise`, by quality). The configured noise is
/// EKF2's, for any sensor at any rate; a sensor five times quieter fused as configured
/// grows the position's σ five times too fast on flow alone (randomised climbs on flow:
/// mean NEES 0.06 north, the pose invalid within a minute at 1.4 m off).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RateNoise {
    /// The running mean of the rows' estimates.
    pub mean: f64,
    /// The sensor's sample rate, Hz (a running mean over its intervals); None until
    /// two samples came.
    pub rate_hz: Option<f64>,
}

impl Default for RateNoise {
    fn default() -> Self {
        Self {
            mean: 1.0,
            rate_hz: None,
        }
    }
}

impl RateNoise {
    /// The fraction of the configured variance to fuse with, for a flow `height` m
    /// above the ground.
    pub fn fraction(&self, height: f64) -> f64 {
        let floor = if height > RATE_NOISE_FLOOR_HEIGHT_M {
            (RATE_NOISE_MIN_FRACTION * (RATE_NOISE_FLOOR_HEIGHT_M / height).powi(2))
                .max(self.lowest_fraction())
        } else {
            RATE_NOISE_MIN_FRACTION
        };
        self.mean.clamp(floor, RATE_NOISE_MAX_FRACTION)
    }

    /// The least fraction at any height: in proportion to the sample rate between
    /// the slow flow's and the fast one's (a rate not yet known is taken as fast).
    fn lowest_fraction(&self) -> f64 {
        let hz = self.rate_hz.unwrap_or(RATE_NOISE_FULL_FLOOR_HZ);
        (RATE_NOISE_LOWEST_FRACTION * hz.max(RATE_NOISE_SLOW_HZ) / RATE_NOISE_FULL_FLOOR_HZ)
            .min(RATE_NOISE_LOWEST_FRACTION)
    }

    /// One interval of `dt_s` between two samples.
    pub fn interval(&mut self, dt_s: f64) {
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return;
        }
        let hz = 1.0 / dt_s;
        self.rate_hz = Some(match self.rate_hz {
            Some(r) => r + (hz - r) / RATE_NOISE_RATE_SAMPLES,
            None => hz,
        });
    }

    /// One row: innovation `y`, its variance `s`, the rate noise's part of the
    /// measurement's variance as fused (`fused`) and as configured (`configured`).
    pub fn observe(&mut self, y: f64, s: f64, fused: f64, configured: f64) {
        if !(y.is_finite() && s.is_finite() && fused.is_finite() && configured > 0.0) {
            return;
        }
        let row = ((y * y - s + fused) / configured).min(RATE_NOISE_ROW_CAP);
        self.mean += (row - self.mean) / RATE_NOISE_ROWS;
    }
}

/// A preprocessed flow sample.
#[derive(Debug, Clone, PartialEq)]
pub struct FlowVelocity {
    /// Compensated angular rate (the seed's compensated_OF), rad/s.
    pub compensated: Vector2<f64>,
    /// Horizontal body-frame velocity, m/s.
    pub vel_body: Vector2<f64>,
    /// Per-axis variance of `vel_body`, (m/s)².
    pub var: Vector2<f64>,
    pub height: f64,
    /// The gyro used for compensation (after low-pass and clamp), rad/s.
    pub gyro: Vector2<f64>,
    /// The scaled raw rate, rad/s.
    pub scaled_rate: Vector2<f64>,
}

/// Rotation compensation and height scaling (pure: testable on constructed motion).
pub fn compensate(
    rate: Vector2<f64>,
    scale: Vector2<f64>,
    gyro: Vector2<f64>,
    clamp: f64,
    height: f64,
    rate_noise: f64,
    height_noise: f64,
) -> FlowVelocity {
    let gyro = gyro.map(|w| w.clamp(-clamp, clamp));
    let scaled_rate = rate.component_mul(&scale);
    let c = scaled_rate - gyro;
    let vel_body = Vector2::new(-c.y * height, c.x * height);
    let var = Vector2::new(
        (rate_noise * height).powi(2) + (c.y * height_noise).powi(2),
        (rate_noise * height).powi(2) + (c.x * height_noise).powi(2),
    );
    FlowVelocity {
        compensated: c,
        vel_body,
        var,
        height,
        gyro,
        scaled_rate,
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum CalState {
    #[default]
    Idle,
    Running,
    Success,
    Failed,
}

/// ArduPilot's flow scale calibrator: per axis, samples (flow_rate, body_rate,
/// los_pred); here the model is `scale·flow = body_rate + los_pred` (sample.rs sign
/// convention; ArduPilot's is `flow·scale = los_pred − body_rate`), so the best scalar
/// of one sample is `(body_rate + los_pred) / flow`, averaged weighted by the sample's
/// residual at scale 1.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FlowCalibrator {
    pub state: CalState,
    pub start_t: i64,
    pub source: Option<String>,
    pub samples: [Vec<(f64, f64, f64)>; 2],
    pub result: Option<Vector2<f64>>,
}

impl FlowCalibrator {
    pub fn start(&mut self, t: i64) {
        *self = Self {
            state: CalState::Running,
            start_t: t,
            ..Self::default()
        };
    }

    fn residual(s: &(f64, f64, f64), scalar: f64) -> f64 {
        s.0 * scalar - (s.1 + s.2)
    }

    /// Best scalar for one axis, with the RMS residual before and after.
    pub fn run_axis(samples: &[(f64, f64, f64)]) -> Option<(f64, f64, f64)> {
        if samples.is_empty() {
            return None;
        }
        let total: f64 = samples.iter().map(|s| Self::residual(s, 1.0).abs()).sum();
        if total <= 0.0 {
            return Some((1.0, 0.0, 0.0));
        }
        let mut best = 0.0;
        for s in samples {
            if s.0 == 0.0 {
                return None;
            }
            let b = (s.1 + s.2) / s.0;
            best += b * Self::residual(s, 1.0).abs() / total;
        }
        let rms = |k: f64| {
            (samples
                .iter()
                .map(|s| Self::residual(s, k).powi(2))
                .sum::<f64>()
                / samples.len() as f64)
                .sqrt()
        };
        Some((best, rms(1.0), rms(best)))
    }
}

/// Why a good sample soon after a poor one in the air is not fused.
const RECOVERING: &str =
    "quality good again for less than flow_quality_hold_ms after a reading below flow_min_quality";
/// Below this height a poor quality is the lens too close to focus (on the gear, in
/// the take-off), not the ground's texture, m.
const FLOW_FOCUS_HEIGHT_M: f64 = 0.3;

/// A flow's height for judging its quality: its own ToF, else a range finder, else
/// the filter's height above the terrain; none known is taken as in the air.
fn near_ground(core: &Core, t: i64, f: &OpticalFlow) -> bool {
    if core.ground.on_ground(t) || core.ground.range_says_ground(t) {
        return true;
    }
    let height = f
        .tof
        .as_ref()
        .map(|tof| tof.distance_m)
        .filter(|d| d.is_finite())
        .or_else(|| core.latest_range_at(t).map(|(_, d)| d))
        .or_else(|| core.ekf.as_ref().map(|e| e.height_above_terrain()));
    height.is_some_and(|h| h < FLOW_FOCUS_HEIGHT_M)
}

/// The flow's rate noise at `quality` (EKF2's EKF2_OF_N_MIN at 255 to EKF2_OF_N_MAX at
/// the least usable quality, linearly): a sensor losing its texture reads slow and
/// noisy before it says so.
fn rate_noise_at(quality: u8, cfg: &super::EstimatorConfig) -> f64 {
    let lo = f64::from(cfg.flow_min_quality);
    let x = ((255.0 - f64::from(quality)) / (255.0 - lo).max(1.0)).clamp(0.0, 1.0);
    cfg.flow_rate_noise + (cfg.flow_rate_noise_max - cfg.flow_rate_noise).max(0.0) * x
}

/// A filter started in flight does not know the vertical speed: 1σ, m/s (multirotors
/// climb and sink at up to 2.5-3 m/s).
const IN_FLIGHT_VZ_STD: f64 = 2.0;
/// How fast the vehicle may have moved vertically since a range reading was taken,
/// m/s: a reading's age times this is part of its error as the flow's height.
const HEIGHT_AGE_SPEED: f64 = 1.0;
/// The fused height scales the flow only while its 1σ is below this, m, or this
/// fraction of the height (the flow's noise carries the height's error as well).
const FUSED_HEIGHT_MAX_STD: f64 = 0.5;
const FUSED_HEIGHT_MAX_FRACTION: f64 = 0.2;

/// A flow module's own ToF's limits, m: the source's, else the defaults.
fn tof_limits(sc: &super::config::SourceConfig) -> (f64, f64) {
    (
        sc.min_m.unwrap_or(super::config::DEFAULT_TOF_MIN_M),
        sc.max_m.unwrap_or(super::config::DEFAULT_TOF_MAX_M),
    )
}

/// The height that scales a flow sample.
#[derive(Debug, Clone, Copy, PartialEq)]
struct FlowHeight {
    /// Along the body's down axis, m.
    slant: f64,
    /// Its variance, m².
    var: f64,
    /// The filter's own height above the terrain (vertical, m) when that is what
    /// scaled it: its error is then the filter's states', carried by the fusion's
    /// Jacobian (as EKF2 fuses flow on its terrain state), not white noise.
    estimated: Option<f64>,
}

/// Height along the body's down axis for the flow and its variance: own ToF, else a
/// range finder (its age adding to its error), else the fused height above the terrain
/// over the tilt cosine (with the filter's own uncertainty of it).
/// `(lo, hi)`: the ToF's limits ([`tof_limits`]).
fn flow_height(
    core: &Core,
    ctx: &Ctx,
    t: i64,
    (lo, hi): (f64, f64),
    f: &OpticalFlow,
) -> Option<FlowHeight> {
    let cfg = ctx.cfg;
    let noise = cfg.range_noise * cfg.range_noise;
    let measured = |slant, var| FlowHeight {
        slant,
        var,
        estimated: None,
    };
    if let Some(tof) = &f.tof {
        if tof.distance_m.is_finite() && tof.distance_m > lo && tof.distance_m < hi {
            return Some(measured(tof.distance_m, noise));
        }
    }
    if let Some((tr, d)) = core.latest_range_at(t) {
        let age = (t - tr).abs() as f64 * 1e-6;
        return Some(measured(d, noise + (age * HEIGHT_AGE_SPEED).powi(2)));
    }
    // A range finder at its minimum says the vehicle is on its gear: the fused height
    // (the middle of [0, min]) is no scale for the flow.
    if core.ground.range_says_ground(t) {
        return None;
    }
    let ekf = core.ekf.as_ref()?;
    let ct = cos_tilt(&core.att.q);
    let var = ekf.height_above_terrain_var().max(0.0);
    let h = ekf.height_above_terrain();
    let max_std = FUSED_HEIGHT_MAX_STD.max(FUSED_HEIGHT_MAX_FRACTION * h);
    (var < max_std * max_std && ct > 0.3 && h > 0.0).then(|| FlowHeight {
        slant: h / ct,
        var: var / (ct * ct),
        estimated: Some(h),
    })
}

pub fn process(core: &mut Core, ctx: &Ctx, t: i64, source: &str, f: &OpticalFlow) {
    let cfg = ctx.cfg;
    let sc = cfg.source(source);
    // Rejected before compensation: the sample still ends the flow's integration
    // interval.
    let unusable = if f.quality < cfg.flow_min_quality {
        Some("quality below flow_min_quality")
    } else if core.att.known() && cos_tilt(&core.att.q) < cfg.range_max_tilt_rad.cos() {
        Some("tilt too large for the flow")
    } else {
        None
    };
    // The module's own ToF is a downward range finder: at or below its minimum it says
    // the vehicle is on its gear, as a separate one would. Without that a flow + ToF
    // vehicle was never "on the ground", so its filter started only once the flow saw
    // texture, in the climb, at rest in no state: the state lagged the climb, the
    // heights (themselves late) looked early against it, and the misfit went into the
    // vertical accelerometer bias (randomised draws 102, 220, 583: valid 3-11 %).
    // Only that: a ToF in range does not contradict a separate range finder on its
    // gear (a longer one's minimum is higher), and the evidence goes stale by itself.
    let tof_lim = tof_limits(&sc);
    if let Some(tof) = f.tof.as_ref().filter(|t| t.distance_m.is_finite()) {
        let min = tof_lim.0;
        if tof.distance_m <= min {
            super::ground::range_sample(&mut core.ground, t, tof.distance_m, min, true);
        }
    }
    // Over poor texture (dark ground, water, a featureless floor) the samples its
    // sensor still calls good read slow: the quality is drawn around the threshold,
    // and what passes is the same blind camera. A poor reading in the air holds the
    // sensor out for `flow_quality_hold_ms`, as a range finder's invalid one does
    // (randomised draw 237: 14 s over dark ground, the passing samples read the speed
    // 1-1.9 m/s slow with σ 0.2-0.45 m/s, and the east error grew to 21 m against σ
    // 4.4 m).
    let poor = f.quality < cfg.flow_min_quality && !near_ground(core, t, f);
    let hold = (cfg.flow_quality_hold_ms * 1000.0) as i64;
    let st = core.flow.get_or_insert_with(source, FlowState::default);
    if poor {
        st.poor_t = Some(t);
    }
    let unusable =
        unusable.or_else(|| super::range::in_hold(st.poor_t, t, hold).then_some(RECOVERING));
    if let Some(why) = unusable {
        st.last_t = Some(t);
        core.reject(t, source, why, ctx);
        return;
    }
    let Some(fh) = flow_height(core, ctx, t, tof_lim, f) else {
        core.reject(t, source, "no height for the flow", ctx);
        return;
    };
    let (height, height_var) = (fh.slant, fh.var);
    // Taken out while this sample works on it (every path puts it back), its key kept.
    let mut st = core
        .flow
        .get_mut(source)
        .map(std::mem::take)
        .unwrap_or_default();
    // Discounted by quality only where an IMU carries the velocity between samples:
    // without one the flow is the velocity, and a noisier flow only makes the
    // constant-velocity stand-in lag it (measured on the real PX4 flight: 1.21 m RMSE
    // against the VIO with, 0.92 m without).
    let imu_drives = core.imu_drives(t, ctx);
    // What this sensor's innovations say of its noise, where an IMU's prediction
    // stands between its samples (without one the prediction is the flow's own past,
    // and a quiet innovation says nothing of the sensor), the IMU's gyro compensates
    // it (its bias error is a state; a flow's own gyro's is never learnt, and the
    // configured noise is part of what covers it) and no noise is configured for the
    // source.
    let learns = cfg.flow_rate_noise_learn && imu_drives && sc.noise.is_none() && f.gyro.is_none();
    let configured_noise = sc.noise.unwrap_or_else(|| {
        if imu_drives {
            rate_noise_at(f.quality, cfg)
        } else {
            cfg.flow_rate_noise
        }
    });
    let rate_noise = if learns {
        configured_noise * st.noise.fraction(height).sqrt()
    } else {
        configured_noise
    };
    let fv = if let Some(rate) = f.rate {
        if !rate.iter().all(|v| v.is_finite()) || rate.amax() > sc.max_rate {
            core.flow.put(source, st);
            core.reject(t, source, "flow rate not finite or above max_rate", ctx);
            return;
        }
        let gyro = match f.gyro.filter(|g| g.iter().all(|v| v.is_finite())) {
            Some(g) => g.xy(),
            // The IMU's, low-passed to the flow's phase, if it is current: a gyro that
            // stopped (a dropout, an IMU refused as too slow) compensates nothing.
            None => match st
                .lpf
                .y
                .filter(|_| st.lpf.t.is_some_and(|g| t - g <= MAX_GYRO_AGE_US))
                .or(core
                    .imu
                    .rate
                    .filter(|(g, _)| t - g <= MAX_GYRO_AGE_US)
                    .map(|r| r.1))
            {
                Some(g) => g.xy(),
                None => {
                    core.flow.put(source, st);
                    core.reject(t, source, "no gyro for rotation compensation", ctx);
                    return;
                }
            },
        };
        let scale = Vector2::new(sc.scale_x, sc.scale_y).component_mul(&st.cal_scale);
        let fv = compensate(
            rate,
            scale,
            gyro,
            sc.gyro_clamp,
            height,
            rate_noise,
            height_var.sqrt(),
        );
        core.debug_point(
            t,
            DebugTopic::OfData,
            source,
            Vector3::new(rate.x, rate.y, 0.0),
        );
        fv
    } else if let Some(v) = f.velocity.filter(|v| v.iter().all(|x| x.is_finite())) {
        let s = rate_noise * height;
        FlowVelocity {
            compensated: Vector2::new(v.y / height, -v.x / height),
            vel_body: v,
            var: Vector2::new(s * s, s * s),
            height,
            gyro: Vector2::zeros(),
            scaled_rate: Vector2::zeros(),
        }
    } else {
        core.flow.put(source, st);
        core.reject(t, source, "flow sample without rate or velocity", ctx);
        return;
    };
    let c = fv.compensated;
    core.debug_point(
        t,
        DebugTopic::CompensatedOf,
        source,
        Vector3::new(c.x, c.y, 0.0),
    );
    // The gyro as used by the compensation (low-passed, clamped): seed 001's plot set.
    let g = fv.gyro;
    core.debug_point(t, DebugTopic::FlowGyro, source, Vector3::new(g.x, g.y, 0.0));
    // Navigation frame by yaw, integrated (seed 001: sum_flow += speed · dt).
    let yaw = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_of(&core.att.q));
    let v_nav = yaw * Vector3::new(fv.vel_body.x, fv.vel_body.y, 0.0);
    let dt = match (st.last_t, f.integration_s) {
        (Some(t0), _) if t > t0 && t - t0 < 500_000 => (t - t0) as f64 * 1e-6,
        (_, Some(i)) if i.is_finite() && i > 0.0 && i < 0.5 => i,
        _ => 0.0,
    };
    st.noise.interval(dt);
    st.last_t = Some(t);
    let low = height < cfg.flow_min_height_m;
    if dt > 0.0 && !low {
        let d = v_nav * dt;
        st.of_sum += d;
        core.debug_point(t, DebugTopic::OfSum, source, st.of_sum);
        core.debug_point(t, DebugTopic::OriginDOf, source, d);
        let var = Vector3::new(fv.var.x * dt * dt, fv.var.y * dt * dt, f64::INFINITY);
        core.wrls.add_relative(source, d, var, dt);
    }
    core.flow.put(source, st);
    if low {
        core.reject(t, source, "below flow_min_height_m", ctx);
        return;
    }
    core.monitors
        .flow_velocity(t, v_nav.xy(), core.position(), cfg);
    calibration_sample(core, ctx, t, source, &fv);
    if !core.initialised() {
        if core.att.known() {
            // Started by the flow, so in the air: its height (with the reading's error,
            // and the climb since the reading: up to its delay times a climb rate
            // nobody knows yet) and its horizontal velocity.
            let ct = cos_tilt(&core.att.q);
            let h = height * ct;
            let var = Vector3::new(
                cfg.init_pos_var,
                cfg.init_pos_var,
                cfg.init_pos_var
                    + height_var * ct * ct
                    + (cfg.delay_std_s * IN_FLIGHT_VZ_STD).powi(2),
            );
            let v = Vector3::new(v_nav.x, v_nav.y, 0.0);
            let vv = Vector3::new(
                fv.var.x.max(fv.var.y),
                fv.var.x.max(fv.var.y),
                IN_FLIGHT_VZ_STD * IN_FLIGHT_VZ_STD,
            );
            core.initialise(
                t,
                source,
                Vector3::new(0.0, 0.0, h),
                var,
                Some(v),
                Some(vv),
                ctx,
            );
        }
        return;
    }
    // While calibrating, flow is not fused if anything else holds the velocity: the
    // calibration compares flow with a fused velocity that must not come from flow.
    if core.flow_cal.state == CalState::Running && core.other_aiding(t, source, ctx) {
        return;
    }
    // Scaled by the filter's own height, the velocity's error from that height is a
    // scale the fusion carries in its Jacobian (the flow against the IMU's metric
    // accelerations then tells the height above the terrain): its noise is the rate's
    // alone. As white noise on each sample nothing learnt that height above the range
    // finder: its σ grew with the distance flown until the flow was dropped (at 20 %
    // of the height) and the estimate coasted (randomised climbs on flow: 11 % valid).
    let var = match fh.estimated {
        Some(_) => Vector2::repeat((rate_noise * height).powi(2)),
        None => fv.var,
    };
    let mut r = Matrix3::from_diagonal(&Vector3::new(var.x, var.y, 0.0));
    core.fuse_body_velocity(
        t,
        source,
        Vector3::new(fv.vel_body.x, fv.vel_body.y, 0.0),
        &mut r,
        BodyVelocity::Flow {
            slant: height,
            height_scale: fh.estimated,
            gyro_bias_tau_s: gyro_bias_tau_s(core, t, f, cfg),
        },
        ctx,
    );
    if learns {
        let (fused, configured) = (
            (rate_noise * height).powi(2),
            (configured_noise * height).powi(2),
        );
        learn_rate_noise(core, t, source, fused, configured);
    }
    if imu_drives {
        watch_calibration(core, ctx, t, source);
    }
    // The module's ToF as height when no range finder is being fused.
    if let Some(tof) = &f.tof {
        if (tof.distance_m - height).abs() < 1e-9 && !core.range_recent(t, ctx) {
            let noise = cfg.range_noise;
            super::range::fuse_height(core, ctx, t, source, height, noise * noise);
        }
    }
}

/// How fast the bias error of the IMU gyro that compensates `f` fades, s: while the
/// autopilot's rates or the own attitude filter teach its bias, else never. None where
/// no IMU gyro compensates it: a flow's own gyro (that compensation is the module's, its
/// error part of the rate noise as configured: EKF2's figure covers it, and its noise
/// is not learnt either), or the autopilot's rates without an IMU (bias-corrected by
/// its own filter).
fn gyro_bias_tau_s(
    core: &Core,
    t: i64,
    f: &OpticalFlow,
    cfg: &super::EstimatorConfig,
) -> Option<f64> {
    if f.gyro.is_some() || core.imu.last.is_none() {
        return None;
    }
    let learnt =
        core.imu.bias_learning(t) || core.att.source == super::attitude::AttitudeSource::Own;
    Some(if learnt {
        cfg.gyro_bias_tau_s
    } else {
        f64::INFINITY
    })
}

/// How long a watch window of a flow's calibration lasts, µs.
const CALIBRATION_WATCH_US: i64 = 1_000_000;
/// How far, in σ of what the window's data taught, a learnt calibration may move.
const CALIBRATION_RUNAWAY_SIGMAS: f64 = 5.0;
/// ... and at least this far (scale, fraction; heading, rad) before it counts: below,
/// the move is too small to matter whatever pushed it.
const CALIBRATION_RUNAWAY_MIN: [f64; 2] = [0.03, 0.03];

/// Checks of the flow's calibration against the IMU it is learnt from. The scale and
/// heading errors are constants (a slow random walk) that the filter learns by holding
/// the flow's velocity changes against the IMU's accelerations. A learnt constant's
/// estimate moves over a window by what the data taught it, whose variance is what its
/// own variance lost (plus its walk); one that moves far beyond that is being pushed
/// by a model that no longer holds, and the IMU is the suspect: an accelerometer that
/// stepped is read by a flow as a vehicle slower or faster than it says, and taken up
/// by the scale (randomised hover, draw 220 with a 1 m/s² step: the scale from −2 % to
/// −57 % in 5 s while its σ said 4 %, the estimate 10 m off with σ 1.4 m). The filters
/// then allow for an accelerometer fault over the window and for the scale or heading
/// to be what it moved to or where it was, and learn again.
fn watch_calibration(core: &mut Core, ctx: &Ctx, t: i64, source: &str) {
    let cfg = ctx.cfg;
    let fault = cfg.dead_reckoning_fault_mps2;
    let Some(bank) = core.ekf.as_ref().filter(|_| fault > 0.0) else {
        return;
    };
    let e = bank.main();
    let Some(i) = e.scale_of(source) else {
        return;
    };
    let now = CalibrationMark {
        t,
        x: [e.x[i], e.x[i + 1]],
        var: [e.p[(i, i)], e.p[(i + 1, i + 1)]],
    };
    let Some(st) = core.flow.get_mut(source) else {
        return;
    };
    let Some(mark) = st.calibration_mark.filter(|m| t >= m.t) else {
        st.calibration_mark = Some(now);
        return;
    };
    if t - mark.t < CALIBRATION_WATCH_US {
        return;
    }
    st.calibration_mark = Some(now);
    let w = (t - mark.t) as f64 * 1e-6;
    let walk = [cfg.flow_scale_rw, cfg.flow_heading_rw].map(|rw| rw * rw * w);
    let Some((k, ratio)) = ran_away(&mark, &now, walk) else {
        return;
    };
    let moved = [0, 1].map(|d| now.x[d] - mark.x[d]);
    if let Some(bank) = core.ekf.as_mut() {
        bank.each(|e| {
            if let Some(j) = e.scale_of(source) {
                for (d, m) in moved.iter().enumerate() {
                    e.p[(j + d, j + d)] += m * m;
                }
            }
            e.add_dead_reckoning_fault(&[0, 1], fault, w);
        });
    }
    restart_calibration_watch(core, source);
    let what = ["scale", "heading"][k];
    let (moved_k, sigma) = (moved[k], (mark.var[k].sqrt(), now.var[k].sqrt()));
    core.event(
        t,
        Some(source),
        format!(
            "{source}: its learnt {what} error moved {moved_k:+.3} in {w:.1} s, {ratio:.1} times what the data could teach (σ {:.3} → {:.3}): the IMU it is learnt against is doubted",
            sigma.0, sigma.1
        ),
        Event::CalibrationRanAway {
            state: what,
            moved: moved_k,
            window_s: w,
            test_ratio: ratio,
        },
    );
}

/// Which of the calibration's two states moved beyond what the window's data could
/// teach it (the variance it lost, plus its walk `walk`), and by how many times the
/// allowance: the worst, or None. None too when a variance grew beyond its walk (a
/// reset or a new filter widened it: the move is not the data's).
fn ran_away(mark: &CalibrationMark, now: &CalibrationMark, walk: [f64; 2]) -> Option<(usize, f64)> {
    let mut worst: Option<(usize, f64)> = None;
    for k in 0..2 {
        if now.var[k] > mark.var[k] + 2.0 * walk[k] {
            return None;
        }
        let taught = (mark.var[k] - now.var[k]).max(0.0) + walk[k];
        let allowed = (CALIBRATION_RUNAWAY_SIGMAS * taught.sqrt()).max(CALIBRATION_RUNAWAY_MIN[k]);
        let ratio = (now.x[k] - mark.x[k]).abs() / allowed;
        if ratio > 1.0 && worst.is_none_or(|(_, r)| ratio > r) {
            worst = Some((k, ratio));
        }
    }
    worst
}

/// The next flow sample starts a new watch window.
fn restart_calibration_watch(core: &mut Core, source: &str) {
    if let Some(st) = core.flow.get_mut(source) {
        st.calibration_mark = None;
    }
}

/// The flow sample of `t` was tested with rate-noise variance `fused` (`configured`
/// before learning): its innovation rows teach [`RateNoise`], refused ones too (each
/// capped): a sensor that turns noisier is refused at the gate first, and a learner
/// deaf to refusals would keep it refused for good.
fn learn_rate_noise(core: &mut Core, t: i64, source: &str, fused: f64, configured: f64) {
    let Some(st) = core
        .stats
        .get(source)
        .filter(|st| st.last_time_us == Some(t))
    else {
        return;
    };
    let Some(fs) = core.flow.get_mut(source) else {
        return;
    };
    for (y, s) in st.innovation.iter().zip(&st.innovation_var) {
        fs.noise.observe(*y, *s, fused, configured);
    }
}

fn calibration_sample(core: &mut Core, ctx: &Ctx, t: i64, source: &str, fv: &FlowVelocity) {
    let cfg = ctx.cfg;
    if core.flow_cal.state != CalState::Running {
        return;
    }
    if core.flow_cal.source.as_deref().is_some_and(|s| s != source) {
        return;
    }
    core.flow_cal.source = Some(source.to_string());
    if (t - core.flow_cal.start_t) as f64 * 1e-6 > cfg.flow_cal_timeout_s {
        core.flow_cal.state = CalState::Failed;
        core.event(
            t,
            Some(source),
            "flow calibration timed out".into(),
            Event::CalibrationResult(CalibrationResult::TimedOut {
                success: false,
                reason: "timeout",
            }),
        );
        return;
    }
    let Some(v) = core.velocity() else { return };
    if !core.other_aiding(t, source, ctx) {
        return;
    }
    let vb = core.att.q.inverse() * v;
    let los = Vector2::new(vb.y / fv.height, -vb.x / fv.height);
    for axis in 0..2 {
        let flow = fv.scaled_rate[axis];
        if flow.abs() >= cfg.flow_cal_min_rate
            && core.flow_cal.samples[axis].len() < cfg.flow_cal_samples
        {
            core.flow_cal.samples[axis].push((flow, fv.gyro[axis], los[axis]));
        }
    }
    if core
        .flow_cal
        .samples
        .iter()
        .all(|s| s.len() >= cfg.flow_cal_samples)
    {
        let rx = FlowCalibrator::run_axis(&core.flow_cal.samples[0]);
        let ry = FlowCalibrator::run_axis(&core.flow_cal.samples[1]);
        let ok = |r: &Option<(f64, f64, f64)>| {
            r.is_some_and(|(s, before, after)| {
                after <= before && s >= cfg.flow_cal_scale_min && s <= cfg.flow_cal_scale_max
            })
        };
        let success = ok(&rx) && ok(&ry);
        let (sx, bx, ax) = rx.unwrap_or((f64::NAN, f64::NAN, f64::NAN));
        let (sy, by, ay) = ry.unwrap_or((f64::NAN, f64::NAN, f64::NAN));
        let what = Event::CalibrationResult(CalibrationResult::Done {
            success,
            scale_x: sx,
            scale_y: sy,
            rms_before: [bx, by],
            rms_after: [ax, ay],
        });
        if success {
            core.flow_cal.state = CalState::Success;
            core.flow_cal.result = Some(Vector2::new(sx, sy));
            if let Some(st) = core.flow.get_mut(source) {
                st.cal_scale = st.cal_scale.component_mul(&Vector2::new(sx, sy));
            }
        } else {
            core.flow_cal.state = CalState::Failed;
        }
        core.event(
            t,
            Some(source),
            format!(
                "flow calibration {}: scale x {sx:.3}, y {sy:.3}",
                if success { "succeeded" } else { "failed" }
            ),
            what,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotation_only_motion_gives_zero_velocity() {
        // Hovering while rocking: the flow sees only the body rate (sample.rs / sim).
        for w in [
            Vector2::new(0.3, -0.2),
            Vector2::new(-1.0, 0.5),
            Vector2::zeros(),
        ] {
            let fv = compensate(w, Vector2::new(1.0, 1.0), w, 4.0, 2.0, 0.03, 0.03);
            assert!(fv.vel_body.norm() < 1e-12, "{}", fv.vel_body);
        }
        // Translation: v = (0.5, -0.2) at d = 2 → rate = (v_y/d, -v_x/d).
        let rate = Vector2::new(-0.2 / 2.0, -0.5 / 2.0);
        let fv = compensate(
            rate,
            Vector2::new(1.0, 1.0),
            Vector2::zeros(),
            4.0,
            2.0,
            0.03,
            0.0,
        );
        assert!((fv.vel_body - Vector2::new(0.5, -0.2)).norm() < 1e-12);
    }

    #[test]
    fn clamp_limits_the_gyro() {
        let fv = compensate(
            Vector2::zeros(),
            Vector2::new(1.0, 1.0),
            Vector2::new(10.0, -10.0),
            2.0,
            1.0,
            0.03,
            0.0,
        );
        assert_eq!(fv.gyro, Vector2::new(2.0, -2.0));
    }

    /// The rows of a sensor whose rate variance is `true_var` (the configured one 1),
    /// with the filter's own part `hph` of each innovation's variance: the learnt
    /// fraction over the second half of `n` rows, averaged (normal draws from a fixed
    /// LCG, Box-Muller).
    fn learnt_fraction(true_var: f64, hph: f64, n: usize) -> f64 {
        learnt_fraction_at(true_var, hph, n, 1.0)
    }

    /// The same for a flow `height` m above the ground.
    fn learnt_fraction_at(true_var: f64, hph: f64, n: usize, height: f64) -> f64 {
        let mut seed: u64 = 0x9e37_79b9_7f4a_7c15;
        let mut uniform = || {
            seed = seed
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            ((seed >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let mut noise = RateNoise::default();
        let mut sum = 0.0;
        for k in 0..n {
            let g = (-2.0 * uniform().ln()).sqrt() * (std::f64::consts::TAU * uniform()).cos();
            let fused = noise.fraction(height);
            noise.observe(g * (hph + true_var).sqrt(), hph + fused, fused, 1.0);
            if k >= n / 2 {
                sum += noise.fraction(height);
            }
        }
        sum / (n - n / 2) as f64
    }

    #[test]
    fn a_calibration_moving_beyond_what_its_data_taught_has_run_away() {
        let mark = |x: f64, sd: f64| CalibrationMark {
            t: 0,
            x: [x, 0.0],
            var: [sd * sd, 0.01],
        };
        let walk = [1e-6, 1e-6];
        // Learning: σ 0.10 → 0.05 allows moves of 5·0.087; 0.2 is one.
        assert_eq!(ran_away(&mark(0.0, 0.1), &mark(0.2, 0.05), walk), None);
        // Converged (σ 0.038 → 0.036, one 1 s window of draw 220): 0.12 is not.
        let (k, ratio) = ran_away(&mark(-0.02, 0.038), &mark(-0.14, 0.036), walk).unwrap();
        assert_eq!(k, 0);
        assert!(ratio > 1.5 && ratio < 2.5, "{ratio}");
        // A move below the least that counts, however sure the state: none.
        assert_eq!(ran_away(&mark(0.0, 0.01), &mark(0.02, 0.01), walk), None);
        // Widened in the window (a reset): its move is not the data's.
        assert_eq!(ran_away(&mark(0.0, 0.01), &mark(0.5, 0.2), walk), None);
        // The heading the same way.
        let turned = CalibrationMark {
            x: [0.0, 0.2],
            ..mark(0.0, 0.01)
        };
        assert_eq!(
            ran_away(&mark(0.0, 0.01), &turned, walk).map(|r| r.0),
            Some(1)
        );
    }

    #[test]
    fn the_rate_noise_is_learnt_from_the_innovations_within_its_bounds() {
        // A sensor 2.5× quieter in variance than configured is fused as it is.
        let f = learnt_fraction(0.4, 0.05, 5_000);
        assert!((f - 0.4).abs() < 0.03, "{f}");
        // Never below the floor (a sensor that seems perfect), never above the
        // configured noise (a noisier one is the misfit's to answer).
        assert!((learnt_fraction(0.0, 0.05, 5_000) - RATE_NOISE_MIN_FRACTION).abs() < 1e-12);
        assert!((learnt_fraction(3.0, 0.05, 5_000) - RATE_NOISE_MAX_FRACTION).abs() < 1e-12);
        // The filter's own uncertainty is not the sensor's: innovations that are
        // mostly the prediction's leave a quiet sensor quiet.
        let f = learnt_fraction(0.4, 0.5, 20_000);
        assert!((f - 0.4).abs() < 0.05, "{f}");
    }

    /// Above the floor's height the floor holds the velocity, not the rate: a quiet
    /// sensor (a hundredth of the configured variance) at 6 m is fused at (4/6)² of the
    /// floor a low flow keeps (above the lowest, so the height's own scaling shows), at
    /// 30 m at the lowest, and at 2 m as before.
    #[test]
    fn a_high_flow_keeps_the_floor_in_velocity_not_in_rate() {
        let quiet = 0.01;
        let low = learnt_fraction_at(quiet, 0.05, 5_000, 2.0);
        assert!((low - RATE_NOISE_MIN_FRACTION).abs() < 1e-12, "{low}");
        let h = 1.5 * RATE_NOISE_FLOOR_HEIGHT_M;
        let high = learnt_fraction_at(quiet, 0.05, 5_000, h);
        assert!(high > RATE_NOISE_LOWEST_FRACTION, "{high}");
        assert!(
            (high - RATE_NOISE_MIN_FRACTION / 2.25).abs() < 1e-12,
            "{high}"
        );
        // The velocity's floor is the same at both heights.
        let v = |f: f64, h: f64| f.sqrt() * h;
        assert!((v(high, h) - v(RATE_NOISE_MIN_FRACTION, RATE_NOISE_FLOOR_HEIGHT_M)).abs() < 1e-9);
        let top = learnt_fraction_at(quiet, 0.05, 5_000, 30.0);
        assert!((top - RATE_NOISE_LOWEST_FRACTION).abs() < 1e-12, "{top}");
        // A sensor as noisy as configured is fused as configured at any height.
        let noisy = learnt_fraction_at(1.5, 0.05, 5_000, 20.0);
        assert!((noisy - RATE_NOISE_MAX_FRACTION).abs() < 1e-12, "{noisy}");
    }

    /// The lowest floor is an information rate: a quiet sensor at 30 m is fused at the
    /// quarter σ when it samples at 46.9 Hz or faster, at a proportion of it below, and
    /// at the slow flow's fraction from 15 Hz down. Up to that rate, no flow learns more
    /// per second than one at it (rate over variance), and low down the floor is the
    /// same at any rate.
    #[test]
    fn the_lowest_floor_is_in_proportion_to_the_flow_rate() {
        let at = |hz: f64, height: f64| {
            let mut noise = RateNoise {
                mean: 0.0,
                rate_hz: None,
            };
            for _ in 0..200 {
                noise.interval(1.0 / hz);
            }
            noise.fraction(height)
        };
        assert!((at(80.0, 30.0) - RATE_NOISE_LOWEST_FRACTION).abs() < 1e-12);
        assert!((at(6.0, 30.0) - RATE_NOISE_SLOW_LOWEST_FRACTION).abs() < 1e-12);
        assert!((at(15.0, 30.0) - RATE_NOISE_SLOW_LOWEST_FRACTION).abs() < 1e-12);
        let mid = at(30.0, 30.0);
        assert!(
            (mid - 2.0 * RATE_NOISE_SLOW_LOWEST_FRACTION).abs() < 1e-6,
            "{mid}"
        );
        let most = RATE_NOISE_FULL_FLOOR_HZ / RATE_NOISE_LOWEST_FRACTION;
        for hz in [6.0, 15.0, 30.0, RATE_NOISE_FULL_FLOOR_HZ] {
            assert!(hz / at(hz, 30.0) <= most * (1.0 + 1e-9), "{hz} Hz");
        }
        for hz in [6.0, 15.0, 30.0, 80.0] {
            assert!((at(hz, 2.0) - RATE_NOISE_MIN_FRACTION).abs() < 1e-12);
        }
        // Not known yet: the fast flow's floor.
        let unknown = RateNoise {
            mean: 0.0,
            rate_hz: None,
        };
        assert!((unknown.fraction(30.0) - RATE_NOISE_LOWEST_FRACTION).abs() < 1e-12);
    }

    #[test]
    fn calibrator_recovers_a_scale_error() {
        // True model: 0.8·flow = body + los (the sensor reads 25 % high).
        let samples: Vec<(f64, f64, f64)> = (0..50)
            .map(|i| {
                let body = 0.1 * ((i as f64) * 0.7).sin();
                let los = 0.5 * ((i as f64) * 0.3).cos() + 0.2;
                ((body + los) / 0.8, body, los)
            })
            .filter(|s| s.0.abs() > 0.05)
            .collect();
        let (s, before, after) = FlowCalibrator::run_axis(&samples).expect("scalar");
        assert!((s - 0.8).abs() < 1e-9, "{s}");
        assert!(after < before);
    }
}
