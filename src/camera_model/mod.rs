//! Camera models: pinhole with radial-tangential distortion and Kannala-Brandt fisheye, their
//! calibration files, and the rectification map that resamples raw frames into the
//! undistorted pinhole view every stage works in.

mod calibration;
mod kannala_brandt;
mod lens;
mod pinhole;
mod rectify;
pub mod yaml;

pub use calibration::{CalibError, Calibration, FISHEYE_VIEW_FOV_DEG};
pub use kannala_brandt::KannalaBrandt;
pub use lens::{CameraModel, Lens};
pub use pinhole::PinholeRadtan;
pub use rectify::{FrameRectifier, RectifyMap};
