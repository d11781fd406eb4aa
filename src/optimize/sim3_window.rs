//! The similarity placing a rigid window of keyframes (one side of a loop, or the newer map of
//! a merge) against fixed map points of the other side: one `S` (world to the reference
//! camera, with scale), every other camera of the window at its pose relative to the reference
//! as the window's own map has it, each matched point reprojected into each camera that
//! matched it. A single keyframe's projections fix its pose but not the scale, and a plane
//! seen far away leaves two poses that fit about equally well (the planar pose ambiguity: a
//! merge was placed half a metre off that way); cameras of the window with a baseline between
//! them fix both. Huber kernel, outliers re-classified between rounds.

use nalgebra::{Matrix3, SMatrix, SVector, Vector2, Vector3};

use super::lie::{projection_jacobian, sim3_retract};
use super::robust::{huber_cost, huber_weight};
use crate::geometry::epipolar::skew;
use crate::geometry::{Intrinsics, Sim3};

const ROUNDS: usize = 3;
const ITERATIONS: usize = 10;

/// A fixed world point matched to a keypoint of camera `view` of the window.
#[derive(Clone, Copy, Debug)]
pub struct WindowObservation {
    pub view: u32,
    pub point: Vector3<f64>,
    pub uv: Vector2<f64>,
    /// 1 / sigma² of the keypoint's octave.
    pub inv_sigma2: f64,
}

/// The point in camera `view` and its pixel residual under `s` (None behind the camera).
fn residual(
    s: &Sim3,
    rel: &[Sim3],
    o: &WindowObservation,
    k: &Intrinsics,
) -> Option<(Vector3<f64>, Vector3<f64>, Vector2<f64>)> {
    let q_ref = s.transform(&o.point);
    let q = rel.get(o.view as usize)?.transform(&q_ref);
    (q.z > 1e-9).then(|| (q_ref, q, k.project(&q) - o.uv))
}

fn cost(
    s: &Sim3,
    rel: &[Sim3],
    obs: &[WindowObservation],
    k: &Intrinsics,
    chi2: f64,
    outlier: &[bool],
) -> f64 {
    obs.iter()
        .zip(outlier)
        .filter(|(_, o)| !**o)
        .map(|(o, _)| {
            residual(s, rel, o, k).map_or(1e6, |(_, _, r)| {
                huber_cost(r.norm_squared() * o.inv_sigma2, chi2)
            })
        })
        .sum()
}

/// Gauss-Newton normal equations of `s` over the inliers (Huber weights when `robust`).
fn normal_equations(
    s: &Sim3,
    rel: &[Sim3],
    obs: &[WindowObservation],
    k: &Intrinsics,
    chi2: f64,
    outlier: &[bool],
    robust: bool,
) -> (SMatrix<f64, 7, 7>, SVector<f64, 7>) {
    let (mut h, mut g) = (SMatrix::<f64, 7, 7>::zeros(), SVector::<f64, 7>::zeros());
    for (o, _) in obs.iter().zip(outlier).filter(|(_, out)| !**out) {
        let Some((q_ref, q, r)) = residual(s, rel, o, k) else {
            continue;
        };
        // Under Exp(δ) S: ∂q_ref/∂δ = [-[q_ref]x, I, q_ref]; the view's rotation carries it on.
        let mut dq = SMatrix::<f64, 3, 7>::zeros();
        dq.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-skew(&q_ref)));
        dq.fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&Matrix3::identity());
        dq.fixed_view_mut::<3, 1>(0, 6).copy_from(&q_ref);
        let v = &rel[o.view as usize];
        let lin = v.rotation.to_rotation_matrix().into_inner() * v.scale;
        let j = projection_jacobian(&q, k.fx, k.fy) * lin * dq;
        let w = o.inv_sigma2
            * if robust {
                huber_weight(r.norm_squared() * o.inv_sigma2, chi2)
            } else {
                1.0
            };
        h += j.transpose() * j * w;
        g += j.transpose() * r * w;
    }
    (h, g)
}

/// Refines `s` (world to the window's reference camera) so that every camera of the window,
/// at `rel[view] ∘ s`, reprojects its observations; `outlier` is read as the starting
/// classification and written (chi² in octave sigma²). Returns the inliers.
pub fn optimize_window_sim3(
    s: &mut Sim3,
    rel: &[Sim3],
    obs: &[WindowObservation],
    k: &Intrinsics,
    chi2: f64,
    outlier: &mut [bool],
) -> usize {
    let n = obs.len().min(outlier.len());
    let (obs, outlier) = (&obs[..n], &mut outlier[..n]);
    let mut inliers = 0;
    for _ in 0..ROUNDS {
        let mut c = cost(s, rel, obs, k, chi2, outlier);
        let mut lambda = 1e-4;
        for _ in 0..ITERATIONS {
            let (h, g) = normal_equations(s, rel, obs, k, chi2, outlier, true);
            let mut improved = false;
            for _ in 0..4 {
                let mut hd = h;
                for d in 0..7 {
                    hd[(d, d)] += lambda * h[(d, d)].max(1e-9);
                }
                let Some(ch) = hd.cholesky() else {
                    lambda *= 10.0;
                    continue;
                };
                let dx = -ch.solve(&g);
                let cand = sim3_retract(s, &[dx[0], dx[1], dx[2], dx[3], dx[4], dx[5], dx[6]]);
                let cc = cost(&cand, rel, obs, k, chi2, outlier);
                if cc <= c {
                    *s = cand;
                    improved = c - cc > 1e-10 * c.max(1e-12) && dx.norm() > 1e-12;
                    c = cc;
                    lambda = (lambda * 0.2).max(1e-9);
                    break;
                }
                lambda *= 10.0;
            }
            if !improved {
                break;
            }
        }
        inliers = 0;
        for (o, out) in obs.iter().zip(outlier.iter_mut()) {
            *out = !residual(s, rel, o, k)
                .is_some_and(|(_, _, r)| r.norm_squared() * o.inv_sigma2 < chi2);
            inliers += (!*out) as usize;
        }
        if inliers < 7 {
            break;
        }
    }
    inliers
}

/// The covariance of `s` (tangent `[ω, v, ln s]` of its left perturbation) from the inlier
/// observations, one pixel of keypoint noise at level 0. None when singular.
pub fn window_sim3_covariance(
    s: &Sim3,
    rel: &[Sim3],
    obs: &[WindowObservation],
    k: &Intrinsics,
    outlier: &[bool],
) -> Option<SMatrix<f64, 7, 7>> {
    normal_equations(s, rel, obs, k, f64::INFINITY, outlier, false)
        .0
        .try_inverse()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    fn k() -> Intrinsics {
        Intrinsics::new(520.0, 520.0, 320.0, 240.0)
    }

    fn sim(scale: f64, rpy: (f64, f64, f64), t: (f64, f64, f64)) -> Sim3 {
        Sim3 {
            scale,
            rotation: UnitQuaternion::from_euler_angles(rpy.0, rpy.1, rpy.2),
            translation: Vector3::new(t.0, t.1, t.2),
        }
    }

    /// Three cameras 20 cm apart see points of a scene; starting from a similarity 10% off in
    /// scale and 15 cm off in position, the window's reprojections bring it back, scale
    /// included (one camera alone cannot fix the scale).
    #[test]
    fn a_window_of_cameras_fixes_pose_and_scale() {
        let truth = sim(0.8, (0.1, -0.2, 0.05), (0.3, -0.1, 0.4));
        let rel = vec![
            Sim3::identity(),
            sim(1.0, (0.0, 0.05, 0.0), (-0.2, 0.0, 0.0)),
            sim(1.0, (0.0, -0.05, 0.0), (0.2, 0.02, 0.0)),
        ];
        let mut obs = Vec::new();
        let mut seed = 5u64;
        let mut rnd = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        for i in 0..150 {
            // A point in the reference camera's frame, then in the world.
            let q_ref = Vector3::new(rnd() * 3.0 - 1.5, rnd() * 2.0 - 1.0, 2.0 + 3.0 * rnd());
            let point = truth.inverse().transform(&q_ref);
            let view = (i % 3) as u32;
            let q = rel[view as usize].transform(&q_ref);
            obs.push(WindowObservation {
                view,
                point,
                uv: k().project(&q) + Vector2::new(rnd() - 0.5, rnd() - 0.5),
                inv_sigma2: 1.0,
            });
        }
        let mut s = Sim3 {
            scale: truth.scale * 1.1,
            translation: truth.translation + Vector3::new(0.15, -0.05, 0.05),
            ..truth
        };
        let mut out = vec![false; obs.len()];
        let n = optimize_window_sim3(&mut s, &rel, &obs, &k(), 5.991, &mut out);
        assert!(n >= 145, "{n} inliers");
        assert!(
            (s.scale / truth.scale - 1.0).abs() < 0.01,
            "scale {} vs {}",
            s.scale,
            truth.scale
        );
        let centre = |x: &Sim3| x.inverse().translation;
        assert!((centre(&s) - centre(&truth)).norm() < 0.01);
        let cov = window_sim3_covariance(&s, &rel, &obs, &k(), &out).unwrap();
        assert!(
            cov[(6, 6)].sqrt() < 0.01,
            "scale sigma {}",
            cov[(6, 6)].sqrt()
        );
        // One camera alone leaves the scale free.
        let one: Vec<WindowObservation> = obs.iter().copied().filter(|o| o.view == 0).collect();
        let cov1 = window_sim3_covariance(&s, &rel, &one, &k(), &vec![false; one.len()]);
        assert!(cov1.is_none_or(|c| c[(6, 6)].sqrt() > 1.0), "{cov1:?}");
    }
}
