//! Evaluation: trajectory error (ATE after Sim3 alignment) by the project's protocol.

mod ate;

pub use crate::geometry::umeyama;
pub use ate::{associate, ate, AteResult, TimedPose};
