//! Knowing when a tracked pose is not one to drive on. Tracking succeeds on inlier count
//! alone (ORB-SLAM); these checks look at how well the final motion-only BA determines the
//! pose and whether it is believable, and turn a doubtful pose into `Degraded` with a reason:
//!
//! - **ambiguous**: the camera centre's 1-sigma uncertainty (from the BA's Hessian, the
//!   rotation marginalised, one pixel of keypoint noise at level 0) is a large share of the
//!   points' median depth. Few points, points in one corner of the image or a far plane let a
//!   sideways move and a turn explain the same image motion.
//! - **poor fit**: the inliers' mean squared reprojection error (in units of their octave's
//!   sigma²) is far above what keypoint noise gives (about 1): the map and the pose disagree.
//! - **jump**: the camera centre lands far from the constant-velocity prediction, a share of
//!   the scene depth no camera moves in one frame.
//!
//! Each bar sits well outside what every sequence of the robustness suite shows (measured in
//! docs/PERFORMANCE.md), so a good pose is never held back; a `Degraded` pose makes no
//! keyframe and stays out of `trajectory.txt`.

use nalgebra::{Vector2, Vector3};

use crate::config::TrackingConfig;
use crate::geometry::CameraFromWorld;
use crate::optimize::MotionOnlyBa;

/// How well the final pose optimisation of a frame determined its pose.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PoseQuality {
    pub inliers: usize,
    /// 1-sigma uncertainty of the camera centre, map units, for one pixel of keypoint noise
    /// at level 0 (octaves scale it). Infinite when the points do not fix the pose.
    pub centre_sigma: f64,
    /// Median depth of the inlier points, map units.
    pub median_depth: f64,
    /// Mean squared reprojection error of the inliers in units of their octave's sigma².
    pub mean_chi2: f64,
    /// Distance of the camera centre from the motion model's prediction, map units (None
    /// without a motion model: right after initialisation or relocalisation).
    pub jump: Option<f64>,
}

/// Why a tracked pose is reported `Degraded` instead of `Ok`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DegradedReason {
    /// The points leave the camera centre poorly determined.
    Ambiguous,
    /// The inliers' reprojection errors are far above keypoint noise.
    PoorFit,
    /// The camera centre jumped away from the motion model's prediction.
    Jump,
}

impl DegradedReason {
    pub const ALL: [DegradedReason; 3] = [
        DegradedReason::Ambiguous,
        DegradedReason::PoorFit,
        DegradedReason::Jump,
    ];

    pub fn name(self) -> &'static str {
        match self {
            DegradedReason::Ambiguous => "ambiguous",
            DegradedReason::PoorFit => "poor_fit",
            DegradedReason::Jump => "jump",
        }
    }
}

impl PoseQuality {
    /// The centre's uncertainty as a share of the scene depth (scale-free, as monocular maps
    /// are).
    pub fn centre_sigma_ratio(&self) -> f64 {
        if self.median_depth > 0.0 {
            self.centre_sigma / self.median_depth
        } else {
            f64::INFINITY
        }
    }

    /// The first check the pose fails, if any (a NaN figure fails its check).
    pub fn judge(&self, c: &TrackingConfig) -> Option<DegradedReason> {
        let within = |v: f64, bar: f64| v.partial_cmp(&bar).is_some_and(|o| o.is_le());
        if !within(self.centre_sigma_ratio(), c.max_centre_sigma_ratio) {
            return Some(DegradedReason::Ambiguous);
        }
        if !within(self.mean_chi2, c.max_mean_chi2) {
            return Some(DegradedReason::PoorFit);
        }
        match self.jump {
            Some(j) if !within(j, c.max_jump_ratio * self.median_depth) => {
                Some(DegradedReason::Jump)
            }
            _ => None,
        }
    }
}

/// A pose and the observations it was optimised on (the motion-only BA's buffers).
pub struct PoseFit<'a> {
    pub t_cw: &'a CameraFromWorld,
    pub pts: &'a [Vector3<f64>],
    pub obs: &'a [Vector2<f64>],
    pub inv_s2: &'a [f64],
    pub outlier: &'a [bool],
}

/// The quality of `fit` (the camera and noise model of `ba`), with `depths` as scratch
/// (reused: no allocation once grown).
pub fn measure(
    ba: &MotionOnlyBa,
    fit: &PoseFit<'_>,
    prediction: Option<&CameraFromWorld>,
    depths: &mut Vec<f64>,
) -> PoseQuality {
    let PoseFit {
        t_cw,
        pts,
        obs,
        inv_s2,
        outlier,
    } = *fit;
    depths.clear();
    let (mut chi2, mut n) = (0.0, 0usize);
    for i in 0..pts
        .len()
        .min(obs.len())
        .min(inv_s2.len())
        .min(outlier.len())
    {
        if outlier[i] {
            continue;
        }
        let pc = t_cw.transform(&pts[i]);
        if pc.z <= 0.0 {
            continue;
        }
        depths.push(pc.z);
        chi2 += (ba.k.project(&pc) - obs[i]).norm_squared() * inv_s2[i];
        n += 1;
    }
    let median_depth = if depths.is_empty() {
        0.0
    } else {
        let mid = depths.len() / 2;
        *depths.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1
    };
    let centre_sigma = ba
        .centre_covariance(t_cw, pts, obs, inv_s2, outlier)
        .map_or(f64::INFINITY, |c| c.trace().max(0.0).sqrt());
    PoseQuality {
        inliers: n,
        centre_sigma,
        median_depth,
        mean_chi2: if n > 0 {
            chi2 / n as f64
        } else {
            f64::INFINITY
        },
        jump: prediction.map(|p| (p.center() - t_cw.center()).norm()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Se3;
    use nalgebra::{Point3, Translation3, UnitQuaternion};

    fn camera() -> crate::geometry::Intrinsics {
        crate::geometry::Intrinsics::new(520.0, 520.0, 320.0, 240.0)
    }

    /// Points seen by `t_cw` at pixels in `[u0, u1] x [v0, v1]` and depths in `[z0, z1]`,
    /// observed exactly.
    fn scene(
        t_cw: &CameraFromWorld,
        n: usize,
        (u0, u1, v0, v1): (f64, f64, f64, f64),
        (z0, z1): (f64, f64),
    ) -> (Vec<Vector3<f64>>, Vec<Vector2<f64>>) {
        let k = camera();
        let (mut pts, mut obs) = (Vec::new(), Vec::new());
        for i in 0..n {
            // A low-discrepancy spread over the box.
            let (a, b, c) = (
                (i as f64 * 0.618_034).fract(),
                (i as f64 * 0.754_877).fract(),
                (i as f64 * 0.569_840).fract(),
            );
            let (u, v, z) = (u0 + a * (u1 - u0), v0 + b * (v1 - v0), z0 + c * (z1 - z0));
            let pc = Vector3::new((u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z);
            pts.push((t_cw.inverse().0 * Point3::from(pc)).coords);
            obs.push(Vector2::new(u, v));
        }
        (pts, obs)
    }

    fn quality_with(
        t_cw: &CameraFromWorld,
        pts: &[Vector3<f64>],
        obs: &[Vector2<f64>],
        prediction: Option<&CameraFromWorld>,
    ) -> PoseQuality {
        let n = pts.len();
        let fit = PoseFit {
            t_cw,
            pts,
            obs,
            inv_s2: &vec![1.0; n],
            outlier: &vec![false; n],
        };
        measure(
            &MotionOnlyBa::new(camera()),
            &fit,
            prediction,
            &mut Vec::new(),
        )
    }

    fn quality(t_cw: &CameraFromWorld, pts: &[Vector3<f64>], obs: &[Vector2<f64>]) -> PoseQuality {
        quality_with(t_cw, pts, obs, None)
    }

    fn pose() -> CameraFromWorld {
        CameraFromWorld(Se3::from_parts(
            Translation3::new(0.2, -0.1, 0.5),
            UnitQuaternion::from_euler_angles(0.1, -0.3, 0.05),
        ))
    }

    #[test]
    fn points_over_the_whole_image_at_varied_depths_fix_the_pose() {
        let t = pose();
        let (pts, obs) = scene(&t, 300, (20.0, 620.0, 20.0, 460.0), (1.0, 4.0));
        let q = quality(&t, &pts, &obs);
        assert_eq!(q.judge(&TrackingConfig::default()), None, "{q:?}");
        assert!(q.centre_sigma_ratio() < 0.002, "{q:?}");
        assert!(q.mean_chi2 < 1e-12, "{q:?}");
    }

    /// Thirty points in one corner of the image on a far wall: a sideways move and a turn give
    /// nearly the same image motion, so the centre is poorly fixed.
    #[test]
    fn a_few_clustered_points_on_a_far_plane_are_ambiguous() {
        let t = pose();
        let (pts, obs) = scene(&t, 30, (500.0, 620.0, 20.0, 120.0), (20.0, 20.5));
        let q = quality(&t, &pts, &obs);
        assert_eq!(
            q.judge(&TrackingConfig::default()),
            Some(DegradedReason::Ambiguous),
            "{q:?}"
        );
    }

    /// The inliers all sit near the chi² gate: map and pose disagree.
    #[test]
    fn reprojection_errors_far_above_noise_are_a_poor_fit() {
        let t = pose();
        let (pts, mut obs) = scene(&t, 300, (20.0, 620.0, 20.0, 460.0), (1.0, 4.0));
        for (i, o) in obs.iter_mut().enumerate() {
            let a = i as f64 * 2.4;
            *o += 2.2 * Vector2::new(a.cos(), a.sin());
        }
        let q = quality(&t, &pts, &obs);
        assert!(q.mean_chi2 > 4.0, "{q:?}");
        assert_eq!(
            q.judge(&TrackingConfig::default()),
            Some(DegradedReason::PoorFit),
            "{q:?}"
        );
    }

    #[test]
    fn a_centre_far_from_the_prediction_is_a_jump() {
        let t = pose();
        let (pts, obs) = scene(&t, 300, (20.0, 620.0, 20.0, 460.0), (1.0, 4.0));
        let q = quality(&t, &pts, &obs);
        let c = TrackingConfig::default();
        let away = |d: f64| {
            CameraFromWorld(Se3::from_parts(
                Translation3::from(t.0.translation.vector + Vector3::new(d, 0.0, 0.0)),
                t.0.rotation,
            ))
        };
        let judge = |pred: CameraFromWorld| quality_with(&t, &pts, &obs, Some(&pred)).judge(&c);
        let small = 0.5 * c.max_jump_ratio * q.median_depth;
        let large = 2.0 * c.max_jump_ratio * q.median_depth;
        assert_eq!(judge(away(small)), None);
        assert_eq!(judge(away(large)), Some(DegradedReason::Jump));
    }

    #[test]
    fn nan_figures_fail_the_checks() {
        let q = PoseQuality {
            inliers: 100,
            centre_sigma: f64::NAN,
            median_depth: 1.0,
            mean_chi2: 1.0,
            jump: None,
        };
        assert_eq!(
            q.judge(&TrackingConfig::default()),
            Some(DegradedReason::Ambiguous)
        );
    }
}
