//! Runtime: stage timing, the run report, and (with the SLAM core) threads and deadlines.

pub mod faults;
mod priority;
mod report;
mod semidense_worker;
mod system;
mod timing;

pub use priority::{
    lower_current_thread_priority, pin_current_thread, set_current_thread_idle, ForegroundBusy,
    ForegroundGate,
};
pub use report::{Report, TimingReport};
pub use system::{FrameResult, ReservedMemory, System, SystemStats};
pub use timing::{Percentiles, StageTimer};
