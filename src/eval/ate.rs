//! Absolute trajectory error: associate poses by timestamp, align by Sim3 (Umeyama), and
//! report RMSE, median and max of the position errors.

use nalgebra::Vector3;
use serde::Serialize;

use crate::geometry::{umeyama, Sim3, WorldFromCamera};

/// A pose with its timestamp (seconds).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TimedPose {
    pub timestamp: f64,
    pub t_wc: WorldFromCamera,
}

/// ATE statistics, in the units of the ground truth.
#[derive(Clone, Debug, Serialize)]
pub struct AteResult {
    pub rmse_m: f64,
    pub mean_m: f64,
    pub median_m: f64,
    pub max_m: f64,
    /// Scale applied to the estimate by the alignment.
    pub scale: f64,
    pub matched: usize,
    /// Estimated poses with no ground truth within the tolerance.
    pub unmatched: usize,
    #[serde(skip)]
    pub alignment: Sim3,
    /// Per matched pose: (timestamp, error).
    #[serde(skip)]
    pub errors: Vec<(f64, f64)>,
}

/// Pairs each estimated pose with a ground-truth pose within `max_dt` seconds: closest pairs
/// first, each pose used once (as TUM's `associate.py`). Returns index pairs (gt, est) ordered
/// by estimate time.
pub fn associate(gt: &[TimedPose], est: &[TimedPose], max_dt: f64) -> Vec<(usize, usize)> {
    let mut cand: Vec<(f64, usize, usize)> = Vec::new();
    for (ei, e) in est.iter().enumerate() {
        // Ground truth is sorted by time: binary search the window.
        let lo = gt.partition_point(|g| g.timestamp < e.timestamp - max_dt);
        for (gi, g) in gt.iter().enumerate().skip(lo) {
            let d = (g.timestamp - e.timestamp).abs();
            if g.timestamp > e.timestamp + max_dt {
                break;
            }
            if d <= max_dt {
                cand.push((d, gi, ei));
            }
        }
    }
    cand.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut used_g = vec![false; gt.len()];
    let mut used_e = vec![false; est.len()];
    let mut out = Vec::new();
    for (_, gi, ei) in cand {
        if !used_g[gi] && !used_e[ei] {
            used_g[gi] = true;
            used_e[ei] = true;
            out.push((gi, ei));
        }
    }
    out.sort_by_key(|&(_, e)| e);
    out
}

/// ATE of `est` against `gt` (both sorted by time) after a 7-DoF alignment (6-DoF when
/// `with_scale` is false). `None` when fewer than 3 poses match or they are degenerate.
pub fn ate(
    gt: &[TimedPose],
    est: &[TimedPose],
    max_dt: f64,
    with_scale: bool,
) -> Option<AteResult> {
    let pairs = associate(gt, est, max_dt);
    let src: Vec<Vector3<f64>> = pairs.iter().map(|&(_, e)| est[e].t_wc.position()).collect();
    let dst: Vec<Vector3<f64>> = pairs.iter().map(|&(g, _)| gt[g].t_wc.position()).collect();
    let align = umeyama(&src, &dst, with_scale)?;
    let errors: Vec<(f64, f64)> = pairs
        .iter()
        .zip(src.iter().zip(&dst))
        .map(|(&(_, e), (s, d))| (est[e].timestamp, (align.transform(s) - d).norm()))
        .collect();
    let n = errors.len() as f64;
    let rmse = (errors.iter().map(|e| e.1 * e.1).sum::<f64>() / n).sqrt();
    let mean = errors.iter().map(|e| e.1).sum::<f64>() / n;
    let mut sorted: Vec<f64> = errors.iter().map(|e| e.1).collect();
    sorted.sort_by(|a, b| a.total_cmp(b));
    let median = if sorted.len() % 2 == 1 {
        sorted[sorted.len() / 2]
    } else {
        0.5 * (sorted[sorted.len() / 2 - 1] + sorted[sorted.len() / 2])
    };
    Some(AteResult {
        rmse_m: rmse,
        mean_m: mean,
        median_m: median,
        max_m: sorted.last().copied().unwrap_or(0.0),
        scale: align.scale,
        matched: pairs.len(),
        unmatched: est.len() - pairs.len(),
        alignment: align,
        errors,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    fn circle(n: usize) -> Vec<TimedPose> {
        (0..n)
            .map(|i| {
                let a = i as f64 * 0.1;
                TimedPose {
                    timestamp: 100.0 + i as f64 / 30.0,
                    t_wc: WorldFromCamera::from_parts(
                        Vector3::new(a.cos() * 2.0, a.sin() * 2.0, 0.3 * a.sin() * a),
                        UnitQuaternion::from_euler_angles(0.0, a, 0.0),
                    ),
                }
            })
            .collect()
    }

    #[test]
    fn known_transform_with_noise_gives_noise_level_error() {
        let gt = circle(200);
        let truth = Sim3 {
            scale: 0.37,
            rotation: UnitQuaternion::from_euler_angles(0.5, -0.2, 1.0),
            translation: Vector3::new(3.0, -2.0, 1.0),
        };
        let inv = truth.inverse();
        // Deterministic +-1 mm noise pattern (in gt units), then map into the estimate's frame.
        let est: Vec<TimedPose> = gt
            .iter()
            .enumerate()
            .map(|(i, g)| {
                let n = Vector3::new(
                    ((i * 7) % 11) as f64 - 5.0,
                    ((i * 5) % 13) as f64 - 6.0,
                    ((i * 3) % 7) as f64 - 3.0,
                ) * 0.0002;
                TimedPose {
                    timestamp: g.timestamp + 0.004,
                    t_wc: inv.apply_to_pose(&WorldFromCamera::from_parts(
                        g.t_wc.position() + n,
                        g.t_wc.0.rotation,
                    )),
                }
            })
            .collect();
        let r = ate(&gt, &est, 0.02, true).unwrap();
        assert_eq!(r.matched, 200);
        // The estimate lives in `inv`'s frame, so aligning it back recovers `truth`.
        assert!((r.scale - 0.37).abs() < 1e-3, "scale {}", r.scale);
        assert!(r.rmse_m < 0.0015 && r.rmse_m > 0.0003, "rmse {}", r.rmse_m);
        assert!(r.max_m >= r.median_m && r.median_m > 0.0);
    }

    #[test]
    fn association_respects_tolerance_and_uniqueness() {
        let gt = circle(10);
        let mut est = gt.clone();
        est[3].timestamp += 0.05; // beyond 20 ms
        let pairs = associate(&gt, &est, 0.02);
        assert_eq!(pairs.len(), 9);
        assert!(pairs.iter().all(|&(g, e)| g == e));
        let r = ate(&gt, &est, 0.02, true).unwrap();
        assert_eq!(r.unmatched, 1);
        assert!(r.rmse_m < 1e-9);
    }

    #[test]
    fn too_few_matches_is_none() {
        let gt = circle(2);
        assert!(ate(&gt, &gt, 0.02, true).is_none());
    }
}
