//! Estimator configuration: the `[estimator]` table of the service config.
//!
//! Every default is a named constant so `config/default.toml` and the code cannot
//! disagree silently. Unknown keys are rejected (`deny_unknown_fields`).

use crate::sample::SensorKind;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Which fusion runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Mode {
    /// Seed 002's weighted recursive least squares over frame-to-frame displacements.
    #[serde(rename = "wrls")]
    Wrls,
    /// IMU-driven error-state Kalman filter with every aiding source.
    #[serde(rename = "ekf")]
    Ekf,
    /// Seed 002's layout: the WRLS output is the EKF's position measurement.
    #[serde(rename = "wrls+ekf")]
    WrlsEkf,
}

impl Mode {
    pub fn as_str(self) -> &'static str {
        match self {
            Mode::Wrls => "wrls",
            Mode::Ekf => "ekf",
            Mode::WrlsEkf => "wrls+ekf",
        }
    }
}

/// Default fusion mode: the EKF had the lowest position error and a consistent
/// covariance on the simulator (see the module docs of `estimator`).
pub const DEFAULT_MODE: Mode = Mode::Ekf;
/// State/sample history kept for late measurements, ms.
pub const DEFAULT_HISTORY_MS: f64 = 500.0;
/// Innovation gate in standard deviations (converted to a chi² quantile per dimension).
pub const DEFAULT_GATE_SIGMA: f64 = 5.0;
/// Window of the per-source clock-offset minimum, s.
pub const DEFAULT_CLOCK_WINDOW_S: f64 = 10.0;
/// A change of (arrival - stamp) larger than this restarts the clock mapping, s.
pub const DEFAULT_CLOCK_JUMP_S: f64 = 1.0;

pub const DEFAULT_INIT_POS_VAR: f64 = 1e-4;
pub const DEFAULT_INIT_VEL_VAR: f64 = 0.25;
pub const DEFAULT_INIT_ACCEL_BIAS_VAR: f64 = 0.01;
/// Accelerometer white noise density, m/s²/√Hz (used when the sample has no covariance).
pub const DEFAULT_ACCEL_NOISE_DENSITY: f64 = 0.004;
/// Gyro white noise density, rad/s/√Hz (own attitude filter, flow compensation).
pub const DEFAULT_GYRO_NOISE_DENSITY: f64 = 0.0003;
/// Accelerometer bias random walk, m/s²/√s.
pub const DEFAULT_ACCEL_BIAS_RW: f64 = 0.002;
/// Attitude 1σ per axis, rad, when the attitude source gives no covariance.
pub const DEFAULT_ATTITUDE_NOISE_RAD: f64 = 0.01;
/// Acceleration noise of the constant-velocity model used while no IMU arrives, m/s².
pub const DEFAULT_NO_IMU_ACCEL_NOISE: f64 = 3.0;
pub const DEFAULT_IMU_TIMEOUT_MS: f64 = 100.0;
/// The filter's IMU period, ms (EKF2's EKF2_PREDICT_US): faster IMU samples are
/// averaged over it before the filter predicts with them; 200 Hz, the rate the noise
/// model was tuned at.
pub const DEFAULT_PREDICT_PERIOD_MS: f64 = 5.0;
/// Variance of the ground's height below a frame started without a height measurement,
/// m² (σ 10 m: anything a range finder or ToF can then see).
pub const UNKNOWN_TERRAIN_VAR: f64 = 100.0;
/// On the ground with no horizontal aiding: 1σ of the held position, m, and of the
/// zero velocity, m/s (see `estimator::ground`).
pub const DEFAULT_GROUND_POS_NOISE: f64 = 0.3;
pub const DEFAULT_GROUND_VEL_NOISE: f64 = 0.1;
/// Unaided and not at rest: 1σ of the loosely held position, m (PX4 EKF2_NOAID_NOISE).
pub const DEFAULT_FAKE_POS_NOISE: f64 = 10.0;
pub const DEFAULT_ATTITUDE_TIMEOUT_MS: f64 = 500.0;
/// Own attitude filter (PX4 attitude_estimator_q): accelerometer weight ATT_W_ACC.
pub const DEFAULT_ATT_W_ACC: f64 = 0.2;
/// Own attitude filter: external heading weight ATT_W_EXT_HDG.
pub const DEFAULT_ATT_W_EXT_HDG: f64 = 0.1;
/// Own attitude filter: gyro bias integral weight ATT_W_GYRO_BIAS.
pub const DEFAULT_ATT_W_GYRO_BIAS: f64 = 0.1;
/// Own attitude filter: gyro bias limit, rad/s (PX4 ATT_BIAS_MAX).
pub const DEFAULT_ATT_BIAS_MAX: f64 = 0.05;
/// Time constant of the gyro bias estimate from the autopilot's rates, s.
pub const DEFAULT_GYRO_BIAS_TAU_S: f64 = 20.0;

/// No position/velocity source fused for this long → invalid, ms.
pub const DEFAULT_AIDING_TIMEOUT_MS: f64 = 1000.0;
/// Largest horizontal/vertical position 1σ that is still valid, m.
pub const DEFAULT_MAX_POS_STD_M: f64 = 5.0;

pub const DEFAULT_MONITOR_ENABLED: bool = true;
/// Departure of the main filter from the applicable monitor that counts as divergence, m.
pub const DEFAULT_MONITOR_POS_BOUND_M: f64 = 3.0;
/// Velocity departure that counts as divergence, m/s.
pub const DEFAULT_MONITOR_VEL_BOUND_MPS: f64 = 1.5;
/// How long the departure must last before the reset, s.
pub const DEFAULT_MONITOR_TIME_S: f64 = 2.0;
/// The flow monitor's position slowly follows the main filter with this time constant, s.
pub const DEFAULT_MONITOR_TRACK_TAU_S: f64 = 30.0;
/// GPS monitor complementary gains (position, velocity), 1/s.
pub const DEFAULT_MONITOR_GPS_K_POS: f64 = 1.0;
pub const DEFAULT_MONITOR_GPS_K_VEL: f64 = 0.3;
/// Flow monitor velocity gain (flow vs integrated accel), 1/s (seed 001).
pub const DEFAULT_MONITOR_FLOW_K_VEL: f64 = 2.0;
/// Position and velocity variance set after a monitor reset.
pub const DEFAULT_RESET_POS_VAR: f64 = 1.0;
pub const DEFAULT_RESET_VEL_VAR: f64 = 0.25;

/// Default latencies per sensor kind (transport + processing), ms.
pub const DEFAULT_LATENCY_MS_IMU: f64 = 2.0;
pub const DEFAULT_LATENCY_MS_ATTITUDE: f64 = 5.0;
pub const DEFAULT_LATENCY_MS_ODOMETRY: f64 = 6.0;
pub const DEFAULT_LATENCY_MS_FLOW: f64 = 10.0;
pub const DEFAULT_LATENCY_MS_RANGE: f64 = 10.0;
pub const DEFAULT_LATENCY_MS_GNSS: f64 = 100.0;
pub const DEFAULT_LATENCY_MS_BARO: f64 = 10.0;

/// GNSS: user equivalent range error used with HDOP when no covariance is sent, m.
pub const DEFAULT_GNSS_UERE_M: f64 = 2.5;
/// GNSS fixes with a horizontal variance above this are not used, m².
pub const DEFAULT_GNSS_MAX_VAR: f64 = 25.0;
/// GNSS velocity 1σ per axis, m/s (messages carry no velocity accuracy).
pub const DEFAULT_GNSS_VEL_NOISE: f64 = 0.1;
pub const DEFAULT_GNSS_FUSE_VELOCITY: bool = true;
/// GNSS slowly varying error (multipath, atmosphere, orbits): horizontal 1σ, m, modelled
/// as a Gauss–Markov state; this part is taken out of the message's variance. A
/// standalone receiver's error wanders by metres over minutes: with this model GNSS
/// anchors the frame while the relative sensors carry the shape (simulator: APE 0.016 m
/// with GNSS + T265 instead of 0.066 m with 1 m / 30 s; RTK users lower it).
pub const DEFAULT_GNSS_BIAS_STD_M: f64 = 3.0;
/// The same, vertical, m.
pub const DEFAULT_GNSS_BIAS_STD_V_M: f64 = 5.0;
/// Correlation time of that error, s.
pub const DEFAULT_GNSS_BIAS_TAU_S: f64 = 120.0;

/// Visual odometry: drift of the odometry frame against the world, m/√s.
pub const DEFAULT_VO_DRIFT_RW: f64 = 0.005;
/// Position step not explained by the velocity that starts a new segment, m.
pub const DEFAULT_VO_JUMP_M: f64 = 0.3;
/// Position 1σ when the message has no covariance, m.
pub const DEFAULT_VO_POS_NOISE: f64 = 0.01;
/// Velocity 1σ when the message has no covariance, m/s.
pub const DEFAULT_VO_VEL_NOISE: f64 = 0.02;
/// Continuous rejection for this long re-aligns the odometry (new segment), s.
pub const DEFAULT_VO_REJECT_REALIGN_S: f64 = 1.0;
pub const DEFAULT_VO_FUSE_VELOCITY: bool = true;

/// Flow: minimum quality (0..255) for use.
pub const DEFAULT_FLOW_MIN_QUALITY: u8 = 50;
/// Flow angular rate noise 1σ, rad/s (PX4 EKF2_OF_N_MIN; a real flight needed it:
/// 0.03 rejected a real PX4 flow sensor's data half the time).
pub const DEFAULT_FLOW_RATE_NOISE: f64 = 0.15;
/// Flow: largest usable raw rate, rad/s.
pub const DEFAULT_FLOW_MAX_RATE: f64 = 4.0;
/// Gyro low-pass for rotation compensation, Hz (seed 001: LPF_1_(3.0, ...)).
pub const DEFAULT_FLOW_GYRO_LPF_HZ: f64 = 3.0;
/// Gyro clamp for rotation compensation, rad/s (seed 001: LIMIT(gyro, -flow_t, flow_t)).
pub const DEFAULT_FLOW_GYRO_CLAMP: f64 = 4.0;
pub const DEFAULT_FLOW_SCALE: f64 = 1.0;
/// Flow: smallest height at which flow is used, m (lens out of focus below).
pub const DEFAULT_FLOW_MIN_HEIGHT_M: f64 = 0.1;
/// Barometer height noise 1σ, m (pressure noise, gusts on the static port; EKF3's
/// EK3_ALT_M_NSE; EKF2's EKF2_BARO_NOISE is 3.5 m). The real PX4 flight's barometer
/// wanders about a metre in minutes indoors: tighter values break "valid" there.
pub const DEFAULT_BARO_NOISE: f64 = 2.0;
/// Random walk of a barometer's offset, m/√s (weather, temperature, downwash).
pub const DEFAULT_BARO_DRIFT_RW: f64 = 0.1;
/// Flow ToF range limits when the sample gives none, m.
pub const DEFAULT_TOF_MIN_M: f64 = 0.05;
pub const DEFAULT_TOF_MAX_M: f64 = 8.0;
/// Flow ToF / range height noise 1σ, m.
pub const DEFAULT_RANGE_NOISE: f64 = 0.03;
pub const DEFAULT_RANGE_MIN_M: f64 = 0.1;
pub const DEFAULT_RANGE_MAX_M: f64 = 12.0;
/// Range samples are not fused above this tilt, rad.
pub const DEFAULT_RANGE_MAX_TILT_RAD: f64 = 0.7;
/// Terrain height random walk (flat ground: small), m/√s.
pub const DEFAULT_TERRAIN_RW: f64 = 0.005;
/// How much the ground may rise or fall per metre travelled, m/m (PX4 EKF2_TERR_GRAD,
/// smaller: most vehicles on range finders fly over floors and fields): the terrain's
/// uncertainty grows with the speed over it, so a vehicle carried off a table, or
/// flown far on the range finder alone, does not claim to know its height above the
/// take-off point to the centimetre.
pub const DEFAULT_TERRAIN_GRADIENT: f64 = 0.1;
/// After a reading its sensor flags invalid or one beyond its maximum, a range source
/// must read good this long before it is fused again, ms (PX4 EKF2_RNG_QLTY_T): a sonar
/// out of range that hears a stray echo now and then is never a height.
pub const DEFAULT_RANGE_QUALITY_HOLD_MS: f64 = 1000.0;
/// A flow sensor's scale error 1σ before anything calibrated it (lens focal length,
/// height error), as a fraction: 0.05 reads up to about 5 % fast or slow. 0 leaves
/// the scale out of the filter (trusted exactly).
pub const DEFAULT_FLOW_SCALE_STD: f64 = 0.05;
/// Random walk of a flow sensor's scale error, 1/√s (texture and height change it).
pub const DEFAULT_FLOW_SCALE_RW: f64 = 0.0005;
/// The heading error 1σ of a flow sensor's velocity as turned into the world, rad: the
/// attitude's yaw error (a magnetometer indoors is off by degrees) and the sensor's
/// mounting. 0 trusts the yaw exactly.
pub const DEFAULT_FLOW_HEADING_STD: f64 = 0.05;
/// How fast that heading error wanders, rad/√s (a compass near steel, a yaw that drifts).
pub const DEFAULT_FLOW_HEADING_RW: f64 = 0.003;
/// Flow calibration: samples per axis, flow-rate threshold, timeout, accepted scale range.
pub const DEFAULT_FLOW_CAL_SAMPLES: usize = 50;
pub const DEFAULT_FLOW_CAL_MIN_RATE: f64 = 0.1;
pub const DEFAULT_FLOW_CAL_TIMEOUT_S: f64 = 120.0;
pub const DEFAULT_FLOW_CAL_SCALE_MIN: f64 = 0.5;
pub const DEFAULT_FLOW_CAL_SCALE_MAX: f64 = 2.0;

/// WRLS tick, ms.
pub const DEFAULT_WRLS_PERIOD_MS: f64 = 20.0;
/// WRLS displacement variance growth per second when no relative source moved it, m²/s.
pub const DEFAULT_WRLS_NO_DELTA_VAR: f64 = 1.0;
/// Rate of the WRLS position as the EKF's measurement in `wrls+ekf`, Hz.
pub const DEFAULT_WRLS_EKF_RATE_HZ: f64 = 5.0;
/// Throttle of repeated events of one kind per source, ms.
pub const DEFAULT_EVENT_THROTTLE_MS: f64 = 1000.0;

/// Per-source settings, keyed by the input id.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SourceConfig {
    /// Latency from measurement to arrival, ms (default per sensor kind).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub latency_ms: Option<f64>,
    /// Use the source at all.
    pub fuse: bool,
    /// Measurement 1σ override (GNSS: horizontal m; odometry: position m; flow: rate
    /// rad/s; range/ToF: m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub noise: Option<f64>,
    /// Velocity 1σ override (GNSS, odometry), m/s.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vel_noise: Option<f64>,
    /// Odometry: camera position in the body frame (FLU), m.
    pub extrinsics_translation: [f64; 3],
    /// Odometry: camera-to-body rotation quaternion [x, y, z, w].
    pub extrinsics_rotation: [f64; 4],
    /// Odometry: drift random walk override, m/√s.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub drift_rw: Option<f64>,
    /// Flow: scale factors applied to the raw rates.
    pub scale_x: f64,
    pub scale_y: f64,
    /// Flow: largest usable raw rate, rad/s.
    pub max_rate: f64,
    /// Flow: gyro low-pass cut-off, Hz (0 = off).
    pub gyro_lpf_hz: f64,
    /// Flow: gyro clamp, rad/s.
    pub gyro_clamp: f64,
    /// Range / ToF limits, m (override the sample's).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub min_m: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_m: Option<f64>,
}

impl Default for SourceConfig {
    fn default() -> Self {
        Self {
            latency_ms: None,
            fuse: true,
            noise: None,
            vel_noise: None,
            extrinsics_translation: [0.0; 3],
            extrinsics_rotation: [0.0, 0.0, 0.0, 1.0],
            drift_rw: None,
            scale_x: DEFAULT_FLOW_SCALE,
            scale_y: DEFAULT_FLOW_SCALE,
            max_rate: DEFAULT_FLOW_MAX_RATE,
            gyro_lpf_hz: DEFAULT_FLOW_GYRO_LPF_HZ,
            gyro_clamp: DEFAULT_FLOW_GYRO_CLAMP,
            min_m: None,
            max_m: None,
        }
    }
}

/// The `[estimator]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EstimatorConfig {
    pub mode: Mode,
    pub history_ms: f64,
    pub gate_sigma: f64,
    pub clock_window_s: f64,
    pub clock_jump_s: f64,
    pub init_pos_var: f64,
    pub init_vel_var: f64,
    pub init_accel_bias_var: f64,
    pub accel_noise_density: f64,
    pub gyro_noise_density: f64,
    pub accel_bias_rw: f64,
    pub attitude_noise_rad: f64,
    pub no_imu_accel_noise: f64,
    pub imu_timeout_ms: f64,
    pub predict_period_ms: f64,
    pub attitude_timeout_ms: f64,
    pub att_w_acc: f64,
    pub att_w_ext_hdg: f64,
    pub att_w_gyro_bias: f64,
    pub att_bias_max: f64,
    pub gyro_bias_tau_s: f64,
    pub aiding_timeout_ms: f64,
    pub ground_pos_noise: f64,
    pub ground_vel_noise: f64,
    pub fake_pos_noise: f64,
    pub max_pos_std_m: f64,
    pub monitor_enabled: bool,
    pub monitor_pos_bound_m: f64,
    pub monitor_vel_bound_mps: f64,
    pub monitor_time_s: f64,
    pub monitor_track_tau_s: f64,
    pub monitor_gps_k_pos: f64,
    pub monitor_gps_k_vel: f64,
    pub monitor_flow_k_vel: f64,
    pub reset_pos_var: f64,
    pub reset_vel_var: f64,
    pub gnss_uere_m: f64,
    pub gnss_max_var: f64,
    pub gnss_vel_noise: f64,
    pub gnss_fuse_velocity: bool,
    pub gnss_bias_std_m: f64,
    pub gnss_bias_std_v_m: f64,
    pub gnss_bias_tau_s: f64,
    pub vo_drift_rw: f64,
    pub vo_jump_m: f64,
    pub vo_pos_noise: f64,
    pub vo_vel_noise: f64,
    pub vo_reject_realign_s: f64,
    pub vo_fuse_velocity: bool,
    pub flow_min_quality: u8,
    pub flow_rate_noise: f64,
    pub flow_min_height_m: f64,
    pub flow_scale_std: f64,
    pub flow_scale_rw: f64,
    pub flow_heading_std: f64,
    pub flow_heading_rw: f64,
    pub range_noise: f64,
    pub baro_noise: f64,
    pub baro_drift_rw: f64,
    pub range_max_tilt_rad: f64,
    pub range_quality_hold_ms: f64,
    pub terrain_rw: f64,
    pub terrain_gradient: f64,
    pub flow_cal_samples: usize,
    pub flow_cal_min_rate: f64,
    pub flow_cal_timeout_s: f64,
    pub flow_cal_scale_min: f64,
    pub flow_cal_scale_max: f64,
    pub wrls_period_ms: f64,
    pub wrls_no_delta_var: f64,
    pub wrls_ekf_rate_hz: f64,
    pub event_throttle_ms: f64,
    /// Per-source settings keyed by input id.
    pub sources: BTreeMap<String, SourceConfig>,
}

impl Default for EstimatorConfig {
    fn default() -> Self {
        Self {
            mode: DEFAULT_MODE,
            history_ms: DEFAULT_HISTORY_MS,
            gate_sigma: DEFAULT_GATE_SIGMA,
            clock_window_s: DEFAULT_CLOCK_WINDOW_S,
            clock_jump_s: DEFAULT_CLOCK_JUMP_S,
            init_pos_var: DEFAULT_INIT_POS_VAR,
            init_vel_var: DEFAULT_INIT_VEL_VAR,
            init_accel_bias_var: DEFAULT_INIT_ACCEL_BIAS_VAR,
            accel_noise_density: DEFAULT_ACCEL_NOISE_DENSITY,
            gyro_noise_density: DEFAULT_GYRO_NOISE_DENSITY,
            accel_bias_rw: DEFAULT_ACCEL_BIAS_RW,
            attitude_noise_rad: DEFAULT_ATTITUDE_NOISE_RAD,
            no_imu_accel_noise: DEFAULT_NO_IMU_ACCEL_NOISE,
            imu_timeout_ms: DEFAULT_IMU_TIMEOUT_MS,
            predict_period_ms: DEFAULT_PREDICT_PERIOD_MS,
            attitude_timeout_ms: DEFAULT_ATTITUDE_TIMEOUT_MS,
            att_w_acc: DEFAULT_ATT_W_ACC,
            att_w_ext_hdg: DEFAULT_ATT_W_EXT_HDG,
            att_w_gyro_bias: DEFAULT_ATT_W_GYRO_BIAS,
            att_bias_max: DEFAULT_ATT_BIAS_MAX,
            gyro_bias_tau_s: DEFAULT_GYRO_BIAS_TAU_S,
            aiding_timeout_ms: DEFAULT_AIDING_TIMEOUT_MS,
            ground_pos_noise: DEFAULT_GROUND_POS_NOISE,
            ground_vel_noise: DEFAULT_GROUND_VEL_NOISE,
            fake_pos_noise: DEFAULT_FAKE_POS_NOISE,
            max_pos_std_m: DEFAULT_MAX_POS_STD_M,
            monitor_enabled: DEFAULT_MONITOR_ENABLED,
            monitor_pos_bound_m: DEFAULT_MONITOR_POS_BOUND_M,
            monitor_vel_bound_mps: DEFAULT_MONITOR_VEL_BOUND_MPS,
            monitor_time_s: DEFAULT_MONITOR_TIME_S,
            monitor_track_tau_s: DEFAULT_MONITOR_TRACK_TAU_S,
            monitor_gps_k_pos: DEFAULT_MONITOR_GPS_K_POS,
            monitor_gps_k_vel: DEFAULT_MONITOR_GPS_K_VEL,
            monitor_flow_k_vel: DEFAULT_MONITOR_FLOW_K_VEL,
            reset_pos_var: DEFAULT_RESET_POS_VAR,
            reset_vel_var: DEFAULT_RESET_VEL_VAR,
            gnss_uere_m: DEFAULT_GNSS_UERE_M,
            gnss_max_var: DEFAULT_GNSS_MAX_VAR,
            gnss_vel_noise: DEFAULT_GNSS_VEL_NOISE,
            gnss_fuse_velocity: DEFAULT_GNSS_FUSE_VELOCITY,
            gnss_bias_std_m: DEFAULT_GNSS_BIAS_STD_M,
            gnss_bias_std_v_m: DEFAULT_GNSS_BIAS_STD_V_M,
            gnss_bias_tau_s: DEFAULT_GNSS_BIAS_TAU_S,
            vo_drift_rw: DEFAULT_VO_DRIFT_RW,
            vo_jump_m: DEFAULT_VO_JUMP_M,
            vo_pos_noise: DEFAULT_VO_POS_NOISE,
            vo_vel_noise: DEFAULT_VO_VEL_NOISE,
            vo_reject_realign_s: DEFAULT_VO_REJECT_REALIGN_S,
            vo_fuse_velocity: DEFAULT_VO_FUSE_VELOCITY,
            flow_min_quality: DEFAULT_FLOW_MIN_QUALITY,
            flow_rate_noise: DEFAULT_FLOW_RATE_NOISE,
            flow_min_height_m: DEFAULT_FLOW_MIN_HEIGHT_M,
            flow_scale_std: DEFAULT_FLOW_SCALE_STD,
            flow_scale_rw: DEFAULT_FLOW_SCALE_RW,
            flow_heading_std: DEFAULT_FLOW_HEADING_STD,
            flow_heading_rw: DEFAULT_FLOW_HEADING_RW,
            range_noise: DEFAULT_RANGE_NOISE,
            baro_noise: DEFAULT_BARO_NOISE,
            baro_drift_rw: DEFAULT_BARO_DRIFT_RW,
            range_max_tilt_rad: DEFAULT_RANGE_MAX_TILT_RAD,
            range_quality_hold_ms: DEFAULT_RANGE_QUALITY_HOLD_MS,
            terrain_rw: DEFAULT_TERRAIN_RW,
            terrain_gradient: DEFAULT_TERRAIN_GRADIENT,
            flow_cal_samples: DEFAULT_FLOW_CAL_SAMPLES,
            flow_cal_min_rate: DEFAULT_FLOW_CAL_MIN_RATE,
            flow_cal_timeout_s: DEFAULT_FLOW_CAL_TIMEOUT_S,
            flow_cal_scale_min: DEFAULT_FLOW_CAL_SCALE_MIN,
            flow_cal_scale_max: DEFAULT_FLOW_CAL_SCALE_MAX,
            wrls_period_ms: DEFAULT_WRLS_PERIOD_MS,
            wrls_no_delta_var: DEFAULT_WRLS_NO_DELTA_VAR,
            wrls_ekf_rate_hz: DEFAULT_WRLS_EKF_RATE_HZ,
            event_throttle_ms: DEFAULT_EVENT_THROTTLE_MS,
            sources: BTreeMap::new(),
        }
    }
}

impl EstimatorConfig {
    /// The settings of one source (defaults if it has no table).
    pub fn source(&self, id: &str) -> SourceConfig {
        self.sources.get(id).cloned().unwrap_or_default()
    }

    /// Latency of a source in µs: its own setting, else the kind's default.
    pub fn latency_us(&self, id: &str, kind: SensorKind) -> i64 {
        let ms = self
            .sources
            .get(id)
            .and_then(|s| s.latency_ms)
            .unwrap_or(match kind {
                SensorKind::Imu => DEFAULT_LATENCY_MS_IMU,
                SensorKind::Attitude => DEFAULT_LATENCY_MS_ATTITUDE,
                SensorKind::Odometry => DEFAULT_LATENCY_MS_ODOMETRY,
                SensorKind::Flow => DEFAULT_LATENCY_MS_FLOW,
                SensorKind::Range => DEFAULT_LATENCY_MS_RANGE,
                SensorKind::Gnss => DEFAULT_LATENCY_MS_GNSS,
                SensorKind::Baro => DEFAULT_LATENCY_MS_BARO,
                SensorKind::AutopilotEstimate | SensorKind::VehicleState => 0.0,
            });
        if ms.is_finite() {
            (ms * 1000.0).round() as i64
        } else {
            0
        }
    }

    /// Check values that would make the filter meaningless.
    pub fn validate(&self) -> Result<(), String> {
        let positive = [
            ("history_ms", self.history_ms),
            ("gate_sigma", self.gate_sigma),
            ("clock_window_s", self.clock_window_s),
            ("init_pos_var", self.init_pos_var),
            ("init_vel_var", self.init_vel_var),
            ("accel_noise_density", self.accel_noise_density),
            ("aiding_timeout_ms", self.aiding_timeout_ms),
            ("ground_pos_noise", self.ground_pos_noise),
            ("ground_vel_noise", self.ground_vel_noise),
            ("fake_pos_noise", self.fake_pos_noise),
            ("max_pos_std_m", self.max_pos_std_m),
            ("baro_noise", self.baro_noise),
            ("wrls_period_ms", self.wrls_period_ms),
            ("monitor_time_s", self.monitor_time_s),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!(
                    "estimator.{name} must be a positive number, got {v}"
                ));
            }
        }
        for (name, v) in [
            ("flow_scale_std", self.flow_scale_std),
            ("flow_scale_rw", self.flow_scale_rw),
            ("flow_heading_std", self.flow_heading_std),
            ("flow_heading_rw", self.flow_heading_rw),
            ("terrain_gradient", self.terrain_gradient),
        ] {
            if !(v.is_finite() && (0.0..1.0).contains(&v)) {
                return Err(format!("estimator.{name} must be between 0 and 1, got {v}"));
            }
        }
        if !(self.range_quality_hold_ms.is_finite() && self.range_quality_hold_ms >= 0.0) {
            return Err(format!(
                "estimator.range_quality_hold_ms must be 0 or more, got {}",
                self.range_quality_hold_ms
            ));
        }
        if !(self.predict_period_ms.is_finite() && (0.0..=100.0).contains(&self.predict_period_ms))
        {
            return Err(format!(
                "estimator.predict_period_ms must be between 0 (every IMU sample) and 100, got {}",
                self.predict_period_ms
            ));
        }
        for (id, s) in &self.sources {
            for (name, v) in [("scale_x", s.scale_x), ("scale_y", s.scale_y)] {
                if !(v.is_finite() && v > 0.0) {
                    return Err(format!("estimator.sources.{id}.{name} must be positive"));
                }
            }
            let q = s.extrinsics_rotation;
            let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
            if !(n.is_finite() && n > 1e-6) {
                return Err(format!(
                    "estimator.sources.{id}.extrinsics_rotation is not a rotation"
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn toml_round_trip_and_unknown_keys_rejected() {
        let mut cfg = EstimatorConfig {
            mode: Mode::WrlsEkf,
            ..EstimatorConfig::default()
        };
        cfg.sources.insert(
            "t265".into(),
            SourceConfig {
                latency_ms: Some(6.0),
                extrinsics_translation: [0.1, 0.0, -0.05],
                ..SourceConfig::default()
            },
        );
        let text = toml::to_string(&cfg).expect("serialise");
        assert!(text.contains("mode = \"wrls+ekf\""), "{text}");
        let back: EstimatorConfig = toml::from_str(&text).expect("parse");
        assert_eq!(back, cfg);
        // Embedded as a table of the service config.
        let wrapped = "[estimator]\nmode = \"wrls\"\n[estimator.sources.flow]\nscale_x = 1.1\n";
        #[derive(Deserialize)]
        struct Outer {
            estimator: EstimatorConfig,
        }
        let o: Outer = toml::from_str(wrapped).expect("parse wrapped");
        assert_eq!(o.estimator.mode, Mode::Wrls);
        assert_eq!(o.estimator.source("flow").scale_x, 1.1);
        assert_eq!(o.estimator.source("flow").gyro_lpf_hz, 3.0);
        let err = toml::from_str::<EstimatorConfig>("gate_sigmaa = 3.0").unwrap_err();
        assert!(err.to_string().contains("gate_sigmaa"), "{err}");
        let err = toml::from_str::<EstimatorConfig>("[sources.x]\nscal_x = 1.0").unwrap_err();
        assert!(err.to_string().contains("scal_x"), "{err}");
        assert!(cfg.validate().is_ok());
    }

    #[test]
    fn latency_defaults_per_kind() {
        let cfg = EstimatorConfig::default();
        assert_eq!(cfg.latency_us("gps", SensorKind::Gnss), 100_000);
        assert_eq!(cfg.latency_us("imu", SensorKind::Imu), 2_000);
    }
}
