//! Flights drawn by the Monte Carlo runs ([`super::monte_carlo`]): a hover, laps, a
//! figure-eight or a climb beyond the range finder, of any length, height, size and
//! speed, each taking off, flying and landing smoothly (the position is C², so the IMU
//! derived from it is consistent). [`super::truth::Profile::Plan`] flies one.

use super::truth::{ramped_distance, smoothstep5};
use nalgebra::Vector3;
use std::f64::consts::PI;

/// What the vehicle does between take-off and landing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum PlanKind {
    /// Position hold with a wind-driven wander of `size_m` and slow yaw changes.
    Hover,
    /// Circles of radius `size_m` at `speed_mps`, nose along the track.
    Laps,
    /// A figure-eight `size_m` wide whose fastest point is `speed_mps`.
    Figure8,
    /// Up to `climb_to_m` (beyond the range finder), a slow figure-eight there, back
    /// down to `height_m`.
    Climb,
    /// An offboard square as PX4's tests fly it: from corner to corner of a square
    /// `size_m` wide in one quick move each (peak `speed_mps`, 5.8·size/T² m/s² at its
    /// ends: the hard steps), holding [`SQUARE_HOLD_S`] at each corner, the nose fixed.
    Square,
}

impl PlanKind {
    /// The kinds the Monte Carlo runs draw from.
    pub const ALL: [PlanKind; 4] = [
        PlanKind::Hover,
        PlanKind::Laps,
        PlanKind::Figure8,
        PlanKind::Climb,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            PlanKind::Hover => "hover",
            PlanKind::Laps => "laps",
            PlanKind::Figure8 => "figure8",
            PlanKind::Climb => "climb",
            PlanKind::Square => "square",
        }
    }
}

/// One flight. Times in seconds from the start (on the ground until `TAKEOFF_S`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlightPlan {
    pub kind: PlanKind,
    /// From the start to standing on the ground again (a few seconds more follow).
    pub duration_s: f64,
    /// Cruise height above the take-off point, m.
    pub height_m: f64,
    /// Fastest horizontal speed, m/s.
    pub speed_mps: f64,
    /// Radius of the laps, width of the figure-eight, amplitude of the hover's wander, m.
    pub size_m: f64,
    /// [`PlanKind::Climb`]: the height climbed to, m.
    pub climb_to_m: f64,
    /// Amplitude of the slow yaw changes, rad (laps: the nose follows the track).
    pub yaw_swing_rad: f64,
    /// Initial heading, rad (ENU, from east).
    pub yaw0_rad: f64,
}

/// On the ground before this, s.
pub const TAKEOFF_S: f64 = 4.0;
/// Vertical speed of take-off and landing, m/s.
const CLIMB_RATE: f64 = 1.0;
/// How long the horizontal motion takes to ramp in and out, s.
const RAMP_S: f64 = 10.0;
/// Vertical speed of the climb beyond the range finder, m/s.
const HIGH_CLIMB_RATE: f64 = 1.5;
/// On the ground after landing before the flight's loop repeats, s.
const AFTER_LANDING_S: f64 = 4.0;
/// [`PlanKind::Square`]: the hold at each corner, s.
pub const SQUARE_HOLD_S: f64 = 4.0;

impl FlightPlan {
    /// The flight's loop: flight, then standing on the ground.
    pub fn loop_s(&self) -> f64 {
        self.duration_s + AFTER_LANDING_S
    }

    fn climb_s(&self) -> f64 {
        (self.height_m / CLIMB_RATE).max(3.0)
    }

    /// [`PlanKind::Square`]: when its first move (its first hard step) starts, s.
    pub fn square_first_move_s(&self) -> f64 {
        self.cruise().0 + SQUARE_HOLD_S
    }

    /// Take-off ends, landing starts.
    fn cruise(&self) -> (f64, f64) {
        let c = self.climb_s();
        (TAKEOFF_S + c, self.duration_s - c)
    }

    /// Fraction of the horizontal motion flown at `t` (0 on the ground, 1 cruising).
    fn envelope(&self, t: f64) -> f64 {
        let (a, b) = self.cruise();
        smoothstep5((t - a) / RAMP_S) * (1.0 - smoothstep5((t - (b - RAMP_S)) / RAMP_S))
    }

    fn height(&self, t: f64) -> f64 {
        let (a, b) = self.cruise();
        let base = self.height_m
            * smoothstep5((t - TAKEOFF_S) / (a - TAKEOFF_S))
            * (1.0 - smoothstep5((t - b) / (self.duration_s - b)));
        if self.kind != PlanKind::Climb {
            return base;
        }
        // Up after the ramp, down before the ramp out.
        let rise = (self.climb_to_m - self.height_m).max(0.0);
        let up_s = (rise / HIGH_CLIMB_RATE).max(4.0);
        let (u0, d0) = (a + RAMP_S, b - RAMP_S - up_s);
        if d0 <= u0 + up_s {
            return base;
        }
        base + rise * smoothstep5((t - u0) / up_s) * (1.0 - smoothstep5((t - d0) / up_s))
    }

    /// Distance along the laps' circle by `t`: ∫ speed · envelope, in closed form
    /// (the smoothstep's integral), so positions are exact at any step.
    fn lap_distance(&self, t: f64) -> f64 {
        self.distance_at(t, self.speed_mps)
    }

    /// Distance flown by `t` at `speed` ramped in and out (see [`Self::lap_distance`]).
    fn distance_at(&self, t: f64, speed: f64) -> f64 {
        let (a, b) = self.cruise();
        ramped_distance(t, a, b, RAMP_S, speed)
    }

    /// [`PlanKind::Square`]: where on the square at `t`. Each move is a quintic
    /// smoothstep over `T = 1.875·size/speed` (its peak speed is `speed_mps`), then the
    /// hold; only moves that end before the landing starts are flown.
    fn square_xy(&self, t: f64) -> Vector3<f64> {
        const CORNERS: [(f64, f64); 4] = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)];
        let side = self.size_m.max(1.0);
        let move_s = 1.875 * side / self.speed_mps.max(0.1);
        let leg_s = move_s + SQUARE_HOLD_S;
        let (a, b) = self.cruise();
        let legs = ((b - a - SQUARE_HOLD_S) / leg_s).floor().max(0.0);
        let tau = (t - a - SQUARE_HOLD_S).clamp(0.0, legs * leg_s);
        let k = (tau / leg_s).floor();
        let frac = if k >= legs {
            0.0
        } else {
            smoothstep5((tau - k * leg_s) / move_s)
        };
        let (x0, y0) = CORNERS[(k as usize) % 4];
        let (x1, y1) = CORNERS[(k as usize + 1) % 4];
        Vector3::new(x0 + (x1 - x0) * frac, y0 + (y1 - y0) * frac, 0.0) * side
    }

    /// Position at `t` (within one loop), m.
    pub fn position(&self, t: f64) -> Vector3<f64> {
        let z = self.height(t);
        let e = self.envelope(t);
        let tau = (t - self.cruise().0).max(0.0);
        let xy = match self.kind {
            PlanKind::Hover => {
                let a = self.size_m * e;
                Vector3::new(
                    a * (0.7 * (2.0 * PI * tau / 41.0).sin() + 0.3 * (2.0 * PI * tau / 13.0).sin()),
                    a * (0.6 * (2.0 * PI * tau / 37.0).sin() + 0.4 * (2.0 * PI * tau / 11.0).sin()),
                    0.0,
                )
            }
            PlanKind::Laps => {
                let r = self.size_m.max(1.0);
                let phi = self.lap_distance(t) / r;
                Vector3::new(r * phi.sin(), r * (1.0 - phi.cos()), 0.0)
            }
            PlanKind::Figure8 | PlanKind::Climb => {
                // x = A sin θ, y = A/2 sin 2θ: fastest at the crossing, A·θ'·√2; θ
                // advances with the ramped speed, as the laps' distance does.
                let a = 0.5 * self.size_m.max(1.0);
                let speed = if self.kind == PlanKind::Climb {
                    self.speed_mps.min(2.0)
                } else {
                    self.speed_mps
                };
                let theta = self.distance_at(t, speed) / (a * 2f64.sqrt());
                Vector3::new(a * theta.sin(), a * 0.5 * (2.0 * theta).sin(), 0.0)
            }
            PlanKind::Square => self.square_xy(t),
        };
        Vector3::new(xy.x, xy.y, z)
    }

    /// Heading at `t`, rad (ENU).
    pub fn yaw(&self, t: f64) -> f64 {
        match self.kind {
            PlanKind::Laps => self.yaw0_rad + self.lap_distance(t) / self.size_m.max(1.0),
            PlanKind::Square => self.yaw0_rad,
            _ => {
                self.yaw0_rad + self.yaw_swing_rad * (2.0 * PI * t / 45.0).sin() * self.envelope(t)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plan(kind: PlanKind) -> FlightPlan {
        FlightPlan {
            kind,
            duration_s: 200.0,
            height_m: 3.0,
            speed_mps: 5.0,
            size_m: if kind == PlanKind::Hover { 1.5 } else { 30.0 },
            climb_to_m: 15.0,
            yaw_swing_rad: 0.5,
            yaw0_rad: 0.3,
        }
    }

    #[test]
    fn every_kind_takes_off_flies_at_its_speed_and_lands() {
        for kind in PlanKind::ALL.into_iter().chain([PlanKind::Square]) {
            let p = plan(kind);
            assert!(p.position(1.0).norm() < 1e-9, "{kind:?} on the ground");
            let landed = p.position(p.duration_s + 1.0);
            let still = p.position(p.duration_s + 2.0) - landed;
            assert!(
                landed.z.abs() < 1e-6 && still.norm() < 1e-6,
                "{kind:?} landed"
            );
            let (mut top_speed, mut top_height) = (0.0f64, 0.0f64);
            let mut t = 0.0;
            while t < p.duration_s {
                let v = (p.position(t + 0.01) - p.position(t - 0.01)) / 0.02;
                top_speed = top_speed.max(v.xy().norm());
                top_height = top_height.max(p.position(t).z);
                t += 0.1;
            }
            let speed_cap = if kind == PlanKind::Climb { 2.0 } else { 5.0 };
            match kind {
                PlanKind::Hover => assert!(top_speed < 2.0, "{kind:?} {top_speed}"),
                _ => assert!(
                    (top_speed - speed_cap).abs() < 0.1,
                    "{kind:?} top speed {top_speed}"
                ),
            }
            let want = if kind == PlanKind::Climb { 15.0 } else { 3.0 };
            assert!((top_height - want).abs() < 1e-3, "{kind:?} {top_height}");
        }
    }
}
