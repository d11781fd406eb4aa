//! PNG writers for rendered frames and depth maps.

use std::path::Path;

use crate::error::{Error, Result};

fn encode_err(path: &Path, e: image::ImageError) -> Error {
    Error::Invalid(format!("{}: cannot encode PNG: {e}", path.display()))
}

/// Writes an RGB image as PNG (atomically).
pub fn write_rgb_png(path: &Path, width: u32, height: u32, rgb: &[u8]) -> Result<()> {
    let mut buf = Vec::new();
    image::codecs::png::PngEncoder::new(&mut buf)
        .write_image(rgb, width, height, image::ExtendedColorType::Rgb8)
        .map_err(|e| encode_err(path, e))?;
    super::write_atomic(path, &buf)
}

/// Writes a depth map (metres, 0 = none) as 16-bit PNG in metres x `factor` (TUM: 5000).
pub fn write_depth_png(
    path: &Path,
    width: u32,
    height: u32,
    depth: &[f32],
    factor: f32,
) -> Result<()> {
    let mut be = Vec::with_capacity(depth.len() * 2);
    for &d in depth {
        let v = if d.is_finite() && d > 0.0 {
            (d * factor).round().clamp(0.0, 65535.0) as u16
        } else {
            0
        };
        be.extend_from_slice(&v.to_be_bytes());
    }
    let mut buf = Vec::new();
    image::codecs::png::PngEncoder::new(&mut buf)
        .write_image(&be, width, height, image::ExtendedColorType::L16)
        .map_err(|e| encode_err(path, e))?;
    super::write_atomic(path, &buf)
}

use image::ImageEncoder;
