//! Relative pose error (Sturm et al., TUM RGB-D benchmark): drift over a fixed time interval.
//! For every estimated pose i and the first pose j at least `delta_s` later, the motion
//! T_i^-1 T_j is compared with the ground truth's over the same timestamps. Monocular estimates
//! have an arbitrary scale: with `with_scale` the estimate's translations are scaled by the
//! Sim3 alignment's factor first.

use serde::Serialize;

use super::{associate, ate, TimedPose};

#[derive(Clone, Debug, Serialize)]
pub struct RpeResult {
    /// Pose pairs compared.
    pub pairs: usize,
    pub delta_s: f64,
    /// Translational error over the interval (ground-truth units).
    pub trans_rmse: f64,
    pub trans_mean: f64,
    pub trans_max: f64,
    /// Rotational error over the interval, degrees.
    pub rot_rmse_deg: f64,
    pub rot_mean_deg: f64,
    /// Scale applied to the estimate (1 without `with_scale`).
    pub scale: f64,
}

/// RPE over `delta_s` seconds; `None` when fewer than one pair or no alignment.
pub fn rpe(
    gt: &[TimedPose],
    est: &[TimedPose],
    max_dt: f64,
    delta_s: f64,
    with_scale: bool,
) -> Option<RpeResult> {
    let scale = if with_scale {
        ate(gt, est, max_dt, true)?.alignment.scale
    } else {
        1.0
    };
    let matches = associate(gt, est, max_dt);
    // matches: (gt index, est index), in est order.
    let (mut t2, mut r2, mut tsum, mut rsum, mut tmax, mut n) =
        (0.0, 0.0, 0.0, 0.0, 0.0f64, 0usize);
    let mut j = 0;
    for i in 0..matches.len() {
        let (gi, ei) = matches[i];
        let ti = est[ei].timestamp;
        j = j.max(i + 1);
        while j < matches.len() && est[matches[j].1].timestamp < ti + delta_s {
            j += 1;
        }
        let Some(&(gj, ej)) = matches.get(j) else {
            break;
        };
        // Only intervals close to delta (gaps in tracking would compare longer motions).
        if est[ej].timestamp - ti > 1.5 * delta_s {
            continue;
        }
        let mut e = est[ei].t_wc.0.inverse() * est[ej].t_wc.0;
        e.translation.vector *= scale;
        let g = gt[gi].t_wc.0.inverse() * gt[gj].t_wc.0;
        let err = g.inverse() * e;
        let dt = err.translation.vector.norm();
        let dr = err.rotation.angle().to_degrees();
        t2 += dt * dt;
        r2 += dr * dr;
        tsum += dt;
        rsum += dr;
        tmax = tmax.max(dt);
        n += 1;
    }
    (n > 0).then(|| RpeResult {
        pairs: n,
        delta_s,
        trans_rmse: (t2 / n as f64).sqrt(),
        trans_mean: tsum / n as f64,
        trans_max: tmax,
        rot_rmse_deg: (r2 / n as f64).sqrt(),
        rot_mean_deg: rsum / n as f64,
        scale,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::WorldFromCamera;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

    fn path(n: usize, drift_per_s: f64, scale: f64) -> Vec<TimedPose> {
        (0..n)
            .map(|i| {
                let t = i as f64 / 30.0;
                let p = Vector3::new(t.cos(), 0.2 * t, t.sin()) * scale
                    + Vector3::new(drift_per_s * t, 0.0, 0.0);
                TimedPose {
                    timestamp: 100.0 + t,
                    t_wc: WorldFromCamera(Isometry3::from_parts(
                        Translation3::from(p),
                        UnitQuaternion::from_euler_angles(0.1 * t, 0.3 * t, 0.0),
                    )),
                }
            })
            .collect()
    }

    #[test]
    fn zero_for_an_exact_estimate_at_any_scale_and_the_drift_otherwise() {
        let gt = path(300, 0.0, 1.0);
        let r = rpe(&gt, &path(300, 0.0, 2.5), 0.02, 1.0, true).unwrap();
        assert!(r.trans_rmse < 1e-9 && r.rot_rmse_deg < 1e-9, "{r:?}");
        assert!((r.scale - 0.4).abs() < 1e-9);
        assert!(r.pairs > 200);
        // 1 cm/s drift along x: 1 cm over each second.
        let r = rpe(&gt, &path(300, 0.01, 1.0), 0.02, 1.0, false).unwrap();
        assert!((r.trans_mean - 0.01).abs() < 1e-3, "{r:?}");
    }
}
