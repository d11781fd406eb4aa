//! Inter-keyframe depth checking and refinement (paper section III-E): each estimate of
//! keyframe i is propagated into its neighbours' inverse-depth maps (eq. 12), must find a
//! compatible estimate (eq. 13) among the 4 pixels around its projection in at least lambda_N
//! neighbours, and its depth is then refined by one Gauss-Newton step over all compatible
//! pixels (eq. 14; linear in depth, so one step is the optimum).

use nalgebra::{Matrix3, Vector3};

use super::epipolar::Intrinsics;
use super::fusion::CHI2_1DOF_95;
use super::DepthPixel;
use crate::geometry::Se3;

/// One neighbour's inverse-depth map, scattered into a dense buffer for lookups.
struct NeighbourMap {
    /// Per pixel (rho, sigma^2), interleaved so a lookup touches one cache line; sigma^2 = 0
    /// marks no estimate.
    est: Vec<[f32; 2]>,
    /// Pixels written, so clearing costs what filling did.
    touched: Vec<u32>,
    /// Reference camera to this neighbour's camera.
    r_ji: Matrix3<f64>,
    t_ji: Vector3<f64>,
}

/// Holds up to `capacity` neighbour maps of one image size; reused across keyframes.
pub struct InterChecker {
    k: Intrinsics,
    width: usize,
    height: usize,
    maps: Vec<NeighbourMap>,
    active: usize,
}

impl InterChecker {
    /// Frees the neighbour maps (no check follows).
    pub fn release_working_memory(&mut self) {
        self.maps = Vec::new();
        self.active = 0;
    }

    pub fn new(k: Intrinsics, width: usize, height: usize, capacity: usize) -> Self {
        let maps = (0..capacity)
            .map(|_| NeighbourMap {
                est: vec![[0.0; 2]; width * height],
                touched: Vec::with_capacity(width * height),
                r_ji: Matrix3::identity(),
                t_ji: Vector3::zeros(),
            })
            .collect();
        InterChecker {
            k,
            width,
            height,
            maps,
            active: 0,
        }
    }

    /// Forgets every neighbour (clears only the pixels that were set).
    pub fn clear(&mut self) {
        for m in &mut self.maps[..self.active] {
            for &i in &m.touched {
                m.est[i as usize] = [0.0; 2];
            }
            m.touched.clear();
        }
        self.active = 0;
    }

    pub fn neighbours(&self) -> usize {
        self.active
    }

    /// Adds a neighbour's (intra-checked) inverse-depth map with `t_ji` mapping reference
    /// camera points into it. False when the capacity is reached.
    pub fn add_neighbour(&mut self, pixels: impl Iterator<Item = DepthPixel>, t_ji: &Se3) -> bool {
        if self.active == self.maps.len() {
            return false;
        }
        let m = &mut self.maps[self.active];
        for p in pixels {
            let i = p.idx as usize;
            if i < m.est.len() {
                m.est[i] = [p.rho, p.sigma * p.sigma];
                m.touched.push(p.idx);
            }
        }
        m.r_ji = *t_ji.rotation.to_rotation_matrix().matrix();
        m.t_ji = t_ji.translation.vector;
        self.active += 1;
        true
    }

    /// Checks the estimate `rho` of pixel `idx` of the reference keyframe; returns the refined
    /// inverse depth when at least `lambda_n` neighbours support it.
    pub fn check(&self, idx: u32, rho: f32, lambda_n: usize) -> Option<f32> {
        let (w, h) = (self.width, self.height);
        let (x, y) = ((idx as usize % w) as f64, (idx as usize / w) as f64);
        let ray = self.k.ray(x, y);
        let depth = 1.0 / rho as f64;
        let (mut support, mut num, mut den) = (0usize, 0.0f64, 0.0f64);
        for m in &self.maps[..self.active] {
            let rx = m.r_ji * ray;
            // Eq. 12: the point in j, and its inverse depth there.
            let pj = rx * depth + m.t_ji;
            if pj.z <= 1e-9 {
                continue;
            }
            let rho_j = 1.0 / pj.z;
            let u = self.k.fx * pj.x * rho_j + self.k.cx;
            let v = self.k.fy * pj.y * rho_j + self.k.cy;
            if !(u >= 0.0 && v >= 0.0 && u < (w - 1) as f64 && v < (h - 1) as f64) {
                continue;
            }
            let (u0, v0) = (u as usize, v as usize);
            let mut found = false;
            for (du, dv) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let [r, s2] = m.est[(v0 + dv) * w + u0 + du];
                let s2 = s2 as f64;
                if s2 <= 0.0 {
                    continue;
                }
                let r = r as f64;
                let d = rho_j - r;
                // Eq. 13.
                if d * d / s2 < CHI2_1DOF_95 as f64 {
                    found = true;
                    // Eq. 14 terms: depth residual d_jn - d_p (r_z . X_p) - t_z, weighted by
                    // the inverse depth variance propagated to depth (d^4 sigma^2).
                    let dj = 1.0 / r;
                    let wgt = 1.0 / (dj * dj * dj * dj * s2);
                    let a = rx.z;
                    num += wgt * a * (dj - m.t_ji.z);
                    den += wgt * a * a;
                }
            }
            if found {
                support += 1;
            }
        }
        if support < lambda_n || den <= 0.0 {
            return None;
        }
        let depth = num / den;
        (depth > 0.0 && depth.is_finite()).then(|| (1.0 / depth) as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    /// A fronto-parallel plane at depth 2 seen by the reference and by neighbours shifted
    /// sideways: neighbour maps are exact, so a correct estimate is kept and refined to the
    /// truth, and a wrong one is rejected.
    #[test]
    fn consistent_estimates_kept_and_refined_inconsistent_rejected() {
        let k = Intrinsics {
            fx: 100.0,
            fy: 100.0,
            cx: 40.0,
            cy: 30.0,
        };
        let (w, h) = (80, 60);
        let mut c = InterChecker::new(k, w, h, 4);
        for n in 0..3 {
            let t_ji = Se3::from_parts(
                Translation3::new(-0.1 * (n + 1) as f64, 0.0, 0.0),
                UnitQuaternion::identity(),
            );
            let pixels: Vec<DepthPixel> = (0..(w * h) as u32)
                .map(|idx| DepthPixel {
                    idx,
                    rho: 0.5,
                    sigma: 0.01,
                })
                .collect();
            assert!(c.add_neighbour(pixels.into_iter(), &t_ji));
        }
        let idx = (30 * w + 40) as u32;
        let refined = c.check(idx, 0.505, 3).unwrap();
        assert!((refined - 0.5).abs() < 1e-4, "{refined}");
        assert_eq!(c.check(idx, 0.8, 3), None);
        assert_eq!(c.check(idx, 0.5, 4), None);
        c.clear();
        assert_eq!(c.neighbours(), 0);
        assert_eq!(c.check(idx, 0.5, 1), None);
    }
}
