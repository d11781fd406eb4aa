//! Ray-cast rendering with bilinear texture sampling, anti-aliasing at geometric edges and
//! mild deterministic noise; rows are rendered in parallel (the result does not depend on the
//! thread count).
//!
//! Textures are sampled bilinearly at about one texel per pixel, so aliasing inside a surface
//! is small; it is at silhouettes and creases (a pixel covering two surfaces) that a single ray
//! would produce jagged edges. Each pixel therefore gets one centre ray, and pixels whose
//! 4-neighbours hit another surface are re-rendered with 4 rotated-grid sub-samples.

use nalgebra::Vector3;
use rayon::prelude::*;

use super::scene::Scene;
use super::texture::mix64;
use crate::camera_model::{CameraModel, Lens};
use crate::geometry::WorldFromCamera;

pub struct Renderer {
    scene: Scene,
    camera: Lens,
    noise_sigma: f64,
    seed: u64,
}

/// Sub-pixel sample offsets (rotated grid).
const SAMPLES: [(f64, f64); 4] = [
    (-0.125, -0.375),
    (0.375, -0.125),
    (0.125, 0.375),
    (-0.375, 0.125),
];

/// No surface (a ray leaving the scene).
const NO_HIT: u32 = u32::MAX;

impl Renderer {
    pub fn new(scene: Scene, camera: Lens, noise_sigma: f64, seed: u64) -> Self {
        Renderer {
            scene,
            camera,
            noise_sigma,
            seed,
        }
    }

    /// Renders the view from `t_wc` into `rgb` (w*h*3); with `depth` (w*h) also the planar
    /// depth of each pixel centre (metres, 0 = no surface). `frame` seeds the noise; moving
    /// objects are where they are at frame 0.
    pub fn render(
        &self,
        t_wc: &WorldFromCamera,
        frame: u64,
        rgb: &mut [u8],
        depth: Option<&mut [f32]>,
    ) {
        self.render_at(t_wc, 0.0, frame, rgb, depth);
    }

    /// [`render`](Self::render) with moving objects where they are at (fractional) frame
    /// `time`.
    pub fn render_at(
        &self,
        t_wc: &WorldFromCamera,
        time: f64,
        frame: u64,
        rgb: &mut [u8],
        depth: Option<&mut [f32]>,
    ) {
        let w = self.camera.size().0 as usize;
        let o = t_wc.position();
        let rot = t_wc.0.rotation.to_rotation_matrix();
        let cam = &self.camera;
        // Unit world ray through (u, v) and the factor turning ray length into planar depth
        // (0 for a fisheye's rays at 90 degrees and more from the axis: no planar depth).
        let ray = |u: f64, v: f64| -> (Vector3<f64>, f64) {
            let d_c = cam.unproject_raw(u, v);
            let n = d_c.norm();
            (rot * (d_c / n), (d_c.z / n).max(0.0))
        };
        // Pass 1: centre rays.
        let mut centre: Vec<([f32; 3], u32, f32)> = vec![([0.0; 3], NO_HIT, 0.0); rgb.len() / 3];
        centre.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (x, c) in row.iter_mut().enumerate() {
                let (d, to_planar) = ray(x as f64, y as f64);
                *c = match self.scene.cast_at(&o, &d, time) {
                    Some(hit) => (hit.rgb, hit.id, (hit.t * to_planar) as f32),
                    None => ([0.0; 3], NO_HIT, 0.0),
                };
            }
        });
        // Pass 2: super-sample edge pixels, add noise, quantise.
        let h = centre.len() / w;
        let noise_seed = mix64(self.seed ^ frame.wrapping_mul(0xD6E8_FEB8_6659_FD93));
        let centre_ref = &centre;
        rgb.par_chunks_mut(w * 3).enumerate().for_each(|(y, row)| {
            for x in 0..w {
                let (col, id, _) = centre_ref[y * w + x];
                let id_at = |xx: usize, yy: usize| centre_ref[yy * w + xx].1;
                let edge = (x > 0 && id_at(x - 1, y) != id)
                    || (x + 1 < w && id_at(x + 1, y) != id)
                    || (y > 0 && id_at(x, y - 1) != id)
                    || (y + 1 < h && id_at(x, y + 1) != id);
                let mut acc = col;
                if edge {
                    acc = [0.0; 3];
                    for (dx, dy) in SAMPLES {
                        let (d, _) = ray(x as f64 + dx, y as f64 + dy);
                        if let Some(hit) = self.scene.cast_at(&o, &d, time) {
                            for (a, c) in acc.iter_mut().zip(hit.rgb) {
                                *a += c / SAMPLES.len() as f32;
                            }
                        }
                    }
                }
                let n = gaussian(mix64(noise_seed ^ (y * w + x) as u64)) * self.noise_sigma;
                for k in 0..3 {
                    row[3 * x + k] = (acc[k] as f64 + n).round().clamp(0.0, 255.0) as u8;
                }
            }
        });
        if let Some(depth) = depth {
            for (d, c) in depth.iter_mut().zip(&centre) {
                *d = c.2;
            }
        }
    }
}

/// Approximately standard normal from a hash (sum of four uniforms, rescaled).
pub(super) fn gaussian(h: u64) -> f64 {
    let u = |s: u32| ((h >> s) & 0xFFFF) as f64 / 65535.0;
    (u(0) + u(16) + u(32) + u(48) - 2.0) * (3.0f64).sqrt()
}
