//! Sensor models over the ground truth: noise, biases, drift, delays and the quirks of
//! each real sensor (T265 odometry in its own frame, flow that sees rotation, GPS with
//! no fix indoors). Deterministic for a given seed.

use super::faults::{Fault, FaultKind, DRIFT_MPS};
use super::truth::{truth_of, Profile, TruthState};
use crate::geo::LocalEnu;
use crate::sample::*;
use nalgebra::{Matrix3, Matrix6, UnitQuaternion, Vector2, Vector3};
use rand::rngs::SmallRng;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

/// Where the simulated flight takes place (PX4 SITL's default home, Zürich).
pub const HOME_LAT: f64 = 47.397_742;
pub const HOME_LON: f64 = 8.545_594;
pub const HOME_ALT: f64 = 488.0;

/// One simulated stream: which config input it feeds, how often, how late.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StreamSpec {
    /// The config input id it is published for (default config names).
    pub input_id: &'static str,
    pub kind: SensorKind,
    pub rate_hz: f64,
    /// Transport + processing latency between measurement and publication, s.
    pub delay_s: f64,
}

/// The demo's streams, matching `config/default.toml`'s enabled inputs.
pub const DEMO_STREAMS: &[StreamSpec] = &[
    StreamSpec {
        input_id: "imu",
        kind: SensorKind::Imu,
        rate_hz: 200.0,
        delay_s: 0.002,
    },
    StreamSpec {
        input_id: "attitude",
        kind: SensorKind::Attitude,
        rate_hz: 50.0,
        delay_s: 0.005,
    },
    StreamSpec {
        input_id: "t265",
        kind: SensorKind::Odometry,
        rate_hz: 200.0,
        delay_s: 0.006,
    },
    StreamSpec {
        input_id: "flow",
        kind: SensorKind::Flow,
        rate_hz: 50.0,
        delay_s: 0.01,
    },
    StreamSpec {
        input_id: "rangefinder",
        kind: SensorKind::Range,
        rate_hz: 25.0,
        delay_s: 0.01,
    },
    StreamSpec {
        input_id: "gps",
        kind: SensorKind::Gnss,
        rate_hz: 10.0,
        delay_s: 0.1,
    },
];

/// The streams of `base` with the IMU at `imu_hz`.
pub fn with_imu_rate(base: &[StreamSpec], imu_hz: f64) -> Vec<StreamSpec> {
    base.iter()
        .map(|s| match s.kind {
            SensorKind::Imu => StreamSpec {
                rate_hz: imu_hz,
                ..*s
            },
            _ => *s,
        })
        .collect()
}

// Noise and error magnitudes, typical of a hobby-grade IMU, a T265, a PMW3901-class
// flow sensor with a VL53-class ToF, a u-blox M8 and a TFmini-class range finder.
const GYRO_NOISE: f64 = 0.003;
const ACCEL_NOISE: f64 = 0.04;
const ORIENTATION_NOISE: f64 = 0.004;
const T265_POS_NOISE: f64 = 0.003;
/// T265 drift random walk, m/√s.
const T265_DRIFT_RW: f64 = 0.004;
const T265_POSE_VAR: f64 = 1e-4;
const FLOW_RATE_NOISE: f64 = 0.02;
const TOF_NOISE: f64 = 0.01;
const TOF_MAX: f64 = 8.0;
const RANGE_NOISE: f64 = 0.02;
const RANGE_MIN: f64 = 0.2;
const RANGE_MAX: f64 = 12.0;
const BARO_NOISE: f64 = 0.1;
/// Barometer slow error random walk, m/√s.
const BARO_DRIFT_RW: f64 = 0.01;
/// The accuracy a u-blox M8 reports standing in the open (hAcc, vAcc as 1σ), m.
const GPS_H_STD: f64 = 0.77;
const GPS_V_STD: f64 = 1.34;
/// How much of it is the slow error (multipath, atmosphere, orbits: a Gauss–Markov
/// wander), the rest white noise: what it reports is what it does.
const GPS_SLOW_FRACTION: f64 = 0.85;
/// Correlation time of the slow error, s.
const GPS_BIAS_TAU_S: f64 = 120.0;

/// What the simulated vehicle carries where scenarios differ, and how its sensors err
/// beyond their white noise: the range finder's limits, whether the flow module has
/// its own ToF, the flow's scale error and mounting, the IMU's biases, the autopilot's
/// heading error, the barometer's and the GNSS's slow errors. The default is the demo
/// vehicle (a TFmini-class range finder to 12 m, a flow module with a ToF, small
/// biases, no heading error); the Monte Carlo runs draw the rest.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hardware {
    pub range_min_m: f64,
    pub range_max_m: f64,
    /// Out of range, a sonar still hears an echo now and then: this fraction of its
    /// readings beyond its maximum are a spurious distance inside its limits, flagged
    /// good (what makes a terrain estimate wander on a real PX4Flow sonar).
    pub range_spurious: f64,
    /// The flow module measures its own height (a ToF) alongside the flow.
    pub flow_tof: bool,
    /// The flow's translational rate is this times the truth (lens focal length or
    /// calibration error: 1.05 reads 5 % fast).
    pub flow_scale: f64,
    /// The flow's integration interval, s (1 / its rate for an integrating sensor).
    pub flow_integration_s: f64,
    /// The flow sensor is mounted turned by this about the body's vertical, rad: its
    /// axes (rates and gyro alike) are the body's turned by it.
    pub flow_mount_yaw_rad: f64,
    /// The flow's rate noise 1σ, rad/s.
    pub flow_rate_noise: f64,
    /// Accelerometer and gyro biases (body FLU); `None`: the small ones drawn from the
    /// seed (a calibrated hobby-grade IMU).
    pub accel_bias: Option<Vector3<f64>>,
    pub gyro_bias: Option<Vector3<f64>>,
    /// The autopilot's heading error (a magnetometer near steel or currents): every
    /// attitude it reports, the IMU message's included, is turned about the vertical
    /// by `bias + amplitude · sin(2πt / period + phase)`, rad.
    pub yaw_error: YawError,
    /// The barometer's slow error: random walk, m/√s; a step while airborne (the
    /// propellers' wash on the static port), m; and an error growing with the
    /// horizontal speed squared (dynamic pressure), m per (m/s)².
    pub baro_drift_rw: f64,
    pub baro_wash_m: f64,
    pub baro_speed_coef: f64,
    /// A visual odometry's drift random walk, m/√s.
    pub vio_drift_rw: f64,
    /// The accuracy the GNSS receiver reports, horizontal and vertical 1σ, m, and what
    /// its error really is: that much, a `GPS_SLOW_FRACTION` of it wandering with this
    /// correlation time, s.
    pub gnss_std_m: (f64, f64),
    pub gnss_bias_tau_s: f64,
    /// GNSS multipath: an offset that ramps in and out over a few seconds, not
    /// reported in the accuracy.
    pub gnss_multipath: [Multipath; 3],
    /// Stretches over dark or featureless ground: the flow's quality drops and it reads
    /// slow and noisy.
    pub dark_ground: [DarkGround; 3],
}

/// A heading error that wanders slowly (see [`Hardware::yaw_error`]).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct YawError {
    pub bias_rad: f64,
    pub amplitude_rad: f64,
    pub period_s: f64,
    pub phase_rad: f64,
}

impl YawError {
    pub fn at(&self, t: f64) -> f64 {
        let wave = if self.period_s > 0.0 {
            (2.0 * std::f64::consts::PI * t / self.period_s + self.phase_rad).sin()
        } else {
            0.0
        };
        self.bias_rad + self.amplitude_rad * wave
    }
}

/// One GNSS multipath episode: `offset` (ENU, m) over `[start_s, start_s + duration_s)`,
/// ramping in and out over [`MULTIPATH_RAMP_S`]. A zero duration is none.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Multipath {
    pub start_s: f64,
    pub duration_s: f64,
    pub offset: [f64; 3],
}

/// How long a multipath offset takes to come and go, s.
pub const MULTIPATH_RAMP_S: f64 = 2.0;

impl Multipath {
    fn at(&self, t: f64) -> Vector3<f64> {
        if self.duration_s <= 0.0 {
            return Vector3::zeros();
        }
        let x = ((t - self.start_s) / MULTIPATH_RAMP_S)
            .min((self.start_s + self.duration_s - t) / MULTIPATH_RAMP_S)
            .clamp(0.0, 1.0);
        Vector3::from(self.offset) * x
    }
}

/// Dark or featureless ground over `[start_s, start_s + duration_s)`: the flow's
/// quality is drawn in `quality` (its sensor still calls much of it good), it reads
/// `scale` times the truth, and its noise is `noise_factor` times the usual. A zero
/// duration is none.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DarkGround {
    pub start_s: f64,
    pub duration_s: f64,
    pub quality: (u8, u8),
    pub scale: f64,
    pub noise_factor: f64,
}

impl DarkGround {
    fn active(&self, t: f64) -> bool {
        self.duration_s > 0.0 && (self.start_s..self.start_s + self.duration_s).contains(&t)
    }
}

impl Default for Hardware {
    fn default() -> Self {
        Self {
            range_min_m: RANGE_MIN,
            range_max_m: RANGE_MAX,
            range_spurious: 0.0,
            flow_tof: true,
            // No flow sensor reads its scale exactly: this one is 3 % fast.
            flow_scale: DEFAULT_FLOW_SCALE,
            flow_integration_s: 0.02,
            flow_mount_yaw_rad: 0.0,
            flow_rate_noise: FLOW_RATE_NOISE,
            accel_bias: None,
            gyro_bias: None,
            yaw_error: YawError::default(),
            baro_drift_rw: BARO_DRIFT_RW,
            baro_wash_m: 0.0,
            baro_speed_coef: 0.0,
            vio_drift_rw: T265_DRIFT_RW,
            gnss_std_m: (GPS_H_STD, GPS_V_STD),
            gnss_bias_tau_s: GPS_BIAS_TAU_S,
            gnss_multipath: [Multipath::default(); 3],
            dark_ground: [DarkGround::default(); 3],
        }
    }
}

/// The demo vehicle's flow reads this times the truth (a lens a little off its nominal
/// focal length, as every real one is).
const DEFAULT_FLOW_SCALE: f64 = 1.03;

/// How fast a visual odometry that lost tracking wanders off, m/s.
const LOST_TRACKING_MPS: f64 = 0.05;

/// Stateful sensor models for one simulated vehicle.
pub struct SensorModels {
    rng: SmallRng,
    pub origin: LocalEnu,
    gyro_bias: Vector3<f64>,
    accel_bias: Vector3<f64>,
    t265_drift: Vector3<f64>,
    t265_last_t: Option<f64>,
    /// The T265 odometry frame is where the camera booted: the start pose.
    t265_origin: (Vector3<f64>, UnitQuaternion<f64>),
    gps_bias: Vector3<f64>,
    gps_last_t: Option<f64>,
    last_fix: (f64, f64, f64),
    profile: Profile,
    pub hardware: Hardware,
    /// The barometer's slow error (weather, temperature), m, and when it was last read.
    baro_bias: f64,
    baro_last_t: Option<f64>,
}

fn n(rng: &mut SmallRng, sigma: f64) -> f64 {
    Normal::new(0.0, sigma)
        .map(|d| d.sample(rng))
        .unwrap_or(0.0)
}

/// Where a visual odometry's frame is when it (re)starts at `s`: at the body, turned by
/// its heading alone. A T265, VINS or OpenVINS levels its frame with gravity from its
/// own IMU; only the heading is arbitrary. (Taking the whole attitude tilted a frame
/// restarted mid-flight by the vehicle's 5-15° of bank, so every metre flown read as
/// centimetres of climb: no real odometry does that.)
fn odometry_frame_at(s: &TruthState) -> (Vector3<f64>, UnitQuaternion<f64>) {
    let yaw = crate::estimator::attitude::yaw_of(&s.attitude);
    (
        s.position,
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
    )
}

fn n3(rng: &mut SmallRng, sigma: f64) -> Vector3<f64> {
    Vector3::new(n(rng, sigma), n(rng, sigma), n(rng, sigma))
}

impl SensorModels {
    pub fn new(seed: u64) -> Self {
        Self::with_profile(seed, Profile::Demo)
    }

    pub fn with_profile(seed: u64, profile: Profile) -> Self {
        let mut rng = SmallRng::seed_from_u64(seed);
        let gyro_bias = n3(&mut rng, 0.003);
        let accel_bias = n3(&mut rng, 0.05);
        let start = truth_of(profile, 0.0);
        Self {
            rng,
            origin: LocalEnu::new(HOME_LAT, HOME_LON, HOME_ALT),
            gyro_bias,
            accel_bias,
            t265_drift: Vector3::zeros(),
            t265_last_t: None,
            t265_origin: odometry_frame_at(&start),
            gps_bias: Vector3::zeros(),
            gps_last_t: None,
            last_fix: (HOME_LAT, HOME_LON, HOME_ALT),
            profile,
            hardware: Hardware::default(),
            baro_bias: 0.0,
            baro_last_t: None,
        }
    }

    /// See [`super::Simulator::set_home`].
    pub fn set_home(&mut self, lat_deg: f64, lon_deg: f64, alt_m: f64) {
        self.origin = LocalEnu::new(lat_deg, lon_deg, alt_m);
        self.last_fix = (lat_deg, lon_deg, alt_m);
    }

    pub fn measure(&mut self, kind: SensorKind, s: &TruthState) -> SensorData {
        self.measure_with(kind, s, &[])
    }

    /// Measure with the lasting effects of faults that have started (`drift`, `reset`).
    pub fn measure_with(
        &mut self,
        kind: SensorKind,
        s: &TruthState,
        started: &[Fault],
    ) -> SensorData {
        match kind {
            SensorKind::Imu => SensorData::Imu(self.imu(s)),
            SensorKind::Attitude => SensorData::Attitude(self.attitude(s)),
            SensorKind::Odometry => SensorData::Odometry(Box::new(self.t265_with(s, started))),
            SensorKind::Flow => SensorData::Flow(self.flow(s)),
            SensorKind::Range => SensorData::Range(self.range(s)),
            SensorKind::Gnss => SensorData::Gnss(self.gps(s)),
            SensorKind::Baro => SensorData::Baro(self.baro(s)),
            // The autopilot's land detector: on the ground below 5 cm.
            SensorKind::VehicleState => SensorData::VehicleState(VehicleState {
                armed: None,
                landed: Some(if s.position.z < 0.05 {
                    LandedState::OnGround
                } else {
                    LandedState::InAir
                }),
            }),
            SensorKind::AutopilotEstimate => SensorData::AutopilotEstimate(AutopilotEstimate {
                local_position: Some(s.position),
                geodetic: None,
                velocity: Some(s.velocity),
                yaw: Some(s.attitude.euler_angles().2),
            }),
        }
    }

    /// Uniform in [0, 1).
    fn uniform(&mut self) -> f64 {
        rand::Rng::gen::<f64>(&mut self.rng)
    }

    fn noisy_attitude(&mut self, q: UnitQuaternion<f64>) -> UnitQuaternion<f64> {
        q * UnitQuaternion::from_scaled_axis(n3(&mut self.rng, ORIENTATION_NOISE))
    }

    /// The attitude the autopilot reports: the truth turned by its heading error, with
    /// noise.
    fn reported_attitude(&mut self, s: &TruthState) -> UnitQuaternion<f64> {
        let yaw_error = self.hardware.yaw_error.at(s.t);
        let q = if yaw_error == 0.0 {
            s.attitude
        } else {
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_error) * s.attitude
        };
        self.noisy_attitude(q)
    }

    pub fn imu(&mut self, s: &TruthState) -> Imu {
        let gyro_bias = self.hardware.gyro_bias.unwrap_or(self.gyro_bias);
        let accel_bias = self.hardware.accel_bias.unwrap_or(self.accel_bias);
        let gyro = s.body_rate + gyro_bias + n3(&mut self.rng, GYRO_NOISE);
        let accel = s.specific_force() + accel_bias + n3(&mut self.rng, ACCEL_NOISE);
        Imu {
            gyro: Some(gyro),
            accel: Some(accel),
            orientation: Some(self.reported_attitude(s)),
            gyro_cov: Some(Box::new(Matrix3::identity() * GYRO_NOISE * GYRO_NOISE)),
            accel_cov: Some(Box::new(Matrix3::identity() * ACCEL_NOISE * ACCEL_NOISE)),
            orientation_cov: Some(Box::new(
                Matrix3::identity() * ORIENTATION_NOISE * ORIENTATION_NOISE,
            )),
        }
    }

    pub fn attitude(&mut self, s: &TruthState) -> Attitude {
        Attitude {
            orientation: self.reported_attitude(s),
            rates: Some(s.body_rate + n3(&mut self.rng, GYRO_NOISE)),
        }
    }

    pub fn t265(&mut self, s: &TruthState) -> Odometry {
        self.t265_with(s, &[])
    }

    fn t265_with(&mut self, s: &TruthState, started: &[Fault]) -> Odometry {
        if let Some(last) = self.t265_last_t {
            let dt = (s.t - last).max(0.0);
            self.t265_drift += n3(&mut self.rng, self.hardware.vio_drift_rw * dt.sqrt());
        }
        self.t265_last_t = Some(s.t);
        let (mut p0, mut q0) = self.t265_origin;
        let mut fault_drift = Vector3::zeros();
        let mut resets = 0u8;
        for f in started {
            match f.kind {
                FaultKind::Drift => {
                    fault_drift.x += DRIFT_MPS * (s.t.min(f.end_s) - f.start_s).max(0.0);
                }
                FaultKind::Reset => {
                    // Tracking lost and restarted: the odometry frame is where it restarted.
                    (p0, q0) = odometry_frame_at(&truth_of(self.profile, f.start_s));
                    fault_drift = Vector3::zeros();
                    resets = resets.wrapping_add(1);
                }
                // A T265 reporting 0.01 has lost tracking: its position wanders off
                // meanwhile, and what it lost stays lost.
                FaultKind::Covariance => {
                    fault_drift.y += LOST_TRACKING_MPS * (s.t.min(f.end_s) - f.start_s).max(0.0);
                }
                // A camera that stopped (USB reset, crash) restarts its frame where it
                // comes back.
                FaultKind::Stop if s.t >= f.end_s => {
                    (p0, q0) = odometry_frame_at(&truth_of(self.profile, f.end_s));
                    fault_drift = Vector3::zeros();
                    resets = resets.wrapping_add(1);
                }
                _ => {}
            }
        }
        let position = q0.inverse() * (s.position - p0)
            + self.t265_drift
            + fault_drift
            + n3(&mut self.rng, T265_POS_NOISE);
        let mut pose_cov = Matrix6::zeros();
        for i in 0..6 {
            pose_cov[(i, i)] = T265_POSE_VAR;
        }
        Odometry {
            position,
            orientation: self.noisy_attitude(q0.inverse() * s.attitude),
            velocity: Some(s.body_velocity() + n3(&mut self.rng, 0.01)),
            angular_velocity: Some(s.body_rate + n3(&mut self.rng, GYRO_NOISE)),
            pose_cov: Some(pose_cov),
            twist_cov: Some(pose_cov),
            frame_id: "camera_odom_frame".into(),
            child_frame_id: "camera_pose_frame".into(),
            reset_counter: (resets > 0).then_some(resets),
            quality: None,
        }
    }

    /// Distance from the sensor to the ground along the body's down axis.
    fn slant_range(s: &TruthState) -> f64 {
        let cos_tilt = (s.attitude * Vector3::z()).z.max(0.2);
        s.position.z.max(0.0) / cos_tilt
    }

    pub fn flow(&mut self, s: &TruthState) -> OpticalFlow {
        // A downward camera at slant range d sees rotation (the body rate) plus
        // translation v/d; in FLU: rate = ω_xy + (v_y, -v_x)/d.
        let hw = self.hardware;
        let d = Self::slant_range(s).max(0.05);
        let dark = hw.dark_ground.iter().find(|g| g.active(s.t)).copied();
        let scale = hw.flow_scale * dark.map_or(1.0, |g| g.scale);
        let noise = hw.flow_rate_noise * dark.map_or(1.0, |g| g.noise_factor);
        let v = s.body_velocity() * scale;
        let body = Vector2::new(s.body_rate.x + v.y / d, s.body_rate.y - v.x / d);
        // The sensor's axes are the body's turned by its mounting.
        let (sn, cs) = (-hw.flow_mount_yaw_rad).sin_cos();
        let rate = Vector2::new(cs * body.x - sn * body.y, sn * body.x + cs * body.y)
            + Vector2::new(n(&mut self.rng, noise), n(&mut self.rng, noise));
        // On the ground the lens is too close to focus: quality collapses.
        let quality = if s.position.z < 0.08 {
            20
        } else if let Some(g) = dark {
            let (lo, hi) = (
                f64::from(g.quality.0),
                f64::from(g.quality.1.max(g.quality.0)),
            );
            (lo + (hi - lo) * self.uniform()).round() as u8
        } else {
            (200.0 + n(&mut self.rng, 15.0)).clamp(120.0, 255.0) as u8
        };
        let tof = (Self::slant_range(s) + 0.02 + n(&mut self.rng, TOF_NOISE)).clamp(0.0, TOF_MAX);
        let tof = self.hardware.flow_tof.then_some(Tof {
            distance_m: tof,
            strength: Some(200),
            precision: Some(5),
            status: Some(0),
        });
        OpticalFlow {
            rate: Some(rate),
            gyro: None,
            velocity: None,
            integration_s: Some(self.hardware.flow_integration_s),
            quality,
            status: Some(if quality >= 50 { 1 } else { 0 }),
            tof,
        }
    }

    pub fn range(&mut self, s: &TruthState) -> Range {
        let hw = self.hardware;
        let (min, max) = (hw.range_min_m, hw.range_max_m);
        let true_d = Self::slant_range(s) + n(&mut self.rng, RANGE_NOISE);
        let mut quality = 90;
        let d = if true_d < max {
            true_d.max(min)
        } else if hw.range_spurious > 0.0 && self.uniform() < hw.range_spurious {
            // An echo off something (a gust of dust, a tree, the vehicle's own wash).
            min + (max - min) * self.uniform()
        } else {
            quality = 1; // MAVLink DISTANCE_SENSOR: 1 = invalid signal
            max
        };
        // MAVLink carries centimetres, the limits too: quantise as the wire does (the
        // limits unquantised, a reading clamped at a minimum of 0.296 m went out as
        // 0.30 m, above its minimum: not on the ground).
        let cm = |x: f64| (x * 100.0).round() / 100.0;
        Range {
            distance_m: cm(d),
            min_m: Some(cm(min)),
            max_m: Some(cm(max)),
            signal_quality: Some(quality),
            variance: None,
            orientation: Some(25),
        }
    }

    /// A barometer: pressure of the true altitude plus a slow random walk and noise
    /// (a BMP388-class sensor: about 0.1 m of noise).
    pub fn baro(&mut self, s: &TruthState) -> Baro {
        if let Some(last) = self.baro_last_t {
            let dt = (s.t - last).max(0.0);
            self.baro_bias += n(&mut self.rng, self.hardware.baro_drift_rw * dt.sqrt());
        }
        self.baro_last_t = Some(s.t);
        let hw = self.hardware;
        let airborne = s.position.z > 0.3;
        let wash = if airborne { hw.baro_wash_m } else { 0.0 };
        let dynamic = hw.baro_speed_coef * s.velocity.xy().norm_squared();
        let h = HOME_ALT
            + s.position.z
            + self.baro_bias
            + wash
            + dynamic
            + n(&mut self.rng, BARO_NOISE);
        Baro {
            pressure_pa: 101_325.0 * (1.0 - h / 44_330.769).powf(1.0 / 0.190_263),
            temperature_c: Some(25.0),
            variance: None,
        }
    }

    pub fn gps(&mut self, s: &TruthState) -> GnssFix {
        let (h, v) = self.hardware.gnss_std_m;
        let slow = Vector3::new(h, h, v) * GPS_SLOW_FRACTION.sqrt();
        let white = Vector3::new(h, h, v) * (1.0 - GPS_SLOW_FRACTION).sqrt();
        // The slow error: Gauss–Markov, started in its stationary spread.
        let wander = |rng: &mut SmallRng, phi: f64| {
            let k = (1.0 - phi * phi).max(0.0).sqrt();
            Vector3::new(n(rng, slow.x * k), n(rng, slow.y * k), n(rng, slow.z * k))
        };
        match self.gps_last_t {
            Some(last) => {
                let dt = (s.t - last).max(0.0);
                let phi = (-dt / self.hardware.gnss_bias_tau_s.max(1.0)).exp();
                self.gps_bias = self.gps_bias * phi + wander(&mut self.rng, phi);
            }
            None => self.gps_bias = wander(&mut self.rng, 0.0),
        }
        self.gps_last_t = Some(s.t);
        let cov = Matrix3::from_diagonal(&Vector3::new(h * h, h * h, v * v));
        if s.indoor {
            let (lat, lon, alt) = self.last_fix;
            return GnssFix {
                lat_deg: lat,
                lon_deg: lon,
                alt_m: alt,
                fix: GnssFixType::NoFix,
                position_cov: Some(Box::new(cov * 1e4)),
                satellites: Some(2),
                hdop: Some(99.0),
                vdop: Some(99.0),
                velocity: None,
                velocity_up_known: false,
            };
        }
        let noise = Vector3::new(
            n(&mut self.rng, white.x),
            n(&mut self.rng, white.y),
            n(&mut self.rng, white.z),
        );
        let multipath: Vector3<f64> = self.hardware.gnss_multipath.iter().map(|m| m.at(s.t)).sum();
        let (lat, lon, alt) = self
            .origin
            .to_geodetic(s.position + self.gps_bias + multipath + noise);
        self.last_fix = (lat, lon, alt);
        GnssFix {
            lat_deg: lat,
            lon_deg: lon,
            alt_m: alt,
            fix: GnssFixType::Fix3d,
            position_cov: Some(Box::new(cov)),
            satellites: Some(14),
            hdop: Some(0.8),
            vdop: Some(1.2),
            velocity: Some(s.velocity + n3(&mut self.rng, 0.05)),
            velocity_up_known: true,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::truth::truth;
    use super::*;

    #[test]
    fn same_seed_same_measurements() {
        let s = truth(30.0);
        let mut a = SensorModels::new(7);
        let mut b = SensorModels::new(7);
        for k in [
            SensorKind::Imu,
            SensorKind::Gnss,
            SensorKind::Flow,
            SensorKind::Odometry,
        ] {
            assert_eq!(a.measure(k, &s), b.measure(k, &s));
        }
        let mut c = SensorModels::new(8);
        assert_ne!(
            a.measure(SensorKind::Imu, &s),
            c.measure(SensorKind::Imu, &s)
        );
    }

    #[test]
    fn flow_minus_gyro_scaled_by_height_is_the_velocity() {
        let mut m = SensorModels::new(1);
        let mut err = Vector2::zeros();
        let mut count = 0.0;
        for i in 0..200 {
            let s = truth(30.0 + i as f64 * 0.05);
            let f = m.flow(&s);
            let (Some(rate), Some(tof)) = (f.rate, f.tof) else {
                panic!("flow without rate or tof")
            };
            let d = tof.distance_m - 0.02;
            let comp = rate - s.body_rate.xy();
            let v = Vector2::new(-comp.y * d, comp.x * d);
            err += v - s.body_velocity().xy();
            count += 1.0;
        }
        let mean = err / count;
        assert!(mean.norm() < 0.02, "mean velocity error {mean}");
    }

    #[test]
    fn a_camera_restarted_in_a_bank_keeps_its_frame_level() {
        // Find a moment of the demo flight banked by more than 5°.
        let tilt = |s: &TruthState| (s.attitude * Vector3::z()).z.acos().to_degrees();
        let Some(start_s) = (200..1400)
            .map(|k| k as f64 * 0.1)
            .find(|&t| tilt(&truth(t)) > 5.0)
        else {
            panic!("the demo flight never banks by 5°");
        };
        let fault = Fault {
            sensor: "t265".into(),
            kind: FaultKind::Reset,
            start_s,
            end_s: start_s + 0.1,
        };
        let mut m = SensorModels::new(5);
        m.hardware.vio_drift_rw = 0.0;
        let (a, b) = (truth(start_s + 1.0), truth(start_s + 6.0));
        let read =
            |m: &mut SensorModels, s: &TruthState| m.t265_with(s, std::slice::from_ref(&fault));
        let (oa, ob) = (read(&mut m, &a), read(&mut m, &b));
        // Level: the odometry's climb is the vehicle's, however far it flew meanwhile.
        let climb = (ob.position.z - oa.position.z) - (b.position.z - a.position.z);
        let flown = (b.position - a.position).xy().norm();
        assert!(flown > 3.0, "flew {flown} m");
        assert!(climb.abs() < 0.03, "climb error {climb} m over {flown} m");
        assert_eq!(ob.reset_counter, Some(1));
    }

    #[test]
    fn a_range_finder_on_its_gear_reads_at_or_below_the_minimum_it_sends() {
        // Centimetres on the wire, the limits too: a minimum of 0.296 m clamps the
        // reading to 0.30 m, which must not read as above a minimum sent as 0.296.
        let mut m = SensorModels::new(2);
        for min in [0.18, 0.296, 0.3049] {
            m.hardware.range_min_m = min;
            let r = m.range(&truth(0.0));
            let sent_min = r.min_m.unwrap_or(f64::NAN);
            assert!(
                r.distance_m <= sent_min,
                "{} > {sent_min} (min {min})",
                r.distance_m
            );
        }
    }

    #[test]
    fn gps_is_near_truth_outdoors_and_no_fix_indoors() {
        let mut m = SensorModels::new(3);
        let s = truth(40.0);
        let g = m.gps(&s);
        let enu = m.origin.to_enu(g.lat_deg, g.lon_deg, g.alt_m);
        assert!((enu - s.position).norm() < 4.0, "{enu} vs {}", s.position);
        assert_eq!(g.fix, GnssFixType::Fix3d);
        assert_eq!(m.gps(&truth(80.0)).fix, GnssFixType::NoFix);
    }
}
