//! Bundle adjustment of keyframe poses and map points: Levenberg-Marquardt with analytic
//! Jacobians of the pinhole reprojection, Huber kernel, per-observation information (1/sigma² of
//! the keypoint octave), fixed poses, and a Schur complement on the points (3x3 point blocks)
//! leaving the reduced camera system, solved by the skyline Cholesky of [`BlockSystem`].
//! Local BA (window + fixed neighbours) and global BA are the same code with different fixed
//! sets. Buffers live in [`BundleAdjuster`] and are reused between calls.

use nalgebra::{Matrix3, SMatrix, Vector2, Vector3};

use super::lie::{point_pose_jacobian, projection_jacobian, se3_retract};
use super::robust::{huber_cost, huber_weight};
use super::skyline::BlockSystem;
use crate::geometry::CameraFromWorld;

/// One observation of a point in a keyframe (undistorted pixel).
#[derive(Clone, Copy, Debug)]
pub struct BaObservation {
    pub pose: u32,
    pub point: u32,
    pub uv: Vector2<f64>,
    /// 1 / sigma² of the keypoint's octave.
    pub inv_sigma2: f64,
}

/// A BA problem: poses (`T_cw`), points (world), observations; intrinsics of the undistorted
/// pinhole.
#[derive(Clone, Debug, Default)]
pub struct BaProblem {
    pub k: crate::geometry::Intrinsics,
    pub poses: Vec<CameraFromWorld>,
    pub pose_fixed: Vec<bool>,
    pub points: Vec<Vector3<f64>>,
    pub observations: Vec<BaObservation>,
    /// Observations left out (outliers); same length as `observations`.
    pub excluded: Vec<bool>,
}

impl BaProblem {
    /// Squared, information-weighted error of observation `o` (infinite behind the camera).
    pub fn chi2(&self, o: usize) -> f64 {
        let ob = &self.observations[o];
        let pc = self.poses[ob.pose as usize].transform(&self.points[ob.point as usize]);
        if pc.z <= 1e-9 {
            return f64::INFINITY;
        }
        let r = Vector2::new(
            self.k.fx * pc.x / pc.z + self.k.cx - ob.uv.x,
            self.k.fy * pc.y / pc.z + self.k.cy - ob.uv.y,
        );
        r.norm_squared() * ob.inv_sigma2
    }

    /// Marks observations with chi² above `gate` (or behind the camera) as excluded; returns how
    /// many are excluded in total.
    pub fn classify_outliers(&mut self, gate: f64) -> usize {
        self.excluded.resize(self.observations.len(), false);
        let mut n = 0;
        for o in 0..self.observations.len() {
            let bad = self.chi2(o) > gate;
            self.excluded[o] = self.excluded[o] || bad;
            n += self.excluded[o] as usize;
        }
        n
    }
}

/// Options of one LM run.
#[derive(Clone, Debug)]
pub struct BaOptions {
    pub iterations: usize,
    /// Huber threshold on the weighted squared error (5.991 for 2 DoF), or none.
    pub robust_delta2: Option<f64>,
    pub initial_lambda: f64,
}

impl Default for BaOptions {
    fn default() -> Self {
        BaOptions {
            iterations: 10,
            robust_delta2: Some(5.991),
            initial_lambda: 1e-4,
        }
    }
}

#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BaReport {
    pub initial_cost: f64,
    pub final_cost: f64,
    pub iterations: usize,
    pub accepted_steps: usize,
    /// Every accepted step decreased the cost (an invariant, reported for tests).
    pub monotone: bool,
}

/// Scratch of the solver.
#[derive(Default)]
pub struct BundleAdjuster {
    var_of_pose: Vec<Option<usize>>,
    /// Observations grouped by point (CSR).
    point_start: Vec<usize>,
    point_obs: Vec<u32>,
    /// Per point: slots of the (pose, pose) pairs of its observation pairs, in CSR order.
    pair_start: Vec<usize>,
    pair_slots: Vec<u32>,
    hll: Vec<Matrix3<f64>>,
    bl: Vec<Vector3<f64>>,
    hll_inv: Vec<Matrix3<f64>>,
    hcl: Vec<SMatrix<f64, 6, 3>>,
    hcc: Vec<SMatrix<f64, 6, 6>>,
    bc: Vec<SMatrix<f64, 6, 1>>,
    dc: Vec<f64>,
    cand_poses: Vec<CameraFromWorld>,
    cand_points: Vec<Vector3<f64>>,
    system: Option<BlockSystem>,
}

/// `dst -= W_a Hcl_b^T` (6x6, row-major), the Schur complement's term of one observation
/// pair, written out: nalgebra's generic product of these shapes runs as iterator loops.
#[inline]
fn sub_outer_6x3(dst: &mut [f64; 36], wa: &SMatrix<f64, 6, 3>, hb: &SMatrix<f64, 6, 3>) {
    for r in 0..6 {
        let (w0, w1, w2) = (wa[(r, 0)], wa[(r, 1)], wa[(r, 2)]);
        for c in 0..6 {
            dst[r * 6 + c] -= w0 * hb[(c, 0)] + w1 * hb[(c, 1)] + w2 * hb[(c, 2)];
        }
    }
}

/// [`sub_outer_6x3`] four columns at a time (then two), with the same operations in the same
/// order, so the result is identical to the bit. A row of the product is
/// `sum_k W_a[r, k] Hcl_b[:, k]^T`, and each column of `Hcl_b` (column-major) is contiguous.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
unsafe fn sub_outer_6x3_avx(dst: &mut [f64; 36], wa: &SMatrix<f64, 6, 3>, hb: &SMatrix<f64, 6, 3>) {
    use std::arch::x86_64::*;
    let h = hb.as_slice();
    let w = wa.as_slice();
    // Columns k of Hcl_b: rows 0-3 and 4-5.
    let h_lo = [
        _mm256_loadu_pd(h.as_ptr()),
        _mm256_loadu_pd(h.as_ptr().add(6)),
        _mm256_loadu_pd(h.as_ptr().add(12)),
    ];
    let h_hi = [
        _mm_loadu_pd(h.as_ptr().add(4)),
        _mm_loadu_pd(h.as_ptr().add(10)),
        _mm_loadu_pd(h.as_ptr().add(16)),
    ];
    for r in 0..6 {
        let (w0, w1, w2) = (w[r], w[6 + r], w[12 + r]);
        let d = dst.as_mut_ptr().add(r * 6);
        let lo = _mm256_add_pd(
            _mm256_add_pd(
                _mm256_mul_pd(_mm256_set1_pd(w0), h_lo[0]),
                _mm256_mul_pd(_mm256_set1_pd(w1), h_lo[1]),
            ),
            _mm256_mul_pd(_mm256_set1_pd(w2), h_lo[2]),
        );
        let hi = _mm_add_pd(
            _mm_add_pd(
                _mm_mul_pd(_mm_set1_pd(w0), h_hi[0]),
                _mm_mul_pd(_mm_set1_pd(w1), h_hi[1]),
            ),
            _mm_mul_pd(_mm_set1_pd(w2), h_hi[2]),
        );
        _mm256_storeu_pd(d, _mm256_sub_pd(_mm256_loadu_pd(d), lo));
        _mm_storeu_pd(d.add(4), _mm_sub_pd(_mm_loadu_pd(d.add(4)), hi));
    }
}

impl BundleAdjuster {
    pub fn new() -> Self {
        Self::default()
    }

    fn cost(
        p: &BaProblem,
        poses: &[CameraFromWorld],
        points: &[Vector3<f64>],
        robust: Option<f64>,
    ) -> f64 {
        let mut c = 0.0;
        for (o, ob) in p.observations.iter().enumerate() {
            if p.excluded.get(o).copied().unwrap_or(false) {
                continue;
            }
            let pc = poses[ob.pose as usize].transform(&points[ob.point as usize]);
            let e2 = if pc.z <= 1e-9 {
                1e6
            } else {
                let r = Vector2::new(
                    p.k.fx * pc.x / pc.z + p.k.cx - ob.uv.x,
                    p.k.fy * pc.y / pc.z + p.k.cy - ob.uv.y,
                );
                r.norm_squared() * ob.inv_sigma2
            };
            c += match robust {
                Some(d2) => huber_cost(e2, d2),
                None => e2,
            };
        }
        c
    }

    /// Builds the index structures (variables, observations by point, system structure).
    fn structure(&mut self, p: &BaProblem) -> usize {
        let np = p.points.len();
        self.var_of_pose.clear();
        let mut nvar = 0;
        for &f in &p.pose_fixed {
            self.var_of_pose.push(if f {
                None
            } else {
                nvar += 1;
                Some(nvar - 1)
            });
        }
        self.point_start.clear();
        self.point_start.resize(np + 1, 0);
        for (o, ob) in p.observations.iter().enumerate() {
            if !p.excluded[o] {
                self.point_start[ob.point as usize + 1] += 1;
            }
        }
        for i in 0..np {
            self.point_start[i + 1] += self.point_start[i];
        }
        self.point_obs.clear();
        self.point_obs.resize(self.point_start[np], 0);
        let mut cursor = self.point_start.clone();
        for (o, ob) in p.observations.iter().enumerate() {
            if !p.excluded[o] {
                let c = &mut cursor[ob.point as usize];
                self.point_obs[*c] = o as u32;
                *c += 1;
            }
        }
        let mut pairs = Vec::new();
        for j in 0..np {
            let obs = &self.point_obs[self.point_start[j]..self.point_start[j + 1]];
            for (a, &oa) in obs.iter().enumerate() {
                for &ob in &obs[a + 1..] {
                    let (va, vb) = (
                        self.var_of_pose[p.observations[oa as usize].pose as usize],
                        self.var_of_pose[p.observations[ob as usize].pose as usize],
                    );
                    if let (Some(va), Some(vb)) = (va, vb) {
                        if va != vb {
                            pairs.push((va, vb));
                        }
                    }
                }
            }
        }
        let sys = self.system.get_or_insert_with(|| BlockSystem::new(6));
        sys.set_structure(nvar, pairs);
        // Slots per observation pair, point by point.
        self.pair_start.clear();
        self.pair_slots.clear();
        for j in 0..np {
            self.pair_start.push(self.pair_slots.len());
            let obs = &self.point_obs[self.point_start[j]..self.point_start[j + 1]];
            for &oa in obs {
                for &ob in obs {
                    let (va, vb) = (
                        self.var_of_pose[p.observations[oa as usize].pose as usize],
                        self.var_of_pose[p.observations[ob as usize].pose as usize],
                    );
                    let slot = match (va, vb) {
                        (Some(a), Some(b)) if a <= b => {
                            sys.slot(a, b).map(|s| s as u32).unwrap_or(u32::MAX)
                        }
                        _ => u32::MAX,
                    };
                    self.pair_slots.push(slot);
                }
            }
        }
        self.pair_start.push(self.pair_slots.len());
        nvar
    }

    /// Runs Levenberg-Marquardt on `p` (poses and points updated in place).
    pub fn solve(&mut self, p: &mut BaProblem, opts: &BaOptions) -> BaReport {
        p.excluded.resize(p.observations.len(), false);
        p.pose_fixed.resize(p.poses.len(), false);
        let nvar = self.structure(p);
        let (np, no) = (p.points.len(), p.observations.len());
        let robust = opts.robust_delta2;
        let mut cost = Self::cost(p, &p.poses, &p.points, robust);
        let mut report = BaReport {
            initial_cost: cost,
            final_cost: cost,
            monotone: true,
            ..Default::default()
        };
        if nvar == 0 && np == 0 {
            return report;
        }
        self.hll.resize(np, Matrix3::zeros());
        self.bl.resize(np, Vector3::zeros());
        self.hll_inv.resize(np, Matrix3::zeros());
        self.hcl.resize(no, SMatrix::zeros());
        self.hcc.resize(nvar, SMatrix::zeros());
        self.bc.resize(nvar, SMatrix::zeros());
        self.dc.resize(nvar * 6, 0.0);
        let mut lambda = opts.initial_lambda;
        for it in 0..opts.iterations {
            report.iterations = it + 1;
            // Linearise.
            self.hll.iter_mut().for_each(|m| *m = Matrix3::zeros());
            self.bl.iter_mut().for_each(|v| *v = Vector3::zeros());
            self.hcc.iter_mut().for_each(|m| *m = SMatrix::zeros());
            self.bc.iter_mut().for_each(|v| *v = SMatrix::zeros());
            for (o, ob) in p.observations.iter().enumerate() {
                if p.excluded[o] {
                    continue;
                }
                let pose = &p.poses[ob.pose as usize];
                let pc = pose.transform(&p.points[ob.point as usize]);
                if pc.z <= 1e-9 {
                    self.hcl[o] = SMatrix::zeros();
                    continue;
                }
                let r = Vector2::new(
                    p.k.fx * pc.x / pc.z + p.k.cx - ob.uv.x,
                    p.k.fy * pc.y / pc.z + p.k.cy - ob.uv.y,
                );
                let e2 = r.norm_squared() * ob.inv_sigma2;
                let w = ob.inv_sigma2 * robust.map_or(1.0, |d2| huber_weight(e2, d2));
                let jpi = projection_jacobian(&pc, p.k.fx, p.k.fy);
                let jl = jpi * pose.0.rotation.to_rotation_matrix().matrix();
                let j = ob.point as usize;
                self.hll[j] += jl.transpose() * jl * w;
                self.bl[j] += jl.transpose() * r * w;
                if let Some(v) = self.var_of_pose[ob.pose as usize] {
                    let jc = jpi * point_pose_jacobian(&pc);
                    self.hcc[v] += jc.transpose() * jc * w;
                    self.bc[v] += jc.transpose() * r * w;
                    self.hcl[o] = jc.transpose() * jl * w;
                } else {
                    self.hcl[o] = SMatrix::zeros();
                }
            }
            // Try damped steps until one lowers the cost.
            let mut accepted = false;
            for _ in 0..8 {
                if self.step(p, nvar, lambda).is_none() {
                    lambda *= 10.0;
                    continue;
                }
                let c = Self::cost(p, &self.cand_poses, &self.cand_points, robust);
                if c < cost {
                    let rel = (cost - c) / cost.max(1e-300);
                    std::mem::swap(&mut p.poses, &mut self.cand_poses);
                    std::mem::swap(&mut p.points, &mut self.cand_points);
                    report.monotone &= c <= cost;
                    cost = c;
                    report.accepted_steps += 1;
                    lambda = (lambda / 3.0).max(1e-12);
                    accepted = rel > 1e-10;
                    break;
                }
                lambda *= 4.0;
            }
            if !accepted {
                break;
            }
        }
        report.final_cost = cost;
        report
    }

    /// Solves the damped system for one step and writes the candidate into `cand_*`.
    fn step(&mut self, p: &BaProblem, nvar: usize, lambda: f64) -> Option<()> {
        let np = p.points.len();
        for j in 0..np {
            let mut h = self.hll[j];
            for d in 0..3 {
                h[(d, d)] += lambda * h[(d, d)] + 1e-12;
            }
            self.hll_inv[j] = h.try_inverse().unwrap_or_else(Matrix3::zeros);
        }
        let sys = self.system.as_mut()?;
        sys.clear();
        for v in 0..nvar {
            // Symmetric: column-major storage is the row-major block.
            sys.add(v, self.hcc[v].as_slice(), false);
            for k in 0..6 {
                sys.rhs[v * 6 + k] = -self.bc[v][k];
            }
        }
        sys.damp(lambda, 1e-12);
        #[cfg(target_arch = "x86_64")]
        let avx = crate::simd::avx();
        for j in 0..np {
            let obs = &self.point_obs[self.point_start[j]..self.point_start[j + 1]];
            let hinv = &self.hll_inv[j];
            let bl = &self.bl[j];
            let mut slot_i = self.pair_start[j];
            for &oa in obs {
                let va = self.var_of_pose[p.observations[oa as usize].pose as usize];
                let wa = self.hcl[oa as usize] * hinv; // 6x3
                if let Some(a) = va {
                    // rhs_a += W_a bl  (from -bc + Hcl Hll^-1 bl)
                    let t = wa * bl;
                    for d in 0..6 {
                        sys.rhs[a * 6 + d] += t[d];
                    }
                }
                for &ob in obs {
                    let slot = self.pair_slots[slot_i];
                    slot_i += 1;
                    if slot == u32::MAX {
                        continue;
                    }
                    let hb = &self.hcl[ob as usize];
                    let Ok(dst) = <&mut [f64; 36]>::try_from(sys.block_mut(slot as usize)) else {
                        continue;
                    };
                    #[cfg(target_arch = "x86_64")]
                    if avx {
                        // SAFETY: AVX is available (checked above).
                        unsafe { sub_outer_6x3_avx(dst, &wa, hb) };
                        continue;
                    }
                    sub_outer_6x3(dst, &wa, hb);
                }
            }
        }
        if !sys.solve(&mut self.dc) {
            return None;
        }
        // Candidate poses.
        self.cand_poses.clear();
        self.cand_poses.extend_from_slice(&p.poses);
        for (i, v) in self.var_of_pose.iter().enumerate() {
            if let Some(v) = v {
                let d = &self.dc[v * 6..v * 6 + 6];
                self.cand_poses[i] = CameraFromWorld(se3_retract(
                    &p.poses[i].0,
                    &[d[0], d[1], d[2], d[3], d[4], d[5]],
                ));
            }
        }
        // Back-substitute the points: dl = Hll^-1 (-bl - Σ Hcl^T dc).
        self.cand_points.clear();
        self.cand_points.extend_from_slice(&p.points);
        for j in 0..np {
            let mut rhs = -self.bl[j];
            for &o in &self.point_obs[self.point_start[j]..self.point_start[j + 1]] {
                if let Some(v) = self.var_of_pose[p.observations[o as usize].pose as usize] {
                    let d = SMatrix::<f64, 6, 1>::from_column_slice(&self.dc[v * 6..v * 6 + 6]);
                    rhs -= self.hcl[o as usize].transpose() * d;
                }
            }
            self.cand_points[j] += self.hll_inv[j] * rhs;
        }
        Some(())
    }
}
