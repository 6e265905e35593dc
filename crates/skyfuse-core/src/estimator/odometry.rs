//! Visual odometry (T265, VIO, MAVLink ODOMETRY): pose in its own world frame.
//!
//! Checks: finite pose, quality not "failed". Preprocessing: camera → body with the
//! configured extrinsics. Control: a *segment* is a stretch over which the odometry
//! frame is aligned to the fused frame (yaw + translation, fixed when the segment
//! starts so that the source's current pose maps onto the current estimate: no jump).
//! A new segment starts on the first sample, on a reset-counter change, on a position
//! step not explained by the velocity (jump), after a gap, after a monitor reset, or
//! after innovations were rejected for `vo_reject_realign_s`. Fuse: the aligned
//! position as `p + b` (b = the segment's drift offset state, random walk), and the
//! body-frame velocity.

use super::attitude::{wrap_pi, yaw_of};
use super::ekf::{Measurement, IDX_P, IDX_V};
use super::{BodyVelocity, Core, Ctx, DebugTopic, Event};
use crate::sample::Odometry;
use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};

/// 1σ of an odometry's heading, rad (a T265 holds its heading to a degree over
/// minutes), and how fast it wanders, rad/√s.
const VO_YAW_NOISE: f64 = 0.01;
pub const VO_YAW_RW: f64 = 0.001;

/// Alignment of one segment: world = rot · odom + trans.
#[derive(Debug, Clone, PartialEq)]
pub struct Align {
    pub rot: UnitQuaternion<f64>,
    pub trans: Vector3<f64>,
    /// Yaw variance of the alignment (our heading uncertainty when it was made), rad².
    pub yaw_var: f64,
    /// Body position in the odometry frame at alignment.
    pub anchor: Vector3<f64>,
}

#[derive(Debug, Clone, PartialEq, Default)]
pub struct OdomState {
    pub segment: u32,
    pub align: Option<Align>,
    /// (time, body position in the odometry frame, body velocity in the odometry frame).
    pub last: Option<(i64, Vector3<f64>, Option<Vector3<f64>>)>,
    pub reset_counter: Option<u8>,
    pub reject_since: Option<i64>,
    pub need_realign: bool,
    /// Heading of the body in the fused frame from this source (time, yaw).
    pub heading: Option<(i64, f64)>,
    /// The offset state's value a second ago or more, and the fused position's σ then
    /// (per axis, m): (time, offset, σ).
    pub drift_from: Option<(i64, Vector3<f64>, Vector3<f64>)>,
}

/// How often the odometry frame's drift rate is measured, µs.
const DRIFT_WINDOW_US: i64 = 1_000_000;

/// How far, in σ of the corrections the fused position took over a window, the offset
/// may move and still be the fused estimate corrected rather than the odometry drifting.
const DRIFT_EXPLAINED_SIGMAS: f64 = 3.0;

/// The body's pose and velocity from a camera odometry sample.
#[derive(Debug, Clone, PartialEq)]
pub struct BodyOdom {
    pub pos: Vector3<f64>,
    pub att: UnitQuaternion<f64>,
    /// Body velocity in body axes.
    pub vel_body: Option<Vector3<f64>>,
    pub pos_cov: Option<Matrix3<f64>>,
    pub vel_cov: Option<Matrix3<f64>>,
}

fn finite3(v: &Vector3<f64>) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// Checks of one sample.
pub fn checks(o: &Odometry) -> Result<(), &'static str> {
    if !finite3(&o.position) || !super::attitude::check_quaternion(&o.orientation) {
        return Err("pose not finite");
    }
    if o.quality == Some(-1) {
        return Err("source reports failure (quality -1)");
    }
    Ok(())
}

/// Camera pose → body pose with extrinsics: `q_bc` rotates camera axes into body
/// axes, `t_bc` is the camera position in the body frame.
pub fn to_body(o: &Odometry, q_bc: &UnitQuaternion<f64>, t_bc: &Vector3<f64>) -> BodyOdom {
    let att = o.orientation * q_bc.inverse();
    let pos = o.position - att * t_bc;
    let omega_b = o.angular_velocity.map(|w| q_bc * w);
    let vel_body = o.velocity.filter(finite3).map(|v| {
        let v_cam_point = q_bc * v;
        match omega_b {
            Some(w) if finite3(&w) => v_cam_point - w.cross(t_bc),
            _ => v_cam_point,
        }
    });
    let rot = q_bc.to_rotation_matrix();
    let pos_cov = o
        .pose_cov
        .map(|c| c.fixed_view::<3, 3>(0, 0).into_owned())
        .filter(|c| c.iter().all(|v| v.is_finite()) && c.trace() > 0.0);
    let vel_cov = o
        .twist_cov
        .map(|c| {
            let c3 = c.fixed_view::<3, 3>(0, 0).into_owned();
            rot.matrix() * c3 * rot.matrix().transpose()
        })
        .filter(|c| c.iter().all(|v| v.is_finite()) && c.trace() > 0.0);
    BodyOdom {
        pos,
        att,
        vel_body,
        pos_cov,
        vel_cov,
    }
}

pub fn process(core: &mut Core, ctx: &Ctx, t: i64, source: &str, o: &Odometry) {
    let cfg = ctx.cfg;
    if let Err(why) = checks(o) {
        core.reject(t, source, why, ctx);
        return;
    }
    let sc = cfg.source(source);
    let [qx, qy, qz, qw] = sc.extrinsics_rotation;
    let q_bc = UnitQuaternion::from_quaternion(Quaternion::new(qw, qx, qy, qz));
    let t_bc = Vector3::from(sc.extrinsics_translation);
    let b = to_body(o, &q_bc, &t_bc);
    if !core.att.known() {
        return;
    }
    if !core.initialised() {
        let height = core.latest_height(t);
        // A range finder's first reading is often its floor (standing on the gear, a
        // hair above its minimum): a quarter of it is the height's 1σ until it flies.
        let mut var = Vector3::repeat(cfg.init_pos_var);
        if let Some(h) = height {
            var.z = var.z.max((0.25 * h).powi(2));
        }
        let v = b.vel_body.map(|vb| core.att.q * vb);
        let v_var = v.map(|_| Vector3::repeat(cfg.vo_vel_noise.powi(2)));
        let z = height.unwrap_or(0.0);
        core.initialise(t, source, Vector3::new(0.0, 0.0, z), var, v, v_var, ctx);
        if height.is_none() {
            // Started with no height measurement (in flight, or the range finder's
            // first sample still to come): where the ground is below this frame is not
            // known, so the first range or ToF sets it instead of being gated out.
            if let Some(bank) = core.ekf.as_mut() {
                let i = super::ekf::IDX_TERRAIN;
                bank.each(|ekf| ekf.p[(i, i)] = super::config::UNKNOWN_TERRAIN_VAR);
            }
        }
    }
    // Control: does a new segment start?
    // Taken out while this sample works on it (every path puts it back), its key kept.
    let mut st = core
        .odom
        .get_mut(source)
        .map(std::mem::take)
        .unwrap_or_default();
    let reject_us = (cfg.vo_reject_realign_s * 1e6) as i64;
    let mut reason: Option<String> = None;
    if st.align.is_none() {
        reason = Some("source started".into());
    } else if st.need_realign {
        reason = Some("filter was reset".into());
    } else if o.reset_counter.is_some() && o.reset_counter != st.reset_counter {
        reason = Some(format!(
            "reset counter {:?} → {:?}",
            st.reset_counter, o.reset_counter
        ));
    } else if let Some((t0, p0, v0)) = st.last {
        let dt = (t - t0) as f64 * 1e-6;
        if dt > cfg.vo_reject_realign_s {
            reason = Some(format!("gap of {dt:.2} s"));
        } else {
            let v_odom = v0
                .or_else(|| b.vel_body.map(|vb| b.att * vb))
                .unwrap_or_else(Vector3::zeros);
            let step = b.pos - p0 - v_odom * dt;
            if step.norm() > cfg.vo_jump_m {
                reason = Some(format!("jump of {:.2} m", step.norm()));
            }
        }
    }
    if reason.is_none() && st.reject_since.is_some_and(|r| t - r > reject_us) {
        reason = Some("innovations rejected".into());
    }
    st.reset_counter = o.reset_counter;
    let v_odom_now = b.vel_body.map(|vb| b.att * vb);
    let new_segment = reason.is_some();
    if let Some(why) = reason {
        // The body's heading in the fused frame: the attitude's, less its heading error.
        let yaw_error = core.ekf.as_ref().map_or(0.0, |e| e.yaw_error());
        let yaw_align = wrap_pi(yaw_of(&core.att.q) - yaw_error - yaw_of(&b.att));
        let rot = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_align);
        let here = core.position().unwrap_or_else(Vector3::zeros);
        st.align = Some(Align {
            rot,
            trans: here - rot * b.pos,
            yaw_var: core.att.cov[(2, 2)],
            anchor: b.pos,
        });
        st.segment += 1;
        st.need_realign = false;
        st.reject_since = None;
        st.drift_from = None;
        if let Some(bank) = core.ekf.as_mut() {
            bank.each(|ekf| {
                ekf.start_block(source);
                ekf.start_align_yaw(source);
            });
        }
        core.event(
            t,
            Some(source),
            format!("odometry segment {} started: {why}", st.segment),
            Event::Segment {
                segment: st.segment,
                reason: why.to_string(),
                yaw_align,
            },
        );
    }
    let Some(al) = st.align.clone() else {
        core.odom.put(source, st);
        return;
    };
    let z = al.rot * b.pos + al.trans;
    st.heading = Some((t, wrap_pi(yaw_of(&b.att) + yaw_of(&al.rot))));
    // The camera in the fused frame as the filter sees it: turned by the alignment
    // error it has estimated since the segment started (ε about where it started; see
    // the position update below). The raw alignment alone parted from the pose by
    // 0.25-0.32 m on the ROS 2 bridge's 4 m circle, an ε of a few degrees.
    let eps = core
        .ekf
        .as_ref()
        .and_then(|e| e.align_yaw_of(source).map(|i| e.x[i]))
        .unwrap_or(0.0);
    // The segment's alignment error ε turns its positions about where it started:
    // z = p + b + ε·ẑ×d, d the aligned displacement since then.
    let d = al.rot * (b.pos - al.anchor);
    let turned = Vector3::new(-d.y, d.x, 0.0);
    core.debug_point(t, DebugTopic::OriUavT265, source, z - turned * eps);
    // WRLS: frame-to-frame displacement within a segment.
    if let (false, Some((t0, p0, _))) = (new_segment, st.last) {
        let dt = (t - t0) as f64 * 1e-6;
        if dt > 0.0 {
            let delta = al.rot * (b.pos - p0);
            let vel_var = b
                .vel_cov
                .map_or(cfg.vo_vel_noise.powi(2), |c| c.trace() / 3.0);
            let drift = sc.drift_rw.unwrap_or(cfg.vo_drift_rw);
            let var = vel_var * dt * dt + drift * drift * dt;
            core.debug_point(t, DebugTopic::OriginDt265, source, delta);
            core.wrls
                .add_relative(source, delta, Vector3::repeat(var), dt);
        }
    }
    st.last = Some((t, b.pos, v_odom_now));
    core.odom.put(source, st);

    // Fuse position: z = p + b.
    let c = match sc.noise {
        Some(s) => Matrix3::identity() * (s * s),
        None => b
            .pos_cov
            .unwrap_or_else(|| Matrix3::identity() * cfg.vo_pos_noise.powi(2)),
    };
    let rm = al.rot.to_rotation_matrix();
    let lever = (b.pos - al.anchor).xy().norm_squared();
    let mut r = rm.matrix() * c * rm.matrix().transpose();
    r[(0, 0)] += al.yaw_var * lever;
    r[(1, 1)] += al.yaw_var * lever;
    let accepted = match core.position_measurement("odometry", z, &r, Some(source)) {
        Some(mut m) if core.ekf_fuses_sensors(ctx) => {
            if let Some(e) = core.ekf.as_ref().and_then(|e| e.align_yaw_of(source)) {
                for row in 0..2 {
                    m.set_jacobian(row, e, turned[row]);
                    m.set_innovation(row, m.innovation()[row] - eps * turned[row]);
                }
            }
            core.update(t, source, "odometry", &m, ctx)
        }
        _ => core.fuse_position(t, source, "odometry", z, &r, Some(source), ctx),
    };
    // The odometry's heading against the attitude's: ψ_a − ε, what the two disagree by
    // since the segment started (the compass's wander, seen by a camera that holds its
    // heading).
    if core.ekf_fuses_sensors(ctx) {
        if let Some(ekf) = core.ekf.as_ref() {
            if let Some(e) = ekf.align_yaw_of(source) {
                let y = wrap_pi(yaw_of(&core.att.q) - yaw_of(&b.att) - yaw_of(&al.rot));
                let mut m = Measurement::new(1);
                m.set_jacobian(0, super::ekf::IDX_YAW, 1.0);
                m.set_jacobian(0, e, -1.0);
                m.set_innovation(0, wrap_pi(y - (ekf.yaw_error() - ekf.x[e])));
                m.set_noise(0, 0, core.att.cov[(2, 2)] + VO_YAW_NOISE * VO_YAW_NOISE);
                core.update(t, source, "odometry", &m, ctx);
            }
        }
    }
    let direct = core.ekf_fuses_sensors(ctx);
    if let Some(st) = core.odom.get_mut(source) {
        if accepted || !direct {
            st.reject_since = None;
        } else if st.reject_since.is_none() {
            st.reject_since = Some(t);
        }
    }
    drift_rate(core, t, source);
    // Fuse velocity (body frame).
    if cfg.vo_fuse_velocity {
        if let Some(vb) = b.vel_body {
            let mut rv = match sc.vel_noise {
                Some(s) => Matrix3::identity() * (s * s),
                None => b
                    .vel_cov
                    .unwrap_or_else(|| Matrix3::identity() * cfg.vo_vel_noise.powi(2)),
            };
            // Never better than the configured noise: a camera's velocity is its pose's
            // derivative (not independent of the position fused beside it) and reports
            // its own noise, not the errors of its model.
            let floor = cfg.vo_vel_noise.powi(2);
            for i in 0..3 {
                rv[(i, i)] = rv[(i, i)].max(floor);
            }
            core.fuse_body_velocity(t, source, vb, &mut rv, BodyVelocity::Odometry, ctx);
        }
    }
}

/// The odometry frame's drift against the fused one over the last second, into the
/// source's status (health judges it); a new segment starts the measure again. The
/// offset is the fused position minus the odometry's, so it moves when either does.
/// The fused position's corrections over the window are what its variance lost
/// (σ₀² − σ₁² per axis, an update's shift having the variance it removes): up to
/// [`DRIFT_EXPLAINED_SIGMAS`] of that is not the odometry's drift. In the demo's first
/// second the offset moved 0.58 m while the position, initialised from GNSS a tenth of
/// a second before, went from σ 0.77 to 0.70 m (σz 1.34 to 1.21 m): the T265 was called
/// drifting, and degraded, for the filter converging. In a steady state the variance
/// stays and every centimetre counts, as before.
fn drift_rate(core: &mut Core, t: i64, source: &str) {
    let Some((b, sigma)) = core.ekf.as_ref().and_then(|e| {
        let i = e.block(source)?;
        Some((
            Vector3::new(e.x[i], e.x[i + 1], e.x[i + 2]),
            Vector3::from_fn(|k, _| e.p[(IDX_P + k, IDX_P + k)].max(0.0).sqrt()),
        ))
    }) else {
        return;
    };
    let Some(st) = core.odom.get_mut(source) else {
        return;
    };
    let segment = st.segment;
    match st.drift_from {
        Some((t0, b0, sigma0)) if t - t0 >= DRIFT_WINDOW_US && t > t0 => {
            let unexplained = Vector3::from_fn(|k, _| {
                let corrected = (sigma0[k].powi(2) - sigma[k].powi(2)).max(0.0).sqrt();
                ((b[k] - b0[k]).abs() - DRIFT_EXPLAINED_SIGMAS * corrected).max(0.0)
            });
            let rate = unexplained.norm() / ((t - t0) as f64 * 1e-6);
            st.drift_from = Some((t, b, sigma));
            let stat = core.stat(source);
            stat.drift_mps = Some(rate);
            stat.segment = Some(segment);
        }
        Some((t0, _, _)) if t >= t0 => {}
        _ => st.drift_from = Some((t, b, sigma)),
    }
}

/// A body-frame velocity measurement's Jacobian (rows of Rᵀ at the velocity states);
/// innovation and noise zero.
pub fn body_velocity_measurement(rot: &Matrix3<f64>, rows: usize) -> Measurement {
    let rt = rot.transpose();
    let mut m = Measurement::new(rows);
    for i in 0..rows {
        for j in 0..3 {
            m.set_jacobian(i, IDX_V + j, rt[(i, j)]);
        }
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn extrinsics_move_the_camera_pose_to_the_body() {
        // Camera 10 cm forward of the body, looking forward (identity rotation); the
        // vehicle yawed 90°: the body is 10 cm "behind" the camera along world -y.
        let q = UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2);
        let o = Odometry {
            position: Vector3::new(1.0, 2.0, 0.5),
            orientation: q,
            velocity: Some(Vector3::new(0.0, 0.0, 0.0)),
            angular_velocity: Some(Vector3::new(0.0, 0.0, 1.0)),
            pose_cov: None,
            twist_cov: None,
            frame_id: "odom".into(),
            child_frame_id: "camera".into(),
            reset_counter: None,
            quality: None,
        };
        let b = to_body(
            &o,
            &UnitQuaternion::identity(),
            &Vector3::new(0.1, 0.0, 0.0),
        );
        assert!(
            (b.pos - Vector3::new(1.0, 1.9, 0.5)).norm() < 1e-12,
            "{}",
            b.pos
        );
        // Camera still while yawing at 1 rad/s about the body: the body origin moves
        // at ω × (-t) = (0, -0.1, 0)… in body axes: -(ω × t_bc) = (0, -0.1, 0).
        let v = b.vel_body.expect("velocity");
        assert!((v - Vector3::new(0.0, -0.1, 0.0)).norm() < 1e-12, "{v}");
    }
}
