//! Evaluation: trajectory error (ATE after Sim3 alignment) by the project's protocol.

mod ate;
mod umeyama;

pub use ate::{associate, ate, AteResult, TimedPose};
pub use umeyama::umeyama;
