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
/// Accelerometer bias prior, (m/s²)²: σ 0.5 m/s². A bench-calibrated IMU is better,
/// but a mounting tilt against the attitude the autopilot reports reads as a bias too
/// (5° is 0.85 m/s² of horizontal specific force), and a prior tighter than the truth
/// makes the first minute's drift look impossible.
pub const DEFAULT_INIT_ACCEL_BIAS_VAR: f64 = 0.25;
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
/// Every measurement of a channel (the horizontal, or the height) refused for this
/// long, with nothing else holding that channel, resets the filter to the newest one,
/// s (EKF2's and EKF3's reset after a source has been rejected for a while): otherwise
/// the filter's own drift keeps its only source locked out for good.
pub const DEFAULT_REJECT_RESET_S: f64 = 3.0;
/// The accelerometer fault allowed for when a velocity comes back refused after a
/// second or more of dead reckoning, or a flow's learnt calibration runs away, m/s²
/// (1σ; 0: never): as large as the biases the randomised flights draw, and the step of
/// PX4's square flown with a shifted mount.
pub const DEFAULT_DEAD_RECKONING_FAULT_MPS2: f64 = 1.0;
/// After such a reset the pose is invalid for this long, and until the source is
/// accepted again, s.
pub const DEFAULT_RESET_CONVERGE_S: f64 = 2.0;
/// Largest horizontal/vertical position 1σ that is still valid, m: a bound beside the
/// protection levels (`integrity`), which are what "valid" answers to.
pub const DEFAULT_MAX_POS_STD_M: f64 = 20.0;

pub const DEFAULT_MONITOR_ENABLED: bool = true;
/// Let a monitor reset the main filter to its own estimate when they part. Off: the
/// monitors are complementary filters that know nothing of biases, delays or scale
/// errors, and over 200 randomised flights their resets turned a sound filter into a
/// worse one more often than not (runs with integrity failures 91 → 71, median fused
/// error 1.16 → 0.73 m with them off); the integrity monitor's bank of filters is
/// what catches a lying source now. They still run and show how far the filter is
/// from them.
pub const DEFAULT_MONITOR_RESET: bool = false;
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
/// GNSS slowly varying error (multipath, atmosphere, orbits), modelled as a
/// Gauss–Markov state: this fraction of the variance the receiver reports is that slow
/// part, the rest is white. A standalone receiver's error wanders by about what it
/// reports over minutes: averaging many fixes does not beat it, and GNSS anchors the
/// frame while the relative sensors carry the shape.
pub const DEFAULT_GNSS_BIAS_FRACTION: f64 = 0.8;
/// The slow part's 1σ is at most this, horizontal and vertical, m, whatever the
/// receiver reports (an RTK user lowers them).
pub const DEFAULT_GNSS_BIAS_STD_M: f64 = 3.0;
pub const DEFAULT_GNSS_BIAS_STD_V_M: f64 = 5.0;
/// Correlation time of that error, s.
pub const DEFAULT_GNSS_BIAS_TAU_S: f64 = 120.0;

/// The heading error of the attitude the estimator is given (a compass near steel or
/// currents): stationary 1σ, rad, and correlation time, s. The heading is known
/// relative to the take-off heading to within the wander of this error; against north
/// (GNSS) to within its 1σ. The correlation time is what lets the σ cover a compass
/// error that swings over a minute or two: the randomised flights draw 2–15° over
/// periods of 60–600 s, whose changes a 100 s Gauss-Markov covers within 3σ on 99.9 %
/// of (flight, interval) pairs (300 s: 99.2 %, and 6.7σ at worst).
pub const DEFAULT_YAW_ERROR_STD: f64 = 0.15;
pub const DEFAULT_YAW_ERROR_TAU_S: f64 = 100.0;
/// How far a position no source measures may drift per metre flown, 1σ per axis: a
/// constant of the flight, as an odometry's "% of distance travelled". A heading
/// error that wanders in time cancels over a closed lap; one fixed in place (steel, a
/// magnetic anomaly) or in step with the laps repeats on every lap, and its sideways
/// error adds up. Randomised draw 141 of seed 3 (figure-eights at 1.1 m/s, a compass
/// swinging ±14° about as often as a lap) drifted 18 m north in 300 s, every metre of
/// it the heading's, with σ 4 m: 49 % of its north poses beyond 3σ. Only in a frame of
/// its own: on Earth a GNSS measures where the vehicle is.
pub const DEFAULT_DEAD_RECKONING_DRIFT: f64 = 0.02;
/// The take-off heading's own 1σ in a frame that starts there, rad (the attitude's
/// noise at that instant).
pub const OWN_FRAME_YAW_STD: f64 = 0.01;
/// An aiding source's delay beyond its configured latency (a sensor that stamps late,
/// a bridge that queues): prior 1σ, s, and random walk, s/√s. Each source's delay is a
/// state of the filter, seen when what it measures changes.
pub const DEFAULT_DELAY_STD_S: f64 = 0.1;
pub const DEFAULT_DELAY_RW: f64 = 0.001;

/// Visual odometry: drift of the odometry frame against the world, m/√s. A T265 drifts
/// by about 1 % of the distance it travels: 2 cm/√s covers a few metres a second for
/// minutes (0.005 was exceeded 4-fold by the drifts the randomised flights draw).
pub const DEFAULT_VO_DRIFT_RW: f64 = 0.02;
/// Position step not explained by the velocity that starts a new segment, m.
pub const DEFAULT_VO_JUMP_M: f64 = 0.3;
/// Position 1σ when the message has no covariance, m.
pub const DEFAULT_VO_POS_NOISE: f64 = 0.01;
/// Velocity 1σ, m/s: when the message has no covariance, and at the least when it has
/// one (a camera's velocity is its pose's derivative, not independent of the position
/// fused beside it; with 0.01 as a T265 reports it, randomised flights drifted in
/// height at millimetres a second with σ of centimetres).
pub const DEFAULT_VO_VEL_NOISE: f64 = 0.05;
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
/// Flow angular rate noise 1σ at the least usable quality, rad/s (PX4 EKF2_OF_N_MAX);
/// between it and `flow_rate_noise` at quality 255, linearly.
pub const DEFAULT_FLOW_RATE_NOISE_MAX: f64 = 0.5;
/// Learn how much quieter than `flow_rate_noise` a flow sensor is from its innovations
/// (see `flow::RateNoise`).
pub const DEFAULT_FLOW_RATE_NOISE_LEARN: bool = true;
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
/// After a sample below `flow_min_quality` in the air, a flow sensor must read good
/// this long before it is fused again, ms: over poor texture the samples it still
/// calls good read slow.
pub const DEFAULT_FLOW_QUALITY_HOLD_MS: f64 = 1000.0;
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
pub const DEFAULT_FLOW_HEADING_RW: f64 = 0.0005;
/// The bias error 1σ of the gyro that compensates a flow's rates before anything
/// learns it, rad/s (a MEMS gyro after its start-up calibration: a few mrad/s).
pub const DEFAULT_FLOW_GYRO_BIAS_STD: f64 = 0.005;
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
    pub max_pos_std_m: f64,
    pub reject_reset_s: f64,
    pub dead_reckoning_fault_mps2: f64,
    pub reset_converge_s: f64,
    pub monitor_enabled: bool,
    pub monitor_reset: bool,
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
    pub gnss_bias_fraction: f64,
    pub gnss_bias_std_m: f64,
    pub gnss_bias_std_v_m: f64,
    pub gnss_bias_tau_s: f64,
    pub yaw_error_std: f64,
    pub yaw_error_tau_s: f64,
    pub dead_reckoning_drift: f64,
    pub delay_std_s: f64,
    pub delay_rw: f64,
    pub vo_drift_rw: f64,
    pub vo_jump_m: f64,
    pub vo_pos_noise: f64,
    pub vo_vel_noise: f64,
    pub vo_reject_realign_s: f64,
    pub vo_fuse_velocity: bool,
    pub flow_min_quality: u8,
    pub flow_rate_noise: f64,
    pub flow_rate_noise_max: f64,
    pub flow_rate_noise_learn: bool,
    pub flow_min_height_m: f64,
    pub flow_scale_std: f64,
    pub flow_scale_rw: f64,
    pub flow_heading_std: f64,
    pub flow_heading_rw: f64,
    pub flow_gyro_bias_std: f64,
    pub range_noise: f64,
    pub baro_noise: f64,
    pub baro_drift_rw: f64,
    pub range_max_tilt_rad: f64,
    pub range_quality_hold_ms: f64,
    pub flow_quality_hold_ms: f64,
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
    /// The service config's `[integrity]` table, put here when it is loaded.
    #[serde(skip)]
    pub integrity: super::integrity::IntegrityConfig,
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
            max_pos_std_m: DEFAULT_MAX_POS_STD_M,
            reject_reset_s: DEFAULT_REJECT_RESET_S,
            dead_reckoning_fault_mps2: DEFAULT_DEAD_RECKONING_FAULT_MPS2,
            reset_converge_s: DEFAULT_RESET_CONVERGE_S,
            monitor_enabled: DEFAULT_MONITOR_ENABLED,
            monitor_reset: DEFAULT_MONITOR_RESET,
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
            gnss_bias_fraction: DEFAULT_GNSS_BIAS_FRACTION,
            gnss_bias_std_m: DEFAULT_GNSS_BIAS_STD_M,
            gnss_bias_std_v_m: DEFAULT_GNSS_BIAS_STD_V_M,
            gnss_bias_tau_s: DEFAULT_GNSS_BIAS_TAU_S,
            yaw_error_std: DEFAULT_YAW_ERROR_STD,
            yaw_error_tau_s: DEFAULT_YAW_ERROR_TAU_S,
            dead_reckoning_drift: DEFAULT_DEAD_RECKONING_DRIFT,
            delay_std_s: DEFAULT_DELAY_STD_S,
            delay_rw: DEFAULT_DELAY_RW,
            vo_drift_rw: DEFAULT_VO_DRIFT_RW,
            vo_jump_m: DEFAULT_VO_JUMP_M,
            vo_pos_noise: DEFAULT_VO_POS_NOISE,
            vo_vel_noise: DEFAULT_VO_VEL_NOISE,
            vo_reject_realign_s: DEFAULT_VO_REJECT_REALIGN_S,
            vo_fuse_velocity: DEFAULT_VO_FUSE_VELOCITY,
            flow_min_quality: DEFAULT_FLOW_MIN_QUALITY,
            flow_rate_noise: DEFAULT_FLOW_RATE_NOISE,
            flow_rate_noise_max: DEFAULT_FLOW_RATE_NOISE_MAX,
            flow_rate_noise_learn: DEFAULT_FLOW_RATE_NOISE_LEARN,
            flow_min_height_m: DEFAULT_FLOW_MIN_HEIGHT_M,
            flow_scale_std: DEFAULT_FLOW_SCALE_STD,
            flow_scale_rw: DEFAULT_FLOW_SCALE_RW,
            flow_heading_std: DEFAULT_FLOW_HEADING_STD,
            flow_heading_rw: DEFAULT_FLOW_HEADING_RW,
            flow_gyro_bias_std: DEFAULT_FLOW_GYRO_BIAS_STD,
            range_noise: DEFAULT_RANGE_NOISE,
            baro_noise: DEFAULT_BARO_NOISE,
            baro_drift_rw: DEFAULT_BARO_DRIFT_RW,
            range_max_tilt_rad: DEFAULT_RANGE_MAX_TILT_RAD,
            range_quality_hold_ms: DEFAULT_RANGE_QUALITY_HOLD_MS,
            flow_quality_hold_ms: DEFAULT_FLOW_QUALITY_HOLD_MS,
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
            integrity: super::integrity::IntegrityConfig::default(),
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
            ("max_pos_std_m", self.max_pos_std_m),
            ("baro_noise", self.baro_noise),
            ("wrls_period_ms", self.wrls_period_ms),
            ("monitor_time_s", self.monitor_time_s),
            ("yaw_error_tau_s", self.yaw_error_tau_s),
            ("reject_reset_s", self.reject_reset_s),
            ("reset_converge_s", self.reset_converge_s),
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
            ("flow_gyro_bias_std", self.flow_gyro_bias_std),
            ("terrain_gradient", self.terrain_gradient),
            ("yaw_error_std", self.yaw_error_std),
            ("dead_reckoning_drift", self.dead_reckoning_drift),
            ("delay_std_s", self.delay_std_s),
            ("delay_rw", self.delay_rw),
            ("gnss_bias_fraction", self.gnss_bias_fraction),
        ] {
            if !(v.is_finite() && (0.0..1.0).contains(&v)) {
                return Err(format!("estimator.{name} must be between 0 and 1, got {v}"));
            }
        }
        for (name, v) in [
            ("range_quality_hold_ms", self.range_quality_hold_ms),
            ("flow_quality_hold_ms", self.flow_quality_hold_ms),
            ("dead_reckoning_fault_mps2", self.dead_reckoning_fault_mps2),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("estimator.{name} must be 0 or more, got {v}"));
            }
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
