//! Evaluation by the project's protocol: trajectory error (ATE after Sim3 alignment) and
//! semi-dense cloud accuracy against ground-truth depth.

mod ate;
mod cloud;
pub mod orb_quality;
mod pose_alignment;
mod rpe;

pub use crate::geometry::umeyama;
pub use ate::{associate, ate, AteResult, TimedPose};
pub use cloud::{cloud_accuracy, CloudAccuracy, CloudAccuracyBuilder, DepthFrame};
pub use pose_alignment::{pose_alignment, AXIS_POINT_M};
pub use rpe::{rpe, RpeResult};
