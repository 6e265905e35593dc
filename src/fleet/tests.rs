use super::*;
use serde_json::json;

const S: Micros = 1_000_000;

fn pose(x: f64, y: f64, yaw_enu_deg: f64, origin: Option<(f64, f64)>) -> Vec<u8> {
    let h = yaw_enu_deg.to_radians() / 2.0;
    json!({
        "time_us": 1, "frame": "map",
        "position": [x, y, 2.0], "orientation": [0.0, 0.0, h.sin(), h.cos()],
        "velocity": [3.0, 4.0, 0.0],
        "position_covariance": [0.04, 0, 0, 0, 0.05, 0, 0, 0, 0.1],
        "velocity_covariance": [0.0, 0, 0, 0, 0, 0, 0, 0, 0], "orientation_covariance": [0.0, 0, 0, 0, 0, 0, 0, 0, 0],
        "sources": ["t265", "imu"], "reset_counter": 0, "valid": true, "invalid_reason": null,
        "origin": origin.map(|(lat, lon)| json!({"lat": lat, "lon": lon, "alt": 400.0})),
    })
    .to_string()
    .into_bytes()
}

fn health(vehicle: &str, started_us: i64, gps: &str, endpoints: usize, sending: bool) -> Vec<u8> {
    json!({
        "time_us": 5,
        "service": {"vehicle": vehicle, "version": "0.1.0", "started_us": started_us,
                    "dashboard": format!("http://{vehicle}:8080/")},
        "vpe": {"endpoints": endpoints, "sending": sending, "sent": 10, "withheld": 0,
                "reason": (!sending).then_some("estimate invalid")},
        "zenoh": {"routers": 1, "peers": 0},
        "sensors": [{"id": "gps", "health": gps}, {"id": "imu", "health": "ok"},
                    {"id": "autopilot", "health": "disabled"}],
        "estimator": {"valid": true},
    })
    .to_string()
    .into_bytes()
}

fn fleet() -> Fleet {
    Fleet::new(FleetConfig::default())
}

fn row<'a>(v: &'a FleetView, id: &str) -> &'a VehicleView {
    v.vehicles
        .iter()
        .find(|r| r.id == id)
        .unwrap_or_else(|| panic!("{id} not in the view"))
}

#[test]
fn keys_split_into_vehicle_and_leaf() {
    assert_eq!(
        Fleet::split_key("bot1/skyfuse/drone/pose"),
        Some(("bot1/skyfuse/drone", "pose"))
    );
    assert_eq!(Fleet::split_key("pose"), None);
    assert_eq!(Fleet::split_key("/pose"), None);
}

#[test]
fn vehicles_join_leave_grey_then_forgotten_and_a_restart_keeps_its_place() {
    let mut f = fleet();
    for (i, id) in ["skyfuse/a", "skyfuse/b", "skyfuse/c"].iter().enumerate() {
        f.token_appeared(id, i as i64 * S);
        f.accept(id, POSE, &pose(1.0, 2.0, 0.0, None), i as i64 * S)
            .unwrap();
    }
    f.refresh(2 * S);
    let v = f.view(2 * S, false);
    assert_eq!(
        v.vehicles
            .iter()
            .map(|r| (r.id.as_str(), r.slot))
            .collect::<Vec<_>>(),
        [("skyfuse/a", 0), ("skyfuse/b", 1), ("skyfuse/c", 2)]
    );
    assert!(v.vehicles.iter().all(|r| r.presence == Presence::Live));

    // b stops: its token goes at once, grey; kept for forget_after_s.
    f.token_lost("skyfuse/b", 2 * S + S / 2);
    let v = f.view(2 * S + S / 2, false);
    assert_eq!(row(&v, "skyfuse/b").presence, Presence::Gone);
    assert_eq!(row(&v, "skyfuse/c").presence, Presence::Live);

    // b restarts within forget_after_s: same slot, one restart (its start time).
    f.accept("skyfuse/b", HEALTH, &health("b", 1, "ok", 1, true), S)
        .unwrap();
    f.token_appeared("skyfuse/b", 30 * S);
    f.accept("skyfuse/b", HEALTH, &health("b", 2, "ok", 1, true), 30 * S)
        .unwrap();
    f.accept("skyfuse/b", POSE, &pose(0.0, 0.0, 0.0, None), 30 * S)
        .unwrap();
    f.refresh(30 * S);
    let v = f.view(30 * S, false);
    let b = row(&v, "skyfuse/b");
    assert_eq!((b.slot, b.presence, b.restarts), (1, Presence::Live, 1));
    // a and c went silent at 1-2 s: gone by silence after gone_after_s.
    assert_eq!(row(&v, "skyfuse/a").presence, Presence::Gone);

    // c is forgotten forget_after_s after it went grey; a newcomer takes its slot.
    let late = 2 * S + secs_us(DEFAULT_GONE_S + DEFAULT_FORGET_S) + 1;
    f.accept("skyfuse/b", POSE, &pose(0.0, 0.0, 0.0, None), late)
        .unwrap();
    f.refresh(late);
    let v = f.view(late, false);
    assert!(
        v.vehicles.iter().all(|r| r.id != "skyfuse/c"),
        "c forgotten"
    );
    assert!(
        v.vehicles.iter().all(|r| r.id != "skyfuse/a"),
        "a forgotten"
    );
    f.accept("skyfuse/d", POSE, &pose(0.0, 0.0, 0.0, None), late)
        .unwrap();
    let v = f.view(late, false);
    assert_eq!(row(&v, "skyfuse/d").slot, 0, "lowest free slot");
    assert_eq!(v.counters.forgotten, 2);
    assert_eq!(v.counters.joined, 4);
}

const DEFAULT_GONE_S: f64 = crate::config::DEFAULT_FLEET_GONE_S;
const DEFAULT_FORGET_S: f64 = crate::config::DEFAULT_FLEET_FORGET_S;

#[test]
fn silence_makes_a_vehicle_stale_then_gone() {
    let mut f = fleet();
    f.token_appeared("skyfuse/a", 0);
    f.accept("skyfuse/a", HEALTH, &health("a", 1, "ok", 1, true), 0)
        .unwrap();
    assert_eq!(f.view(2 * S, false).vehicles[0].presence, Presence::Live);
    assert_eq!(f.view(4 * S, false).vehicles[0].presence, Presence::Stale);
    assert_eq!(f.view(11 * S, false).vehicles[0].presence, Presence::Gone);
    // Heard again: live.
    f.accept("skyfuse/a", HEALTH, &health("a", 1, "ok", 1, true), 12 * S)
        .unwrap();
    let v = f.view(12 * S, false);
    assert_eq!(v.vehicles[0].presence, Presence::Live);
    assert_eq!(v.vehicles[0].restarts, 0, "same start time: no restart");
    // A new start time is a restart even if the token never went.
    f.accept("skyfuse/a", HEALTH, &health("a", 2, "ok", 1, true), 13 * S)
        .unwrap();
    assert_eq!(f.view(13 * S, false).vehicles[0].restarts, 1);
}

#[test]
fn health_gives_worst_sensor_vpe_link_and_identity() {
    let mut f = fleet();
    f.accept(
        "ns/skyfuse/x",
        HEALTH,
        &health("drone7", 1, "stale", 1, false),
        0,
    )
    .unwrap();
    f.accept(
        "ns/skyfuse/x",
        EVENTS,
        br#"{"time_us": 3, "t": 0.1, "kind": "health", "source": "gps", "message": "gps stale"}"#,
        0,
    )
    .unwrap();
    let v = f.view(0, false);
    let r = &v.vehicles[0];
    assert_eq!(r.name, "drone7");
    assert_eq!(r.worst_health.as_deref(), Some("stale"));
    assert_eq!(
        r.unhealthy,
        ["gps: stale"],
        "disabled sensors are not counted"
    );
    assert_eq!(
        (r.vpe, r.vpe_reason.as_deref()),
        (Some("withheld"), Some("estimate invalid"))
    );
    assert_eq!(r.dashboard.as_deref(), Some("http://drone7:8080/"));
    assert_eq!(r.zenoh.map(|z| z.routers), Some(1));
    assert_eq!(
        r.last_event.as_ref().map(|e| e.message.as_str()),
        Some("gps stale")
    );
    assert_eq!(r.valid, None, "no pose yet");

    f.accept("ns/skyfuse/y", HEALTH, &health("y", 1, "ok", 0, false), 0)
        .unwrap();
    let v = f.view(0, false);
    assert_eq!(
        row(&v, "ns/skyfuse/y").vpe,
        Some("off"),
        "no MAVLink endpoint"
    );
    assert_eq!(row(&v, "ns/skyfuse/y").worst_health.as_deref(), Some("ok"));
}

#[test]
fn vehicles_with_a_gnss_origin_share_one_map_frame() {
    let mut f = fleet();
    // b's origin is ~111 m north of a's (0.001° of latitude); both at their local (10, 0).
    f.accept(
        "skyfuse/a",
        POSE,
        &pose(10.0, 0.0, 0.0, Some((47.0, 8.0))),
        0,
    )
    .unwrap();
    f.accept(
        "skyfuse/b",
        POSE,
        &pose(10.0, 0.0, 90.0, Some((47.001, 8.0))),
        0,
    )
    .unwrap();
    f.accept("skyfuse/c", POSE, &pose(5.0, 6.0, 0.0, None), 0)
        .unwrap();
    f.refresh(0);
    let v = f.view(0, true);
    let a = row(&v, "skyfuse/a");
    let b = row(&v, "skyfuse/b");
    let c = row(&v, "skyfuse/c");
    let [ax, ay] = a.xy.unwrap();
    let [bx, by] = b.xy.unwrap();
    assert!((ax - 10.0).abs() < 1e-6 && ay.abs() < 1e-6, "{ax} {ay}");
    assert!(
        (bx - 10.0).abs() < 0.05 && (by - 111.2).abs() < 0.2,
        "{bx} {by}"
    );
    assert_eq!((a.frame, c.frame), (Some("geo"), Some("local")));
    assert_eq!(c.xy, Some([5.0, 6.0]));
    // ENU yaw 0 (facing east) is heading 90°; yaw 90° (north) is heading 0°.
    assert!((a.heading_deg.unwrap() - 90.0).abs() < 1e-9);
    assert!(b.heading_deg.unwrap().abs() < 1e-9 || (b.heading_deg.unwrap() - 360.0).abs() < 1e-9);
    assert!((a.speed_m_s.unwrap() - 5.0).abs() < 1e-12);
    assert!((a.position_std_m.unwrap() - 0.09f64.sqrt()).abs() < 1e-12);
    assert_eq!(v.reference.map(|r| r.lat), Some(47.0));
    assert_eq!(a.track.as_deref(), Some(&[[ax, ay]][..]));
}

#[test]
fn poses_are_parsed_at_refresh_and_the_track_keeps_a_point_a_second() {
    let mut f = fleet();
    // 30 Hz for 3 s, refreshed at 2 Hz: only the newest pose of each refresh is read.
    for i in 0..90 {
        let t = i * S / 30;
        f.accept("skyfuse/a", POSE, &pose(i as f64, 0.0, 0.0, None), t)
            .unwrap();
        if i % 15 == 14 {
            f.refresh(t);
        }
    }
    let v = f.view(3 * S, true);
    let track = v.vehicles[0].track.clone().unwrap();
    assert_eq!(track.len(), 3, "{track:?}");
    assert_eq!(v.vehicles[0].xy, Some([89.0, 0.0]));
    assert_eq!(v.counters.messages, 90);
}

#[test]
fn bad_payloads_are_counted_and_change_nothing() {
    let mut f = fleet();
    f.accept("skyfuse/a", POSE, &pose(1.0, 1.0, 0.0, None), 0)
        .unwrap();
    f.refresh(0);
    assert!(f.accept("skyfuse/a", HEALTH, b"{not json", S).is_err());
    assert!(f.accept("skyfuse/a", EVENTS, br#"{"kind": 1}"#, S).is_err());
    assert!(f.accept("skyfuse/a", "other", b"{}", S).is_err());
    f.accept("skyfuse/a", POSE, b"\xff\x00garbage", S).unwrap();
    let errors = f.refresh(S);
    assert_eq!(errors.len(), 1);
    assert_eq!(errors[0].key, "skyfuse/a/pose");
    let v = f.view(S, false);
    assert_eq!(
        v.vehicles[0].xy,
        Some([1.0, 1.0]),
        "the last good pose stays"
    );
    assert_eq!(v.counters.rejected, 4);
    // A pose with a huge number (serde reads 1e999 as an error, not infinity).
    f.accept("skyfuse/a", POSE, br#"{"position": [1e999, 0, 0]}"#, S)
        .unwrap();
    assert_eq!(f.refresh(S).len(), 1);
}

#[test]
fn a_vehicle_that_gains_a_gnss_origin_starts_a_new_track() {
    let mut f = fleet();
    f.accept(
        "skyfuse/a",
        POSE,
        &pose(0.0, 0.0, 0.0, Some((47.0, 8.0))),
        0,
    )
    .unwrap();
    f.refresh(0);
    // b first has no origin (its own frame), then one 100 m further north.
    f.accept("skyfuse/b", POSE, &pose(1.0, 1.0, 0.0, None), 0)
        .unwrap();
    f.refresh(0);
    f.accept(
        "skyfuse/b",
        POSE,
        &pose(1.0, 1.0, 0.0, Some((47.0009, 8.0))),
        2 * S,
    )
    .unwrap();
    f.refresh(2 * S);
    let v = f.view(2 * S, true);
    let b = row(&v, "skyfuse/b");
    assert_eq!(b.frame, Some("geo"));
    let track = b.track.clone().unwrap();
    assert_eq!(
        track.len(),
        1,
        "the local point is not joined to the geo one: {track:?}"
    );
    assert!(track[0][1] > 90.0, "{track:?}");
}

fn summary(vehicle: &str, started_us: i64, gps: &str, x: f64) -> Vec<u8> {
    let p: serde_json::Value =
        serde_json::from_slice(&pose(x, 0.0, 90.0, Some((47.0, 8.0)))).expect("pose");
    let h: serde_json::Value =
        serde_json::from_slice(&health(vehicle, started_us, gps, 1, true)).expect("health");
    summary_json(Some(p), &h).to_string().into_bytes()
}

#[test]
fn a_summary_alone_gives_the_whole_row() {
    let mut f = fleet();
    let s = summary("a", 7, "degraded", 3.0);
    f.accept("ns/skyfuse/a", SUMMARY, &s, 0).expect("summary");
    f.refresh(0);
    let v = f.view(0, true);
    let r = row(&v, "ns/skyfuse/a");
    assert_eq!(r.name, "a");
    assert_eq!(r.valid, Some(true));
    assert_eq!(r.frame, Some("geo"));
    assert_eq!(r.worst_health.as_deref(), Some("degraded"));
    assert_eq!(r.unhealthy, vec!["gps: degraded".to_string()]);
    assert_eq!(r.vpe, Some("sending"));
    assert_eq!(r.track.as_ref().map(Vec::len), Some(1));
    // A new start time in a summary is a restart, as in a health message.
    f.accept("ns/skyfuse/a", SUMMARY, &summary("a", 8, "ok", 4.0), S)
        .expect("summary");
    f.refresh(S);
    assert_eq!(row(&f.view(S, false), "ns/skyfuse/a").restarts, 1);
    // A summary before the first pose (pose null) still names the vehicle.
    let h: serde_json::Value =
        serde_json::from_slice(&health("b", 1, "ok", 0, false)).expect("health");
    let early = summary_json(None, &h).to_string().into_bytes();
    f.accept("ns/skyfuse/b", SUMMARY, &early, S).expect("early");
    let v = f.view(S, false);
    assert_eq!(row(&v, "ns/skyfuse/b").valid, None);
    assert_eq!(row(&v, "ns/skyfuse/b").vpe, Some("off"));
}

#[test]
fn a_summary_with_a_non_finite_pose_is_refused_whole() {
    let mut f = fleet();
    let bad = summary("a", 1, "ok", 1.0)
        .iter()
        .map(|&b| b as char)
        .collect::<String>()
        .replacen("\"position\":[1.0", "\"position\":[1e999", 1);
    assert!(bad.contains("1e999"), "{bad}");
    assert!(f.accept("skyfuse/a", SUMMARY, bad.as_bytes(), 0).is_err());
    assert_eq!(f.counters().rejected, 1);
    assert!(f.is_empty(), "nothing of it is shown");
}

#[test]
fn memory_is_bounded_per_vehicle_and_in_vehicles() {
    let mut f = Fleet::new(FleetConfig {
        max_vehicles: 3,
        ..FleetConfig::default()
    });
    for i in 0..5 {
        let _ = f.accept(
            &format!("skyfuse/v{i}"),
            SUMMARY,
            &summary("v", 1, "ok", 0.0),
            0,
        );
    }
    assert_eq!(f.len(), 3);
    assert_eq!(f.counters().refused, 2);
    // An id longer than the cap is refused, a payload over the cap is not read.
    let long = format!("skyfuse/{}", "x".repeat(MAX_ID_LEN));
    let mut g = fleet();
    g.accept(&long, SUMMARY, &summary("v", 1, "ok", 0.0), 0)
        .expect("read, not kept");
    assert!(g.is_empty());
    assert_eq!(g.counters().refused, 1);
    let huge = vec![b' '; MAX_PAYLOAD + 1];
    assert!(g.accept("skyfuse/a", SUMMARY, &huge, 0).is_err());
    assert!(g.is_empty());
    // Lists and texts are capped: a health with 1000 sensors and a 10 KB name.
    let sensors: Vec<serde_json::Value> = (0..1000)
        .map(|i| json!({"id": format!("s{i}"), "health": "failed"}))
        .collect();
    let h = json!({"service": {"vehicle": "n".repeat(10_000), "version": "1", "started_us": 1,
                               "dashboard": null},
                   "sensors": sensors});
    g.accept("skyfuse/a", HEALTH, h.to_string().as_bytes(), 0)
        .expect("health");
    let v = g.view(0, false);
    let r = row(&v, "skyfuse/a");
    assert!(r.name.len() <= 300, "{}", r.name.len());
    assert!(r.unhealthy.len() <= 32, "{}", r.unhealthy.len());
}

#[test]
fn slots_are_reused_lowest_first_after_a_vehicle_is_forgotten() {
    let mut f = fleet();
    for (i, id) in ["skyfuse/a", "skyfuse/b", "skyfuse/c"].iter().enumerate() {
        f.token_appeared(id, i as i64);
    }
    f.token_lost("skyfuse/a", 0);
    f.token_lost("skyfuse/b", 0);
    // Forgotten after forget_after_s; c stays (it was heard later and keeps its token).
    let later = 125 * S;
    f.token_appeared("skyfuse/c", later);
    f.refresh(later);
    assert_eq!(f.len(), 1);
    f.token_appeared("skyfuse/d", later);
    f.token_appeared("skyfuse/e", later);
    f.token_appeared("skyfuse/f", later);
    let v = f.view(later, false);
    assert_eq!(row(&v, "skyfuse/c").slot, 2);
    assert_eq!(row(&v, "skyfuse/d").slot, 0);
    assert_eq!(row(&v, "skyfuse/e").slot, 1);
    assert_eq!(row(&v, "skyfuse/f").slot, 3);
}

#[test]
fn the_summary_rounds_what_a_map_shows_and_leaves_out_what_the_view_does_not_read() {
    let pose = json!({
        "time_us": 7, "frame": "map",
        "position": [5.895998034390311, -0.7185101202318966, 1.7917912186656828],
        "orientation": [-0.010617414527257387, -0.011077593999817224, 0.34240022377629004, 0.9394288925607333],
        "velocity": [0.123456789, 0.0, -2.5],
        "position_covariance": [0.000016123456, 0.0, 0.0, 0.0, 123456.789, 0.0, 0.0, 0.0, 1.0],
        "velocity_covariance": [0.0, 0, 0, 0, 0, 0, 0, 0, 0], "orientation_covariance": [0.0, 0, 0, 0, 0, 0, 0, 0, 0],
        "sources": ["gps"], "reset_counter": 0, "valid": true, "invalid_reason": null,
        "origin": {"lat": 47.397741065338046, "lon": 8.545616413970455, "alt": 488.6081333681941},
        "protection": {"horizontal_m": 1.0, "vertical_m": 2.0, "horizontal_alert_m": 10.0, "vertical_alert_m": 15.0},
    });
    let h: serde_json::Value =
        serde_json::from_slice(&health("a", 1, "ok", 1, true)).expect("health");
    let s = summary_json(Some(pose), &h);
    let p = &s["pose"];
    assert_eq!(p["position"], json!([5.896, -0.719, 1.792]));
    assert_eq!(p["orientation"][2], json!(0.3424));
    assert_eq!(p["velocity"], json!([0.123, 0.0, -2.5]));
    assert_eq!(
        p["position_covariance"],
        json!([1.612e-5, 0.0, 0.0, 0.0, 123500.0, 0.0, 0.0, 0.0, 1.0])
    );
    assert_eq!(p["origin"]["lat"], json!(47.39774107));
    for gone in [
        "velocity_covariance",
        "orientation_covariance",
        "protection",
        "frame",
    ] {
        assert!(p.get(gone).is_none(), "{gone} in {p}");
    }
    // What the view reads of it is all there: it makes a row.
    let mut f = fleet();
    f.accept("skyfuse/a", SUMMARY, s.to_string().as_bytes(), 0)
        .expect("summary");
    f.refresh(0);
    let v = f.view(0, false);
    assert_eq!(row(&v, "skyfuse/a").valid, Some(true));
    assert_eq!(row(&v, "skyfuse/a").frame, Some("geo"));
}
