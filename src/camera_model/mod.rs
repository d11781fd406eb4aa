//! Camera model: pinhole with radial-tangential distortion, its calibration files, and the
//! rectification map that produces undistorted images.

mod calibration;
mod pinhole;
mod rectify;
pub mod yaml;

pub use calibration::{CalibError, Calibration};
pub use pinhole::PinholeRadtan;
pub use rectify::{FrameRectifier, RectifyMap};
