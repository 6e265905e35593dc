//! `skyfuse sim --fleet N`: N light stand-in vehicles from one process, for the fleet
//! view's tests and benchmarks at hundreds to thousands of vehicles.
//!
//! Each holds the liveliness token `skyfuse/<name>/alive` and publishes what a real
//! skyfuse publishes under its default `[output] prefix`: `pose` (the same JSON,
//! [`PoseMessage`]) at `--pose-hz`, `health` and `summary` ([`crate::fleet::summary_json`],
//! the function the real output calls) once a second, and one `events` message at start.
//! No estimator and no sensors: a vehicle costs a few messages' serialisation, so a
//! thousand fit on a small machine beside their routers and the monitor. Keys go through
//! the session's namespace (`--namespace`), as a real vehicle's do.
//!
//! Each flies a circle of its own around an origin of its own (a grid of 30 m cells
//! north-east of `--home`); every 17th reports a degraded GNSS and every 29th an invalid
//! estimate, so a fleet page has states to sort and filter.

use crate::estimator::Protection;
use crate::output::summary::{summary_json, ALIVE, EVENTS, HEALTH, POSE, SUMMARY};
use crate::output::zenoh_out::{GeoPoint, PoseMessage};
use std::future::Future;
use std::time::{Duration, Instant};

/// What to fly.
#[derive(Debug, Clone)]
pub struct FleetSim {
    pub vehicles: usize,
    /// The first vehicle's number (names `v<first>`, `v<first+1>`, …): two processes on
    /// two routers fly disjoint fleets.
    pub first: usize,
    pub pose_hz: f64,
    /// GNSS home of the grid: lat, lon (deg), alt (m).
    pub home: (f64, f64, f64),
    /// Seconds to fly (infinite: until a signal).
    pub duration: f64,
}

/// Messages and payload bytes published, by key.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct FleetSimReport {
    pub vehicles: usize,
    pub seconds: f64,
    pub messages: Counts,
    pub bytes: Counts,
    /// Poses per vehicle per second actually published.
    pub pose_rate_per_vehicle: f64,
    /// Puts Zenoh refused (none expected).
    pub errors: u64,
}

#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct Counts {
    pub pose: u64,
    pub summary: u64,
    pub health: u64,
    pub events: u64,
}

/// The grid cell, m.
const CELL_M: f64 = 30.0;
/// Vehicles per grid row.
const ROW: usize = 40;
/// Metres per degree of latitude (near enough for placing origins).
const M_PER_DEG: f64 = 111_320.0;

/// The name of vehicle `i`.
pub fn name(i: usize) -> String {
    format!("v{i:04}")
}

struct Vehicle {
    name: String,
    origin: GeoPoint,
    radius_m: f64,
    omega: f64,
    phase: f64,
    pose: zenoh::pubsub::Publisher<'static>,
    summary: zenoh::pubsub::Publisher<'static>,
    health: zenoh::pubsub::Publisher<'static>,
    _token: zenoh::liveliness::LivelinessToken,
}

impl Vehicle {
    /// The pose message at `t` s into the flight.
    fn pose(&self, i: usize, t: f64, time_us: i64) -> serde_json::Value {
        let a = self.omega * t + self.phase;
        let (s, c) = a.sin_cos();
        let r = self.radius_m;
        let yaw = a + std::f64::consts::FRAC_PI_2;
        let valid = i % 29 != 28;
        let sources: Vec<String> = ["attitude", "flow", "gps", "imu", "rangefinder", "t265"]
            .map(String::from)
            .into();
        let m = PoseMessage {
            time_us,
            frame: "map",
            position: [r * c, r * s, 10.0],
            orientation: [0.0, 0.0, (yaw / 2.0).sin(), (yaw / 2.0).cos()],
            velocity: [-r * self.omega * s, r * self.omega * c, 0.0],
            position_covariance: [0.09, 0.0, 0.0, 0.0, 0.09, 0.0, 0.0, 0.0, 0.2],
            velocity_covariance: [0.01, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.02],
            orientation_covariance: [1e-4, 0.0, 0.0, 0.0, 1e-4, 0.0, 0.0, 0.0, 4e-4],
            sources: &sources,
            reset_counter: 0,
            valid,
            invalid_reason: (!valid).then_some("position uncertainty above the limit"),
            origin: Some(self.origin),
            protection: Protection {
                horizontal_m: 1.5,
                vertical_m: 2.5,
                horizontal_alert_m: 10.0,
                vertical_alert_m: 15.0,
                anchored_us: None,
            },
        }
        .rounded();
        serde_json::to_value(m).unwrap_or(serde_json::Value::Null)
    }

    /// The health message, shaped as `AppState::health_json`'s.
    fn health(&self, i: usize, started_us: i64, time_us: i64) -> serde_json::Value {
        let gps = if i % 17 == 16 { "degraded" } else { "ok" };
        let valid = i % 29 != 28;
        serde_json::json!({
            "time_us": time_us,
            "service": {"vehicle": self.name, "version": env!("CARGO_PKG_VERSION"),
                        "started_us": started_us, "dashboard": null},
            "vpe": {"endpoints": 1, "sending": valid, "sent": 0, "withheld": 0,
                    "reason": (!valid).then_some("estimate invalid: position uncertainty above the limit")},
            "zenoh": {"routers": 1, "peers": 0},
            // The default config's inputs, as a demo vehicle lists them (the disabled
            // ones too): the summary then weighs what a real one does (~1.1 KB).
            "sensors": [{"id": "gps", "health": gps}, {"id": "t265", "health": "ok"},
                        {"id": "imu", "health": "ok"}, {"id": "flow", "health": "ok"},
                        {"id": "attitude", "health": "ok"}, {"id": "rangefinder", "health": "ok"},
                        {"id": "autopilot", "health": "disabled"}, {"id": "armed", "health": "disabled"},
                        {"id": "landed", "health": "disabled"}, {"id": "baro", "health": "disabled"},
                        {"id": "gps_raw", "health": "disabled"}, {"id": "flow_rad", "health": "disabled"}],
            "estimator": {"valid": valid},
        })
    }
}

/// Declares the fleet's tokens and publishers, then publishes until `duration` or
/// `shutdown`; the tokens go when the vehicles are dropped, as a stopping skyfuse's do.
pub async fn run(
    session: &zenoh::Session,
    sim: &FleetSim,
    shutdown: impl Future<Output = ()>,
) -> Result<FleetSimReport, String> {
    let (lat0, lon0, alt0) = sim.home;
    let m_per_deg_lon = M_PER_DEG * lat0.to_radians().cos().max(1e-6);
    let mut fleet = Vec::with_capacity(sim.vehicles);
    for k in 0..sim.vehicles {
        let i = sim.first + k;
        let name = name(i);
        let prefix = format!("skyfuse/{name}");
        let publisher = |leaf: &str| {
            let key = format!("{prefix}/{leaf}");
            async move {
                session
                    .declare_publisher(key.clone())
                    .congestion_control(zenoh::qos::CongestionControl::Drop)
                    .await
                    .map_err(|e| format!("{key}: {e}"))
            }
        };
        let pose = publisher(POSE).await?;
        let summary = publisher(SUMMARY).await?;
        let health = publisher(HEALTH).await?;
        let token = session
            .liveliness()
            .declare_token(format!("{prefix}/{ALIVE}"))
            .await
            .map_err(|e| format!("{prefix}/{ALIVE}: {e}"))?;
        let (east, north) = ((i % ROW) as f64 * CELL_M, (i / ROW) as f64 * CELL_M);
        fleet.push(Vehicle {
            name,
            origin: GeoPoint {
                lat: lat0 + north / M_PER_DEG,
                lon: lon0 + east / m_per_deg_lon,
                alt: alt0,
            },
            radius_m: 5.0 + (i % 7) as f64,
            omega: 0.2 + 0.02 * (i % 5) as f64,
            phase: i as f64 * 0.7,
            pose,
            summary,
            health,
            _token: token,
        });
    }
    let started_us = crate::clock::now_us();
    let mut report = FleetSimReport {
        vehicles: sim.vehicles,
        ..Default::default()
    };
    for (k, v) in fleet.iter().enumerate() {
        let ev = serde_json::json!({"time_us": started_us, "kind": "started", "source": "service",
                                    "message": format!("{} started (fleet stand-in)", v.name), "data": null});
        let bytes = ev.to_string().into_bytes();
        report.bytes.events += bytes.len() as u64;
        report.messages.events += 1;
        if let Err(e) = session
            .put(format!("skyfuse/{}/{EVENTS}", name(sim.first + k)), bytes)
            .await
        {
            tracing::warn!("fleet sim: event: {e}");
            report.errors += 1;
        }
    }
    tracing::info!(
        vehicles = sim.vehicles,
        first = sim.first,
        pose_hz = sim.pose_hz,
        "fleet sim: publishing"
    );
    let tick = Duration::from_secs_f64(1.0 / sim.pose_hz);
    // The once-a-second messages are spread over the second's ticks, not sent in one
    // burst of N: vehicle k's go out on tick k mod ticks-per-second.
    let per_second = (sim.pose_hz.round() as usize).max(1);
    let mut every = tokio::time::interval(tick);
    every.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let t0 = Instant::now();
    let mut shutdown = std::pin::pin!(shutdown);
    let mut n_tick = 0usize;
    loop {
        tokio::select! {
            _ = every.tick() => {}
            _ = &mut shutdown => break,
        }
        let t = t0.elapsed().as_secs_f64();
        if t >= sim.duration {
            break;
        }
        let now = crate::clock::now_us();
        for (k, v) in fleet.iter().enumerate() {
            let i = sim.first + k;
            let pose = v.pose(i, t, now);
            let bytes = pose.to_string().into_bytes();
            report.messages.pose += 1;
            report.bytes.pose += bytes.len() as u64;
            if v.pose.put(bytes).await.is_err() {
                report.errors += 1;
            }
            if k % per_second == n_tick % per_second {
                let health = v.health(i, started_us, now);
                let summary = summary_json(Some(pose), &health).to_string().into_bytes();
                let health = health.to_string().into_bytes();
                report.messages.summary += 1;
                report.bytes.summary += summary.len() as u64;
                report.messages.health += 1;
                report.bytes.health += health.len() as u64;
                if v.summary.put(summary).await.is_err() || v.health.put(health).await.is_err() {
                    report.errors += 1;
                }
            }
        }
        n_tick += 1;
    }
    report.seconds = t0.elapsed().as_secs_f64();
    report.pose_rate_per_vehicle =
        report.messages.pose as f64 / (sim.vehicles.max(1) as f64 * report.seconds.max(1e-9));
    // Tokens and publishers go here: the vehicles leave as a stopping skyfuse does.
    drop(fleet);
    Ok(report)
}
