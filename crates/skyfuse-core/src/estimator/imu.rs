//! IMU: drives the prediction. Checks (finite, plausible), control (attitude source,
//! gyro bias from the autopilot's rates), fuse (= the EKF/monitor prediction step,
//! done by the core when time advances).

use super::attitude::check_quaternion;
use super::config::EstimatorConfig;
use super::ekf::IDX_BA;
use super::{Core, Ctx, DebugTopic, Event};
use crate::sample::{Attitude, Imu};
use nalgebra::{Matrix3, Vector3};
use std::sync::Arc;

/// Largest plausible specific force, m/s², and rate, rad/s.
const MAX_ACCEL: f64 = 160.0;
const MAX_GYRO: f64 = 35.0;
/// Longest interval between an IMU's samples that still drives the prediction, µs
/// (20 Hz): each sample is held until the next, so a slower one (a log's 2 Hz
/// `vehicle_imu`, a link that drops most of it) would push stale forces through the
/// filter for that long. Its samples are refused, as EKF2 refuses an IMU whose interval
/// is far from its filter period.
pub const MAX_IMU_INTERVAL_US: i64 = 50_000;

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
    /// When the autopilot's rates last taught the gyro bias, µs (none: never).
    pub bias_rates_t: Option<i64>,
    /// Latest bias-corrected body rate, rad/s.
    pub rate: Option<(i64, Vector3<f64>)>,
    /// Each IMU source's last sample time, used or not.
    pub last_seen: Vec<(Arc<str>, i64)>,
    /// The IMU that drives the prediction. One at a time: each IMU has its own biases
    /// (three in one autopilot read 0.2, 0.4 and 0.7 m/s² apart at rest, and one of
    /// them 2 m/s² off in fast flight), and the filter has one set of bias states, so
    /// samples of several taken in turn are a bias that jumps with every sample.
    pub selected: Option<Arc<str>>,
    /// What the prediction misses, learnt from the velocity innovations.
    pub noise: PredictionNoise,
}

/// The prediction's noise, checked against what the velocity measurements say.
///
/// An IMU's datasheet noise is the least of what integrating it gets wrong: the
/// attitude it is turned with (an AHRS off by 1° is 0.17 m/s²), vibration aliased
/// into a logged or bridged stream, clipping, a mounting the autopilot does not
/// know. On real logs the IMU's velocity left the GNSS's by 0.3–1.2 m/s in a second
/// where the noise model allowed 0.03: every fix was then refused as an outlier, and
/// the filter claimed 5 cm/s while it was 2 m/s off. So the innovations of every
/// velocity measurement (yᵢ²/Sᵢ, 1 on average when the model is right) drive a
/// velocity random walk added to the prediction: raised while they are larger than
/// their variances say, lowered back while smaller (covariance matching, in a
/// multiplicative step so that it neither oscillates nor goes negative). Horizontal and
/// vertical apart: vibration and a tilt error show differently in each.
#[derive(Debug, Clone, PartialEq)]
pub struct PredictionNoise {
    /// Mean of yᵢ²/Sᵢ, horizontal and vertical rows, over about [`NOISE_AVERAGE_ROWS`].
    pub ratio: [f64; 2],
    /// The velocity random walk, horizontal and vertical, m²/s³.
    pub q: [f64; 2],
}

/// Rows averaged in the innovation ratio (about 2 s of a 5 Hz GNSS's two axes).
pub const NOISE_AVERAGE_ROWS: f64 = 20.0;
/// One row's ratio counts at most this much (a 5σ outlier): a glitch moves the mean
/// by at most 25/20, a lasting misfit moves it all the way.
const NOISE_RATIO_CAP: f64 = 25.0;
/// Step of ln q per row and per unit of (ratio − 1).
const NOISE_STEP: f64 = 0.05;
/// Bounds of the random walk, m²/s³: from nothing the model misses to 1 m/s/√s, more
/// than any IMU that still helps.
pub const NOISE_Q_MIN: f64 = 1e-6;
pub const NOISE_Q_MAX: f64 = 1.0;

impl Default for PredictionNoise {
    fn default() -> Self {
        Self {
            ratio: [1.0; 2],
            q: [NOISE_Q_MIN; 2],
        }
    }
}

impl PredictionNoise {
    /// One row of a velocity measurement: innovation `y`, variance `s`, on the
    /// vertical axis or not.
    pub fn observe(&mut self, y: f64, s: f64, vertical: bool) {
        if !(y.is_finite() && s.is_finite() && s > 0.0) {
            return;
        }
        let i = usize::from(vertical);
        let r = (y * y / s).min(NOISE_RATIO_CAP);
        self.ratio[i] += (r - self.ratio[i]) / NOISE_AVERAGE_ROWS;
        let step = (NOISE_STEP * (self.ratio[i] - 1.0)).clamp(-0.5, 0.5);
        self.q[i] = (self.q[i] * step.exp()).clamp(NOISE_Q_MIN, NOISE_Q_MAX);
    }

    /// Per axis (east, north, up), m²/s³.
    pub fn per_axis(&self) -> Vector3<f64> {
        Vector3::new(self.q[0], self.q[0], self.q[1])
    }
}

impl ImuState {
    /// The autopilot's rates are teaching the IMU gyro's bias at `t` (the latest
    /// within [`BIAS_RATES_MAX_DT_S`]).
    pub fn bias_learning(&self, t: i64) -> bool {
        self.bias_rates_t
            .is_some_and(|l| t - l <= (BIAS_RATES_MAX_DT_S * 1e6) as i64)
    }

    /// The interval since `source`'s previous sample (none for its first), and `t`
    /// remembered as its latest.
    fn last_of(&self, source: &str) -> Option<i64> {
        self.last_seen
            .iter()
            .find(|(s, _)| s.as_ref() == source)
            .map(|(_, t)| *t)
    }

    fn interval(&mut self, source: &str, t: i64) -> Option<i64> {
        match self
            .last_seen
            .iter_mut()
            .find(|(s, _)| s.as_ref() == source)
        {
            Some((_, last)) => Some(t - std::mem::replace(last, t)),
            None => {
                self.last_seen.push((Arc::from(source), t));
                None
            }
        }
    }
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

/// EKF2's IMU down-sampling: raw samples that come faster than the filter's prediction
/// period are averaged over it (the rates' and specific forces' time-weighted means,
/// i.e. delta angle and delta velocity over their total time) and the filter sees one
/// sample per period. The output predictor still takes every raw sample, so the pose is
/// as fresh. A sample at or slower than the period passes through untouched, so a
/// 200 Hz IMU at a 5 ms period is fused exactly as without this; a 1 kHz IMU costs the
/// filter what a 200 Hz one does and meets the noise model at the rate it was tuned at.
#[derive(Debug, Clone, Default)]
pub struct DownSampler {
    /// Per IMU source (few): what has accumulated since the last sample passed on.
    sources: Vec<(Arc<str>, Accumulated)>,
}

#[derive(Debug, Clone)]
struct Accumulated {
    /// The last sample passed on: this accumulation covers (start_t, last_t].
    start_t: i64,
    last_t: i64,
    /// Raw samples in the sums; 0 when nothing waits.
    n: u32,
    gyro: Vector3<f64>,
    gyro_s: f64,
    accel: Vector3<f64>,
    accel_s: f64,
    /// The newest raw sample: its orientation and covariances go with the means.
    newest: Option<Imu>,
}

impl DownSampler {
    /// Adds the raw `imu` of `source` at host time `t` and appends to `out` what the
    /// filter gets now: nothing, the sample or the period's mean, or also what waited
    /// when a gap or an out-of-order sample ends an accumulation early. `period_us` 0
    /// passes every sample.
    pub fn add(
        &mut self,
        source: &Arc<str>,
        t: i64,
        imu: &Imu,
        period_us: i64,
        out: &mut Vec<(i64, Imu)>,
    ) {
        let Some(i) = self.sources.iter().position(|(s, _)| s == source) else {
            self.sources.push((source.clone(), Accumulated::new(t)));
            out.push((t, imu.clone()));
            return;
        };
        let acc = &mut self.sources[i].1;
        let dt = t - acc.last_t;
        if period_us <= 0 || dt <= 0 || dt > period_us {
            // A gap longer than a period, or out of order: what waits goes on its own
            // and this sample starts afresh.
            out.extend(acc.take());
            *acc = Accumulated::new(t);
            out.push((t, imu.clone()));
            return;
        }
        acc.add(t, dt, imu);
        // On once a whole period has gathered, give or take half a raw interval (so a
        // 200 Hz IMU's jitter never holds a sample back at a 5 ms period).
        if t - acc.start_t >= period_us - dt / 2 {
            out.extend(acc.take());
        }
    }

    /// What waits, of every source: (source, time, sample).
    pub fn take_all(&mut self) -> Vec<(Arc<str>, i64, Imu)> {
        self.sources
            .iter_mut()
            .filter_map(|(s, a)| a.take().map(|(t, imu)| (s.clone(), t, imu)))
            .collect()
    }
}

impl Accumulated {
    fn new(t: i64) -> Self {
        Self {
            start_t: t,
            last_t: t,
            n: 0,
            gyro: Vector3::zeros(),
            gyro_s: 0.0,
            accel: Vector3::zeros(),
            accel_s: 0.0,
            newest: None,
        }
    }

    fn add(&mut self, t: i64, dt_us: i64, imu: &Imu) {
        let dt = dt_us as f64 * 1e-6;
        if let Some(g) = imu.gyro {
            self.gyro += g * dt;
            self.gyro_s += dt;
        }
        if let Some(a) = imu.accel {
            self.accel += a * dt;
            self.accel_s += dt;
        }
        self.n += 1;
        self.last_t = t;
        self.newest = Some(imu.clone());
    }

    /// What waits, as one sample at the newest raw sample's time (a single raw sample as
    /// it came, several as their means), and a fresh accumulation from there. Stamped at
    /// the end of what it averages, it is never older than the samples it follows, so
    /// it never lands behind the filter's horizon.
    fn take(&mut self) -> Option<(i64, Imu)> {
        let t = self.last_t;
        let done = std::mem::replace(self, Accumulated::new(t));
        let newest = done.newest?;
        if done.n == 1 {
            return Some((done.last_t, newest));
        }
        let n = f64::from(done.n);
        let mean = |sum: Vector3<f64>, s: f64| (s > 0.0).then(|| sum / s);
        Some((
            done.last_t,
            Imu {
                gyro: mean(done.gyro, done.gyro_s),
                accel: mean(done.accel, done.accel_s),
                orientation: newest.orientation,
                // The mean of n samples with independent noise.
                gyro_cov: newest.gyro_cov.map(|c| Box::new(*c / n)),
                accel_cov: newest.accel_cov.map(|c| Box::new(*c / n)),
                orientation_cov: newest.orientation_cov,
            },
        ))
    }
}

/// Per-sample specific-force variance: the message's covariance, else the density.
fn accel_var(imu: &Imu, dt: f64, cfg: &EstimatorConfig) -> f64 {
    match imu.accel_cov.as_deref() {
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
    // Control: which IMU drives the prediction. The selected one while it keeps
    // sending (its own continue condition below); another when it has stopped.
    let selected_stale = match core.imu.selected.as_deref() {
        None => true,
        Some(s) if s == source => false,
        Some(s) => core
            .imu
            .last_of(s)
            .is_none_or(|last| t - last > MAX_IMU_INTERVAL_US),
    };
    if selected_stale {
        let from = core.imu.selected.replace(Arc::from(source));
        if from.is_some() {
            core.imu.last = None;
        }
        let from = from.map(|f| f.to_string());
        core.event(
            t,
            Some(source),
            match &from {
                Some(f) => format!("IMU {source} drives the prediction now ({f} stopped)"),
                None => format!("IMU {source} drives the prediction"),
            },
            Event::SourceSwitch(crate::event::SourceSwitch::Imu {
                imu: source.to_string(),
                why: if from.is_some() { "stopped" } else { "first" },
                from,
            }),
        );
    } else if core.imu.selected.as_deref() != Some(source) {
        // A standby IMU: checked and timed, ready to take over.
        core.imu.interval(source, t);
        return;
    }
    // Continue condition: the previous sample close enough to integrate from; else
    // the held sample is dropped too, so nothing stale drives the prediction.
    if core
        .imu
        .interval(source, t)
        .is_some_and(|dt| dt > MAX_IMU_INTERVAL_US)
    {
        core.imu.last = None;
        core.reject(
            t,
            source,
            "IMU samples too far apart to integrate (below 20 Hz)",
            ctx,
        );
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
            .as_deref()
            .copied()
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
    // The accelerometer's bias as the filter knows it (nothing known before it starts).
    let bias = match core.ekf.as_ref() {
        Some(e) => (
            e.accel_bias(),
            e.cov3(IDX_BA).diagonal().max().max(0.0).sqrt(),
        ),
        None => (
            Vector3::zeros(),
            ctx.cfg.init_accel_bias_var.max(0.0).sqrt(),
        ),
    };
    super::ground::imu_sample(&mut core.ground, t, imu.gyro, imu.accel, bias);
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

/// The step the gyro bias takes from the first of the autopilot's rates, s (one
/// 50 Hz sample's), and the longest interval one sample stands for, s.
const BIAS_RATES_FIRST_DT_S: f64 = 0.02;
const BIAS_RATES_MAX_DT_S: f64 = 1.0;

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
                // Its time constant in time, not in samples: a gain per sample made
                // it 100 s at a 10 Hz attitude, and the flow, compensated with the
                // gyro, read the bias times the height as a velocity for minutes (a
                // hover at 3.4 m drifted 5 m with σ 1-2 m, randomised draw 403).
                let dt = core.imu.bias_rates_t.map_or(BIAS_RATES_FIRST_DT_S, |t0| {
                    ((t - t0) as f64 * 1e-6).clamp(0.0, BIAS_RATES_MAX_DT_S)
                });
                let k = (dt / cfg.gyro_bias_tau_s.max(dt)).min(1.0);
                core.imu.gyro_bias += ((g - rates) - core.imu.gyro_bias) * k;
                core.imu.bias_rates_t = Some(t);
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

    fn raw(g: f64, a: f64) -> Imu {
        Imu::from_rates(
            Some(Vector3::new(g, 0.0, 0.0)),
            Some(Vector3::new(0.0, 0.0, a)),
        )
    }

    /// Feeds (t, imu) pairs; returns what the filter got.
    fn feed(d: &mut DownSampler, period_us: i64, samples: &[(i64, Imu)]) -> Vec<(i64, Imu)> {
        let src: Arc<str> = "imu".into();
        let mut out = Vec::new();
        for (t, imu) in samples {
            d.add(&src, *t, imu, period_us, &mut out);
        }
        out
    }

    #[test]
    fn a_200_hz_imu_passes_untouched_at_a_5_ms_period() {
        // Jittered ±0.4 ms around 5 ms: every sample goes on as it came, at its time.
        let samples: Vec<(i64, Imu)> = (0..400)
            .map(|i| {
                (
                    i * 5_000 + [0, 400, -300, 200][i as usize % 4],
                    raw(i as f64, 9.8),
                )
            })
            .collect();
        let out = feed(&mut DownSampler::default(), 5_000, &samples);
        assert_eq!(out, samples);
    }

    #[test]
    fn a_1_khz_imu_becomes_one_mean_per_period() {
        let samples: Vec<(i64, Imu)> = (0..=1000)
            .map(|i| (i * 1_000, raw(i as f64, 9.0 + (i % 5) as f64)))
            .collect();
        let mut d = DownSampler::default();
        let out = feed(&mut d, 5_000, &samples);
        // The first passes on its own, then one per 5 ms.
        assert_eq!(out.len(), 201);
        assert_eq!(out[0], samples[0]);
        for (k, (t, imu)) in out.iter().enumerate().skip(1) {
            assert_eq!(
                *t,
                k as i64 * 5_000,
                "stamped at the last sample it averages"
            );
            // Samples 5k-4 ..= 5k, each over 1 ms: the means of their values.
            let g = (5 * k - 2) as f64;
            assert!((imu.gyro.unwrap().x - g).abs() < 1e-9, "{imu:?}");
            assert!((imu.accel.unwrap().z - 11.0).abs() < 1e-9, "{imu:?}");
        }
        assert!(
            d.take_all().is_empty(),
            "nothing left over at a period's end"
        );
    }

    #[test]
    fn a_gap_or_a_sample_out_of_order_ends_the_accumulation() {
        let mut d = DownSampler::default();
        let out = feed(
            &mut d,
            5_000,
            &[
                (0, raw(0.0, 9.8)),
                (1_000, raw(1.0, 9.8)),
                (2_000, raw(3.0, 9.8)),
                // 20 ms later: what waited (two samples) goes, then this one as it is.
                (22_000, raw(7.0, 9.8)),
                (23_000, raw(8.0, 9.8)),
                // Back in time: the one waiting goes, then this.
                (22_500, raw(9.0, 9.8)),
            ],
        );
        let times: Vec<i64> = out.iter().map(|(t, _)| *t).collect();
        assert_eq!(times, [0, 2_000, 22_000, 23_000, 22_500]);
        assert!((out[1].1.gyro.unwrap().x - 2.0).abs() < 1e-12);
        assert_eq!(out[2].1, raw(7.0, 9.8));
        assert_eq!(out[3].1, raw(8.0, 9.8), "a single sample goes as it came");
        assert_eq!(out[4].1, raw(9.0, 9.8));
    }

    #[test]
    fn a_zero_period_passes_every_sample_and_flush_takes_what_waits() {
        let samples: Vec<(i64, Imu)> = (0..50).map(|i| (i * 1_000, raw(1.0, 9.8))).collect();
        assert_eq!(feed(&mut DownSampler::default(), 0, &samples), samples);
        let mut d = DownSampler::default();
        let out = feed(&mut d, 5_000, &samples[..3]);
        assert_eq!(out.len(), 1);
        let left = d.take_all();
        assert_eq!(left.len(), 1);
        assert_eq!(left[0].1, 2_000);
        assert!(d.take_all().is_empty());
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
