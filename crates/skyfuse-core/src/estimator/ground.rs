//! No horizontal aiding: constrain the state instead of dead-reckoning on the IMU, as
//! the anchors do (PX4 EKF2's fake position and zero-velocity update, ArduPilot EKF3's
//! constant-position mode). Same verbs as the aiding sources: checks (on the ground?
//! at rest?), control (start/continue conditions), fuse.
//!
//! - **On the ground** (ground evidence and at rest, below): the vehicle is where it
//!   was when aiding stopped. Fused every [`FUSE_EVERY_US`]: zero velocity (σ
//!   `ground_vel_noise`), the held horizontal position (σ `ground_pos_noise`) and,
//!   when the range finder reads at or below its minimum, the height above the ground
//!   within `[0, min]`. This counts as aiding: the estimate is valid, so an autopilot
//!   can arm on it before flow or a camera can see anything (a flow + range vehicle
//!   on its landing gear). A flow + range vehicle with nothing else also starts its
//!   filter here.
//! - **Unaided otherwise** (in the air, carried, or stillness unknown): nothing is
//!   fused (EKF2 fuses a fake position here; held as a measurement it pulls the
//!   estimate back to where aiding stopped while the vehicle flies on, and the σ it
//!   leaves is a lie once aiding returns): the estimate dead-reckons with the
//!   uncertainty its model gives, not aiding, so it turns invalid after
//!   `aiding_timeout_ms` and VPE stops.
//!
//! Ground evidence: the autopilot says landed (EXTENDED_SYS_STATE / PX4
//! vehicle_land_detected) or disarmed (a multirotor on its gear), or a downward range
//! finder reads at or below its minimum. At rest: the IMU's low-passed specific force
//! is gravity alone and its low-passed rate near zero for [`REST_AFTER_US`] (a
//! vibrating but standing vehicle averages out; a vehicle carried by hand does not);
//! without an IMU, only the autopilot's landed state counts. When aiding returns the
//! track continues from the held position: no jump, no reset.

use super::ekf::{Measurement, GRAVITY, IDX_P, IDX_V};
use super::imu::Lpf3;
use super::{Core, Ctx, Event};
use crate::event::ConstraintChange;
use crate::sample::{LandedState, VehicleState};
use nalgebra::Vector3;

/// Constraints are fused at most this often, µs (EKF2 fuses its fake position at 5 Hz).
pub const FUSE_EVERY_US: i64 = 100_000;
/// The IMU must look still this long before the vehicle counts as at rest, µs.
const REST_AFTER_US: i64 = 500_000;
/// Low-pass time constant of the stillness test, s (averages out motor vibration).
const REST_LPF_TAU_S: f64 = 0.2;
/// The slow average the filtered specific force is compared with, s.
const REST_SLOW_TAU_S: f64 = 2.0;
/// At rest: low-passed |specific force| − g and low-passed |rate| below these.
const REST_ACCEL: f64 = 0.25;
/// The magnitude's allowance for the accelerometer's bias, in its initial 1σ.
const REST_BIAS_SIGMAS: f64 = 3.0;
const REST_GYRO: f64 = 0.05;
/// Evidence older than this does not count, µs.
const RANGE_FRESH_US: i64 = 500_000;
/// Range readings at their minimum say the ground once they have for this long, µs
/// (three readings of a 10 Hz range finder).
const RANGE_LOW_HOLD_US: i64 = 150_000;
const STATE_FRESH_US: i64 = 3_000_000;
const IMU_FRESH_US: i64 = 200_000;
/// A handled vehicle stays invalid this long after the last sign of handling, µs.
const HANDLED_HOLD_US: i64 = 1_000_000;
/// Horizontal speed above which a disarmed vehicle counts as moved, m/s.
const HANDLED_SPEED: f64 = 0.3;
/// The filter starts on the ground only after this long at rest with nothing else
/// starting it, µs (a GNSS fix or a camera normally start it at once).
const INIT_AFTER_US: i64 = 1_000_000;

/// Which constraint holds the state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Constraint {
    OnGround,
    FakePosition,
}

impl Constraint {
    pub fn as_str(self) -> &'static str {
        match self {
            Constraint::OnGround => "on_ground",
            Constraint::FakePosition => "fake_position",
        }
    }
}

#[derive(Debug, Clone, PartialEq, Default)]
pub struct GroundState {
    /// The autopilot's latest word: (time, value).
    pub armed: Option<(i64, bool)>,
    pub landed: Option<(i64, LandedState)>,
    /// Latest downward range reading at or below its minimum: (time, reading, minimum).
    pub range_low: Option<(i64, f64, f64)>,
    /// The first of the low readings since the last that was not low, time.
    range_low_since: Option<i64>,
    /// Latest downward range reading inside its limits (the vehicle is up), time.
    pub range_in_range: Option<i64>,
    /// Latest downward range reading at or beyond its maximum (up, and high), time.
    range_high: Option<i64>,
    /// Low-passed specific force and rate (body), and the last IMU time; the slow
    /// low-pass of the specific force is gravity's direction in the body.
    accel_lpf: Lpf3,
    accel_slow: Lpf3,
    gyro_lpf: Lpf3,
    imu_t: Option<i64>,
    /// Since when the IMU has looked still.
    still_since: Option<i64>,
    /// Last real horizontal aiding (GNSS, odometry, flow), time.
    pub last_h_aiding: Option<i64>,
    /// Held position while constrained.
    pub hold: Option<Vector3<f64>>,
    /// The position variance (per axis) when the hold began: holding still says the
    /// vehicle does not move, not where it is, so the constraints never make the
    /// position more certain than it was then.
    pub hold_var: Vector3<f64>,
    pub active: Option<Constraint>,
    pub since: Option<i64>,
    last_fuse: Option<i64>,
    /// Since when the vehicle has been on the ground (for starting the filter).
    on_ground_since: Option<i64>,
    /// Disarmed but moving (carried by hand): the estimate is not valid until then.
    pub handled_until: Option<i64>,
}

/// Checks: an autopilot state sample.
pub fn process_vehicle_state(core: &mut Core, t: i64, source: &str, v: &VehicleState) {
    if let Some(a) = v.armed {
        core.ground.armed = Some((t, a));
    }
    if let Some(l) = v.landed {
        core.ground.landed = Some((t, l));
    }
    core.mark_used(t, source);
}

/// Checks: an IMU sample for the stillness test. `accel_bias`: the accelerometer's
/// bias as the filter knows it (body, m/s²) and the largest 1σ of that per axis.
pub fn imu_sample(
    g: &mut GroundState,
    t: i64,
    gyro: Option<Vector3<f64>>,
    accel: Option<Vector3<f64>>,
    (accel_bias, accel_bias_std): (Vector3<f64>, f64),
) {
    g.imu_t = Some(t);
    // Time constant τ as the cut-off 1/(2πτ) of imu's first-order low-pass.
    let hz = |tau: f64| 1.0 / (2.0 * std::f64::consts::PI * tau);
    if let Some(a) = accel {
        g.accel_lpf.update(a, t, hz(REST_LPF_TAU_S));
        g.accel_slow.update(a, t, hz(REST_SLOW_TAU_S));
    }
    if let Some(w) = gyro {
        g.gyro_lpf.update(w, t, hz(REST_LPF_TAU_S));
    }
    // Still: the specific force is gravity alone (its magnitude, less the
    // accelerometer's bias as the filter knows it, and give or take what it does not
    // know of it) and steady (no departure from its slow average in any direction: a
    // carry sways sideways, which the magnitude alone hardly shows), and no rotation.
    // Against g alone an IMU 0.67 m/s² off along the vertical never stood still: the
    // filter did not start on the ground, and a climb beyond the range finder on a
    // flow started in the air or never (randomised seed 2, draw 61: valid 0.9 %). The
    // bias's prior allowed once the filter runs, a steady take-off looked still and a
    // range finder's reading held the vehicle on its gear 1.2 s into the climb
    // (scenario `sonar-climb-imu`: the height ran away 290 m); with the prior only
    // until the filter ran, the ground's hold went with it as the filter started, and
    // flights on a flow drifted up while standing (seed 1, draws 29, 430: 63 integrity
    // failures). On the gear the hold teaches the filter the bias, and the test
    // narrows with it.
    let weight = REST_ACCEL + REST_BIAS_SIGMAS * accel_bias_std.max(0.0);
    let accel_still = match (g.accel_lpf.y, g.accel_slow.y) {
        (Some(f), Some(s)) => {
            ((f - accel_bias).norm() - GRAVITY).abs() < weight && (f - s).norm() < REST_ACCEL
        }
        _ => true,
    };
    let still = accel_still
        && g.gyro_lpf.y.is_none_or(|w| w.norm() < REST_GYRO)
        && (g.accel_lpf.y.is_some() || g.gyro_lpf.y.is_some());
    if !still {
        g.still_since = None;
    } else if g.still_since.is_none() {
        g.still_since = Some(t);
    }
}

/// Checks: a downward range reading at or below its minimum (the vehicle is on its
/// gear), or inside its limits.
pub fn range_sample(g: &mut GroundState, t: i64, reading: f64, min: f64, low: bool) {
    if low {
        g.range_low = Some((t, reading, min));
        g.range_low_since.get_or_insert(t);
    } else {
        g.range_in_range = Some(t);
        g.range_low_since = None;
    }
}

/// Checks: a downward range reading at or beyond its maximum. Up, so the low reading
/// before it was not the ground: a range finder above its range that hears an echo at
/// its minimum, among readings at its maximum, was taken for the gear for 0.5 s
/// (randomised seed 2, draw 89: a hovering IMU looked still, and the ground's
/// constraints moved the estimate 8 m at 14 m up).
pub fn range_high_sample(g: &mut GroundState, t: i64) {
    g.range_high = Some(t);
    g.range_low_since = None;
}

impl GroundState {
    /// The autopilot's arming state, if it said so lately.
    fn armed_now(&self, t: i64) -> Option<bool> {
        self.armed
            .filter(|(at, _)| t - at <= STATE_FRESH_US)
            .map(|(_, a)| a)
    }

    /// The autopilot says disarmed (fresh).
    fn disarmed_now(&self, t: i64) -> bool {
        self.armed_now(t) == Some(false)
    }

    /// Disarmed, and yet lifted off its gear or moving: carried by hand (or on a cart).
    /// Flow and range may still track it, but nothing flies on such a pose: invalid
    /// until [`HANDLED_HOLD_US`] after it stops.
    pub fn handled(&self, t: i64) -> bool {
        self.handled_until.is_some_and(|u| t <= u)
    }

    fn landed_now(&self, t: i64) -> Option<bool> {
        let landed = self
            .landed
            .filter(|(lt, _)| t - lt <= STATE_FRESH_US)
            .map(|(_, l)| l == LandedState::OnGround);
        let disarmed = self.armed_now(t).map(|a| !a);
        match (landed, disarmed) {
            // The land detector knows better than the arming state (armed on the ground
            // before take-off, or disarmed in a carry).
            (Some(l), _) => Some(l),
            (None, d) => d,
        }
    }

    pub fn range_says_ground(&self, t: i64) -> bool {
        let low = self.range_low.filter(|(rt, _, _)| t - rt <= RANGE_FRESH_US);
        // Low readings for a while, not one: an echo is one reading.
        let held = |rt: i64| {
            self.range_low_since
                .is_some_and(|s| rt - s >= RANGE_LOW_HOLD_US)
        };
        low.is_some_and(|(rt, _, _)| {
            held(rt)
                && self.range_in_range.is_none_or(|u| u < rt)
                && self.range_high.is_none_or(|u| u < rt)
        })
    }

    /// At rest: the IMU still for long enough; without an IMU, the autopilot's word.
    fn at_rest(&self, t: i64) -> bool {
        if self.imu_t.is_some_and(|it| t - it <= IMU_FRESH_US) {
            self.still_since.is_some_and(|s| t - s >= REST_AFTER_US)
        } else {
            self.landed_now(t) == Some(true)
        }
    }

    /// On the ground: ground evidence and at rest. The autopilot saying "in the air"
    /// overrides a range reading (a range finder over a close obstacle reads low).
    pub fn on_ground(&self, t: i64) -> bool {
        let evidence = match self.landed_now(t) {
            Some(l) => l,
            None => self.range_says_ground(t),
        };
        evidence && self.at_rest(t)
    }
}

/// Control and fuse, after each sample. Horizontal aiding fused recently releases the
/// constraint; otherwise the one that applies is fused at [`FUSE_EVERY_US`].
pub fn control(core: &mut Core, ctx: &Ctx, t: i64) {
    if core.mode_wrls {
        return;
    }
    if core.ground.disarmed_now(t) {
        let lifted = core
            .ground
            .range_in_range
            .is_some_and(|u| t - u <= RANGE_FRESH_US)
            && !core.ground.range_says_ground(t);
        // Moving for certain: the speed and beyond its own uncertainty (an estimate
        // without aiding does not know that it stands still).
        let moving = core.ekf.as_ref().is_some_and(|e| {
            let speed = e.vel().xy().norm();
            let std = e.cov3(IDX_V).diagonal().xy().max().max(0.0).sqrt();
            speed > HANDLED_SPEED && speed > 3.0 * std
        });
        // Moving: the IMU says so now. An IMU that has only just started (still, but
        // not yet for `REST_AFTER_US`) is not a carry.
        let imu_moving = core.ground.imu_t.is_some_and(|it| t - it <= IMU_FRESH_US)
            && core.ground.still_since.is_none();
        if lifted || moving || imu_moving {
            if !core.ground.handled(t) {
                core.event(
                    t,
                    None,
                    "disarmed but moving: carried, the estimate is not valid until it is set down"
                        .into(),
                    Event::Handled {
                        lifted,
                        moving,
                        imu_moving,
                    },
                );
            }
            core.ground.handled_until = Some(t + HANDLED_HOLD_US);
        }
    }
    // A carried vehicle is not at rest, whatever the land detector says (it does not
    // see a carry; without an IMU its word is all the stillness test has).
    let on_ground = core.ground.on_ground(t) && !core.ground.handled(t);
    if on_ground {
        core.ground.on_ground_since.get_or_insert(t);
    } else {
        core.ground.on_ground_since = None;
    }
    if core.ekf.is_none() {
        let ready = core
            .ground
            .on_ground_since
            .is_some_and(|s| t - s >= INIT_AFTER_US);
        if ready && core.att.known() {
            let (h, h_var) = ground_height(core, t).unwrap_or((0.0, ctx.cfg.init_pos_var));
            let p = ctx.cfg.init_pos_var;
            let var = Vector3::new(p, p, h_var.max(p));
            let v = Some(Vector3::zeros());
            let vv = Some(Vector3::repeat(ctx.cfg.ground_vel_noise.powi(2)));
            core.initialise(t, "ground", Vector3::new(0.0, 0.0, h), var, v, vv, ctx);
        }
        return;
    }
    // Horizontal aiding within the aiding timeout: a 2 Hz GNSS between its fixes is
    // still aiding.
    let gap = (ctx.cfg.aiding_timeout_ms * 1000.0) as i64;
    let aided = core
        .ground
        .last_h_aiding
        .is_some_and(|l| t - l <= gap && l <= t);
    let want = if aided {
        None
    } else if on_ground {
        Some(Constraint::OnGround)
    } else {
        Some(Constraint::FakePosition)
    };
    if want != core.ground.active {
        transition(core, t, want);
    }
    let Some(active) = want else { return };
    if core
        .ground
        .last_fuse
        .is_some_and(|l| t - l < FUSE_EVERY_US && l <= t)
    {
        return;
    }
    core.ground.last_fuse = Some(t);
    let Some(hold) = core.ground.hold else { return };
    let floor = core.ground.hold_var;
    let cfg = ctx.cfg;
    match active {
        Constraint::OnGround => {
            let pn = cfg.ground_pos_noise.powi(2);
            let vn = cfg.ground_vel_noise.powi(2);
            let mut ok = fuse_zero_velocity(core, vn);
            for axis in 0..2 {
                ok &= fuse_to_floor(core, IDX_P + axis, hold[axis], pn, floor[axis]);
            }
            if let Some((h, var)) = ground_height(core, t) {
                fuse_height_force(core, h, var);
            }
            if ok {
                core.mark_aiding(t, "ground", "ground");
            }
        }
        // Nothing is fused: the estimate dead-reckons on the IMU with the uncertainty
        // its model gives (invalid meanwhile). A held point fused as a position pulls
        // the estimate back towards where aiding stopped while the vehicle flies on:
        // 16 m off with σ 0.8 m after a 17 s flow dropout on a randomised flight.
        Constraint::FakePosition => {}
    }
}

/// Fuse a direct measurement of state `i` (value `z`, variance at least `var`),
/// ungated, but never below `floor` for its variance: a constraint fused again and
/// again is one fact, not new information each time. The measurement's variance is
/// raised so that the state's comes out at `floor` at the least; above it, it is not
/// fused. Returns whether the update went through (or was not needed).
fn fuse_to_floor(core: &mut Core, i: usize, z: f64, var: f64, floor: f64) -> bool {
    let Some(bank) = core.ekf.as_mut() else {
        return false;
    };
    // A constraint of every filter of the bank, each on its own state.
    bank.each_main(|ekf| {
        let p = ekf.p[(i, i)];
        if p <= floor * (1.0 + 1e-9) {
            return true;
        }
        // Posterior p·r/(p + r) ≥ floor  ⇔  r ≥ p·floor/(p − floor).
        let r = var.max(p * floor / (p - floor));
        let mut m = Measurement::new(1);
        m.set_jacobian(0, i, 1.0);
        m.set_innovation(0, z - ekf.x[i]);
        m.set_noise(0, 0, r);
        ekf.update(&m, 0.0, true).accepted
    })
}

/// Height above the ground while the range finder reads at or below its minimum: the
/// middle of `[0, min]`, σ half of it (at least 5 cm), as a variance.
fn ground_height(core: &Core, t: i64) -> Option<(f64, f64)> {
    let g = &core.ground;
    if !g.range_says_ground(t) {
        return None;
    }
    let (_, _, min) = g.range_low?;
    let s = (0.5 * min).max(0.05);
    Some((0.5 * min, s * s))
}

fn transition(core: &mut Core, t: i64, to: Option<Constraint>) {
    let from = core.ground.active;
    let pos = core.ekf.as_ref().map(|e| e.pos());
    match to {
        Some(c) => {
            // The held point is where aiding left the vehicle; kept when it goes from
            // the ground to unaided motion (it left from there).
            // Set down after moving unaided (carried, or in the air): it stands where
            // the estimate has it now, as uncertain as that is, not where it was.
            let set_down = from == Some(Constraint::FakePosition) && c == Constraint::OnGround;
            if set_down {
                // How far it went unseen is as uncertain as its position became since the
                // hold began; the ground may differ by the gradient over that.
                let before = core.ground.hold_var;
                let left_from = core.ground.hold;
                if let Some(bank) = core.ekf.as_mut() {
                    bank.each(|ekf| {
                        let now = ekf.cov3(IDX_P).diagonal();
                        let moved = (now.x - before.x).max(0.0) + (now.y - before.y).max(0.0);
                        let g = ekf.terrain_gradient;
                        ekf.add_terrain_uncertainty(g * g * moved);
                        // Its σ is at least how far the estimate went unaided: that motion
                        // is the prediction's alone, as likely drift as travel, and the
                        // held point's loose bound kept σ from growing with it (a real PX4
                        // log: 17 m in 5 s of IMU alone, σ 1.5 m, valid once set down).
                        if let Some(from) = left_from {
                            let d = ekf.pos() - from;
                            for axis in 0..2 {
                                let i = IDX_P + axis;
                                ekf.p[(i, i)] = ekf.p[(i, i)].max(d[axis] * d[axis]);
                            }
                        }
                    });
                }
            }
            if core.ground.hold.is_none() || set_down {
                core.ground.hold = pos;
                core.ground.hold_var = core
                    .ekf
                    .as_ref()
                    .map_or(Vector3::zeros(), |e| e.cov3(IDX_P).diagonal());
            }
            let p = core.ground.hold.unwrap_or_else(Vector3::zeros);
            let message = match c {
                Constraint::OnGround => format!(
                    "on the ground without horizontal aiding: holding ({:.2}, {:.2}) with zero velocity",
                    p.x, p.y
                ),
                Constraint::FakePosition => format!(
                    "no horizontal aiding and not at rest: position held loosely at ({:.2}, {:.2}, {:.2}) to bound the estimate (invalid until aiding returns)",
                    p.x, p.y, p.z
                ),
            };
            core.event(
                t,
                None,
                message,
                Event::Constraint(ConstraintChange::Started {
                    constraint: c.as_str(),
                    hold: p.into(),
                }),
            );
            if from.is_none() {
                core.ground.since = Some(t);
            }
        }
        None => {
            let held_s = core.ground.since.map_or(0.0, |s| (t - s) as f64 * 1e-6);
            core.event(
                t,
                None,
                format!("horizontal aiding resumed after {held_s:.1} s of constraints"),
                Event::Constraint(ConstraintChange::Released {
                    constraint: None,
                    held_s,
                }),
            );
            core.ground.hold = None;
            core.ground.since = None;
            core.ground.last_fuse = None;
        }
    }
    core.ground.active = to;
}

/// Zero velocity on the ground, forced, the horizontal position considered, not
/// corrected: that the vehicle stands still says nothing of where it stands. Set down
/// after moving unseen, the velocity's correlation with the position would otherwise
/// shrink the position's uncertainty (σ 1.5 → 0.3 m on a real PX4 log, 11 m from GPS)
/// and call a lost estimate valid.
fn fuse_zero_velocity(core: &mut Core, var: f64) -> bool {
    let Some(bank) = core.ekf.as_mut() else {
        return false;
    };
    bank.each_main(|ekf| {
        let mut m = Measurement::new(3);
        for row in 0..3 {
            let i = IDX_V + row;
            m.set_jacobian(row, i, 1.0);
            m.set_innovation(row, -ekf.x[i]);
            m.set_noise(row, row, var);
        }
        m.consider(IDX_P);
        m.consider(IDX_P + 1);
        ekf.update(&m, 0.0, true).accepted
    })
}

/// The height above the ground while on it, a fact about an interval (`[0, min]` of the
/// range finder): fused down to its own variance and no further, however often.
fn fuse_height_force(core: &mut Core, h_meas: f64, var: f64) {
    let Some(bank) = core.ekf.as_mut() else {
        return;
    };
    bank.each(|ekf| {
        let mut m = Measurement::height(h_meas - ekf.height_above_terrain(), var);
        let p = ekf.height_above_terrain_var();
        if p <= var * (1.0 + 1e-9) {
            return;
        }
        m.set_noise(0, 0, var.max(p * var / (p - var)));
        ekf.update(&m, 0.0, true);
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    fn still_imu(g: &mut GroundState, from: i64, to: i64) {
        let mut t = from;
        while t <= to {
            imu_sample(
                g,
                t,
                Some(Vector3::zeros()),
                Some(Vector3::new(0.0, 0.0, GRAVITY)),
                (Vector3::zeros(), 0.0),
            );
            t += 5_000;
        }
    }

    /// Range readings at `reading`, at or below the minimum 0.2 m, every 0.1 s up to `to`.
    fn low_readings(g: &mut GroundState, from: i64, to: i64, reading: f64) {
        let mut t = from;
        while t <= to {
            range_sample(g, t, reading, 0.2, true);
            t += 100_000;
        }
    }

    #[test]
    fn range_at_minimum_and_still_imu_is_the_ground() {
        let mut g = GroundState::default();
        still_imu(&mut g, 0, 1_000_000);
        assert!(!g.on_ground(1_000_000), "no evidence yet");
        range_sample(&mut g, 800_000, 0.0, 0.2, true);
        assert!(!g.on_ground(1_000_000), "one reading is no evidence");
        low_readings(&mut g, 800_000, 1_000_000, 0.0);
        assert!(g.on_ground(1_000_000));
        // The range finder sees the floor from above: up.
        range_sample(&mut g, 1_100_000, 1.5, 0.2, false);
        assert!(!g.on_ground(1_100_000));
    }

    /// A range finder above its range, hovering: an echo at its minimum among readings
    /// at its maximum is not the ground.
    #[test]
    fn an_echo_above_the_range_is_not_the_ground() {
        let mut g = GroundState::default();
        still_imu(&mut g, 0, 1_000_000);
        let mut t = 0;
        while t < 1_000_000 {
            range_high_sample(&mut g, t);
            t += 15_000;
        }
        range_sample(&mut g, t, 0.2, 0.2, true);
        assert!(!g.on_ground(t));
        range_high_sample(&mut g, t + 15_000);
        range_sample(&mut g, t + 200_000, 0.2, 0.2, true);
        assert!(!g.on_ground(t + 200_000));
    }

    /// An accelerometer 0.7 m/s² off along the vertical, standing on its gear: still,
    /// within the bias the filter starts with (randomised seed 2, draw 61: a climb on a
    /// flow with such an IMU never started on the ground, 1 % valid).
    #[test]
    fn an_accelerometer_bias_is_no_motion() {
        let on_gear = |accel_bias_std: f64| {
            let mut g = GroundState::default();
            let mut t = 0;
            while t <= 1_000_000 {
                let f = Vector3::new(0.0, 0.0, GRAVITY + 0.7);
                let bias = (Vector3::zeros(), accel_bias_std);
                imu_sample(&mut g, t, Some(Vector3::zeros()), Some(f), bias);
                t += 5_000;
            }
            low_readings(&mut g, t - 200_000, t, 0.0);
            g.on_ground(t)
        };
        assert!(on_gear(0.5));
        assert!(!on_gear(0.0), "the magnitude alone says moving");
    }

    #[test]
    fn a_carried_vehicle_is_not_at_rest_whatever_the_autopilot_says() {
        let mut g = GroundState::default();
        process_state(&mut g, 0, Some(false), Some(LandedState::OnGround));
        still_imu(&mut g, 0, 1_000_000);
        assert!(g.on_ground(1_000_000));
        // Walking: a 1 Hz sway of 1.5 m/s² on x.
        let mut t = 1_000_000;
        while t < 2_000_000 {
            let a = 1.5 * (2.0 * std::f64::consts::PI * t as f64 * 1e-6).sin();
            imu_sample(
                &mut g,
                t,
                Some(Vector3::zeros()),
                Some(Vector3::new(a, 0.0, GRAVITY)),
                (Vector3::zeros(), 0.0),
            );
            t += 5_000;
        }
        assert!(!g.on_ground(2_000_000));
    }

    #[test]
    fn motor_vibration_averages_out() {
        let mut g = GroundState::default();
        // Standing, then the motors spin up (armed on the ground).
        still_imu(&mut g, 0, 1_000_000);
        let mut t = 1_005_000;
        let mut sign = 1.0;
        while t <= 2_500_000 {
            // ±3 m/s² at 100 Hz on every axis, ±0.3 rad/s on the gyro.
            sign = -sign;
            imu_sample(
                &mut g,
                t,
                Some(Vector3::repeat(0.3 * sign)),
                Some(Vector3::new(3.0 * sign, 3.0 * sign, GRAVITY + 3.0 * sign)),
                (Vector3::zeros(), 0.0),
            );
            t += 5_000;
        }
        low_readings(&mut g, 2_300_000, 2_500_000, 0.05);
        assert!(g.on_ground(2_500_000));
    }

    #[test]
    fn the_land_detector_overrides_a_low_range() {
        let mut g = GroundState::default();
        still_imu(&mut g, 0, 1_000_000);
        low_readings(&mut g, 800_000, 1_000_000, 0.1);
        process_state(&mut g, 1_000_000, Some(true), Some(LandedState::InAir));
        assert!(!g.on_ground(1_000_000));
    }

    fn process_state(g: &mut GroundState, t: i64, armed: Option<bool>, l: Option<LandedState>) {
        if let Some(a) = armed {
            g.armed = Some((t, a));
        }
        if let Some(l) = l {
            g.landed = Some((t, l));
        }
    }
}
