//! Frame sources for sdslam.
//!
//! Everything that reads frames from outside the process lives here: image-list replays
//! (TUM RGB-D, EuRoC, plain folders) that act as the file-backed mock of a camera, pacing
//! (as fast as possible or real time with drop-oldest), and device back ends. Frames are
//! written into caller-owned, preallocated [`Frame`] buffers so the consumer never
//! allocates per frame.

pub mod capped;
pub mod decode;
pub mod device;
pub mod error;
pub mod files;
pub mod frame;
pub mod list;
#[cfg(feature = "mcap")]
pub mod mcap;
pub mod pacing;
pub mod source;

pub use error::SourceError;
pub use files::ImageListSource;
pub use frame::Frame;
pub use pacing::{PacedSource, Pacing, PacingStats};
pub use source::{FrameSource, FrameStatus, SourceInfo};
