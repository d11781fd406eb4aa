//! The Sim3 that brings an estimate's map into the ground-truth frame for judging a cloud.
//!
//! Keyframe positions alone fix a Sim3 only up to a rotation about the path when the path is
//! near-straight (forward driving, a sideways pan): the cloud is then rotated about the path
//! and a good cloud scores badly. The evaluation protocol therefore fits the Sim3 to the
//! keyframe centres plus, per keyframe, one point 0.5 m (ground-truth units) along each of the
//! camera's three axes, which ties the camera orientations in as well.

use nalgebra::Vector3;

use super::ate::{associate, TimedPose};
use crate::geometry::{umeyama, Sim3};

/// Length of the axis points, in ground-truth units (metres).
pub const AXIS_POINT_M: f64 = 0.5;

/// The Sim3 (estimate to ground truth) fitted to matched centres and axis points, poses
/// matched by timestamp within `max_dt`. The estimate's axis points are `AXIS_POINT_M / s`
/// long, `s` its scale to the ground truth: estimated by positions first, then refitted until
/// it settles (a fixed point: the axis points pull the fitted scale towards the assumed one).
/// `None` with fewer than 3 matches or a degenerate fit.
pub fn pose_alignment(gt: &[TimedPose], est: &[TimedPose], max_dt: f64) -> Option<Sim3> {
    let pairs = associate(gt, est, max_dt);
    if pairs.len() < 3 {
        return None;
    }
    let centres_est: Vec<Vector3<f64>> =
        pairs.iter().map(|&(_, e)| est[e].t_wc.position()).collect();
    let centres_gt: Vec<Vector3<f64>> = pairs.iter().map(|&(g, _)| gt[g].t_wc.position()).collect();
    // The scale from positions when they span a volume or a line; from a first full fit with
    // unit axes otherwise (a camera turning on the spot).
    let mut scale = umeyama(&centres_est, &centres_gt, true)
        .map(|a| a.scale)
        .filter(|s| s.is_finite() && *s > 0.0)
        .unwrap_or(1.0);
    let mut best = None;
    for _ in 0..50 {
        let mut src = Vec::with_capacity(pairs.len() * 4);
        let mut dst = Vec::with_capacity(pairs.len() * 4);
        for &(g, e) in &pairs {
            let (pe, pg) = (&est[e].t_wc.0, &gt[g].t_wc.0);
            src.push(pe.translation.vector);
            dst.push(pg.translation.vector);
            for axis in [Vector3::x(), Vector3::y(), Vector3::z()] {
                src.push(pe.translation.vector + pe.rotation * axis * (AXIS_POINT_M / scale));
                dst.push(pg.translation.vector + pg.rotation * axis * AXIS_POINT_M);
            }
        }
        let a = umeyama(&src, &dst, true)?;
        if !(a.scale.is_finite() && a.scale > 0.0) {
            return best;
        }
        let settled = (a.scale - scale).abs() <= 1e-12 * scale;
        scale = a.scale;
        best = Some(a);
        if settled {
            break;
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::WorldFromCamera;
    use nalgebra::UnitQuaternion;

    /// A straight path (positions on a line) with the camera looking sideways: positions alone
    /// leave the rotation about the line free; the axis points recover the true Sim3.
    #[test]
    fn recovers_the_rotation_about_a_straight_path() {
        let gt: Vec<TimedPose> = (0..40)
            .map(|i| TimedPose {
                timestamp: i as f64 * 0.1,
                t_wc: WorldFromCamera::from_parts(
                    Vector3::new(0.2 * i as f64, 0.0, 0.0),
                    UnitQuaternion::from_euler_angles(0.0, -1.2, 0.01 * i as f64),
                ),
            })
            .collect();
        let truth = Sim3 {
            scale: 2.5,
            rotation: UnitQuaternion::from_euler_angles(0.7, -0.3, 1.1),
            translation: Vector3::new(1.0, -2.0, 0.5),
        };
        // The estimate = truth^-1 applied to the ground truth (so truth maps it back).
        let inv = truth.inverse();
        let est: Vec<TimedPose> = gt
            .iter()
            .map(|p| TimedPose {
                timestamp: p.timestamp,
                t_wc: WorldFromCamera::from_parts(
                    inv.transform(&p.t_wc.position()),
                    inv.rotation * p.t_wc.0.rotation,
                ),
            })
            .collect();
        let a = pose_alignment(&gt, &est, 0.02).expect("aligned");
        assert!((a.scale - truth.scale).abs() < 1e-9, "{}", a.scale);
        assert!(a.rotation.angle_to(&truth.rotation) < 1e-9);
        assert!((a.translation - truth.translation).norm() < 1e-9);
        // A point 2 m beside the path maps where the truth maps it.
        let q = Vector3::new(1.0, 0.0, 2.0);
        assert!((a.transform(&q) - truth.transform(&q)).norm() < 1e-9);
    }
}
