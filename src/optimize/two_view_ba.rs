//! Two-view bundle adjustment after [`crate::geometry::two_view::initialize`]: the maximum
//! likelihood motion and structure (first-order refinements stop short of it, e.g. for forward
//! motion). Camera 1 is the gauge; the scale is restored to `|t| = 1` afterwards.

use nalgebra::{Matrix3, Vector2};

use super::{BaObservation, BaOptions, BaProblem, BundleAdjuster};
use crate::geometry::two_view::TwoViewMotion;
use crate::geometry::{CameraFromWorld, Se3};

/// Refines `m` in place on the matches `x1[i] <-> x2[i]` (undistorted pixels) whose points were
/// triangulated; points failing the chi² 5.991 gate afterwards are dropped from `m.points`.
pub fn refine_two_view(
    m: &mut TwoViewMotion,
    x1: &[Vector2<f64>],
    x2: &[Vector2<f64>],
    k: &Matrix3<f64>,
    sigma: f64,
) {
    let idx: Vec<usize> = (0..m.points.len())
        .filter(|&i| m.points[i].is_some())
        .collect();
    if idx.len() < 8 {
        return;
    }
    let inv_s2 = 1.0 / (sigma * sigma);
    let mut p = BaProblem {
        k: crate::geometry::Intrinsics::new(k[(0, 0)], k[(1, 1)], k[(0, 2)], k[(1, 2)]),
        poses: vec![CameraFromWorld(Se3::identity()), CameraFromWorld(m.t_21)],
        pose_fixed: vec![true, false],
        points: idx.iter().filter_map(|&i| m.points[i]).collect(),
        observations: Vec::with_capacity(idx.len() * 2),
        excluded: Vec::new(),
    };
    for (j, &i) in idx.iter().enumerate() {
        p.observations.push(BaObservation {
            pose: 0,
            point: j as u32,
            uv: x1[i],
            inv_sigma2: inv_s2,
        });
        p.observations.push(BaObservation {
            pose: 1,
            point: j as u32,
            uv: x2[i],
            inv_sigma2: inv_s2,
        });
    }
    let mut ba = BundleAdjuster::new();
    ba.solve(
        &mut p,
        &BaOptions {
            iterations: 10,
            ..BaOptions::default()
        },
    );
    p.classify_outliers(5.991);
    ba.solve(
        &mut p,
        &BaOptions {
            iterations: 10,
            robust_delta2: None,
            ..BaOptions::default()
        },
    );
    let t = p.poses[1].0;
    let s = t.translation.vector.norm();
    if s.is_nan() || s <= 1e-9 {
        return;
    }
    m.t_21 = Se3::from_parts(
        nalgebra::Translation3::from(t.translation.vector / s),
        t.rotation,
    );
    for (j, &i) in idx.iter().enumerate() {
        let ok = !p.excluded[2 * j] && !p.excluded[2 * j + 1];
        m.points[i] = ok.then(|| p.points[j] / s);
    }
}
