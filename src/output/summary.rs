//! The keys under a vehicle's output prefix that the fleet view reads, and
//! `<prefix>/summary`, the once-a-second message made for it. Here, with the outputs,
//! because the vehicle publishes them; the fleet view (`crate::fleet`) and the
//! stand-in fleet (`crate::sim::fleet`) use them from here.

/// The JSON pose, at the output rate.
pub const POSE: &str = "pose";
/// Health, once a second.
pub const HEALTH: &str = "health";
/// Each event.
pub const EVENTS: &str = "events";
/// The once-a-second summary (pose and health verdict) the fleet view reads by default.
pub const SUMMARY: &str = "summary";
/// The liveliness token a vehicle holds while it runs.
pub const ALIVE: &str = "alive";

use super::precision::{
    decimals, significant, COVARIANCE_DIGITS, DEGREE_DECIMALS, METRE_DECIMALS, QUATERNION_DECIMALS,
};

/// `<prefix>/summary`, as a vehicle publishes it once a second: its newest pose (the
/// `<prefix>/pose` message, null before the first) cut to what the fleet view reads,
/// and the parts of its health message it reads (who it is, VISION_POSITION_ESTIMATE,
/// its Zenoh link, each sensor's state without the detail). About 1 KB once a second
/// against the pose's 50 a second and the health's 10 KB: what lets one monitor follow
/// a thousand vehicles.
///
/// The pose keeps `time_us`, `position`, `orientation`, `velocity`,
/// `position_covariance`, `sources`, `valid`, `invalid_reason`, `origin`, its numbers
/// to the precision of [`super::precision`] (as `<prefix>/pose` writes them; rounded
/// again here for poses from elsewhere); the pose with every covariance and the
/// protection levels stays on `<prefix>/pose`.
pub fn summary_json(
    pose: Option<serde_json::Value>,
    health: &serde_json::Value,
) -> serde_json::Value {
    let sensors: Vec<serde_json::Value> = health["sensors"]
        .as_array()
        .map(|a| {
            a.iter()
                .map(|s| serde_json::json!({"id": s["id"], "health": s["health"]}))
                .collect()
        })
        .unwrap_or_default();
    let pose = pose.filter(|p| p.is_object()).map(|p| {
        let dec = |key: &str, d: i32| rounded(&p[key], |x| decimals(x, d));
        serde_json::json!({
            "time_us": p["time_us"],
            "position": dec("position", METRE_DECIMALS),
            "orientation": dec("orientation", QUATERNION_DECIMALS),
            "velocity": dec("velocity", METRE_DECIMALS),
            "position_covariance": rounded(&p["position_covariance"], |x| significant(x, COVARIANCE_DIGITS)),
            "sources": p["sources"],
            "valid": p["valid"],
            "invalid_reason": p["invalid_reason"],
            "origin": if p["origin"].is_object() {
                serde_json::json!({
                    "lat": rounded(&p["origin"]["lat"], |x| decimals(x, DEGREE_DECIMALS)),
                    "lon": rounded(&p["origin"]["lon"], |x| decimals(x, DEGREE_DECIMALS)),
                    "alt": rounded(&p["origin"]["alt"], |x| decimals(x, METRE_DECIMALS)),
                })
            } else {
                serde_json::Value::Null
            },
        })
    });
    serde_json::json!({
        "time_us": health["time_us"],
        "pose": pose,
        "service": health["service"],
        "vpe": {
            "endpoints": health["vpe"]["endpoints"],
            "sending": health["vpe"]["sending"],
            "reason": health["vpe"]["reason"],
        },
        "zenoh": health["zenoh"],
        "sensors": sensors,
    })
}

/// A number, or each number of an array, through `f`; anything else as it is.
fn rounded(v: &serde_json::Value, f: impl Fn(f64) -> f64) -> serde_json::Value {
    rounded_dyn(v, &f)
}

fn rounded_dyn(v: &serde_json::Value, f: &dyn Fn(f64) -> f64) -> serde_json::Value {
    match v {
        serde_json::Value::Array(a) => {
            serde_json::Value::Array(a.iter().map(|x| rounded_dyn(x, f)).collect())
        }
        serde_json::Value::Number(n) => n
            .as_f64()
            .map(f)
            .and_then(serde_json::Number::from_f64)
            .map_or_else(|| v.clone(), serde_json::Value::Number),
        _ => v.clone(),
    }
}
