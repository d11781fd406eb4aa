//! Chessboard images rendered through a known camera (intrinsics and distortion), for testing
//! calibration: each pixel is supersampled 4x4, undistorted, and its ray intersected with the
//! board plane. Square (0, 0), between inner corners (0,0) and (1,1), is dark.

use nalgebra::{Translation3, UnitQuaternion};
use rayon::prelude::*;

use super::texture::Rng;
use crate::calibrate::Board;
use crate::camera_model::{CameraModel, Lens};
use crate::geometry::Se3;

const DARK: f64 = 35.0;
const LIGHT: f64 = 215.0;
const BACKGROUND: f64 = 110.0;

/// Renders `board` seen from `pose` (camera from board) into `out` (row-major grey), with
/// Gaussian noise of `noise` grey levels (seeded).
pub fn render_chessboard(
    cam: &(impl CameraModel + Sync),
    pose: &Se3,
    board: &Board,
    noise: f64,
    seed: u64,
    out: &mut [u8],
) {
    let (w, h) = cam.size();
    let (w, h) = (w as usize, h as usize);
    let r = pose.rotation.to_rotation_matrix();
    let n = r.matrix().column(2).into_owned();
    let t = pose.translation.vector;
    let rt = r.transpose();
    let s = board.square;
    let (cols, rows) = (board.size.cols as f64, board.size.rows as f64);
    let shade = |u: f64, v: f64| -> f64 {
        let d = cam.unproject_raw(u, v);
        let denom = n.dot(&d);
        if denom.abs() < 1e-12 {
            return BACKGROUND;
        }
        let lambda = n.dot(&t) / denom;
        if lambda <= 0.0 {
            return BACKGROUND;
        }
        let b = rt * (d * lambda - t);
        let (x, y) = (b.x / s, b.y / s);
        let inside = |lo: f64, hi: f64, v: f64| v >= lo && v < hi;
        if inside(-1.0, cols, x) && inside(-1.0, rows, y) {
            if (x.floor() as i64 + y.floor() as i64).rem_euclid(2) == 0 {
                DARK
            } else {
                LIGHT
            }
        } else if inside(-2.0, cols + 1.0, x) && inside(-2.0, rows + 1.0, y) {
            LIGHT // the white margin round the squares
        } else {
            BACKGROUND
        }
    };
    const SS: usize = 4;
    out[..w * h]
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(y, row)| {
            let mut rng = Rng::new(seed ^ (y as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
            for (x, px) in row.iter_mut().enumerate() {
                let mut acc = 0.0;
                for sy in 0..SS {
                    for sx in 0..SS {
                        let du = (sx as f64 + 0.5) / SS as f64 - 0.5;
                        let dv = (sy as f64 + 0.5) / SS as f64 - 0.5;
                        acc += shade(x as f64 + du, y as f64 + dv);
                    }
                }
                // Box-Muller from the seeded generator.
                let g = (-2.0 * rng.f().max(1e-12).ln()).sqrt()
                    * (std::f64::consts::TAU * rng.f()).cos();
                *px = (acc / (SS * SS) as f64 + noise * g)
                    .round()
                    .clamp(0.0, 255.0) as u8;
            }
        });
}

/// A spread of board poses that fills the image and tilts up to ~40 degrees: what a careful
/// user waves in front of the camera. Deterministic.
pub fn calibration_poses(cam: &Lens, board: &Board, count: usize, seed: u64) -> Vec<Se3> {
    let (width, height) = cam.size();
    let (width, height) = (width as f64, height as f64);
    let mut rng = Rng::new(seed);
    let (bw, bh) = (
        (board.size.cols - 1) as f64 * board.square,
        (board.size.rows - 1) as f64 * board.square,
    );
    // Distance at which the board spans about 60% of the image width.
    let base = cam.focal_x() * bw / (0.6 * width);
    let mut poses = Vec::with_capacity(count);
    while poses.len() < count {
        let k = poses.len();
        let tilt_x = rng.range(-0.6, 0.6);
        let tilt_y = rng.range(-0.6, 0.6);
        let roll = rng.range(-0.4, 0.4);
        let dist = base * rng.range(0.75, 1.3);
        // Board centre aimed at one of nine image regions in turn.
        let (gx, gy) = ((k % 3) as f64 - 1.0, ((k / 3) % 3) as f64 - 1.0);
        let (u, v) = (
            width * (0.5 + 0.25 * gx) + rng.range(-20.0, 20.0),
            height * (0.5 + 0.25 * gy) + rng.range(-20.0, 20.0),
        );
        // The image point aimed at is taken in the lens's own model without distortion (the
        // pinhole's K alone), so the spread does not depend on the distortion.
        let ray = match cam {
            Lens::Pinhole(c) => c.unproject(u, v),
            Lens::KannalaBrandt(k) => k.unproject(u, v),
        };
        let centre_c = ray / ray.z * dist;
        let rot = UnitQuaternion::from_euler_angles(tilt_x, tilt_y, roll);
        let centre_b = nalgebra::Vector3::new(bw / 2.0, bh / 2.0, 0.0);
        let t = centre_c - rot * centre_b;
        let pose = Se3::from_parts(Translation3::from(t), rot);
        // Keep poses whose every corner (with one square of margin) is inside the image.
        let inside = [
            (-1.0, -1.0),
            (board.size.cols as f64, -1.0),
            (-1.0, board.size.rows as f64),
            (board.size.cols as f64, board.size.rows as f64),
        ]
        .iter()
        .all(|(i, j)| {
            let p = pose * nalgebra::Point3::new(i * board.square, j * board.square, 0.0);
            if p.z <= 0.0 {
                return false;
            }
            cam.project_raw(&p.coords)
                .is_some_and(|q| q.x > 8.0 && q.y > 8.0 && q.x < width - 8.0 && q.y < height - 8.0)
        });
        if inside {
            poses.push(pose);
        }
    }
    poses
}
