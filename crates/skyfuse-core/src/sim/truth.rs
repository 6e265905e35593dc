//! Ground-truth flight: take-off, figure-eight outdoors, an indoor stretch without GPS,
//! figure-eight again, landing, then on the ground until the loop repeats. Smooth in
//! position (C²), so the IMU the sensor models derive from it is consistent.

use nalgebra::{UnitQuaternion, Vector3};
use std::f64::consts::PI;

pub const GRAVITY: f64 = 9.806_65;

/// Phase boundaries of one loop of the demo flight, seconds.
pub const T_TAKEOFF: f64 = 4.0;
pub const T_CRUISE: f64 = 10.0;
pub const T_INDOOR: f64 = 70.0;
pub const T_OUTDOOR_AGAIN: f64 = 100.0;
pub const T_LANDING: f64 = 130.0;
pub const T_LANDED: f64 = 136.0;
/// One loop, seconds; the demo repeats it.
pub const LOOP_S: f64 = 140.0;
pub const CRUISE_HEIGHT: f64 = 2.0;
const EIGHT_A: f64 = 6.0;
const EIGHT_PERIOD: f64 = 30.0;

/// The vehicle's true state at one instant (world ENU, body FLU).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthState {
    pub t: f64,
    pub position: Vector3<f64>,
    pub velocity: Vector3<f64>,
    pub acceleration: Vector3<f64>,
    /// Body FLU → world ENU.
    pub attitude: UnitQuaternion<f64>,
    /// Body angular rate, FLU, rad/s.
    pub body_rate: Vector3<f64>,
    /// True when the vehicle is in the indoor stretch (no GPS).
    pub indoor: bool,
}

/// Smooth step 0→1 over [0,1] with zero first and second derivatives at both ends.
pub(crate) fn smoothstep5(x: f64) -> f64 {
    let x = x.clamp(0.0, 1.0);
    x * x * x * (10.0 - 15.0 * x + 6.0 * x * x)
}

/// Horizontal figure-eight amplitude envelope: ramps in after take-off, out before landing.
fn envelope(t: f64) -> f64 {
    let ramp = 6.0;
    smoothstep5((t - T_CRUISE) / ramp) * (1.0 - smoothstep5((t - (T_LANDING - ramp)) / ramp))
}

/// The shape of the flight.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Profile {
    /// Take-off, figure-eight with an indoor stretch (70–100 s) without GPS, landing.
    Demo,
    /// The same flight, outdoors throughout.
    Figure8,
    /// The same flight, indoors throughout (no GPS fix ever).
    Indoor,
    /// Take-off, hold position with slow yaw changes, landing.
    Hover,
    /// Climb to [`HIGH_HOVER_M`] (well above a short-range sonar), hold position
    /// outdoors for minutes with a wind-driven wander, descend and land: a PX4Flow
    /// with its 0.3-3.7 m sonar on a vehicle flying at 12 m.
    HighHover,
    /// A long outdoor flight at cruise speed (a [`LAP_RADIUS_M`] circle at
    /// [`LAP_SPEED`]) at [`LAP_HEIGHT_M`]: a low-rate flow sensor over open ground.
    Laps,
    /// A drawn flight (the Monte Carlo runs), outdoors throughout.
    Plan(super::plan::FlightPlan),
}

/// Height of the [`Profile::HighHover`] flight, m.
pub const HIGH_HOVER_M: f64 = 12.0;
/// Phases of the [`Profile::HighHover`] flight, s: climb from take-off until
/// `HIGH_CLIMBED`, hover until `HIGH_DESCENT`, land at `HIGH_LANDED`; its loop.
const HIGH_CLIMBED: f64 = 16.0;
const HIGH_DESCENT: f64 = 300.0;
const HIGH_LANDED: f64 = 312.0;
const HIGH_LOOP_S: f64 = 320.0;
/// Wander of the high hover (wind gusts against the position controller), m.
const HIGH_WANDER_M: f64 = 1.5;
/// The [`Profile::Laps`] flight: a circle of this radius, flown at this speed and
/// height; it ramps up over [`LAP_RAMP_S`] after the climb and lands at the end.
pub const LAP_RADIUS_M: f64 = 60.0;
pub const LAP_SPEED: f64 = 4.0;
pub const LAP_HEIGHT_M: f64 = 3.0;
const LAP_RAMP_S: f64 = 10.0;
const LAP_LANDING: f64 = 300.0;
const LAP_LANDED: f64 = 306.0;
const LAP_LOOP_S: f64 = 312.0;

/// One loop of `profile`'s flight, s (the flight repeats after it).
pub fn loop_s(profile: Profile) -> f64 {
    match profile {
        Profile::HighHover => HIGH_LOOP_S,
        Profile::Laps => LAP_LOOP_S,
        Profile::Plan(p) => p.loop_s(),
        Profile::Demo | Profile::Figure8 | Profile::Indoor | Profile::Hover => LOOP_S,
    }
}

/// Climb to `height` between take-off and `climbed`, descend from `descent` to
/// `landed`.
fn height_profile(t: f64, height: f64, climbed: f64, descent: f64, landed: f64) -> f64 {
    height
        * smoothstep5((t - T_TAKEOFF) / (climbed - T_TAKEOFF))
        * (1.0 - smoothstep5((t - descent) / (landed - descent)))
}

fn position_at(profile: Profile, t_loop: f64) -> Vector3<f64> {
    let t = t_loop;
    match profile {
        Profile::Plan(p) => return p.position(t),
        Profile::HighHover => {
            let z = height_profile(t, HIGH_HOVER_M, HIGH_CLIMBED, HIGH_DESCENT, HIGH_LANDED);
            // Gusts: two slow periods per axis, the wander fading in once up.
            let e = smoothstep5((t - HIGH_CLIMBED) / 10.0)
                * (1.0 - smoothstep5((t - (HIGH_DESCENT - 10.0)) / 10.0));
            let a = HIGH_WANDER_M * e;
            return Vector3::new(
                a * (0.7 * (2.0 * PI * t / 41.0).sin() + 0.3 * (2.0 * PI * t / 13.0).sin()),
                a * (0.6 * (2.0 * PI * t / 37.0).cos() + 0.4 * (2.0 * PI * t / 11.0).sin())
                    - a * 0.6,
                z,
            );
        }
        Profile::Laps => {
            let z = height_profile(t, LAP_HEIGHT_M, T_CRUISE, LAP_LANDING, LAP_LANDED);
            // Distance along the circle: the speed ramps up and down smoothly (its
            // integral is taken numerically below, exactly enough at 1 ms steps).
            let s = lap_distance(t);
            let phi = s / LAP_RADIUS_M;
            return Vector3::new(
                LAP_RADIUS_M * phi.sin(),
                LAP_RADIUS_M * (1.0 - phi.cos()),
                z,
            );
        }
        Profile::Demo | Profile::Figure8 | Profile::Indoor | Profile::Hover => {}
    }
    let z = CRUISE_HEIGHT
        * smoothstep5((t - T_TAKEOFF) / (T_CRUISE - T_TAKEOFF))
        * (1.0 - smoothstep5((t - T_LANDING) / (T_LANDED - T_LANDING)));
    let w = 2.0 * PI / EIGHT_PERIOD;
    let tau = (t - T_CRUISE).max(0.0);
    if profile == Profile::Hover {
        // Position hold wanders a little (wind, controller): ±0.3 m, slowly.
        let e = envelope(t);
        return Vector3::new(
            e * HOVER_WANDER_M * (2.0 * PI * tau / 23.0).sin(),
            e * HOVER_WANDER_M * (2.0 * PI * tau / 17.0).sin(),
            z,
        );
    }
    let e = envelope(t);
    Vector3::new(
        e * EIGHT_A * (w * tau).sin(),
        e * EIGHT_A * 0.5 * (2.0 * w * tau).sin(),
        z,
    )
}

/// Distance flown along the laps' circle by `t`: the speed ramps in over
/// [`LAP_RAMP_S`] after the climb and out before the landing.
fn lap_distance(t: f64) -> f64 {
    ramped_distance(t, T_CRUISE, LAP_LANDING, LAP_RAMP_S, LAP_SPEED)
}

/// Distance flown by `t` at `speed` between `start` and `end`, the speed ramped in over
/// `ramp_s` after `start` and out over `ramp_s` before `end` (closed form of the
/// integral of speed × smoothstep, so positions are exact at any step).
pub(super) fn ramped_distance(t: f64, start: f64, end: f64, ramp_s: f64, speed: f64) -> f64 {
    // ∫ smoothstep5 over [0, x] (x in 0..1) = x⁴(2.5 − 3x + x²)... times the ramp.
    fn ramp_integral(x: f64) -> f64 {
        let x = x.clamp(0.0, 1.0);
        x.powi(4) * (2.5 - 3.0 * x + x * x)
    }
    let up = |t: f64| {
        let x = (t - start) / ramp_s;
        if x <= 1.0 {
            ramp_s * ramp_integral(x)
        } else {
            ramp_s * ramp_integral(1.0) + (t - start - ramp_s)
        }
    };
    let down_start = end - ramp_s;
    let down = |t: f64| {
        // What the ramp-down takes away from full speed after down_start.
        let x = (t - down_start) / ramp_s;
        if x <= 0.0 {
            0.0
        } else if x <= 1.0 {
            ramp_s * ramp_integral(x)
        } else {
            ramp_s * ramp_integral(1.0) + (t - down_start - ramp_s)
        }
    };
    speed * (up(t.max(start)) - down(t))
}

/// Amplitude of the hover's wander, m.
const HOVER_WANDER_M: f64 = 0.3;

fn yaw_at(profile: Profile, t: f64) -> f64 {
    match profile {
        // Nose along the track, as a vehicle cruising forward flies.
        Profile::Laps => 0.4 + lap_distance(t) / LAP_RADIUS_M,
        Profile::Plan(p) => p.yaw(t),
        _ => 0.4 + 0.5 * (2.0 * PI * t / 45.0).sin() * envelope(t),
    }
}

fn attitude_from(acc: Vector3<f64>, yaw: f64) -> UnitQuaternion<f64> {
    // A multirotor tilts its thrust axis (body z) along the required specific force.
    let thrust = acc + Vector3::new(0.0, 0.0, GRAVITY);
    let q_yaw = UnitQuaternion::from_euler_angles(0.0, 0.0, yaw);
    let q_tilt = UnitQuaternion::rotation_between(&Vector3::z(), &thrust)
        .unwrap_or_else(UnitQuaternion::identity);
    q_tilt * q_yaw
}

/// Truth of the demo flight at time `t` seconds since the start (loops every [`LOOP_S`]).
pub fn truth(t: f64) -> TruthState {
    truth_of(Profile::Demo, t)
}

/// Truth of a flight `profile` at time `t` seconds since the start (loops every [`LOOP_S`]).
pub fn truth_of(profile: Profile, t: f64) -> TruthState {
    let position_at = |t: f64| position_at(profile, t);
    // The demo's flights repeat; a drawn one stays where it landed.
    let tl = match profile {
        Profile::Plan(p) => t.clamp(0.0, p.loop_s()),
        _ => t.rem_euclid(loop_s(profile)),
    };
    let h = 1e-3;
    let p0 = position_at(tl - h);
    let p1 = position_at(tl);
    let p2 = position_at(tl + h);
    let velocity = (p2 - p0) / (2.0 * h);
    let acceleration = (p2 - 2.0 * p1 + p0) / (h * h);
    let att = |tt: f64| {
        let a = (position_at(tt + h) - 2.0 * position_at(tt) + position_at(tt - h)) / (h * h);
        attitude_from(a, yaw_at(profile, tt))
    };
    let attitude = att(tl);
    let q_next = att(tl + h);
    let q_prev = att(tl - h);
    // Body rate from the attitude's derivative: q⁻¹·q(t+h) over 2h, centred.
    let body_rate = (q_prev.inverse() * q_next).scaled_axis() / (2.0 * h);
    TruthState {
        t,
        position: p1,
        velocity,
        acceleration,
        attitude,
        body_rate,
        indoor: match profile {
            Profile::Demo => (T_INDOOR..T_OUTDOOR_AGAIN).contains(&tl),
            Profile::Indoor => true,
            Profile::Figure8
            | Profile::Hover
            | Profile::HighHover
            | Profile::Laps
            | Profile::Plan(_) => false,
        },
    }
}

impl TruthState {
    /// What an ideal accelerometer reads: specific force in body FLU.
    pub fn specific_force(&self) -> Vector3<f64> {
        self.attitude.inverse() * (self.acceleration + Vector3::new(0.0, 0.0, GRAVITY))
    }

    /// Velocity in body FLU.
    pub fn body_velocity(&self) -> Vector3<f64> {
        self.attitude.inverse() * self.velocity
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn on_ground_level_and_still_at_start() {
        let s = truth(1.0);
        assert!(s.position.norm() < 1e-9);
        assert!((s.specific_force() - Vector3::new(0.0, 0.0, GRAVITY)).norm() < 1e-6);
    }

    #[test]
    fn cruise_height_and_motion() {
        let s = truth(40.0);
        assert!((s.position.z - CRUISE_HEIGHT).abs() < 1e-6);
        assert!(s.velocity.norm() > 0.3, "moving: {}", s.velocity);
        assert!(truth(80.0).indoor && !truth(40.0).indoor);
        // Back on the ground at the end of a loop.
        assert!(truth(LOOP_S - 1.0).position.norm() < 1e-6);
    }

    #[test]
    fn body_rate_integrates_to_the_attitude() {
        // Integrating the body rate reproduces the attitude change: checks the sign
        // convention the IMU model relies on.
        let (t0, t1, dt) = (20.0, 22.0, 1e-3);
        let mut q = truth(t0).attitude;
        let mut t = t0;
        while t < t1 - 1e-9 {
            let w = truth(t + dt / 2.0).body_rate;
            q *= UnitQuaternion::from_scaled_axis(w * dt);
            t += dt;
        }
        let err = (q.inverse() * truth(t1).attitude).angle();
        assert!(err < 1e-4, "attitude error {err}");
    }

    #[test]
    fn tilt_follows_acceleration() {
        let s = truth(25.0);
        let f = s.attitude * s.specific_force();
        let thrust_dir = s.attitude * Vector3::z();
        assert!((f.normalize() - thrust_dir).norm() < 1e-6);
    }
}
