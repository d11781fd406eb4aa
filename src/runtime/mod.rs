//! Runtime: stage timing, the run report, and (with the SLAM core) threads and deadlines.

mod report;
mod timing;

pub use report::{Report, TimingReport};
pub use timing::{Percentiles, StageTimer};
