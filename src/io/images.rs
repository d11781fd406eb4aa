//! PNG writers for rendered frames and depth maps.

use std::path::Path;

use crate::error::{Error, Result};

fn encode_err(path: &Path, e: image::ImageError) -> Error {
    Error::format(path, e)
}

/// Writes an RGB image as PNG (atomically).
pub fn write_rgb_png(path: &Path, width: u32, height: u32, rgb: &[u8]) -> Result<()> {
    let mut buf = Vec::new();
    image::codecs::png::PngEncoder::new(&mut buf)
        .write_image(rgb, width, height, image::ExtendedColorType::Rgb8)
        .map_err(|e| encode_err(path, e))?;
    super::write_atomic(path, &buf)
}

/// Writes a grey image as 8-bit PNG (atomically).
pub fn write_gray_png(path: &Path, width: u32, height: u32, gray: &[u8]) -> Result<()> {
    let mut buf = Vec::new();
    image::codecs::png::PngEncoder::new(&mut buf)
        .write_image(gray, width, height, image::ExtendedColorType::L8)
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
    // The encoder takes 16-bit samples in native byte order (it writes PNG's big endian).
    let mut ne = Vec::with_capacity(depth.len() * 2);
    for &d in depth {
        let v = if d.is_finite() && d > 0.0 {
            (d * factor).round().clamp(0.0, 65535.0) as u16
        } else {
            0
        };
        ne.extend_from_slice(&v.to_ne_bytes());
    }
    let mut buf = Vec::new();
    image::codecs::png::PngEncoder::new(&mut buf)
        .write_image(&ne, width, height, image::ExtendedColorType::L16)
        .map_err(|e| encode_err(path, e))?;
    super::write_atomic(path, &buf)
}

use image::ImageEncoder;

/// Reads a 16-bit depth PNG into metres (value / `factor`; 0 stays 0 = no depth).
pub fn read_depth_png(path: &Path, factor: f32) -> Result<(u32, u32, Vec<f32>)> {
    let bytes = sdslam_camera::capped::read_capped(path, sdslam_camera::capped::BULK_CAP)
        .map_err(|e| Error::io(path, e))?;
    let img = image::load_from_memory(&bytes).map_err(|e| Error::format(path, e))?;
    let (w, h) = (img.width(), img.height());
    let px = img.into_luma16();
    Ok((w, h, px.pixels().map(|p| p.0[0] as f32 / factor).collect()))
}

/// Loads a TUM folder's ground-truth depth maps (`depth.txt`, metres x `factor`) with the
/// ground-truth pose nearest in time to each (within 20 ms; maps without a pose are left
/// out). Sorted by time. Errors name the file (and line for the list).
pub fn load_tum_depth_frames(
    dir: &Path,
    groundtruth: &[crate::eval::TimedPose],
    width: u32,
    height: u32,
    factor: f32,
    wanted: Option<&[f64]>,
) -> Result<Vec<crate::eval::DepthFrame>> {
    let list = dir.join("depth.txt");
    let text = sdslam_camera::capped::read_text_capped(&list, sdslam_camera::capped::LIST_CAP)
        .map_err(|e| Error::io(&list, e))?;
    let mut entries = sdslam_camera::list::parse_tum(&text, &list)?;
    entries.sort_by(|a, b| a.timestamp.total_cmp(&b.timestamp));
    // Only the depth map nearest in time to some wanted timestamp (the evaluation uses no
    // other), so a long sequence's depth maps are not all held in memory.
    let mut keep = vec![wanted.is_none(); entries.len()];
    for &t in wanted.unwrap_or(&[]) {
        let i = entries.partition_point(|e| e.timestamp < t);
        let near = [i.checked_sub(1), (i < entries.len()).then_some(i)]
            .into_iter()
            .flatten()
            .min_by(|&a, &b| {
                (entries[a].timestamp - t)
                    .abs()
                    .total_cmp(&(entries[b].timestamp - t).abs())
            });
        if let Some(j) = near {
            keep[j] = true;
        }
    }
    let mut frames = Vec::with_capacity(keep.iter().filter(|&&k| k).count());
    for (e, _) in entries.into_iter().zip(keep).filter(|(_, k)| *k) {
        let i = groundtruth.partition_point(|g| g.timestamp < e.timestamp);
        let near = [i.checked_sub(1), Some(i)]
            .into_iter()
            .flatten()
            .filter_map(|j| groundtruth.get(j))
            .min_by(|a, b| {
                (a.timestamp - e.timestamp)
                    .abs()
                    .total_cmp(&(b.timestamp - e.timestamp).abs())
            });
        let Some(g) = near.filter(|g| (g.timestamp - e.timestamp).abs() <= 0.02) else {
            continue;
        };
        let path = dir.join(&e.file);
        let (w, h, depth) = read_depth_png(&path, factor)?;
        if (w, h) != (width, height) {
            return Err(Error::Invalid(format!(
                "{}: depth map is {w}x{h}, the calibration says {width}x{height}",
                path.display()
            )));
        }
        frames.push(crate::eval::DepthFrame {
            timestamp: e.timestamp,
            t_wc: g.t_wc,
            depth,
        });
    }
    frames.sort_by(|a, b| a.timestamp.total_cmp(&b.timestamp));
    Ok(frames)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_png_round_trips_in_metres() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("d.png");
        let depth = [0.0f32, 1.0, 2.5, 0.0002, 13.1];
        write_depth_png(&p, 5, 1, &depth, 5000.0).unwrap();
        let (w, h, back) = read_depth_png(&p, 5000.0).unwrap();
        assert_eq!((w, h), (5, 1));
        for (a, b) in depth.iter().zip(&back) {
            assert!((a - b).abs() <= 0.5 / 5000.0, "{a} read back as {b}");
        }
    }
}
