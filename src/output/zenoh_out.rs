//! Zenoh out: the fused pose, health and events as JSON under `<prefix>/`, and the
//! seed's ROS topics as ROS 2 CDR (zenoh-bridge-ros2dds turns them into ROS topics):
//! `data_fusion/pose_msg` (geometry_msgs/PoseStamped) and the debug series as
//! geometry_msgs/PointStamped, so the seed's rqt_plot commands work unchanged.

use crate::codec::ros::{Point, PointStamped, Pose, PoseStamped, Quaternion, RosMessage};
use crate::codec::{EncodeError, RosType};
use crate::config::OutputConfig;
use crate::estimator::{DebugSeries, DebugTopic, FusedPose, Protection};
use crate::pipeline::{DebugReceiver, PoseReceiver};
use serde_json::Value;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::broadcast;

/// The summary's period; the full health goes every `[output] health_interval_s` of them.
const SUMMARY_INTERVAL: Duration = Duration::from_secs(1);

/// Counters for the status API.
#[derive(Debug, Default)]
pub struct ZenohOutStats {
    pub poses: AtomicU64,
    clock: super::SendClock,
    pub debug_points: AtomicU64,
    pub events: AtomicU64,
    pub health: AtomicU64,
    pub errors: AtomicU64,
    pub last_error: Mutex<Option<String>>,
    pub px4_odometry: AtomicU64,
    pub px4_withheld: AtomicU64,
    pub px4_not_sending: Mutex<Option<String>>,
}

impl ZenohOutStats {
    fn error(&self, e: String) {
        self.errors.fetch_add(1, Relaxed);
        let mut l = crate::sync::lock(&self.last_error);
        if l.as_deref() != Some(e.as_str()) {
            tracing::warn!("Zenoh output: {e}");
        }
        *l = Some(e);
    }

    /// A pose was not sent to PX4 as VehicleOdometry, for `why`.
    fn px4_withheld(&self, why: String) {
        self.px4_withheld.fetch_add(1, Relaxed);
        let mut r = crate::sync::lock(&self.px4_not_sending);
        let kind = |t: &str| t.split(':').next().unwrap_or(t).to_string();
        if r.as_deref().map(kind) != Some(kind(&why)) {
            tracing::warn!("px4_msgs odometry: not sending: {why}");
        }
        *r = Some(why);
    }

    /// A pose was published at `now`.
    fn sent(&self, now: i64) {
        self.poses.fetch_add(1, Relaxed);
        self.clock.sent(now);
    }

    pub fn status(&self, now: i64, cfg: &OutputConfig, prefix: &str) -> super::OutputStatus {
        // What the page and /metrics say comes from here: sending only if a pose left
        // lately, and why not otherwise.
        let reason = match self.clock.age_us(now) {
            None => Some(
                "no pose published yet: the estimator has produced none (see its status)"
                    .to_string(),
            ),
            Some(_) if self.clock.recent(now) => None,
            Some(age) => Some(format!(
                "no pose published for {:.0} s: the estimator has produced none (see its status)",
                age as f64 * 1e-6
            )),
        };
        let ros = if cfg.ros2 {
            format!(", {}", cfg.ros2_pose_key)
        } else {
            String::new()
        };
        super::OutputStatus {
            name: "zenoh",
            kind: "zenoh",
            endpoint: format!("{prefix}/{{pose,health,events}}{ros}"),
            sent: self.poses.load(Relaxed),
            // Zenoh's put does not queue: nothing to drop.
            dropped: 0,
            errors: self.errors.load(Relaxed),
            last_error: crate::sync::lock(&self.last_error).clone(),
            sending: reason.is_none(),
            not_sending_reason: reason,
            rate_hz: self.clock.rate_hz(now),
            last_sent_age_ms: self.clock.age_ms(now),
            detail: super::OutputDetail::Zenoh {
                debug_points: self.debug_points.load(Relaxed),
                events: self.events.load(Relaxed),
                health: self.health.load(Relaxed),
                px4_odometry_sent: self.px4_odometry.load(Relaxed),
                px4_odometry_withheld: self.px4_withheld.load(Relaxed),
                px4_odometry_not_sending: crate::sync::lock(&self.px4_not_sending).clone(),
            },
        }
    }
}

/// geometry_msgs/PoseStamped of the fused pose (ENU, REP-103); an error for a time ROS
/// cannot hold.
pub fn pose_stamped(p: &FusedPose, frame_id: &str) -> Result<PoseStamped, EncodeError> {
    let q = p.orientation;
    Ok(PoseStamped {
        header: crate::codec::ros::header(p.time_us, frame_id, false)?,
        pose: Pose {
            position: Point {
                x: p.position.x,
                y: p.position.y,
                z: p.position.z,
            },
            orientation: Quaternion {
                x: q.i,
                y: q.j,
                z: q.k,
                w: q.w,
            },
        },
    })
}

/// The JSON pose on `<prefix>/pose` (README "Outputs"). Covariances row-major, m² /
/// (m/s)² / rad²; `orientation` as x, y, z, w (body FLU → ENU). Its numbers to the
/// precision of [`super::precision`] (see [`PoseMessage::rounded`]).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PoseMessage<'a> {
    pub time_us: i64,
    pub frame: &'a str,
    pub position: [f64; 3],
    pub orientation: [f64; 4],
    pub velocity: [f64; 3],
    pub position_covariance: [f64; 9],
    pub velocity_covariance: [f64; 9],
    pub orientation_covariance: [f64; 9],
    pub sources: &'a [String],
    pub reset_counter: u8,
    pub valid: bool,
    pub invalid_reason: Option<&'a str>,
    /// The ENU origin, once a GNSS fix set it.
    pub origin: Option<GeoPoint>,
    /// The integrity monitor's bounds on the position error, and their limits.
    pub protection: Protection,
}

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct GeoPoint {
    pub lat: f64,
    pub lon: f64,
    pub alt: f64,
}

impl<'a> PoseMessage<'a> {
    pub fn of(p: &'a FusedPose, frame_id: &'a str) -> Self {
        let q = p.orientation;
        let rows = |m: &nalgebra::Matrix3<f64>| -> [f64; 9] {
            let mut out = [0.0; 9];
            for (o, v) in out.iter_mut().zip(m.transpose().iter()) {
                *o = *v;
            }
            out
        };
        Self {
            time_us: p.time_us,
            frame: frame_id,
            position: p.position.into(),
            orientation: [q.i, q.j, q.k, q.w],
            velocity: p.velocity.into(),
            position_covariance: rows(&p.position_cov),
            velocity_covariance: rows(&p.velocity_cov),
            orientation_covariance: rows(&p.orientation_cov),
            sources: &p.sources,
            reset_counter: p.reset_counter,
            valid: p.valid,
            invalid_reason: p.invalid_reason.as_deref(),
            origin: p.origin.map(|(lat, lon, alt)| GeoPoint { lat, lon, alt }),
            protection: p.protection,
        }
        .rounded()
    }

    /// Its numbers to millimetres (position, velocity, protection levels, altitude),
    /// 1e-6 (quaternion), four significant digits (covariances) and 1e-8° (origin):
    /// below what the estimator resolves, in two thirds of the bytes of 17 digits (at
    /// 50 messages a second, most of a vehicle's output).
    pub fn rounded(self) -> Self {
        use super::precision::*;
        let metres = |v: [f64; 3]| v.map(|x| decimals(x, METRE_DECIMALS));
        let cov = |m: [f64; 9]| m.map(|x| significant(x, COVARIANCE_DIGITS));
        let p = self.protection;
        Self {
            position: metres(self.position),
            orientation: self.orientation.map(|x| decimals(x, QUATERNION_DECIMALS)),
            velocity: metres(self.velocity),
            position_covariance: cov(self.position_covariance),
            velocity_covariance: cov(self.velocity_covariance),
            orientation_covariance: cov(self.orientation_covariance),
            origin: self.origin.map(|o| GeoPoint {
                lat: decimals(o.lat, DEGREE_DECIMALS),
                lon: decimals(o.lon, DEGREE_DECIMALS),
                alt: decimals(o.alt, METRE_DECIMALS),
            }),
            protection: Protection {
                horizontal_m: decimals(p.horizontal_m, METRE_DECIMALS),
                vertical_m: decimals(p.vertical_m, METRE_DECIMALS),
                horizontal_alert_m: decimals(p.horizontal_alert_m, METRE_DECIMALS),
                vertical_alert_m: decimals(p.vertical_alert_m, METRE_DECIMALS),
                anchored_us: p.anchored_us,
            },
            ..self
        }
    }

    pub fn to_bytes(&self) -> Vec<u8> {
        serde_json::to_vec(self).unwrap_or_default()
    }
}

/// The ROS 2 outputs as rmw_zenoh publishes them: skyfuse as node `/skyfuse` with one
/// publisher per output (liveliness tokens alive while the output runs), each sample on
/// its rmw_zenoh key with the attachment (sequence from 1, source time, the
/// publisher's GID).
struct RmwOutputs {
    _tokens: Vec<zenoh::liveliness::LivelinessToken>,
    /// By the output's bridge key: (rmw_zenoh key, GID, next sequence number).
    topics: BTreeMap<String, (String, [u8; 16], i64)>,
}

/// The node's name on the rmw_zenoh graph.
const RMW_NODE: &str = "skyfuse";

/// The outputs rmw_zenoh carries: (bridge key, ROS 2 type, RIHS01 hash).
fn rmw_outputs(cfg: &OutputConfig) -> Vec<(String, &'static str, Option<String>)> {
    cfg.announced_outputs()
        .into_iter()
        .map(|(key, ty)| (key, ty, crate::ros_graph::rihs01(ty)))
        .collect()
}

impl RmwOutputs {
    async fn declare(session: &zenoh::Session, cfg: &OutputConfig) -> RmwOutputs {
        use crate::codec::ros::rmw_zenoh as rz;
        use sha2::{Digest, Sha256};
        let zid = session.zid().to_string();
        let domain = cfg.rmw_zenoh_domain_id;
        let mut keys = vec![rz::node_token(domain, &zid, 0, "/", RMW_NODE)];
        let mut topics = BTreeMap::new();
        for (i, (key, ty, hash)) in rmw_outputs(cfg).into_iter().enumerate() {
            let Some(hash) = hash else {
                tracing::warn!(%key, "rmw_zenoh: no type hash for {ty}: not published");
                continue;
            };
            let (Some(data), Some(token)) = (
                rz::data_key(domain, &key, ty, &hash),
                rz::publisher_token(
                    domain,
                    &zid,
                    0,
                    i as u32 + 1,
                    "/",
                    RMW_NODE,
                    &key,
                    ty,
                    &hash,
                    rz::QOS_RELIABLE_DEPTH_10,
                ),
            ) else {
                continue;
            };
            // rmw_zenoh hashes the token with XXH3-128; any 16 bytes of our own do.
            let digest = Sha256::digest(token.as_bytes());
            let mut gid = [0u8; 16];
            gid.copy_from_slice(&digest[..16]);
            topics.insert(key, (data, gid, 1));
            keys.push(token);
        }
        let mut tokens = Vec::new();
        for k in keys {
            match session.liveliness().declare_token(&k).await {
                Ok(t) => tokens.push(t),
                Err(e) => tracing::warn!(token = %k, "rmw_zenoh: cannot declare token: {e}"),
            }
        }
        tracing::info!(
            domain,
            publishers = topics.len(),
            "rmw_zenoh: node /{RMW_NODE} on the graph"
        );
        RmwOutputs {
            _tokens: tokens,
            topics,
        }
    }

    /// The rmw_zenoh key and attachment for the next sample of the output on `key`.
    fn next(&mut self, key: &str) -> Option<(String, Vec<u8>)> {
        let (data, gid, seq) = self.topics.get_mut(key)?;
        let attachment = crate::codec::ros::rmw_zenoh::Attachment {
            sequence_number: *seq,
            source_timestamp_ns: crate::clock::now_us().saturating_mul(1000),
            source_gid: *gid,
        };
        *seq += 1;
        Some((data.clone(), attachment.to_bytes()))
    }
}

/// Everything the Zenoh output publishes from.
pub struct ZenohOutInputs {
    /// Poses at the output rate (the estimator limits it).
    pub pose: PoseReceiver,
    /// The debug series at their rate (likewise).
    pub debug: DebugReceiver,
    pub events: broadcast::Receiver<Arc<Value>>,
    /// Builds the health JSON (the status API's sensors and estimator).
    pub health: Arc<dyn Fn() -> Value + Send + Sync>,
    /// The ROS 2 CDR outputs go to the recorder and Foxglove too.
    pub tap: crate::tap::Tap,
    /// PX4's clock at a host time, µs, as the MAVLink TIMESYNC knows it (`None` before).
    pub mavlink_px4_time: Arc<dyn Fn(i64) -> Option<i64> + Send + Sync>,
    /// The horizontal 1σ at which a pose's quality reaches 0 (the estimator's limit).
    pub max_std_m: f64,
}

/// PX4's clock minus the agent's (this host's), µs, from px4_msgs/TimesyncStatus.
type Px4Offset = Arc<Mutex<Option<i64>>>;

/// Follow TimesyncStatus on `[output] px4_timesync_key` into `offset`.
async fn watch_px4_timesync(
    session: &zenoh::Session,
    cfg: &OutputConfig,
    offset: Px4Offset,
    stats: Arc<ZenohOutStats>,
) -> Option<zenoh::pubsub::Subscriber<()>> {
    use crate::codec::ros::px4;
    use crate::config::RosTransport;
    let key = match cfg.px4_timesync_transport {
        RosTransport::RmwZenoh => crate::codec::ros::rmw_zenoh::subscription_key(
            cfg.rmw_zenoh_domain_id,
            &cfg.px4_timesync_key,
            Some(px4::Px4Type::TimesyncStatus.ros2_name()),
        ),
        _ => cfg.px4_timesync_key.trim_start_matches('/').to_string(),
    };
    let xcdr2 = cfg.px4_timesync_transport == RosTransport::Px4Zenoh;
    let what = key.clone();
    match session
        .declare_subscriber(&key)
        .callback(
            move |s| match px4::decode_timesync_status(&s.payload().to_bytes(), xcdr2) {
                Ok(t) => *crate::sync::lock(&offset) = Some(t.estimated_offset_us),
                Err(e) => stats.error(format!("{what}: TimesyncStatus: {e}")),
            },
        )
        .await
    {
        Ok(sub) => Some(sub),
        Err(e) => {
            tracing::warn!(%key, "px4_msgs odometry: cannot subscribe to TimesyncStatus: {e}");
            None
        }
    }
}

/// Run until the pose channel closes.
pub async fn run(
    session: zenoh::Session,
    cfg: OutputConfig,
    prefix: String,
    mut inp: ZenohOutInputs,
    stats: Arc<ZenohOutStats>,
) {
    let mut sent_debug: BTreeMap<DebugTopic, i64> = BTreeMap::new();
    let mut summary_tick = tokio::time::interval(SUMMARY_INTERVAL);
    summary_tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    // The first tick publishes the health too: a new subscriber learns who this is at once.
    let mut ticks = 0u64;
    // `attachment`: rmw_zenoh's, on its keys.
    let put = |key: String, payload: Vec<u8>, attachment: Option<Vec<u8>>| {
        let session = session.clone();
        let stats = stats.clone();
        async move {
            if let Err(e) = session
                .put(&key, payload)
                .attachment(attachment)
                .congestion_control(zenoh::qos::CongestionControl::Drop)
                .await
            {
                stats.error(format!("{key}: {e}"));
                false
            } else {
                true
            }
        }
    };
    let mut rmw = if cfg.rmw_zenoh && (cfg.ros2 || cfg.px4_odometry) {
        Some(RmwOutputs::declare(&session, &cfg).await)
    } else {
        None
    };
    let px4_offset: Px4Offset = Default::default();
    let _px4_timesync = if cfg.px4_odometry && cfg.px4_clock == crate::config::Px4Clock::Px4 {
        watch_px4_timesync(&session, &cfg, px4_offset.clone(), stats.clone()).await
    } else {
        None
    };
    let px4_type = RosType::Px4(crate::codec::ros::px4::Px4Msg::new(
        crate::codec::ros::px4::Px4Type::VehicleOdometry,
    ));
    // The debug series change with every sample: watched only when they are published.
    let debug_on = cfg.ros2 && cfg.ros2_debug;
    tracing::info!(prefix = %prefix, json = cfg.json, ros2 = cfg.ros2, pose_key = %cfg.ros2_pose_key, "Zenoh output running");
    loop {
        tokio::select! {
            changed = inp.pose.changed() => {
                if changed.is_err() { break; }
                let Some(p) = inp.pose.borrow_and_update().clone() else { continue };
                let mut ok = true;
                if cfg.json {
                    ok &= put(format!("{prefix}/pose"), PoseMessage::of(&p, &cfg.ros2_frame_id).to_bytes(), None).await;
                }
                // ROS consumers get only valid poses: rviz and planners cannot read a flag.
                if cfg.ros2 && p.valid {
                    match pose_stamped(&p, &cfg.ros2_frame_id) {
                        Ok(m) => {
                            let cdr = m.to_cdr();
                            inp.tap.ros2_out(p.time_us, &cfg.ros2_pose_key, RosType::PoseStamped, &cdr);
                            if let Some((k, a)) = rmw.as_mut().and_then(|r| r.next(&cfg.ros2_pose_key)) {
                                put(k, cdr.clone(), Some(a)).await;
                            }
                            ok &= put(cfg.ros2_pose_key.clone(), cdr, None).await;
                        }
                        Err(e) => stats.error(format!("{}: {e}", cfg.ros2_pose_key)),
                    }
                }
                if cfg.px4_odometry {
                    let stamp = match cfg.px4_clock {
                        crate::config::Px4Clock::Agent => Some(p.time_us),
                        crate::config::Px4Clock::Px4 => {
                            let offset = *crate::sync::lock(&px4_offset);
                            offset
                                .map(|o| p.time_us + o)
                                .or_else(|| (inp.mavlink_px4_time)(p.time_us))
                        }
                    };
                    let msg = match stamp {
                        Some(t) if t > 0 => crate::output::vpe::px4_vehicle_odometry(&p, t as u64, inp.max_std_m)
                            .map_err(|e| e.to_string()),
                        Some(t) => Err(format!("PX4 clock: timestamp_sample {t} µs is not after PX4's boot")),
                        None => Err(format!(
                            "PX4 clock not known yet: no TimesyncStatus on {} and no MAVLink TIMESYNC",
                            cfg.px4_timesync_key
                        )),
                    };
                    match msg {
                        Ok(m) => {
                            let cdr = m.to_cdr();
                            inp.tap.ros2_out(p.time_us, &cfg.px4_odometry_key, px4_type, &cdr);
                            if let Some((k, a)) = rmw.as_mut().and_then(|r| r.next(&cfg.px4_odometry_key)) {
                                put(k, cdr.clone(), Some(a)).await;
                            }
                            if put(cfg.px4_odometry_key.clone(), cdr, None).await {
                                stats.px4_odometry.fetch_add(1, Relaxed);
                                *crate::sync::lock(&stats.px4_not_sending) = None;
                            }
                        }
                        Err(why) => stats.px4_withheld(why),
                    }
                }
                if ok {
                    stats.sent(crate::clock::now_us());
                }
            }
            changed = inp.debug.changed(), if debug_on => {
                if changed.is_err() { break; }
                let d: Arc<DebugSeries> = inp.debug.borrow_and_update().clone();
                for topic in DebugTopic::PUBLISHED {
                    let Some(pt) = d.series.get(&topic) else { continue };
                    if sent_debug.get(&topic).is_some_and(|&t| t >= pt.time_us) { continue; }
                    sent_debug.insert(topic, pt.time_us);
                    let topic = topic.name();
                    let header = match crate::codec::ros::header(pt.time_us, &cfg.ros2_frame_id, false) {
                        Ok(h) => h,
                        Err(e) => { stats.error(format!("{topic}: {e}")); continue; }
                    };
                    let msg = PointStamped {
                        header,
                        point: Point { x: pt.value[0], y: pt.value[1], z: pt.value[2] },
                    };
                    let key = format!("{}/{topic}", cfg.ros2_debug_prefix);
                    let cdr = msg.to_cdr();
                    inp.tap.ros2_out(pt.time_us, &key, RosType::PointStamped, &cdr);
                    if let Some((k, a)) = rmw.as_mut().and_then(|r| r.next(&key)) {
                        put(k, cdr.clone(), Some(a)).await;
                    }
                    if put(key, cdr, None).await {
                        stats.debug_points.fetch_add(1, Relaxed);
                    }
                }
            }
            ev = inp.events.recv() => match ev {
                Ok(e) => {
                    if cfg.json && put(format!("{prefix}/events"), e.to_string().into_bytes(), None).await {
                        stats.events.fetch_add(1, Relaxed);
                    }
                }
                Err(broadcast::error::RecvError::Lagged(n)) => stats.error(format!("{n} events skipped (output slower than events)")),
                Err(broadcast::error::RecvError::Closed) => break,
            },
            _ = summary_tick.tick() => {
                if cfg.json {
                    let h = (inp.health)();
                    if ticks.is_multiple_of(cfg.health_interval_s.max(1))
                        && put(format!("{prefix}/health"), h.to_string().into_bytes(), None).await
                    {
                        stats.health.fetch_add(1, Relaxed);
                    }
                    ticks += 1;
                    // The fleet view's once-a-second message: the newest pose with the
                    // health's verdict (a monitor of many vehicles reads only this).
                    let pose = inp.pose.borrow().clone().and_then(|p| {
                        serde_json::to_value(PoseMessage::of(&p, &cfg.ros2_frame_id)).ok()
                    });
                    let summary = super::summary::summary_json(pose, &h);
                    put(format!("{prefix}/{}", super::summary::SUMMARY), summary.to_string().into_bytes(), None).await;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, UnitQuaternion, Vector3};

    #[test]
    fn pose_stamped_round_trips_through_cdr() {
        let p = FusedPose {
            time_us: 1_700_000_000_123_456,
            position: Vector3::new(1.0, -2.0, 3.5),
            velocity: Vector3::zeros(),
            orientation: UnitQuaternion::from_euler_angles(0.0, 0.0, 0.5),
            angular_velocity: None,
            position_cov: Matrix3::identity(),
            velocity_cov: Matrix3::identity(),
            orientation_cov: Matrix3::identity(),
            sources: vec![],
            reset_counter: 0,
            valid: true,
            invalid_reason: None,
            origin: None,
            protection: Default::default(),
        };
        let bytes = pose_stamped(&p, "map").expect("encodes").to_cdr();
        let back = PoseStamped::from_cdr(&bytes).expect("decodes");
        assert_eq!(back.header.stamp_us(false), Some(1_700_000_000_123_456));
        assert_eq!(back.header.frame_id, "map");
        assert_eq!(back.pose.position.y, -2.0);
        assert!((back.pose.orientation.z - (0.25f64).sin()).abs() < 1e-12);
        let j: Value =
            serde_json::from_slice(&PoseMessage::of(&p, "map").to_bytes()).expect("json");
        assert_eq!(j["position"][2], 3.5);
        assert_eq!(j["valid"], true);
        assert_eq!(j["frame"], "map");
        assert!(j["origin"].is_null());
    }

    #[test]
    fn the_json_pose_keeps_what_matters_in_fewer_bytes() {
        let cov = Matrix3::new(
            2.018_275_660_724_975_5e-3,
            -1.877_272_000_504_888e-3,
            6.145_901_887_503_639e-7,
            -1.877_272_000_504_888e-3,
            2.494_557_987_701_466e-3,
            4.141_175_086_192_634e-7,
            6.145_901_887_503_639e-7,
            4.141_175_086_192_634e-7,
            2.407_508_701_094_493e-4,
        );
        let p = FusedPose {
            time_us: 1_796_154_029_816_706,
            position: Vector3::new(1.175_454_868_630_353_9, 1.021_874_715_397_650_2, 2.000_509),
            velocity: Vector3::new(1.331_479_976_665_580_7, 1.042_014, -0.001_968_634),
            orientation: UnitQuaternion::from_euler_angles(0.012, -0.075, 0.591_234_567),
            angular_velocity: None,
            position_cov: cov,
            velocity_cov: cov * 1.5,
            orientation_cov: Matrix3::identity() * 1.6e-5,
            sources: ["attitude", "flow", "gps", "imu", "rangefinder", "t265"]
                .map(String::from)
                .into(),
            reset_counter: 0,
            valid: true,
            invalid_reason: None,
            origin: Some((
                47.397_741_065_312_94,
                8.545_616_413_950_166,
                488.608_147_778_548_3,
            )),
            protection: Protection {
                horizontal_m: 12.181_604_129_955_55,
                vertical_m: 1.318_851_641_771_287_4,
                horizontal_alert_m: 50.0,
                vertical_alert_m: 20.0,
                anchored_us: None,
            },
        };
        let bytes = PoseMessage::of(&p, "map").to_bytes();
        // 1 141 bytes with 17 digits a number (the demo's, before).
        assert!(
            bytes.len() < 760,
            "{} bytes: {}",
            bytes.len(),
            String::from_utf8_lossy(&bytes)
        );
        let j: Value = serde_json::from_slice(&bytes).expect("json");
        let num = |v: &Value| v.as_f64().unwrap_or(f64::NAN);
        for i in 0..3 {
            assert!((num(&j["position"][i]) - p.position[i]).abs() <= 0.000_5 + 1e-12);
            assert!((num(&j["velocity"][i]) - p.velocity[i]).abs() <= 0.000_5 + 1e-12);
        }
        let q = p.orientation;
        for (i, c) in [q.i, q.j, q.k, q.w].into_iter().enumerate() {
            assert!((num(&j["orientation"][i]) - c).abs() <= 5e-7 + 1e-12);
        }
        // Row-major, each entry to four significant digits.
        for (i, &c) in cov.transpose().iter().enumerate() {
            let got = num(&j["position_covariance"][i]);
            assert!((got - c).abs() <= 5e-4 * c.abs(), "{i}: {got} for {c}");
        }
        assert_eq!(j["position_covariance"][1], -0.001877);
        assert_eq!(j["origin"]["lat"], 47.39774107);
        assert_eq!(j["origin"]["alt"], 488.608);
        assert_eq!(j["protection"]["horizontal_m"], 12.182);
        assert_eq!(j["time_us"], 1_796_154_029_816_706_i64);
        assert_eq!(j["sources"].as_array().map(Vec::len), Some(6));
    }
}
