//! The Kalman filter maths: state layout, IMU-driven prediction, Joseph-form update with
//! Mahalanobis (chi²) gating, and the covariance surgery that resets and odometry
//! segments need.
//!
//! State (world ENU): position p (0..3), velocity v (3..6), accelerometer bias in the
//! body frame b_a (6..9), terrain height z_t (9: the ground under the vehicle; 0 by
//! definition at the take-off pose, uncertain once GNSS anchors the frame at the first
//! fix, whose altitude error is the terrain's height in that frame; range measures
//! p_z − z_t), GNSS error b_g (10..13: the slowly varying part of the GNSS error,
//! first-order Gauss–Markov, so averaging many fixes does not make the filter
//! over-confident), the heading error of the attitude the filter is given ψ_a (13: the
//! autopilot's yaw is off by a compass's error, which wanders; the specific force and
//! every body-frame velocity are turned into the world by the true heading
//! `Rz(−ψ_a)·R`), then one 3-state block per visual-odometry source: the offset
//! of that source's aligned frame from the world (its drift), so odometry positions are
//! modelled as `z = p + b`. A block starts fully correlated with p (b = 0,
//! P_bb = P_pp, P_bp = -P_pp), which makes the first measurements carry only relative
//! information, as they should.

pub use super::measurement::{Measurement, MAX_ROWS};
use nalgebra::{Cholesky, Const, DMatrix, DVector, Matrix3, SMatrix, SVector, Vector3};

/// Standard gravity, m/s².
pub const GRAVITY: f64 = 9.806_65;
pub const IDX_P: usize = 0;
pub const IDX_V: usize = 3;
pub const IDX_BA: usize = 6;
pub const IDX_TERRAIN: usize = 9;
pub const IDX_BG: usize = 10;
pub const IDX_YAW: usize = 13;
pub const CORE_STATES: usize = 14;
/// Smallest variance kept on the diagonal (numerical floor).
const VAR_FLOOR: f64 = 1e-12;

/// The variance a replaced state takes before the measurement that replaces it, (m/s)²
/// or m²: far beyond any innovation, so the measurement alone decides.
const REPLACED_PRIOR_VAR: f64 = 1e6;

/// Result of one measurement update.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UpdateOutcome {
    rows: usize,
    innovation: [f64; MAX_ROWS],
    /// Innovation variances (diagonal of S).
    innovation_var: [f64; MAX_ROWS],
    /// Normalised innovation squared yᵀS⁻¹y.
    pub nis: f64,
    /// NIS over the gate threshold: > 1 means rejected.
    pub test_ratio: f64,
    pub accepted: bool,
}

impl UpdateOutcome {
    pub fn innovation(&self) -> &[f64] {
        &self.innovation[..self.rows]
    }

    /// Innovation variances (diagonal of S).
    pub fn innovation_var(&self) -> &[f64] {
        &self.innovation_var[..self.rows]
    }
}

/// The filter: state vector, covariance, and the odometry offset blocks.
#[derive(Debug, Clone, PartialEq)]
pub struct Ekf {
    pub x: DVector<f64>,
    pub p: DMatrix<f64>,
    /// (source id, first index) of each odometry offset block.
    pub blocks: Vec<(String, usize)>,
    /// (source id, index) of each flow source's scale error k and, at the next index,
    /// its heading error ψ: the flow reads (1 + k)·Rz(ψ) times the truth (ψ: the
    /// attitude's yaw error and the sensor's mounting, as the flow's velocity is turned
    /// into the world by that yaw). Unobservable from flow alone, they make the
    /// position's uncertainty grow with the distance from where the flow started, as
    /// the error does; another velocity or position source calibrates them.
    pub scales: Vec<(String, usize)>,
    /// (source id, index, correlation time s) of each flow source's compensation gyro
    /// bias error (δb_x, δb_y, rad/s, at the index and the next): the flow reads it
    /// times the height as a velocity, an offset no innovation shows (the prediction
    /// follows it), so it is considered, never corrected: the position's σ grows with
    /// it as the error does. It fades with the correlation time where the bias is
    /// being learnt (the autopilot's rates), and stays where nothing learns it.
    pub gyro_biases: Vec<(String, usize, f64)>,
    /// Random walk of the scale errors, 1/√s, and of the heading errors, rad/√s.
    pub scale_rw: f64,
    pub heading_rw: f64,
    /// Terrain height random walk, m/√s.
    pub terrain_rw: f64,
    /// How much the terrain may rise or fall per metre travelled (EKF2_TERR_GRAD): its
    /// uncertainty grows with the horizontal speed.
    pub terrain_gradient: f64,
    /// GNSS slow error: stationary 1σ per axis (m) and correlation time (s).
    pub gnss_bias_std: Vector3<f64>,
    pub gnss_bias_tau_s: f64,
    /// The attitude's heading error ψ_a: stationary 1σ (rad) and correlation time (s).
    pub yaw_error_std: f64,
    pub yaw_error_tau_s: f64,
    /// Index of the drift per metre flown (east, and north at the next), if the filter
    /// has it: the position moves by it times the horizontal speed. A constant of the
    /// flight, considered by every update, never corrected, so its estimate stays nil
    /// and only its covariance moves (see `config::DEFAULT_DEAD_RECKONING_DRIFT`).
    pub drift: Option<usize>,
    /// The drift is a state still (a GNSS fix ends it; see [`Self::end_drift`]).
    drifting: bool,
    /// (source id, index) of each aiding source's unknown delay τ (s): it measures
    /// the state of `τ` ago, `h(x(t − τ)) ≈ h(x) − τ·dh/dt`.
    pub delays: Vec<(String, usize)>,
    /// Random walk of the delays, s/√s.
    pub delay_rw: f64,
    /// (source id, index) of each odometry segment's alignment error ε (rad): the
    /// heading error the segment was aligned with, so that its positions turn about
    /// where it started by ε.
    pub align_yaws: Vec<(String, usize)>,
    /// Random walk of those (an odometry's own heading drift), rad/√s.
    pub align_yaw_rw: f64,
    /// Correlation time of the velocity, s: infinite while an IMU drives the
    /// prediction; without one (the constant-velocity stand-in) a multicopter's
    /// velocity is a Gauss–Markov process that returns to rest, not a value held for
    /// ever (unaided, a held velocity carries the position away in a straight line).
    pub velocity_tau_s: f64,
    /// The world acceleration of the predictions, low-passed over
    /// [`ACCEL_SMOOTH_TAU_S`], m/s²: what a velocity's delay turns into a difference.
    /// The raw one would be the IMU's noise and vibration, which a delay's Jacobian
    /// would take for information (a vehicle standing on the ground "seeing" its
    /// camera's delay to 5 ms).
    pub accel_world: Vector3<f64>,
    /// Velocity random walk on top of the IMU's white noise, per axis (east, north,
    /// up), m²/s³: what the innovations showed the prediction misses (see
    /// [`super::imu::PredictionNoise`]).
    pub vel_q_extra: Vector3<f64>,
}

impl Ekf {
    pub fn new(
        pos: Vector3<f64>,
        vel: Vector3<f64>,
        pos_var: Vector3<f64>,
        vel_var: Vector3<f64>,
        bias_var: f64,
    ) -> Self {
        let mut x = DVector::zeros(CORE_STATES);
        x.fixed_rows_mut::<3>(IDX_P).copy_from(&pos);
        x.fixed_rows_mut::<3>(IDX_V).copy_from(&vel);
        let mut p = DMatrix::zeros(CORE_STATES, CORE_STATES);
        for i in 0..3 {
            p[(IDX_P + i, IDX_P + i)] = pos_var[i];
            p[(IDX_V + i, IDX_V + i)] = vel_var[i];
            p[(IDX_BA + i, IDX_BA + i)] = bias_var;
        }
        Self {
            x,
            p,
            blocks: Vec::new(),
            scales: Vec::new(),
            gyro_biases: Vec::new(),
            scale_rw: 0.0,
            heading_rw: 0.0,
            terrain_rw: 0.0,
            terrain_gradient: 0.0,
            gnss_bias_std: Vector3::zeros(),
            gnss_bias_tau_s: 1.0,
            yaw_error_std: 0.0,
            yaw_error_tau_s: 1.0,
            drift: None,
            drifting: false,
            velocity_tau_s: f64::INFINITY,
            delays: Vec::new(),
            delay_rw: 0.0,
            align_yaws: Vec::new(),
            align_yaw_rw: 0.0,
            accel_world: Vector3::zeros(),
            vel_q_extra: Vector3::zeros(),
        }
    }

    /// A short name for every state, in order (for a developer's listing).
    pub fn state_names(&self) -> Vec<String> {
        let core = [
            "px", "py", "pz", "vx", "vy", "vz", "bax", "bay", "baz", "terrain", "bgx", "bgy",
            "bgz", "yaw",
        ];
        let mut names: Vec<String> = core.iter().map(|s| s.to_string()).collect();
        names.resize(self.n(), String::new());
        for (s, i) in &self.blocks {
            for (k, axis) in ["x", "y", "z"].iter().enumerate() {
                names[i + k] = format!("{s}.b{axis}");
            }
        }
        for (s, i) in &self.scales {
            names[*i] = format!("{s}.scale");
            names[i + 1] = format!("{s}.heading");
        }
        for (s, i, _) in &self.gyro_biases {
            names[*i] = format!("{s}.gyro_bias_x");
            names[i + 1] = format!("{s}.gyro_bias_y");
        }
        for (s, i) in &self.delays {
            names[*i] = format!("{s}.delay");
        }
        for (s, i) in &self.align_yaws {
            names[*i] = format!("{s}.align_yaw");
        }
        if let Some(i) = self.drift {
            names[i] = "drift_e".into();
            names[i + 1] = "drift_n".into();
        }
        names
    }

    /// The heading error of the attitude the filter is given, rad.
    pub fn yaw_error(&self) -> f64 {
        self.x[IDX_YAW]
    }

    /// The attitude's rotation corrected by the heading error: body → world.
    pub fn true_rotation(&self, rot: &Matrix3<f64>) -> Matrix3<f64> {
        yaw_rotation(-self.yaw_error()) * rot
    }

    /// Set the heading error's model and its prior 1σ (rad).
    pub fn set_yaw_error_model(&mut self, std: f64, tau_s: f64, prior_std: f64) {
        self.yaw_error_std = std;
        self.yaw_error_tau_s = tau_s;
        self.p[(IDX_YAW, IDX_YAW)] = prior_std * prior_std;
    }

    /// The position drifts by up to `std` (1σ per axis) per metre flown, a constant of
    /// the flight (see [`Self::drift`]).
    pub fn add_drift(&mut self, std: f64) {
        if !(std.is_finite() && std > 0.0) || self.drift.is_some() {
            return;
        }
        let n = self.n();
        self.grow(2);
        self.p[(n, n)] = std * std;
        self.p[(n + 1, n + 1)] = std * std;
        self.drift = Some(n);
        self.drifting = true;
    }

    /// The drift's index while it is a state.
    fn drift_state(&self) -> Option<usize> {
        self.drift.filter(|_| self.drifting)
    }

    /// Whether an odometry (a camera) has an offset block: it measures the position.
    /// A barometer's block measures the height alone.
    fn has_odometry(&self) -> bool {
        self.blocks
            .iter()
            .any(|(s, _)| !s.starts_with(super::baro::BLOCK_PREFIX))
    }

    /// A position source now measures where the vehicle is (GNSS anchors the frame on
    /// Earth): the drift is its business, not a state's. Held at nil from here.
    pub fn end_drift(&mut self) {
        if let Some(i) = self.drift_state() {
            self.forget(&[i, i + 1], 0.0);
            self.drifting = false;
        }
    }

    /// The index of `source`'s compensation gyro bias error (x, and y at the next),
    /// added (0, variance `var` per axis) on first use; `tau_s` its correlation time
    /// from now on (infinite: held).
    pub fn gyro_bias_state(&mut self, source: &str, var: f64, tau_s: f64) -> usize {
        if let Some(g) = self.gyro_biases.iter_mut().find(|(s, ..)| s == source) {
            g.2 = tau_s;
            return g.1;
        }
        let n = self.n();
        self.grow(2);
        self.p[(n, n)] = var;
        self.p[(n + 1, n + 1)] = var;
        self.gyro_biases.push((source.to_string(), n, tau_s));
        n
    }

    /// The index of `source`'s delay state, added (0, variance `var`) on first use.
    pub fn delay_state(&mut self, source: &str, var: f64) -> usize {
        if let Some(i) = self.delay_of(source) {
            return i;
        }
        let n = self.n();
        self.grow(1);
        self.p[(n, n)] = var;
        self.delays.push((source.to_string(), n));
        n
    }

    /// Start (or restart) `source`'s alignment error ε: the error of the heading error
    /// estimate now, `ψ_a − ψ̂_a`, so 0 with ψ_a's variance and correlations.
    pub fn start_align_yaw(&mut self, source: &str) -> usize {
        let idx = match self.align_yaw_of(source) {
            Some(i) => i,
            None => {
                let n = self.n();
                self.grow(1);
                self.align_yaws.push((source.to_string(), n));
                n
            }
        };
        let n = self.n();
        self.x[idx] = 0.0;
        for j in 0..n {
            let c = if j == idx {
                self.p[(IDX_YAW, IDX_YAW)]
            } else {
                self.p[(IDX_YAW, j)]
            };
            self.p[(idx, j)] = c;
            self.p[(j, idx)] = c;
        }
        self.symmetrise();
        idx
    }

    /// The index of `source`'s alignment error, if it has one.
    pub fn align_yaw_of(&self, source: &str) -> Option<usize> {
        index_of(&self.align_yaws, source)
    }

    /// Holds every delay state within ±`max_s` (EKF2's constrainStates for its biases),
    /// and at or above its source's `floor` (s; none: −`max_s`), what it physically
    /// cannot be below: a delay is seen through what the source measures changing,
    /// and a model error of the same shape (a vertical velocity the IMU got wrong,
    /// against a barometer) is explained as a delay just as well; unbounded, a
    /// barometer's ran to 0.8 s on a real log and the velocity error it hid grew on.
    pub fn constrain_delays(&mut self, max_s: f64, floor: impl Fn(&str) -> Option<f64>) {
        for (source, i) in &self.delays {
            let lo = floor(source).map_or(-max_s, |f| f.max(-max_s)).min(max_s);
            self.x[*i] = self.x[*i].clamp(lo, max_s);
        }
    }

    /// What the prediction misses bounds what the filter may claim to know of the
    /// states that would explain a misfit in its stead. `q` is the learnt velocity
    /// random walk per world axis (m²/s³; see `imu::PredictionNoise`). An accelerometer
    /// bias known to 5 mm/s² after a minute's hover cannot take a 1 m/s² step (a knock, a
    /// loose mount's vibration): the misfit went into a GNSS delay instead, adopted as
    /// 0.1 s, and every later move was sent 0.5 m ahead with σ 4 cm. So the bias is
    /// never surer than what the model misses in [`BIAS_MISFIT_S`], and while the model
    /// is plainly wrong (`q` towards [`Q_MODEL_WRONG`]) each delay is as open as its prior:
    /// what was learnt under a wrong model is learnt again. A height source's delay
    /// (`vertical`) is left as it is: a barometer's or a range finder's is seen only
    /// against the vertical, whose noise their own errors teach, and reopened by it on
    /// randomised draw 740 (hover; range 297 ms and baro 272 ms late) the two wandered,
    /// the barometer was excluded 40 m off and 18 011 valid poses broke their
    /// protection level (none without).
    pub fn doubt_under_misfit(
        &mut self,
        q: Vector3<f64>,
        delay_prior_var: f64,
        vertical: impl Fn(&str) -> bool,
    ) {
        // The horizontal axes only: the vertical bias is seen against heights whose
        // own errors (a barometer's drift, a sonar's echoes) teach the vertical
        // noise, and floored by it the bias followed them (a real log, 11-2-2015_112:
        // 178 poses beyond 5σ with it, none without).
        for i in 0..2 {
            let k = IDX_BA + i;
            let floor = q[i] * BIAS_MISFIT_S;
            if self.p[(k, k)] < floor {
                self.p[(k, k)] = floor;
            }
        }
        let floor = delay_prior_var * (q.x.max(q.y) / Q_MODEL_WRONG).min(1.0);
        for &(ref source, k) in &self.delays {
            if vertical(source) {
                continue;
            }
            if self.p[(k, k)] < floor {
                self.p[(k, k)] = floor;
            }
        }
    }

    /// The index of `source`'s scale error (its heading error at the next), if it has
    /// one.
    pub fn scale_of(&self, source: &str) -> Option<usize> {
        index_of(&self.scales, source)
    }

    /// The index of `source`'s delay state, if it has one.
    pub fn delay_of(&self, source: &str) -> Option<usize> {
        index_of(&self.delays, source)
    }

    /// `extra` more states, zero, uncorrelated, variance zero until set.
    fn grow(&mut self, extra: usize) {
        let n = self.n();
        let mut x = DVector::zeros(n + extra);
        x.rows_mut(0, n).copy_from(&self.x);
        let mut p = DMatrix::zeros(n + extra, n + extra);
        p.view_mut((0, 0), (n, n)).copy_from(&self.p);
        self.x = x;
        self.p = p;
    }

    pub fn n(&self) -> usize {
        self.x.len()
    }

    pub fn pos(&self) -> Vector3<f64> {
        self.x.fixed_rows::<3>(IDX_P).into_owned()
    }

    pub fn vel(&self) -> Vector3<f64> {
        self.x.fixed_rows::<3>(IDX_V).into_owned()
    }

    pub fn accel_bias(&self) -> Vector3<f64> {
        self.x.fixed_rows::<3>(IDX_BA).into_owned()
    }

    pub fn gnss_bias(&self) -> Vector3<f64> {
        self.x.fixed_rows::<3>(IDX_BG).into_owned()
    }

    /// Set the GNSS slow-error model and its prior.
    pub fn set_gnss_bias_model(&mut self, std: Vector3<f64>, tau_s: f64) {
        self.gnss_bias_std = std;
        self.gnss_bias_tau_s = tau_s;
        for i in 0..3 {
            self.p[(IDX_BG + i, IDX_BG + i)] = std[i] * std[i];
        }
        self.symmetrise();
    }

    pub fn cov3(&self, i: usize) -> Matrix3<f64> {
        self.p.fixed_view::<3, 3>(i, i).into_owned()
    }

    pub fn block(&self, source: &str) -> Option<usize> {
        self.blocks
            .iter()
            .find(|(s, _)| s == source)
            .map(|&(_, i)| i)
    }

    /// True if every state and covariance entry is finite.
    pub fn is_finite(&self) -> bool {
        all_finite(self.x.as_slice()) && all_finite(self.p.as_slice())
    }

    /// Propagate by `dt` seconds with specific force `f_body` (body FLU) rotated by `rot`
    /// (body → world). `accel_var` is the per-axis variance of the specific force
    /// (white, per step); `bias_rw` in m/s²/√s; `drift_rw[i]` for each offset block.
    pub fn predict(
        &mut self,
        f_body: Vector3<f64>,
        rot: &Matrix3<f64>,
        dt: f64,
        accel_var: f64,
        bias_rw: f64,
        drift_rw: impl Fn(&str) -> f64,
    ) {
        if dt <= 0.0 {
            return;
        }
        let n = self.n();
        let ba = self.accel_bias();
        // The true heading: the given attitude turned back by its heading error.
        let rot = &self.true_rotation(rot);
        let u = rot * (f_body - ba);
        let a = u - Vector3::new(0.0, 0.0, GRAVITY);
        let k = (dt / (ACCEL_SMOOTH_TAU_S + dt)).min(1.0);
        self.accel_world += (a - self.accel_world) * k;
        let phi_v = if self.velocity_tau_s.is_finite() {
            (-dt / self.velocity_tau_s.max(1e-3)).exp()
        } else {
            1.0
        };
        // Metres flown over the step, by which the drift per metre moves the position's
        // uncertainty (its estimate is nil). Where a camera measures the position, its
        // offset's random walk is the drift: both, and a flow and a camera's fused
        // track went 0.03 → 0.23 m off.
        let flown = self.x[IDX_V].hypot(self.x[IDX_V + 1]) * dt;
        let drift = self.drift_state().filter(|_| !self.has_odometry());
        let p = self.pos() + self.vel() * dt + a * (0.5 * dt * dt);
        let v = self.vel() * phi_v + a * dt;
        self.x.fixed_rows_mut::<3>(IDX_P).copy_from(&p);
        self.x.fixed_rows_mut::<3>(IDX_V).copy_from(&v);

        let phi = (-dt / self.gnss_bias_tau_s.max(1e-3)).exp();
        for i in 0..3 {
            self.x[IDX_BG + i] *= phi;
        }
        // P ← F P Fᵀ. F is the identity but for the p and v rows (their v and b_a
        // columns) and the b_g diagonal, so F P changes 9 rows of P and (F P) Fᵀ the same
        // 9 columns: O(n) work per row instead of two dense n³ products and their
        // allocations (the IMU runs this at its full rate).
        // d(Rz(−ψ)·u)/dψ = (u_y, −u_x, 0): the specific force turned by the heading error.
        let turn = Vector3::new(u.y, -u.x, 0.0);
        let phi_yaw = (-dt / self.yaw_error_tau_s.max(1e-3)).exp();
        self.x[IDX_YAW] *= phi_yaw;
        let f = Transition {
            dt,
            p_ba: -rot * (0.5 * dt * dt),
            v_ba: -rot * dt,
            p_yaw: turn * (0.5 * dt * dt),
            v_yaw: turn * dt,
            phi,
            phi_yaw,
            phi_v,
            drift: drift.map(|i| (i, flown)),
        };
        f.apply_to_columns(self.p.as_mut_slice(), n);
        f.apply_to_rows(self.p.as_mut_slice(), n);
        // Process noise: white specific force over the step, bias and drift random walks.
        let next = &mut self.p;
        let q = accel_var;
        for i in 0..3 {
            next[(IDX_P + i, IDX_P + i)] += q * dt.powi(4) / 4.0;
            next[(IDX_P + i, IDX_V + i)] += q * dt.powi(3) / 2.0;
            next[(IDX_V + i, IDX_P + i)] += q * dt.powi(3) / 2.0;
            next[(IDX_V + i, IDX_V + i)] += q * dt * dt;
            // A velocity random walk: rate-independent, whatever the IMU's rate.
            let w = self.vel_q_extra[i];
            next[(IDX_P + i, IDX_P + i)] += w * dt.powi(3) / 3.0;
            next[(IDX_P + i, IDX_V + i)] += w * dt * dt / 2.0;
            next[(IDX_V + i, IDX_P + i)] += w * dt * dt / 2.0;
            next[(IDX_V + i, IDX_V + i)] += w * dt;
            next[(IDX_BA + i, IDX_BA + i)] += bias_rw * bias_rw * dt;
        }
        // Speed over the ground (EKF2's terrain process noise; a move nobody saw, a carry,
        // is accounted for when the vehicle is set down: see `add_terrain_uncertainty`).
        let speed = self.x[IDX_V].hypot(self.x[IDX_V + 1]);
        let terrain_q = self.terrain_rw.powi(2) + (self.terrain_gradient * speed).powi(2);
        next[(IDX_TERRAIN, IDX_TERRAIN)] += terrain_q * dt;
        for i in 0..3 {
            next[(IDX_BG + i, IDX_BG + i)] += self.gnss_bias_std[i].powi(2) * (1.0 - phi * phi);
        }
        next[(IDX_YAW, IDX_YAW)] += self.yaw_error_std.powi(2) * (1.0 - phi_yaw * phi_yaw);
        for &(_, idx) in &self.delays {
            next[(idx, idx)] += self.delay_rw * self.delay_rw * dt;
        }
        for &(_, idx) in &self.align_yaws {
            next[(idx, idx)] += self.align_yaw_rw * self.align_yaw_rw * dt;
        }
        for &(_, idx) in &self.scales {
            next[(idx, idx)] += self.scale_rw * self.scale_rw * dt;
            next[(idx + 1, idx + 1)] += self.heading_rw * self.heading_rw * dt;
        }
        for (source, idx) in &self.blocks {
            let (rw, idx) = (drift_rw(source), *idx);
            for i in 0..3 {
                next[(idx + i, idx + i)] += rw * rw * dt;
            }
        }
        // The compensation gyro bias errors fade as the bias is learnt: F's diagonal
        // φ there, no noise (what is learnt is what they lose).
        for &(_, idx, tau) in &self.gyro_biases {
            if !tau.is_finite() {
                continue;
            }
            let phi = (-dt / tau.max(1e-3)).exp();
            let n = self.p.nrows();
            for k in idx..idx + 2 {
                self.x[k] *= phi;
                for j in 0..n {
                    self.p[(k, j)] *= phi;
                }
                for j in 0..n {
                    self.p[(j, k)] *= phi;
                }
            }
        }
        // Only the entries between two changed states can have lost their symmetry: an
        // entry between a changed and an unchanged state got the same arithmetic on the
        // same operands in both passes, and the noise is added symmetrically.
        self.symmetrise_among(&Transition::CHANGED);
    }

    /// Measurement update: innovation, Jacobian and noise in `m`. Rejected (state
    /// untouched) when the NIS exceeds `gate` (a chi² threshold for as many degrees of
    /// freedom as `m` has rows), unless `force`. Allocates nothing up to
    /// [`STACK_STATES`] states.
    pub fn update(&mut self, m: &Measurement, gate: f64, force: bool) -> UpdateOutcome {
        match m.rows() {
            1 => self.update_rows::<1>(m, gate, force),
            2 => self.update_rows::<2>(m, gate, force),
            _ => self.update_rows::<3>(m, gate, force),
        }
    }

    /// [`Self::update`] for an `M`-row measurement: S and its Cholesky factor are
    /// fixed-size, P·Hᵀ and the gain are n×M on the stack.
    fn update_rows<const M: usize>(
        &mut self,
        m: &Measurement,
        gate: f64,
        force: bool,
    ) -> UpdateOutcome {
        let n = self.n();
        with_scratch(3 * n * M, |scratch| {
            let (pht, rest) = scratch.split_at_mut(n * M);
            let (k, kl) = rest.split_at_mut(n * M);
            let (out, chol) = self.test_rows::<M>(m, gate, force, pht);
            let Some(mut chol) = chol.filter(|_| out.accepted) else {
                return out;
            };
            if !m.replaced().is_empty() {
                // Gated against the prior; now the replaced states start from nothing.
                // (S stays positive definite: P does, and the replaced rows' 1e6 only
                // adds to it; a non-finite P is the one way out, said as refused.)
                self.forget(m.replaced(), REPLACED_PRIOR_VAR);
                match self.test_rows::<M>(m, gate, true, pht).1 {
                    Some(c) => chol = c,
                    None => {
                        return UpdateOutcome {
                            accepted: false,
                            ..out
                        }
                    }
                }
            }
            let y = SVector::<f64, M>::from_fn(|i, _| m.innovation()[i]);
            // K = P Hᵀ S⁻¹, row j of it S⁻¹ (H P)[:, j] (S and P symmetric).
            for j in 0..n {
                let mut row = SVector::<f64, M>::from_fn(|c, _| pht[c * n + j]);
                chol.solve_mut(&mut row);
                for c in 0..M {
                    k[c * n + j] = row[c];
                }
            }
            // Consider states are not corrected: their gain rows are zero. Nor is the
            // drift per metre, by anything: a flow and an IMU do not see it, and the
            // positions given without a camera or a GNSS (an anchor, a hold) would
            // teach it wrong.
            let drift = self.drift_state().map(|i| [i, i + 1]);
            let consider = m.considered();
            for &j in consider.iter().chain(drift.iter().flatten()) {
                for c in 0..M {
                    k[c * n + j] = 0.0;
                }
            }
            // x += K y, summed by K's columns.
            let x = self.x.as_mut_slice();
            for (j, xj) in x.iter_mut().enumerate() {
                let mut dx = k[j] * y[0];
                for c in 1..M {
                    dx += k[c * n + j] * y[c];
                }
                *xj += dx;
            }
            if !consider.is_empty() || drift.is_some() {
                // A gain that is not optimal (Schmidt's): the full Joseph form, P − K H P
                // − (K H P)ᵀ + K S Kᵀ, S = L Lᵀ.
                let l = chol.l();
                // K L, once (column e at e·n), for K S Kᵀ = (K L)(K L)ᵀ.
                for e in 0..M {
                    for i in 0..n {
                        kl[e * n + i] = (0..M).map(|c| k[c * n + i] * l[(c, e)]).sum();
                    }
                }
                let p = self.p.as_mut_slice();
                for j in 0..n {
                    for i in 0..n {
                        let mut d = 0.0;
                        for c in 0..M {
                            d += k[c * n + i] * pht[c * n + j] + pht[c * n + i] * k[c * n + j];
                        }
                        for e in 0..M {
                            d -= kl[e * n + i] * kl[e * n + j];
                        }
                        p[j * n + i] -= d;
                    }
                }
                self.symmetrise();
                return out;
            }
            // P ← P − K H P: with the optimal gain this is the Joseph form
            // (I − KH) P (I − KH)ᵀ + K R Kᵀ, at O(n² m) instead of three n³
            // products; symmetrising and the variance floor keep it well formed, as
            // in EKF2. (H P)[c, j] is (P Hᵀ)[j, c].
            let p = self.p.as_mut_slice();
            for (j, column) in p.chunks_exact_mut(n).enumerate() {
                for c in 0..M {
                    let hp = pht[c * n + j];
                    let kc = &k[c * n..(c + 1) * n];
                    for (pij, kic) in column.iter_mut().zip(kc) {
                        *pij -= kic * hp;
                    }
                }
            }
            self.symmetrise();
            out
        })
    }

    /// The gate test of an `M`-row measurement, the state untouched: the outcome (the
    /// update would go in when it says accepted) and S's Cholesky factor (None when S
    /// is not positive definite); P·Hᵀ is left in `pht` (n×M).
    fn test_rows<const M: usize>(
        &self,
        m: &Measurement,
        gate: f64,
        force: bool,
        pht: &mut [f64],
    ) -> (UpdateOutcome, Option<Cholesky<f64, Const<M>>>) {
        let n = self.n();
        assert!(
            m.max_state().is_none_or(|s| s < n),
            "the measurement reads a state the filter does not have"
        );
        self.p_ht::<M>(m, pht);
        let s = innovation_cov::<M>(m, pht, n);
        let mut out = UpdateOutcome {
            rows: M,
            innovation: [0.0; MAX_ROWS],
            innovation_var: [0.0; MAX_ROWS],
            nis: f64::INFINITY,
            test_ratio: f64::INFINITY,
            accepted: false,
        };
        out.innovation[..M].copy_from_slice(m.innovation());
        for i in 0..M {
            out.innovation_var[i] = s[(i, i)];
        }
        let Some(chol) = Cholesky::new(s) else {
            return (out, None);
        };
        let y = SVector::<f64, M>::from_fn(|i, _| m.innovation()[i]);
        out.nis = dot(y.as_slice(), chol.solve(&y).as_slice());
        out.test_ratio = if gate > 0.0 { out.nis / gate } else { 0.0 };
        out.accepted = out.nis.is_finite() && (force || out.test_ratio <= 1.0);
        (out, Some(chol))
    }

    /// What [`Self::update`] would say of `m` (its innovation, variances, test ratio,
    /// acceptance), the state untouched: a source health has taken out is still tested.
    pub fn innovation_test(&self, m: &Measurement, gate: f64) -> UpdateOutcome {
        fn test<const M: usize>(ekf: &Ekf, m: &Measurement, gate: f64) -> UpdateOutcome {
            with_scratch(ekf.n() * M, |pht| ekf.test_rows::<M>(m, gate, false, pht).0)
        }
        match m.rows() {
            1 => test::<1>(self, m, gate),
            2 => test::<2>(self, m, gate),
            _ => test::<3>(self, m, gate),
        }
    }

    /// `P·Hᵀ` (n×M, column-major, into `out`) over H's non-zero entries: column i is
    /// Σ_k H[i,k]·P[:,k] (P symmetric), O(nnz·n) where the dense product is O(m·n²).
    fn p_ht<const M: usize>(&self, m: &Measurement, out: &mut [f64]) {
        let n = self.n();
        let p = self.p.as_slice();
        for (i, col) in out.chunks_exact_mut(n).enumerate().take(M) {
            col.fill(0.0);
            for (k, hik) in m.jacobian_row(i).entries() {
                for (o, pk) in col.iter_mut().zip(&p[k * n..(k + 1) * n]) {
                    *o += hik * pk;
                }
            }
        }
    }

    /// Make P exactly symmetric and keep its diagonal above a tiny floor.
    pub fn symmetrise(&mut self) {
        let n = self.n();
        let p = self.p.as_mut_slice();
        for j in 0..n {
            for i in (j + 1)..n {
                let m = 0.5 * (p[i + j * n] + p[j + i * n]);
                p[i + j * n] = m;
                p[j + i * n] = m;
            }
            if p[j + j * n] < VAR_FLOOR {
                p[j + j * n] = VAR_FLOOR;
            }
        }
    }

    /// [`Self::symmetrise`] where only the entries among `states` can be asymmetric.
    fn symmetrise_among(&mut self, states: &[usize]) {
        let n = self.n();
        let p = self.p.as_mut_slice();
        for (a, &j) in states.iter().enumerate() {
            for &i in &states[a + 1..] {
                let m = 0.5 * (p[i + j * n] + p[j + i * n]);
                p[i + j * n] = m;
                p[j + i * n] = m;
            }
        }
        for j in 0..n {
            if p[j + j * n] < VAR_FLOOR {
                p[j + j * n] = VAR_FLOOR;
            }
        }
    }

    /// Add or restart the offset block of an odometry source: b = 0, correlated with p
    /// so that the source carries only relative information from here on.
    pub fn start_block(&mut self, source: &str) -> usize {
        let idx = match self.block(source) {
            Some(i) => i,
            None => {
                let n = self.n();
                self.grow(3);
                self.blocks.push((source.to_string(), n));
                n
            }
        };
        let n = self.n();
        for i in 0..3 {
            self.x[idx + i] = 0.0;
        }
        // b = -δp: Cov(b, x) = -Cov(p, x) for every other state, Var(b) = Var(p).
        let p_rows = self.p.rows(IDX_P, 3).into_owned();
        for j in 0..n {
            if (idx..idx + 3).contains(&j) {
                continue;
            }
            for i in 0..3 {
                self.p[(idx + i, j)] = -p_rows[(i, j)];
                self.p[(j, idx + i)] = -p_rows[(i, j)];
            }
        }
        let ppp = self.cov3(IDX_P);
        self.p.view_mut((idx, idx), (3, 3)).copy_from(&ppp);
        self.symmetrise();
        idx
    }

    /// The index of `source`'s scale error (its heading error at the next), added
    /// (both 0, variances `scale_var` and `heading_var`, uncorrelated) on first use.
    pub fn scale_state(&mut self, source: &str, scale_var: f64, heading_var: f64) -> usize {
        if let Some(i) = self.scale_of(source) {
            return i;
        }
        let n = self.n();
        self.grow(2);
        self.p[(n, n)] = scale_var;
        self.p[(n + 1, n + 1)] = heading_var;
        self.scales.push((source.to_string(), n));
        n
    }

    /// The world frame moved by an uncertain amount (covariance `s`), e.g. when GNSS
    /// anchors a frame that started at the take-off pose: p and the terrain (world
    /// points) share the error, every odometry offset has it with the opposite sign.
    pub fn add_frame_uncertainty(&mut self, s: &Matrix3<f64>) {
        let n = self.n();
        let mut j: DMatrix<f64> = DMatrix::zeros(n, 3);
        j.view_mut((IDX_P, 0), (3, 3))
            .copy_from(&Matrix3::identity());
        j[(IDX_TERRAIN, 2)] = 1.0;
        for &(_, idx) in &self.blocks {
            j.view_mut((idx, 0), (3, 3))
                .copy_from(&(-Matrix3::identity()));
        }
        let sd = DMatrix::from_iterator(3, 3, s.iter().copied());
        self.p += &j * sd * j.transpose();
        self.symmetrise();
    }

    /// The filter was just started at a GNSS fix: its position's error is the fix's, whose slow part (variance
    /// `slow_var` per axis) is what the bias states hold, so `cov(p, b) = −P_bb` as in
    /// [`Self::reset_pos_vel_through_bias`]. Without it one fix counted twice, as the
    /// position's prior and as the bias's, and the first minute's fixes "separated"
    /// them: randomised draw 95's σ up fell from 3.3 to 1.8 m in 20 s with its height
    /// 9 m off for the whole flight. The bias was never fused before: its prior is
    /// `slow_var`.
    pub fn tie_to_gnss_bias(&mut self, slow_var: Vector3<f64>) {
        let n = self.n();
        for i in 0..3 {
            let (p, b) = (IDX_P + i, IDX_BG + i);
            let var = slow_var[i].max(0.0);
            for j in 0..n {
                self.p[(b, j)] = 0.0;
                self.p[(j, b)] = 0.0;
            }
            self.p[(b, b)] = var;
            // At most the position's own variance: the joint covariance stays positive.
            let c = -var.min(self.p[(p, p)]);
            self.p[(p, b)] = c;
            self.p[(b, p)] = c;
        }
        self.symmetrise();
    }

    /// The GNSS slow error is at least `std` uncertain per axis (a receiver that may be
    /// as wrong as a jump the filter was reset over): its variance only grows.
    pub fn widen_gnss_bias(&mut self, std: &Vector3<f64>) {
        for i in 0..3 {
            let k = IDX_BG + i;
            self.p[(k, k)] = self.p[(k, k)].max(std[i] * std[i]);
        }
    }

    /// The frame's heading became uncertain by `var` (rad²): a frame that started at
    /// the take-off heading the autopilot gave is anchored to the geographic one by
    /// GNSS. The heading error of the attitude is now relative to north, and the
    /// velocity, kept in the old axes, turns with it, and so does every odometry
    /// alignment made in them (the position does not: the origin is placed where the
    /// vehicle is).
    /// How the errors move when the frame turns by a small angle: the heading error by
    /// it, the velocity (kept in the frame's axes) across itself, and every odometry
    /// alignment made in those axes by it too. An odometry aligned in the old axes is
    /// off north by the same angle: a camera aligned before the first fix, its
    /// alignment error left at 0.6°, held the heading to the old frame's: the yaw
    /// crept 7.5° towards north in 16 s with σ 0.6°, and the GNSS was excluded for
    /// disagreeing with the camera (randomised draw 251: 312 poses beyond 5σ).
    fn frame_turn(&self) -> DVector<f64> {
        let v = self.vel();
        let mut j = DVector::zeros(self.n());
        j[IDX_YAW] = 1.0;
        j[IDX_V] = -v.y;
        j[IDX_V + 1] = v.x;
        for &(_, i) in &self.align_yaws {
            j[i] = 1.0;
        }
        j
    }

    pub fn add_heading_uncertainty(&mut self, var: f64) {
        if !(var.is_finite() && var > 0.0) {
            return;
        }
        let j = self.frame_turn();
        self.p += &j * j.transpose() * var;
        self.symmetrise();
    }

    /// What an accelerometer off by `accel` (m/s², 1σ) for the last `gap_s` could have
    /// done on the world `axes`: the velocity off by a·T, the position by a·T²/2, and
    /// the bias that would learn it as uncertain as the fault (body axes, taken level:
    /// x and y for the horizontal, z for the up). Uncorrelated: when the fault began
    /// in the gap nobody knows, so the velocity measured after it does not say what
    /// it did to the position (taken as one error from the gap's start, a flow back
    /// after 13 s moved the position by its velocity's half-gap, 24 m the wrong way).
    pub fn add_dead_reckoning_fault(&mut self, axes: &[usize], accel: f64, gap_s: f64) {
        let (dv, dp) = (accel * gap_s, 0.5 * accel * gap_s * gap_s);
        for &a in axes {
            let (p, v, b) = (IDX_P + a, IDX_V + a, IDX_BA + a);
            self.p[(p, p)] += dp * dp;
            self.p[(v, v)] += dv * dv;
            self.p[(b, b)] += accel * accel;
        }
        self.symmetrise();
    }

    /// The states `idx` forget what they knew: variance `var`, uncorrelated with the
    /// rest (what a reset to a measurement starts from).
    pub fn forget(&mut self, idx: &[usize], var: f64) {
        let n = self.n();
        for &i in idx {
            for j in 0..n {
                self.p[(i, j)] = 0.0;
                self.p[(j, i)] = 0.0;
            }
            self.p[(i, i)] = var;
        }
        self.symmetrise();
    }

    /// Set position and velocity (a reset): the new values are uncorrelated with the
    /// rest and have the given variances. Odometry blocks must be restarted afterwards.
    pub fn reset_pos_vel(
        &mut self,
        pos: Vector3<f64>,
        vel: Option<Vector3<f64>>,
        pos_var: Vector3<f64>,
        vel_var: f64,
    ) {
        let n = self.n();
        let mut idx: Vec<usize> = (0..3).map(|i| IDX_P + i).collect();
        self.x.fixed_rows_mut::<3>(IDX_P).copy_from(&pos);
        if let Some(v) = vel {
            self.x.fixed_rows_mut::<3>(IDX_V).copy_from(&v);
            idx.extend((0..3).map(|i| IDX_V + i));
        }
        for &i in &idx {
            for j in 0..n {
                self.p[(i, j)] = 0.0;
                self.p[(j, i)] = 0.0;
            }
        }
        for i in 0..3 {
            self.p[(IDX_P + i, IDX_P + i)] = pos_var[i];
            if vel.is_some() {
                self.p[(IDX_V + i, IDX_V + i)] = vel_var;
            }
        }
        self.symmetrise();
    }

    /// [`Self::reset_pos_vel`] to a GNSS fix `z` that carries the slow error the bias
    /// states hold: the position is `z − b`, so its variance is the fix's plus the
    /// bias's, and it is correlated with the bias (`cov(p, b) = −P_bb`). Without that
    /// the reset position claimed the fix's white noise alone (the link-loss flight: 1.3 m
    /// off for seconds with σ 0.5 m).
    pub fn reset_pos_vel_through_bias(
        &mut self,
        z: Vector3<f64>,
        vel: Option<Vector3<f64>>,
        fix_var: Vector3<f64>,
        vel_var: f64,
    ) {
        let bias = self.x.fixed_rows::<3>(IDX_BG).into_owned();
        // The bias rows before the reset (their bias block is P_bb).
        let p_bx = self.p.rows(IDX_BG, 3).into_owned();
        self.reset_pos_vel(z - bias, vel, fix_var, vel_var);
        let n = self.n();
        let was_reset = |j: usize| {
            (IDX_P..IDX_P + 3).contains(&j) || (vel.is_some() && (IDX_V..IDX_V + 3).contains(&j))
        };
        // p = z − b: its covariance with every other state is minus the bias's.
        for i in 0..3 {
            for j in (0..n).filter(|&j| !was_reset(j)) {
                let c = -p_bx[(i, j)];
                self.p[(IDX_P + i, j)] = c;
                self.p[(j, IDX_P + i)] = c;
            }
            for k in 0..3 {
                self.p[(IDX_P + i, IDX_P + k)] += p_bx[(i, IDX_BG + k)];
            }
        }
        self.symmetrise();
    }

    /// Where the position and velocity would go if `m` were exact: `P Hᵀ (H P Hᵀ)⁻¹ y`
    /// on them, the filter's own correlations sharing the innovation out. What the
    /// estimate is wrong by if a measurement it refused was the truth. None when
    /// `H P Hᵀ` is singular. Allocates nothing (it runs on every refused sample).
    pub fn shift_if_exact(&self, m: &Measurement) -> Option<(Vector3<f64>, Vector3<f64>)> {
        fn shift<const M: usize>(
            ekf: &Ekf,
            m: &Measurement,
        ) -> Option<(Vector3<f64>, Vector3<f64>)> {
            let n = ekf.n();
            with_scratch(n * M, |pht| {
                ekf.p_ht::<M>(m, pht);
                let s = h_p_ht::<M>(m, pht, n) + SMatrix::<f64, M, M>::identity() * VAR_FLOOR;
                let y = SVector::<f64, M>::from_fn(|i, _| m.innovation()[i]);
                let a = Cholesky::new(s)?.solve(&y);
                let at = |k: usize| (0..M).map(|j| pht[j * n + k] * a[j]).sum::<f64>();
                let (p, v) = (
                    Vector3::from_fn(|i, _| at(IDX_P + i)),
                    Vector3::from_fn(|i, _| at(IDX_V + i)),
                );
                (all_finite(p.as_slice()) && all_finite(v.as_slice())).then_some((p, v))
            })
        }
        match m.rows() {
            1 => shift::<1>(self, m),
            2 => shift::<2>(self, m),
            _ => shift::<3>(self, m),
        }
    }

    /// The normalised innovation test ratio a measurement would get (NIS / gate), without
    /// updating: infinite when S is singular.
    pub fn test_ratio(&self, m: &Measurement, gate: f64) -> f64 {
        self.innovation_test(m, gate).test_ratio
    }

    /// A terrain reset: the ground under the vehicle is `height` (m) below it, with the
    /// reading's variance `var`. The terrain is the vehicle's height minus that, so it
    /// is as uncertain as the height is (plus the reading) and moves with it: its row
    /// is the height's. Setting it uncorrelated with the reading's variance alone
    /// claimed the ground's absolute height known to centimetres; the next range
    /// reading then collapsed σz from 1.8 m to 5 cm over a 4.9 m error (randomised
    /// flight 874 of seed 1). The vehicle's position is untouched.
    pub fn reset_terrain(&mut self, height: f64, var: f64) {
        let (z, tr) = (IDX_P + 2, IDX_TERRAIN);
        self.x[tr] = self.x[z] - height;
        for j in 0..self.n() {
            let c = self.p[(z, j)];
            self.p[(tr, j)] = c;
            self.p[(j, tr)] = c;
        }
        self.p[(tr, tr)] = self.p[(z, z)] + var;
        self.symmetrise();
    }

    /// The terrain under the vehicle is less known by `var` (m²): it moved by an amount
    /// nobody measured.
    pub fn add_terrain_uncertainty(&mut self, var: f64) {
        if var.is_finite() && var > 0.0 {
            self.p[(IDX_TERRAIN, IDX_TERRAIN)] += var;
        }
    }

    /// Height of the vehicle above the terrain state, m: what a downward range finder
    /// measures (times the tilt cosine), with Jacobian [`h_height`].
    pub fn height_above_terrain(&self) -> f64 {
        self.x[IDX_P + 2] - self.x[IDX_TERRAIN]
    }

    /// The variance of [`Self::height_above_terrain`], m².
    pub fn height_above_terrain_var(&self) -> f64 {
        let (z, t) = (IDX_P + 2, IDX_TERRAIN);
        self.p[(z, z)] + self.p[(t, t)] - 2.0 * self.p[(z, t)]
    }

    /// The frame re-anchored at `at` (E, N) and at the heading the filter has now: the
    /// position is put there, and its horizontal error and the heading's are nil from
    /// here by definition of the frame (a change of variables, not a measurement: the
    /// frame moves by the position's error and turns about it by the heading's). The
    /// velocity, kept in the turned axes, and every odometry alignment made in them
    /// turn with it (as [`Self::add_heading_uncertainty`] turns them the other way);
    /// the odometry offsets keep what their sources measure (position + offset), and
    /// take the position's move and error. The other states keep their uncertainty.
    pub fn anchor_frame(&mut self, at: [f64; 2]) {
        let n = self.n();
        // Heading: ε' = ε − j·ε_ψ, j the direction a turn of the frame moves the errors.
        let j = self.frame_turn();
        let mut t: DMatrix<f64> = DMatrix::identity(n, n);
        for i in 0..n {
            t[(i, IDX_YAW)] -= j[i];
        }
        // Position: ε_p' = 0, each offset's error takes the position's.
        for (a, &to) in at.iter().enumerate() {
            let i = IDX_P + a;
            let d = to - self.x[i];
            self.x[i] = to;
            for &(_, idx) in &self.blocks {
                self.x[idx + a] -= d;
                let row = t.row(i).into_owned();
                let mut r = t.row_mut(idx + a);
                r += row;
            }
            t.row_mut(i).fill(0.0);
        }
        self.p = &t * &self.p * t.transpose();
        for i in [IDX_P, IDX_P + 1, IDX_YAW] {
            self.p[(i, i)] = VAR_FLOOR;
        }
        self.symmetrise();
    }

    /// Shift the position (origin reset); the covariance is unchanged.
    pub fn shift_position(&mut self, d: Vector3<f64>) {
        let p = self.pos() + d;
        self.x.fixed_rows_mut::<3>(IDX_P).copy_from(&p);
    }
}

/// The state transition of one IMU step, by its non-identity parts: p += v·dt +
/// p_ba·b_a + p_yaw·ψ_a, v ← phi_v·v + v_ba·b_a + v_yaw·ψ_a, b_g *= phi, ψ_a *= phi_yaw.
struct Transition {
    dt: f64,
    p_ba: Matrix3<f64>,
    v_ba: Matrix3<f64>,
    p_yaw: Vector3<f64>,
    v_yaw: Vector3<f64>,
    phi: f64,
    phi_yaw: f64,
    /// The velocity's decay over the step (1 while an IMU drives the prediction).
    phi_v: f64,
    /// The drift per metre's index and the metres flown over the step: p += d·flown.
    drift: Option<(usize, f64)>,
}

impl Transition {
    /// The states whose rows (and columns) F changes: p, v, b_g and ψ_a.
    const CHANGED: [usize; 10] = [
        IDX_P,
        IDX_P + 1,
        IDX_P + 2,
        IDX_V,
        IDX_V + 1,
        IDX_V + 2,
        IDX_BG,
        IDX_BG + 1,
        IDX_BG + 2,
        IDX_YAW,
    ];

    /// One line (a column of F·m, or a row of m·Fᵀ: the same operation on the
    /// transpose), given by `at(k)`, the index in storage of its k-th element.
    #[inline(always)]
    fn apply(&self, m: &mut [f64], at: impl Fn(usize) -> usize) {
        let v = Vector3::new(m[at(IDX_V)], m[at(IDX_V + 1)], m[at(IDX_V + 2)]);
        let ba = Vector3::new(m[at(IDX_BA)], m[at(IDX_BA + 1)], m[at(IDX_BA + 2)]);
        let yaw = m[at(IDX_YAW)];
        let mut dp = v * self.dt + self.p_ba * ba + self.p_yaw * yaw;
        if let Some((i, flown)) = self.drift {
            dp.x += m[at(i)] * flown;
            dp.y += m[at(i + 1)] * flown;
        }
        let dv = self.v_ba * ba + self.v_yaw * yaw;
        for i in 0..3 {
            m[at(IDX_P + i)] += dp[i];
            m[at(IDX_V + i)] = v[i] * self.phi_v + dv[i];
            m[at(IDX_BG + i)] *= self.phi;
        }
        m[at(IDX_YAW)] = yaw * self.phi_yaw;
    }

    /// m ← F·m for the n×n column-major `m`: each column is contiguous.
    fn apply_to_columns(&self, m: &mut [f64], n: usize) {
        for column in m.chunks_exact_mut(n) {
            self.apply(column, |k| k);
        }
    }

    /// m ← m·Fᵀ for the n×n column-major `m`.
    fn apply_to_rows(&self, m: &mut [f64], n: usize) {
        assert!(m.len() >= n * CORE_STATES);
        for row in 0..n {
            self.apply(m, |k| row + k * n);
        }
    }
}

/// See [`Ekf::doubt_under_misfit`]: the accelerometer bias's variance is at least the
/// learnt prediction noise over this long, s.
pub const BIAS_MISFIT_S: f64 = 1.0;
/// The learnt velocity random walk, m²/s³, at which every delay state is as uncertain
/// as its prior (0.3 m/s/√s: an IMU prediction that misses that much has taught the
/// delays nothing worth keeping). At 0.01 the real log 14-11-2014_118 was valid 18 %
/// of the time instead of 39 %; the square above is the same at either.
pub const Q_MODEL_WRONG: f64 = 0.1;

/// Time constant of the world acceleration a delay is judged by, s.
pub const ACCEL_SMOOTH_TAU_S: f64 = 0.1;

/// Rotation about the vertical by `yaw`, rad.
pub fn yaw_rotation(yaw: f64) -> Matrix3<f64> {
    let (s, c) = yaw.sin_cos();
    Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
}

/// P·Hᵀ, the gain and (a considered state's update) K·L of a filter this large fit on
/// the stack (14 core states and 16 odometry sources); a larger one takes them from the
/// heap.
pub const STACK_STATES: usize = 64;

/// Runs `f` on `len` zeroed scratch values: on the stack up to [`STACK_STATES`]·3·3.
fn with_scratch<R>(len: usize, f: impl FnOnce(&mut [f64]) -> R) -> R {
    const STACK: usize = 3 * STACK_STATES * MAX_ROWS;
    if len <= STACK {
        let mut buf = [0.0; STACK];
        f(&mut buf[..len])
    } else {
        f(&mut vec![0.0; len])
    }
}

/// H (P Hᵀ) as summed, not yet symmetric; `pht` is n×M column-major.
fn h_p_ht_raw<const M: usize>(m: &Measurement, pht: &[f64], n: usize) -> SMatrix<f64, M, M> {
    let mut s = SMatrix::<f64, M, M>::zeros();
    for i in 0..M {
        for (k, hik) in m.jacobian_row(i).entries() {
            for j in 0..M {
                s[(i, j)] += hik * pht[j * n + k];
            }
        }
    }
    s
}

/// H (P Hᵀ), made exactly symmetric: what the state's uncertainty alone puts into the
/// innovation.
fn h_p_ht<const M: usize>(m: &Measurement, pht: &[f64], n: usize) -> SMatrix<f64, M, M> {
    let s = h_p_ht_raw::<M>(m, pht, n);
    (s + s.transpose()) * 0.5
}

/// S = H (P Hᵀ) + R, made exactly symmetric.
fn innovation_cov<const M: usize>(m: &Measurement, pht: &[f64], n: usize) -> SMatrix<f64, M, M> {
    let mut s = h_p_ht_raw::<M>(m, pht, n);
    for i in 0..M {
        for j in 0..M {
            s[(i, j)] += m.noise(i, j);
        }
    }
    (s + s.transpose()) * 0.5
}

/// Σ a_i·b_i in order.
fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).fold(0.0, |acc, (x, y)| acc + x * y)
}

// ---- chi² gate ----------------------------------------------------------------------

fn erfc(x: f64) -> f64 {
    // Numerical Recipes erfcc (Chebyshev), fractional error < 1.2e-7.
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let ans = t
        * (-z * z - 1.265_512_23
            + t * (1.000_023_68
                + t * (0.374_091_96
                    + t * (0.096_784_18
                        + t * (-0.186_288_06
                            + t * (0.278_868_07
                                + t * (-1.135_203_98
                                    + t * (1.488_515_87
                                        + t * (-0.822_152_23 + t * 0.170_872_77)))))))))
            .exp();
    if x >= 0.0 {
        ans
    } else {
        2.0 - ans
    }
}

/// Regularised lower incomplete gamma P(k/2, x/2) = chi² CDF with k degrees of freedom.
pub fn chi2_cdf(k: usize, x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    if k == 1 {
        return 1.0 - erfc((x / 2.0).sqrt());
    }
    let a = k as f64 / 2.0;
    let hx = x / 2.0;
    // Series: P(a, x) = x^a e^-x / Γ(a+1) Σ x^n / ((a+1)…(a+n)).
    let mut gamma_a1 = 1.0; // Γ(a + 1) for integer or half-integer a.
    let mut m = a;
    while m > 0.6 {
        gamma_a1 *= m;
        m -= 1.0;
    }
    if (m - 0.5).abs() < 1e-9 {
        gamma_a1 *= 0.5 * std::f64::consts::PI.sqrt();
    }
    let mut term = 1.0;
    let mut sum = 1.0;
    for n in 1..500 {
        term *= hx / (a + n as f64);
        sum += term;
        if term < sum * 1e-16 {
            break;
        }
    }
    (hx.powf(a) * (-hx).exp() / gamma_a1 * sum).min(1.0)
}

/// The chi² quantile with `k` degrees of freedom that has the same tail probability as
/// a `sigma` standard-deviation gate in one dimension (5σ → 25 for k = 1, 31.8 for 3).
pub fn chi2_gate(k: usize, sigma: f64) -> f64 {
    let p = 1.0 - erfc(sigma / std::f64::consts::SQRT_2);
    if k <= 1 {
        return sigma * sigma;
    }
    let (mut lo, mut hi) = (0.0, 1000.0);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if chi2_cdf(k, mid) < p {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Every value finite, looked at with integer operations that vectorise (the whole
/// covariance is checked with every pose): a finite double's exponent bits, plus one
/// in their lowest place, stay below the sign bit; an infinity's or a NaN's carry into it.
fn all_finite(v: &[f64]) -> bool {
    const EXPONENT: u64 = 0x7ff0_0000_0000_0000;
    const EXPONENT_ONE: u64 = 1 << 52;
    let carried = v.iter().fold(0_u64, |acc, x| {
        acc | ((x.to_bits() & EXPONENT) + EXPONENT_ONE)
    });
    carried >> 63 == 0
}

/// The state index a per-source list gives `source`, if it has one.
fn index_of(list: &[(String, usize)], source: &str) -> Option<usize> {
    list.iter().find(|(s, _)| s == source).map(|&(_, i)| i)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn all_finite_is_the_standard_librarys_is_finite_on_every_kind_of_double() {
        let values = [
            0.0,
            -0.0,
            1.0,
            -1e300,
            f64::MAX,
            f64::MIN,
            f64::MIN_POSITIVE,
            5e-324,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            -f64::NAN,
        ];
        for v in values {
            assert_eq!(all_finite(&[1.0, v, 2.0]), v.is_finite(), "{v:e}");
        }
        assert!(all_finite(&[]));
        let mut long = vec![0.5; 600];
        assert!(all_finite(&long));
        long[577] = f64::NAN;
        assert!(!all_finite(&long));
    }

    /// A delay is held within ±max, and never below its source's floor (a sample is not
    /// measured after it arrived): the camera's −0.3 s is its −6 ms latency, the flow's
    /// 0.5 s the bound, and a source without a floor keeps what is within the bounds.
    #[test]
    fn a_delay_is_held_above_its_floor_and_within_its_bound() {
        let mut ekf = unit_filter();
        let (cam, flow, gnss) = (
            ekf.delay_state("t265", 0.01),
            ekf.delay_state("flow", 0.01),
            ekf.delay_state("gps", 0.01),
        );
        ekf.x[cam] = -0.3;
        ekf.x[flow] = 0.5;
        ekf.x[gnss] = -0.3;
        ekf.constrain_delays(0.4, |s| match s {
            "t265" => Some(-0.006),
            "flow" => Some(-0.01),
            _ => None,
        });
        assert_eq!([ekf.x[cam], ekf.x[flow], ekf.x[gnss]], [-0.006, 0.4, -0.3]);
    }

    /// A terrain reset moves the ground, not what is known of the vehicle's height: a
    /// range reading that agrees with the reset leaves σz as it was, and the height
    /// above the terrain is known to the reading's σ.
    #[test]
    fn a_terrain_reset_claims_nothing_about_the_height() {
        let mut ekf = Ekf::new(
            Vector3::new(0.0, 0.0, 2.0),
            Vector3::zeros(),
            Vector3::new(1.0, 1.0, 1.8 * 1.8),
            Vector3::repeat(0.01),
            0.0,
        );
        let (height, r) = (0.56, 0.02 * 0.02);
        ekf.reset_terrain(height, r);
        assert!((ekf.height_above_terrain() - height).abs() < 1e-12);
        assert!((ekf.height_above_terrain_var() - r).abs() < 1e-9);
        let sz = ekf.p[(IDX_P + 2, IDX_P + 2)].sqrt();
        assert!(
            ekf.update(&Measurement::height(0.01, r), 5.0, false)
                .accepted
        );
        let after = ekf.p[(IDX_P + 2, IDX_P + 2)].sqrt();
        assert!(after > 0.99 * sz, "σz {sz:.3} -> {after:.3} m");
        assert!(ekf.p.clone().cholesky().is_some());
    }

    /// Schmidt's consider update: a measurement of a + c with c considered corrects a as
    /// the optimal filter would, with c's uncertainty in the innovation, and leaves c,
    /// its variance, and nothing else touched; P stays symmetric and positive.
    #[test]
    fn a_considered_state_is_counted_but_not_corrected() {
        let (a, c) = (IDX_P, IDX_P + 1);
        let (pa, pc, r) = (4.0, 0.25, 1.0);
        let mut ekf = Ekf::new(
            Vector3::zeros(),
            Vector3::zeros(),
            Vector3::new(pa, pc, 9.0),
            Vector3::repeat(1.0),
            0.0,
        );
        let before = ekf.clone();
        let mut m = Measurement::new(1);
        m.set_jacobian(0, a, 1.0);
        m.set_jacobian(0, c, 1.0);
        m.set_innovation(0, 2.0);
        m.set_noise(0, 0, r);
        m.consider(c);
        assert!(ekf.update(&m, 0.0, true).accepted);
        let s = pa + pc + r;
        assert!((ekf.x[a] - pa / s * 2.0).abs() < 1e-12, "{}", ekf.x[a]);
        assert_eq!(ekf.x[c], before.x[c]);
        assert!((ekf.p[(a, a)] - (pa - pa * pa / s)).abs() < 1e-12);
        assert!((ekf.p[(c, c)] - pc).abs() < 1e-12);
        // The a–c covariance: −K_a·(H P)_c = −(pa/s)·pc.
        assert!((ekf.p[(a, c)] + pa / s * pc).abs() < 1e-12);
        assert!((ekf.p[(a, c)] - ekf.p[(c, a)]).abs() < 1e-15);
        for i in 0..ekf.n() {
            if i != a && i != c {
                assert_eq!(ekf.p[(i, i)], before.p[(i, i)].max(VAR_FLOOR), "state {i}");
            }
        }
        assert!(ekf.p.clone().cholesky().is_some());
        // Not considered, the same measurement corrects both.
        let mut both = before.clone();
        let mut plain = Measurement::new(1);
        plain.set_jacobian(0, a, 1.0);
        plain.set_jacobian(0, c, 1.0);
        plain.set_innovation(0, 2.0);
        plain.set_noise(0, 0, r);
        assert!(both.update(&plain, 0.0, true).accepted);
        assert!((both.x[c] - pc / s * 2.0).abs() < 1e-12);
    }

    /// A replaced state: gated against its prior, then the measurement's value and
    /// variance (with the considered state's part), correlated with the rest only
    /// through that considered state; the position it was correlated with keeps its
    /// value and variance.
    #[test]
    fn a_replaced_state_takes_the_measurement_after_its_gate() {
        let (p, v, c) = (IDX_P, IDX_V, IDX_TERRAIN);
        let (pc, r) = (0.25, 0.04);
        let mut ekf = unit_filter();
        ekf.p[(v, v)] = 1.0;
        ekf.p[(p, v)] = 0.5;
        ekf.p[(v, p)] = 0.5;
        ekf.p[(c, c)] = pc;
        let before = ekf.clone();
        let measure = |y: f64| {
            let mut m = Measurement::new(1);
            m.set_jacobian(0, v, 1.0);
            m.set_jacobian(0, c, 1.0);
            m.set_innovation(0, y);
            m.set_noise(0, 0, r);
            m.consider(c);
            m.replace(v);
            m
        };
        // Gated against the prior (S = 1 + 0.25 + 0.04): 2 m/s off is 3.1 S-σ², refused
        // at a gate of 3 and the state untouched.
        let out = ekf.update(&measure(2.0), 3.0, false);
        assert!(
            !out.accepted && (out.nis - 4.0 / 1.29).abs() < 1e-9,
            "{out:?}"
        );
        assert_eq!(ekf.x, before.x);
        assert_eq!(ekf.p, before.p);
        assert!(ekf.update(&measure(1.0), 3.0, false).accepted);
        assert!(
            (ekf.x[v] - 1.0).abs() < 1e-5,
            "the measured value: {}",
            ekf.x[v]
        );
        assert_eq!(ekf.x[p], before.x[p]);
        assert_eq!(ekf.x[c], before.x[c]);
        // v = z − c: its variance r + pc, its covariance with c −pc, none with p.
        assert!((ekf.p[(v, v)] - (r + pc)).abs() < 1e-5, "{}", ekf.p[(v, v)]);
        assert!((ekf.p[(v, c)] + pc).abs() < 1e-5, "{}", ekf.p[(v, c)]);
        assert!(ekf.p[(v, p)].abs() < 1e-5, "{}", ekf.p[(v, p)]);
        assert!((ekf.p[(p, p)] - before.p[(p, p)]).abs() < 1e-9);
        assert!(ekf.p.clone().cholesky().is_some());
    }

    /// A frame anchored to north: the heading's new doubt is the alignments' too, the
    /// same angle, so what a camera says of the heading against its own alignment (ψ − ε)
    /// is as sure as before, while each of the two is as unsure as the frame.
    #[test]
    fn a_heading_anchored_to_north_turns_the_odometry_alignments_with_it() {
        let mut ekf = unit_filter();
        ekf.p[(IDX_YAW, IDX_YAW)] = 1e-4;
        let e = ekf.start_align_yaw("t265");
        // The alignment was made a while ago: partly its own since.
        ekf.p[(e, e)] += 1e-4;
        let diff = |k: &Ekf| k.p[(IDX_YAW, IDX_YAW)] + k.p[(e, e)] - 2.0 * k.p[(IDX_YAW, e)];
        let before = diff(&ekf);
        ekf.add_heading_uncertainty(0.02);
        assert!((ekf.p[(IDX_YAW, IDX_YAW)] - 0.0201).abs() < 1e-12);
        assert!((ekf.p[(e, e)] - 0.0202).abs() < 1e-12);
        assert!(
            (diff(&ekf) - before).abs() < 1e-12,
            "{} vs {before}",
            diff(&ekf)
        );
    }

    /// At rest at the origin, unit position and velocity variances, no bias.
    /// An accelerometer fault over a gap of T widens the velocity by a·T and the
    /// position by a·T²/2 on the axes asked, uncorrelated, and reopens their bias: a
    /// velocity measured after it then says nothing of the position (nobody knows
    /// when in the gap the fault began), and a velocity 6 m/s off that the gate
    /// refused before passes after a 4 s gap.
    #[test]
    fn a_dead_reckoning_fault_widens_what_it_could_have_moved() {
        let mut ekf = unit_filter();
        let m = Measurement::of_states(
            IDX_V,
            2,
            &Vector3::new(6.0, 0.0, 0.0),
            &(Matrix3::identity() * 0.01),
        );
        assert!(!ekf.innovation_test(&m, 9.0).accepted);
        let before = ekf.p.clone();
        ekf.add_dead_reckoning_fault(&[0, 1], 1.0, 4.0);
        for a in 0..2 {
            let (p, v, b) = (IDX_P + a, IDX_V + a, IDX_BA + a);
            assert!((ekf.p[(p, p)] - before[(p, p)] - 64.0).abs() < 1e-9);
            assert!((ekf.p[(v, v)] - before[(v, v)] - 16.0).abs() < 1e-9);
            assert!((ekf.p[(b, b)] - before[(b, b)] - 1.0).abs() < 1e-9);
            assert_eq!(ekf.p[(p, v)], before[(p, v)]);
        }
        for i in [IDX_P + 2, IDX_V + 2, IDX_BA + 2] {
            let grew = ekf.p[(i, i)] - before[(i, i)];
            assert!(grew.abs() < 1e-9, "the up axis is untouched: {grew}");
        }
        assert!(ekf.innovation_test(&m, 9.0).accepted);
        let p_east = ekf.p[(IDX_P, IDX_P)];
        assert!(ekf.update(&m, 9.0, false).accepted);
        assert!((ekf.x[IDX_V] - 6.0).abs() < 0.5, "{}", ekf.x[IDX_V]);
        assert!(
            ekf.p[(IDX_P, IDX_P)] > 0.99 * p_east,
            "the position kept its doubt: {} of {p_east}",
            ekf.p[(IDX_P, IDX_P)]
        );
    }

    fn unit_filter() -> Ekf {
        Ekf::new(
            Vector3::zeros(),
            Vector3::zeros(),
            Vector3::repeat(1.0),
            Vector3::repeat(1.0),
            0.0,
        )
    }

    /// A filter with state `x` and covariance `p` over the core states and one odometry
    /// block.
    fn with_odometry_block(x: DVector<f64>, p: &DMatrix<f64>) -> Ekf {
        let mut ekf = unit_filter();
        ekf.x = x;
        ekf.p = p.clone();
        ekf.blocks.push(("vo".into(), CORE_STATES));
        ekf
    }

    /// Re-anchored, the horizontal position is where it was put and the heading where
    /// the filter had it, both with no error, and nothing else changes its
    /// uncertainty: the velocity keeps its own less the frame's turn, the height its
    /// own, and an odometry keeps what it measures (position + offset), estimate and
    /// variance alike.
    #[test]
    fn an_anchor_clears_the_horizontal_position_and_the_heading() {
        let n = CORE_STATES + 3;
        let x = DVector::from_fn(n, |i, _| 0.1 * i as f64);
        // A full covariance: every state correlated with the position and the heading.
        let a = DMatrix::from_fn(n, n, |i, j| ((i * 7 + j * 3) % 11) as f64 * 0.05);
        let p = &a * a.transpose() + DMatrix::identity(n, n);
        let mut ekf = with_odometry_block(x, &p);
        let before = ekf.clone();
        let var = |e: &Ekf, w: &DVector<f64>| (w.transpose() * &e.p * w)[(0, 0)];
        let unit = |i: usize| DVector::from_fn(n, |k, _| f64::from(u8::from(k == i)));
        // What the anchor keeps: position + offset, and the velocity less the turn.
        let kept: Vec<DVector<f64>> = (0..2)
            .map(|k| unit(IDX_P + k) + unit(CORE_STATES + k))
            .chain((0..2).map(|k| {
                let turn = if k == 0 {
                    -before.vel().y
                } else {
                    before.vel().x
                };
                unit(IDX_V + k) - unit(IDX_YAW) * turn
            }))
            .chain([IDX_P + 2, IDX_V + 2].map(unit))
            .collect();
        ekf.anchor_frame([3.0, -2.0]);
        assert_eq!((ekf.x[IDX_P], ekf.x[IDX_P + 1]), (3.0, -2.0));
        assert_eq!(ekf.x[IDX_YAW], before.x[IDX_YAW]);
        for i in [IDX_P, IDX_P + 1, IDX_YAW] {
            assert!(ekf.p[(i, i)] <= VAR_FLOOR);
            for j in (0..n).filter(|&j| j != i) {
                assert_eq!(ekf.p[(i, j)], 0.0, "states {i}, {j}");
            }
        }
        for k in 0..2 {
            let sum = |e: &Ekf| e.x[IDX_P + k] + e.x[CORE_STATES + k];
            assert!((sum(&ekf) - sum(&before)).abs() < 1e-12);
        }
        for w in &kept {
            assert!((var(&ekf, w) - var(&before, w)).abs() < 1e-9, "{w}");
        }
    }

    /// A drift per metre is a constant of the flight: over closed laps (5 m/s circles of
    /// 10 s on an IMU) the position's 1σ grows by σ·50 m a lap, as the distance flown,
    /// not back to nothing as the displacement. No measurement corrects it; an anchor
    /// takes the position's error and keeps the drift's (it grows again from there at
    /// the same rate); a camera's offset takes it over; a frame on Earth ends it.
    #[test]
    fn a_drift_per_metre_grows_with_the_distance_flown() {
        let (speed, lap_s, dt, std) = (5.0, 10.0, 0.01, 0.02);
        let w = 2.0 * std::f64::consts::PI / lap_s;
        let lap = |ekf: &mut Ekf| {
            for k in 0..(lap_s / dt).round() as usize {
                let h = w * k as f64 * dt;
                let rot = yaw_rotation(h);
                let accel = Vector3::new(-h.sin(), h.cos(), 0.0) * speed * w;
                let f_body = rot.transpose() * (accel + Vector3::z() * GRAVITY);
                ekf.predict(f_body, &rot, dt, 0.0, 0.0, |_| 0.0);
            }
            [0, 1].map(|a| ekf.p[(IDX_P + a, IDX_P + a)].sqrt())
        };
        let tiny = Vector3::repeat(1e-12);
        let mut ekf = Ekf::new(
            Vector3::zeros(),
            Vector3::new(speed, 0.0, 0.0),
            tiny,
            tiny,
            0.0,
        );
        ekf.add_drift(std);
        let per_lap = std * speed * lap_s;
        for k in 1..=3 {
            for sigma in lap(&mut ekf) {
                let expected = k as f64 * per_lap;
                assert!(
                    (sigma / expected - 1.0).abs() < 0.01,
                    "lap {k}: {sigma} against {expected}"
                );
            }
        }
        let i = ekf.drift.expect("drift states");
        let m = Measurement::of_states(IDX_P, 2, &Vector3::zeros(), &(Matrix3::identity() * 0.01));
        assert!(ekf.update(&m, 1e9, true).accepted);
        assert!(
            (ekf.p[(i, i)] - std * std).abs() < 1e-15,
            "{}",
            ekf.p[(i, i)]
        );
        ekf.anchor_frame([0.0, 0.0]);
        for sigma in lap(&mut ekf) {
            assert!(
                (sigma / per_lap - 1.0).abs() < 0.01,
                "from the anchor: {sigma}"
            );
        }
        // A lap adds nothing to the position's σ.
        let holds = |ekf: &mut Ekf, what: &str| {
            let before = [0, 1].map(|a| ekf.p[(IDX_P + a, IDX_P + a)].sqrt());
            let after = lap(ekf);
            for a in 0..2 {
                assert!(
                    (after[a] - before[a]).abs() < 1e-6,
                    "{what}: {after:?} from {before:?}"
                );
            }
        };
        let mut camera = ekf.clone();
        camera.start_block("t265");
        holds(&mut camera, "a camera");
        ekf.end_drift();
        holds(&mut ekf, "ended");
    }

    /// A flow's compensation gyro bias error fades with its correlation time where the
    /// bias is being learnt (and what it put into the position stays), and is held
    /// where nothing learns it.
    #[test]
    fn a_gyro_bias_error_fades_only_while_it_is_learnt() {
        let mut ekf = Ekf::new(
            Vector3::zeros(),
            Vector3::zeros(),
            Vector3::repeat(1.0),
            Vector3::repeat(1.0),
            0.0,
        );
        let learnt = ekf.gyro_bias_state("flow", 1e-4, 10.0);
        let held = ekf.gyro_bias_state("flow_own_gyro", 1e-4, f64::INFINITY);
        assert_eq!(ekf.gyro_bias_state("flow", 1e-4, 10.0), learnt);
        ekf.p[(IDX_P, learnt)] = 5e-3;
        ekf.p[(learnt, IDX_P)] = 5e-3;
        for _ in 0..100 {
            ekf.predict(
                Vector3::new(0.0, 0.0, GRAVITY),
                &Matrix3::identity(),
                0.1,
                0.0,
                0.0,
                |_| 0.0,
            );
        }
        let e2 = (-2.0f64).exp();
        assert!((ekf.p[(learnt, learnt)] - 1e-4 * e2).abs() < 1e-9);
        assert!((ekf.p[(learnt + 1, learnt + 1)] - 1e-4 * e2).abs() < 1e-9);
        assert!((ekf.p[(IDX_P, learnt)] - 5e-3 * (-1.0f64).exp()).abs() < 1e-9);
        assert_eq!(ekf.p[(held, held)], 1e-4);
        assert_eq!(ekf.state_names()[learnt], "flow.gyro_bias_x");
    }

    /// The structured prediction equals the dense F P Fᵀ it replaces, on a full (random,
    /// positive definite) covariance with an odometry block and a GNSS time constant.
    #[test]
    fn structured_prediction_equals_the_dense_product() {
        let n = CORE_STATES + 3;
        let a = DMatrix::from_fn(n, n, |i, j| ((i * 7 + j * 13) % 11) as f64 / 11.0 - 0.4);
        let p0 = &a * a.transpose() + DMatrix::identity(n, n) * 0.5;
        let mut ekf = with_odometry_block(DVector::from_fn(n, |i, _| i as f64 * 0.1), &p0);
        ekf.gnss_bias_tau_s = 30.0;
        let rot = *nalgebra::Rotation3::from_euler_angles(0.1, -0.2, 0.7).matrix();
        let dt = 0.005;
        ekf.predict(Vector3::new(0.3, -0.1, 9.9), &rot, dt, 0.0, 0.0, |_| 0.0);

        // The attitude's heading error state turns the specific force: the true
        // rotation is Rz(−ψ_a)·R, and F has the derivative by ψ_a in the p and v rows.
        let x0 = DVector::from_fn(n, |i, _| i as f64 * 0.1);
        let rot_true = yaw_rotation(-x0[IDX_YAW]) * rot;
        let ba = Vector3::new(x0[IDX_BA], x0[IDX_BA + 1], x0[IDX_BA + 2]);
        let u = rot_true * (Vector3::new(0.3, -0.1, 9.9) - ba);
        let turn = Vector3::new(u.y, -u.x, 0.0);
        let mut f = DMatrix::identity(n, n);
        for i in 0..3 {
            f[(IDX_P + i, IDX_V + i)] = dt;
            f[(IDX_P + i, IDX_YAW)] = turn[i] * 0.5 * dt * dt;
            f[(IDX_V + i, IDX_YAW)] = turn[i] * dt;
        }
        f.view_mut((IDX_P, IDX_BA), (3, 3))
            .copy_from(&(-rot_true * (0.5 * dt * dt)));
        f.view_mut((IDX_V, IDX_BA), (3, 3))
            .copy_from(&(-rot_true * dt));
        let phi = (-dt / 30.0f64).exp();
        for i in 0..3 {
            f[(IDX_BG + i, IDX_BG + i)] = phi;
        }
        f[(IDX_YAW, IDX_YAW)] = (-dt / ekf.yaw_error_tau_s).exp();
        let dense = &f * &p0 * f.transpose();
        let worst = (&ekf.p - &dense).abs().max();
        assert!(worst < 1e-12, "differs by {worst}");
        // Symmetric to the bit, though only the changed states' block was symmetrised.
        assert_eq!(ekf.p, ekf.p.transpose());
        assert!(
            p0.iter()
                .zip(dense.iter())
                .any(|(a, b)| (a - b).abs() > 1e-6),
            "F did something"
        );
    }

    /// 1-D constant-velocity KF by hand: x = [p, v], F = [[1, dt], [0, 1]], no process
    /// noise, H = [1, 0], R = 1, P0 = diag(4, 1), x0 = 0, dt = 1, z = 2.
    /// Predict: P⁻ = [[5, 1], [1, 1]]; S = 6; K = [5/6, 1/6];
    /// x⁺ = [5/3, 1/3]; P⁺ = [[5/6, 1/6], [1/6, 5/6]].
    #[test]
    fn hand_worked_constant_velocity_step() {
        // Map the 1-D problem onto the x axis of the 9-state filter with zero specific
        // force balancing gravity (f = +g on z, identity attitude) and no process noise.
        let mut ekf = Ekf::new(
            Vector3::zeros(),
            Vector3::zeros(),
            Vector3::new(4.0, 1.0, 1.0),
            Vector3::new(1.0, 1.0, 1.0),
            0.0,
        );
        ekf.predict(
            Vector3::new(0.0, 0.0, GRAVITY),
            &Matrix3::identity(),
            1.0,
            0.0,
            0.0,
            |_| 0.0,
        );
        assert!((ekf.p[(0, 0)] - 5.0).abs() < 1e-12);
        assert!((ekf.p[(0, 3)] - 1.0).abs() < 1e-12);
        let y = Vector3::new(2.0 - ekf.pos().x, 0.0, 0.0);
        let m = Measurement::of_states(IDX_P, 1, &y, &Matrix3::identity());
        let out = ekf.update(&m, 25.0, false);
        assert!(out.accepted);
        assert!((out.nis - 4.0 / 6.0).abs() < 1e-12);
        assert!((ekf.x[0] - 5.0 / 3.0).abs() < 1e-12, "{}", ekf.x[0]);
        assert!((ekf.x[3] - 1.0 / 3.0).abs() < 1e-12);
        assert!((ekf.p[(0, 0)] - 5.0 / 6.0).abs() < 1e-12);
        assert!((ekf.p[(0, 3)] - 1.0 / 6.0).abs() < 1e-12);
        assert!((ekf.p[(3, 3)] - 5.0 / 6.0).abs() < 1e-12);
    }

    /// A reference run against filterpy 2.0.0 (`KalmanFilter(dim_x=2, dim_z=1)`,
    /// F = [[1, .1], [0, 1]], H = [[1, 0]], R = .25, Q = Q_discrete_white_noise(2, .1,
    /// var=.5) (= q·[[dt⁴/4, dt³/2], [dt³/2, dt²]]), P = diag(1, 1), x = 0, measurements
    /// z = 0.1, 0.25, 0.33, 0.52, 0.61), printed with `%.17g`.
    #[test]
    fn matches_filterpy_reference() {
        let mut ekf = Ekf::new(
            Vector3::zeros(),
            Vector3::zeros(),
            Vector3::new(1.0, 1.0, 1.0),
            Vector3::new(1.0, 1.0, 1.0),
            0.0,
        );
        for z in [0.1, 0.25, 0.33, 0.52, 0.61] {
            ekf.predict(
                Vector3::new(0.0, 0.0, GRAVITY),
                &Matrix3::identity(),
                0.1,
                0.5,
                0.0,
                |_| 0.0,
            );
            let y = Vector3::new(z - ekf.x[0], 0.0, 0.0);
            let m = Measurement::of_states(IDX_P, 1, &y, &(Matrix3::identity() * 0.25));
            ekf.update(&m, 1e9, false);
        }
        let expected_x = [FILTERPY_X0, FILTERPY_X1];
        let expected_p = [FILTERPY_P00, FILTERPY_P01, FILTERPY_P11];
        assert!((ekf.x[0] - expected_x[0]).abs() < 1e-9, "{}", ekf.x[0]);
        assert!((ekf.x[3] - expected_x[1]).abs() < 1e-9, "{}", ekf.x[3]);
        assert!((ekf.p[(0, 0)] - expected_p[0]).abs() < 1e-9);
        assert!((ekf.p[(0, 3)] - expected_p[1]).abs() < 1e-9);
        assert!((ekf.p[(3, 3)] - expected_p[2]).abs() < 1e-9);
    }

    const FILTERPY_X0: f64 = 0.434_852_747_884_779;
    const FILTERPY_X1: f64 = 0.421_324_390_538_872_83;
    const FILTERPY_P00: f64 = 0.078_846_995_353_556_04;
    const FILTERPY_P01: f64 = 0.146_288_875_010_112_37;
    const FILTERPY_P11: f64 = 0.690_019_288_207_295_5;

    #[test]
    fn gate_rejects_an_outlier_and_keeps_the_state() {
        let mut ekf = Ekf::new(
            Vector3::zeros(),
            Vector3::zeros(),
            Vector3::new(1.0, 1.0, 1.0),
            Vector3::new(1.0, 1.0, 1.0),
            0.01,
        );
        let before = ekf.clone();
        let r = Matrix3::identity();
        let gate = chi2_gate(3, 5.0);
        let m = Measurement::of_states(IDX_P, 3, &Vector3::new(20.0, 0.0, 0.0), &r);
        let out = ekf.update(&m, gate, false);
        assert!(!out.accepted && out.test_ratio > 1.0);
        assert_eq!(ekf, before);
        let m = Measurement::of_states(IDX_P, 3, &Vector3::new(1.0, -1.0, 0.5), &r);
        let out = ekf.update(&m, gate, false);
        assert!(out.accepted && out.test_ratio < 0.1);
    }

    #[test]
    fn chi2_quantiles() {
        assert!((chi2_gate(1, 5.0) - 25.0).abs() < 1e-9);
        assert!((chi2_cdf(2, 2.0) - (1.0 - (-1.0f64).exp())).abs() < 1e-12);
        // scipy 1.17 stats.chi2.ppf(1 - 2 * norm.sf(5), k): 28.7437 (k = 2), 31.8121 (k = 3).
        let g3 = chi2_gate(3, 5.0);
        let g2 = chi2_gate(2, 5.0);
        assert!((g2 - 28.7437).abs() < 0.01, "{g2}");
        assert!((g3 - 31.8121).abs() < 0.01, "{g3}");
    }

    #[test]
    fn odometry_block_is_relative_at_start_and_covariance_stays_pd() {
        let mut ekf = Ekf::new(
            Vector3::zeros(),
            Vector3::zeros(),
            Vector3::new(2.0, 2.0, 2.0),
            Vector3::new(1.0, 1.0, 1.0),
            0.01,
        );
        let idx = ekf.start_block("vo");
        let mut m = Measurement::of_states(
            IDX_P,
            3,
            &Vector3::new(0.01, 0.0, 0.0),
            &(Matrix3::identity() * 1e-4),
        );
        for i in 0..3 {
            m.set_jacobian(i, idx + i, 1.0);
        }
        // H P Hᵀ is zero: the first odometry sample says nothing about absolute position.
        let s = dense_h(&m, ekf.n()) * &ekf.p * dense_h(&m, ekf.n()).transpose();
        assert!(s.norm() < 1e-9, "{s}");
        for _ in 0..50 {
            ekf.predict(
                Vector3::new(0.1, 0.0, GRAVITY),
                &Matrix3::identity(),
                0.01,
                1e-4,
                1e-3,
                |_| 0.01,
            );
            ekf.update(&m, 1e9, false);
        }
        assert!(ekf.p.clone().cholesky().is_some(), "not positive definite");
        assert_eq!(ekf.p, ekf.p.transpose());
    }

    /// H as a dense rows×n matrix.
    fn dense_h(m: &Measurement, n: usize) -> DMatrix<f64> {
        let mut h = DMatrix::zeros(m.rows(), n);
        for i in 0..m.rows() {
            for (k, v) in m.jacobian_row(i).entries() {
                h[(i, k)] = v;
            }
        }
        h
    }

    /// The sparse, fixed-size update equals the textbook dense one (S = H P Hᵀ + R,
    /// K = P Hᵀ S⁻¹, x += K y, P −= K H P) for 1, 2 and 3 rows, on a full covariance
    /// with an odometry block, rows reading several states (a rotated body velocity, a
    /// position with its offset) and correlated noise.
    #[test]
    fn update_equals_the_dense_textbook_update() {
        let n = CORE_STATES + 3;
        let a = DMatrix::from_fn(n, n, |i, j| ((i * 5 + j * 11) % 13) as f64 / 13.0 - 0.45);
        let p0 = &a * a.transpose() + DMatrix::identity(n, n) * 0.3;
        let rot = *nalgebra::Rotation3::from_euler_angles(0.2, 0.1, -0.9).matrix();
        for rows in 1..=3 {
            let x0 = DVector::from_fn(n, |i, _| (i as f64 * 0.37).sin());
            let mut ekf = with_odometry_block(x0.clone(), &p0);
            let mut m = Measurement::new(rows);
            for i in 0..rows {
                m.set_innovation(i, 0.3 - 0.2 * i as f64);
                for j in 0..3 {
                    m.set_jacobian(i, IDX_V + j, rot[(j, i)]);
                }
                m.set_jacobian(i, CORE_STATES + i, 1.0);
                for j in 0..rows {
                    m.set_noise(i, j, if i == j { 0.5 } else { 0.1 });
                }
            }
            let h = dense_h(&m, n);
            let r = DMatrix::from_fn(rows, rows, |i, j| m.noise(i, j));
            let y = DVector::from_column_slice(m.innovation());
            let s = &h * &p0 * h.transpose() + &r;
            let s_inv = s.clone().try_inverse().expect("S invertible");
            let k = &p0 * h.transpose() * &s_inv;
            let x = &ekf.x + &k * &y;
            let p = &p0 - &k * &h * &p0;
            let nis = (y.transpose() * &s_inv * &y)[(0, 0)];

            let out = ekf.update(&m, 1e9, false);
            assert!(out.accepted);
            assert!(
                (out.nis - nis).abs() < 1e-12,
                "{rows} rows: nis {} vs {nis}",
                out.nis
            );
            assert_eq!(out.innovation(), y.as_slice());
            for i in 0..rows {
                assert!((out.innovation_var()[i] - s[(i, i)]).abs() < 1e-12);
            }
            let dx = (&ekf.x - &x).abs().max();
            let dp = (&ekf.p - &p).abs().max();
            assert!(
                dx < 1e-12 && dp < 1e-12,
                "{rows} rows: x off by {dx}, P by {dp}"
            );
            assert!(
                (&ekf.x - &x0).abs().max() > 1e-3,
                "the update moved the state"
            );
            // The gate test alone, on the updated filter: NIS / gate, the state untouched.
            let s_now = &h * &ekf.p * h.transpose() + &r;
            let nis_now = (y.transpose() * s_now.try_inverse().expect("S") * &y)[(0, 0)];
            assert!((ekf.test_ratio(&m, 2.0) - nis_now / 2.0).abs() < 1e-12);
        }
    }

    /// A filter started at a GNSS fix has that fix's error, whose slow part the bias
    /// states hold: the same fix fused again (or any fix while the slow error has not
    /// changed) cannot make the position surer than that slow part. Untied, the two
    /// priors counted as two measurements and σ fell to √(S/2).
    #[test]
    fn a_filter_started_at_a_fix_does_not_count_its_slow_error_twice() {
        let (slow, white) = (0.8, 0.2);
        let mut ekf = Ekf::new(
            Vector3::zeros(),
            Vector3::zeros(),
            Vector3::repeat(slow + white),
            Vector3::repeat(1.0),
            0.0,
        );
        ekf.set_gnss_bias_model(Vector3::repeat(slow.sqrt()), 120.0);
        ekf.tie_to_gnss_bias(Vector3::repeat(slow));
        let r = Matrix3::identity() * white;
        for _ in 0..20 {
            let mut m = Measurement::of_states(IDX_P, 3, &Vector3::zeros(), &r);
            for i in 0..3 {
                m.set_jacobian(i, IDX_BG + i, 1.0);
            }
            assert!(ekf.update(&m, 5.0, false).accepted);
        }
        for i in 0..3 {
            let var = ekf.p[(IDX_P + i, IDX_P + i)];
            assert!(
                var >= slow - 1e-9,
                "axis {i}: position variance {var} below the slow part {slow}"
            );
        }
        assert!(
            ekf.p.symmetric_eigen().eigenvalues.min() > -1e-9,
            "covariance not positive"
        );
    }
}
