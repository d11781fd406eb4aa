//! Image buffers, the ORB scale pyramid and filters. Buffers are allocated once and reused.

mod blur;
pub mod colour;
mod padded;
mod pyramid;
pub mod warp;

pub use blur::gaussian_blur_7x7;
pub use padded::PaddedImage;
pub use pyramid::{Pyramid, PyramidConfig};
