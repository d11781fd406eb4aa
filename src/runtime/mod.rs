//! Runtime: stage timing, the run report, and (with the SLAM core) threads and deadlines.

pub mod faults;
mod report;
mod semidense_worker;
mod system;

pub use crate::threads::{
    lower_current_thread_priority, pin_current_thread, set_current_thread_idle, ForegroundBusy,
    ForegroundGate,
};
pub use crate::timing::{Percentiles, StageTimer};
pub use report::{MapRecord, Report, SemiDenseFinalReport, TimingReport};
pub use system::{AtlasSummary, FrameResult, ReservedMemory, System, SystemStats};
