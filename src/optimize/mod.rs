//! Optimisation: motion-only BA (tracking), bundle adjustment with a Schur complement on the
//! points (local and global BA), and Sim3 pose-graph optimisation (loop correction).
//!
//! Perturbation convention (stated once for the whole module): **left** perturbation,
//! `T <- Exp(δ) T`, with `δ = [ω, v]` for SE3 and `[ω, v, σ]` for Sim3, where
//! `Exp(δ)` rotates by `exp(ω)`, scales by `e^σ` and then translates by `v`. With `p_c = T p_w`,
//! `∂p_c/∂ω = -[p_c]x`, `∂p_c/∂v = I`.

pub mod ba;
pub mod lie;
pub mod motion_only;
pub mod pose_graph;
pub mod robust;
pub mod sim3_window;
pub mod skyline;
pub mod two_view_ba;

pub use ba::{BaObservation, BaOptions, BaProblem, BaReport, BundleAdjuster};
pub use motion_only::{MotionOnlyBa, MotionOnlyConfig};
pub use pose_graph::{PoseGraph, PoseGraphEdge, PoseGraphReport};
pub use sim3_window::{optimize_window_sim3, window_sim3_covariance, WindowObservation};
pub use two_view_ba::refine_two_view;
