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
pub struct NeighbourMap {
    /// Per pixel (rho, sigma^2), interleaved so a lookup touches one cache line; sigma^2 = 0
    /// marks no estimate.
    est: Vec<[f32; 2]>,
    /// Pixels written, so clearing costs what filling did.
    touched: Vec<u32>,
    /// Reference pixels to this neighbour's pixels: `K R_ji K^-1` and `K t_ji`.
    kr: Matrix3<f64>,
    kt: Vector3<f64>,
}

impl NeighbourMap {
    /// Replaces the map by `pixels` (intra-checked estimates), with `t_ji` mapping reference
    /// camera points into this neighbour; clears only the pixels the previous fill set.
    pub fn fill(&mut self, k: &Intrinsics, pixels: impl Iterator<Item = DepthPixel>, t_ji: &Se3) {
        for &i in &self.touched {
            self.est[i as usize] = [0.0; 2];
        }
        self.touched.clear();
        for p in pixels {
            let i = p.idx as usize;
            if i < self.est.len() {
                self.est[i] = [p.rho, p.sigma * p.sigma];
                self.touched.push(p.idx);
            }
        }
        (self.kr, self.kt) = k.pixel_transform(t_ji);
    }
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
                kr: Matrix3::identity(),
                kt: Vector3::zeros(),
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

    /// Forgets every neighbour (their maps are cleared when refilled).
    pub fn clear(&mut self) {
        self.active = 0;
    }

    pub fn neighbours(&self) -> usize {
        self.active
    }

    /// Forgets the neighbours and returns the intrinsics and the maps of the next `n` (at
    /// most the capacity), each to be filled with `NeighbourMap::fill`: independent, so in
    /// parallel if wanted.
    pub fn begin(&mut self, n: usize) -> (Intrinsics, &mut [NeighbourMap]) {
        self.active = n.min(self.maps.len());
        (self.k, &mut self.maps[..self.active])
    }

    /// Adds a neighbour's (intra-checked) inverse-depth map with `t_ji` mapping reference
    /// camera points into it. False when the capacity is reached.
    pub fn add_neighbour(&mut self, pixels: impl Iterator<Item = DepthPixel>, t_ji: &Se3) -> bool {
        if self.active == self.maps.len() {
            return false;
        }
        self.maps[self.active].fill(&self.k, pixels, t_ji);
        self.active += 1;
        true
    }

    /// Checks the estimate `rho` of pixel `idx` of the reference keyframe; returns the refined
    /// inverse depth when at least `lambda_n` neighbours support it.
    pub fn check(&self, idx: u32, rho: f32, lambda_n: usize) -> Option<f32> {
        let (w, h) = (self.width, self.height);
        let x = Vector3::new((idx as usize % w) as f64, (idx as usize / w) as f64, 1.0);
        let rho = rho as f64;
        let (u_max, v_max) = ((w - 1) as f64, (h - 1) as f64);
        let (mut support, mut num, mut den) = (0usize, 0.0f64, 0.0f64);
        let maps = &self.maps[..self.active];
        for (i, m) in maps.iter().enumerate() {
            // Too few neighbours left for lambda_n supports: rejected whatever they hold.
            if support + (maps.len() - i) < lambda_n {
                return None;
            }
            // Eq. 12 in pixels: K X_j / depth_i = a + rho K t with a = K R K^-1 x, so the
            // point's inverse depth in j is rho / h.z and its pixel (h.x, h.y) / h.z.
            let a = m.kr * x;
            let hp = a + m.kt * rho;
            if hp.z <= 1e-9 * rho {
                continue;
            }
            let inv = 1.0 / hp.z;
            let (u, v) = (hp.x * inv, hp.y * inv);
            if !(u >= 0.0 && v >= 0.0 && u < u_max && v < v_max) {
                continue;
            }
            let rho_j = rho * inv;
            let (u0, v0) = (u as usize, v as usize);
            let mut found = false;
            for (du, dv) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let [r, s2] = m.est[(v0 + dv) * w + u0 + du];
                if s2 <= 0.0 {
                    continue;
                }
                let (r, s2) = (r as f64, s2 as f64);
                let d = rho_j - r;
                // Eq. 13.
                if d * d < CHI2_1DOF_95 as f64 * s2 {
                    found = true;
                    // Eq. 14 terms: depth residual d_jn - d_p (r_z . X_p) - t_z, with
                    // d_jn = 1 / r, r_z . X_p = a.z (K's last row is (0, 0, 1)), weighted by
                    // the inverse depth variance propagated to depth (d_jn^4 sigma^2):
                    // weight r^4 / s2, so the terms are a.z r^3 (1 - r t_z) / s2, a.z^2 r^4 / s2.
                    let r3_s2 = r * r * r / s2;
                    num += a.z * r3_s2 * (1.0 - r * m.kt.z);
                    den += a.z * a.z * r3_s2 * r;
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
