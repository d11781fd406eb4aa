//! Pose-graph optimisation over Sim3 (7-DoF) for loop correction (Strasdat et al. 2010, as
//! ORB-SLAM's essential graph): vertices are `S_iw`, an edge (i, j) measures `S_ji` with
//! `S_jw ≈ S_ji S_iw`, residual `e = log(S_ji S_iw S_jw⁻¹)` in `[ω, v, σ]` coordinates.
//! Levenberg-Marquardt with first-order Jacobians `∂e/∂δ_i = Adj(S_ji)`, `∂e/∂δ_j = -Adj(E)`,
//! solved on the 7x7-block sparse system.

use nalgebra::SMatrix;

use super::lie::{sim3_adjoint, sim3_compose, sim3_log_decoupled, sim3_retract};
use super::skyline::BlockSystem;
use crate::geometry::Sim3;

/// A relative constraint between vertices `i` and `j`.
#[derive(Clone, Copy, Debug)]
pub struct PoseGraphEdge {
    pub i: u32,
    pub j: u32,
    /// Measured `S_ji` (maps camera-i coordinates to camera-j coordinates).
    pub s_ji: Sim3,
    /// Scalar information (ORB-SLAM: 1; covisibility weights may raise it).
    pub weight: f64,
}

#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PoseGraphReport {
    pub initial_cost: f64,
    pub final_cost: f64,
    pub iterations: usize,
}

/// The graph: vertices `S_iw`, fixed flags, edges.
#[derive(Default)]
pub struct PoseGraph {
    pub poses: Vec<Sim3>,
    pub fixed: Vec<bool>,
    pub edges: Vec<PoseGraphEdge>,
    system: Option<BlockSystem>,
    cand: Vec<Sim3>,
    dx: Vec<f64>,
}

fn residual(e: &PoseGraphEdge, poses: &[Sim3]) -> (Sim3, [f64; 7]) {
    let (si, sj) = (&poses[e.i as usize], &poses[e.j as usize]);
    let err = sim3_compose(&sim3_compose(&e.s_ji, si), &sj.inverse());
    (err, sim3_log_decoupled(&err))
}

impl PoseGraph {
    /// A graph over `poses` (`S_iw`) with `edges`; vertices flagged in `fixed` do not move.
    pub fn new(poses: Vec<Sim3>, fixed: Vec<bool>, edges: Vec<PoseGraphEdge>) -> Self {
        PoseGraph {
            poses,
            fixed,
            edges,
            ..Default::default()
        }
    }

    pub fn cost_of(&self, poses: &[Sim3]) -> f64 {
        self.edges
            .iter()
            .map(|e| e.weight * residual(e, poses).1.iter().map(|v| v * v).sum::<f64>())
            .sum()
    }

    /// Optimises the free vertices; returns costs before and after.
    pub fn optimize(&mut self, iterations: usize) -> PoseGraphReport {
        let n = self.poses.len();
        self.fixed.resize(n, false);
        let mut var = vec![None; n];
        let mut nvar = 0;
        for (i, v) in var.iter_mut().enumerate() {
            if !self.fixed[i] {
                *v = Some(nvar);
                nvar += 1;
            }
        }
        let mut cost = self.cost_of(&self.poses);
        let mut rep = PoseGraphReport {
            initial_cost: cost,
            final_cost: cost,
            iterations: 0,
        };
        if nvar == 0 {
            return rep;
        }
        let mut sys = self.system.take().unwrap_or_else(|| BlockSystem::new(7));
        let pairs: Vec<(usize, usize)> = self
            .edges
            .iter()
            .filter_map(|e| Some((var[e.i as usize]?, var[e.j as usize]?)))
            .collect();
        sys.set_structure(nvar, pairs);
        // Slots of each edge's blocks, looked up once.
        let slots: Vec<[Option<usize>; 3]> = self
            .edges
            .iter()
            .map(|e| {
                let (vi, vj) = (var[e.i as usize], var[e.j as usize]);
                [
                    vi,
                    vj,
                    match (vi, vj) {
                        (Some(a), Some(b)) if a != b => sys.slot(a, b),
                        _ => None,
                    },
                ]
            })
            .collect();
        self.dx.resize(nvar * 7, 0.0);
        let ne = self.edges.len();
        // Linearisation cache: per edge Hii, Hjj, Hij (row-major 7x7) and gradients.
        let mut hii = vec![[0.0f64; 49]; ne];
        let mut hjj = vec![[0.0f64; 49]; ne];
        let mut hij = vec![[0.0f64; 49]; ne];
        let mut gi = vec![[0.0f64; 7]; ne];
        let mut gj = vec![[0.0f64; 7]; ne];
        let put = |dst: &mut [f64; 49], m: &SMatrix<f64, 7, 7>| {
            for r in 0..7 {
                for c in 0..7 {
                    dst[r * 7 + c] = m[(r, c)];
                }
            }
        };
        let mut lambda = 1e-6;
        for it in 0..iterations {
            rep.iterations = it + 1;
            for (k, e) in self.edges.iter().enumerate() {
                let (err, r) = residual(e, &self.poses);
                let r = SMatrix::<f64, 7, 1>::from_row_slice(&r);
                let ji = sim3_adjoint(&e.s_ji) * e.weight.sqrt();
                let jj = -sim3_adjoint(&err) * e.weight.sqrt();
                let r = r * e.weight.sqrt();
                put(&mut hii[k], &(ji.transpose() * ji));
                put(&mut hjj[k], &(jj.transpose() * jj));
                put(&mut hij[k], &(ji.transpose() * jj));
                let (a, b) = (ji.transpose() * r, jj.transpose() * r);
                gi[k].copy_from_slice(a.as_slice());
                gj[k].copy_from_slice(b.as_slice());
            }
            let mut accepted = false;
            for _ in 0..8 {
                sys.clear();
                for (k, sl) in slots.iter().enumerate() {
                    if let Some(a) = sl[0] {
                        sys.add(a, &hii[k], false);
                        for (d, g) in gi[k].iter().enumerate() {
                            sys.rhs[a * 7 + d] -= g;
                        }
                    }
                    if let Some(b) = sl[1] {
                        sys.add(b, &hjj[k], false);
                        for (d, g) in gj[k].iter().enumerate() {
                            sys.rhs[b * 7 + d] -= g;
                        }
                    }
                    if let (Some(s), Some(a), Some(b)) = (sl[2], sl[0], sl[1]) {
                        // Stored block is (min, max); hij is block (a, b).
                        sys.add(s, &hij[k], a > b);
                    }
                }
                sys.damp(lambda, 1e-12);
                if !sys.solve(&mut self.dx) {
                    lambda *= 10.0;
                    continue;
                }
                self.cand.clear();
                self.cand.extend_from_slice(&self.poses);
                for (i, v) in var.iter().enumerate() {
                    if let Some(v) = v {
                        let d: [f64; 7] = std::array::from_fn(|k| self.dx[v * 7 + k]);
                        self.cand[i] = sim3_retract(&self.poses[i], &d);
                    }
                }
                let c = self.cost_of(&self.cand);
                if c < cost {
                    let rel = (cost - c) / cost.max(1e-300);
                    std::mem::swap(&mut self.poses, &mut self.cand);
                    cost = c;
                    lambda = (lambda / 3.0).max(1e-12);
                    // Converged when the cost stops falling relatively (saves the failing
                    // retries a further iteration would spend).
                    accepted = rel > 1e-6;
                    break;
                }
                // A rejected step that is already tiny: at the optimum.
                let step: f64 = self.dx.iter().map(|v| v * v).sum::<f64>().sqrt();
                if step < 1e-10 {
                    break;
                }
                lambda *= 4.0;
            }
            // Stop when the step stalled, or the residual is at rounding level (a consistent graph).
            if !accepted || cost <= 1e-14 * rep.initial_cost {
                break;
            }
        }
        self.system = Some(sys);
        rep.final_cost = cost;
        rep
    }
}
