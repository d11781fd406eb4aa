//! The built-in synthetic sequence: a deterministic ray-cast rendering of a textured room
//! along a smooth orbit that returns to its start, with exact poses and depth. It is the
//! default input of `sdslam run` and the data of self-contained tests.

pub mod chessboard;

mod path;
mod render;
mod scenario;
mod scene;
mod texture;

pub use path::OrbitPath;
pub use render::Renderer;
pub use scenario::{CameraPath, Scenario};
pub use scene::Scene;

use sdslam_camera::{Frame, FrameSource, FrameStatus, SourceError, SourceInfo};

use crate::camera_model::{Calibration, KannalaBrandt, Lens, PinholeRadtan};
use crate::eval::TimedPose;
use crate::geometry::WorldFromCamera;

/// Parameters of the built-in sequence.
#[derive(Clone, Debug, PartialEq)]
pub struct SyntheticConfig {
    pub frames: usize,
    pub width: u32,
    pub height: u32,
    pub fps: f64,
    /// Scene and noise seed.
    pub seed: u64,
    /// Standard deviation of the additive image noise, grey levels.
    pub noise_sigma: f64,
    /// First timestamp, seconds.
    pub t0: f64,
    /// Scene and motion (the default orbit, or a stress scene).
    pub scenario: Scenario,
    /// Render through a 170-degree fisheye lens instead of the pinhole camera.
    pub fisheye: bool,
}

impl Default for SyntheticConfig {
    fn default() -> Self {
        SyntheticConfig {
            frames: 300,
            width: 640,
            height: 480,
            fps: 30.0,
            seed: 2015,
            noise_sigma: 1.5,
            t0: 1_700_000_000.0,
            scenario: Scenario::Desk,
            fisheye: false,
        }
    }
}

impl SyntheticConfig {
    /// The pinhole camera of the sequence (no distortion).
    pub fn camera(&self) -> PinholeRadtan {
        let f = 520.0 * self.width as f64 / 640.0;
        PinholeRadtan::pinhole(
            f,
            f,
            (self.width as f64 - 1.0) / 2.0,
            (self.height as f64 - 1.0) / 2.0,
            self.width,
            self.height,
        )
    }

    /// The fisheye lens of `fisheye` sequences: Kannala-Brandt with a 170 degree horizontal
    /// field (more than 180 degrees across the diagonal) and mild higher-order terms.
    pub fn fisheye_lens(&self) -> KannalaBrandt {
        let (w, h) = (self.width as f64, self.height as f64);
        let mut k = KannalaBrandt {
            fx: 1.0,
            fy: 1.0,
            cx: (w - 1.0) / 2.0,
            cy: (h - 1.0) / 2.0,
            k1: -0.012,
            k2: 0.004,
            k3: -0.001,
            k4: 0.0001,
            width: self.width,
            height: self.height,
        };
        let f = (w / 2.0) / k.theta_d(85f64.to_radians());
        (k.fx, k.fy) = (f, f);
        k
    }

    /// The lens the frames are rendered through.
    pub fn lens(&self) -> Lens {
        if self.fisheye {
            Lens::KannalaBrandt(self.fisheye_lens())
        } else {
            Lens::Pinhole(self.camera())
        }
    }

    pub fn calibration(&self) -> Calibration {
        if self.fisheye {
            Calibration::fisheye(self.fisheye_lens(), self.fps)
        } else {
            Calibration::pinhole(self.camera(), self.fps)
        }
    }

    pub fn timestamp(&self, i: usize) -> f64 {
        self.t0 + i as f64 / self.fps
    }
}

/// The sequence: scene, path and renderer, usable as a [`FrameSource`].
pub struct SyntheticSequence {
    pub config: SyntheticConfig,
    renderer: Renderer,
    path: CameraPath,
    info: SourceInfo,
    next: usize,
}

impl SyntheticSequence {
    pub fn new(config: SyntheticConfig) -> Self {
        let mut scene = Scene::room(config.seed, config.scenario.surfaces());
        if config.scenario.moving_objects() {
            scene.add_movers(config.seed);
        }
        let renderer = Renderer::new(scene, config.lens(), config.noise_sigma, config.seed);
        let path = CameraPath::new(config.scenario, config.frames);
        let mut name = match config.scenario {
            Scenario::Desk => "synthetic".to_string(),
            s => format!("synthetic:{}", s.name()),
        };
        if config.fisheye {
            name.push_str(" (fisheye)");
        }
        let info = SourceInfo {
            name,
            width: config.width,
            height: config.height,
            fps: config.fps,
            has_color: true,
            len: Some(config.frames),
        };
        SyntheticSequence {
            config,
            renderer,
            path,
            info,
            next: 0,
        }
    }

    /// Exact camera poses (`T_wc`) of every frame.
    pub fn ground_truth(&self) -> Vec<TimedPose> {
        (0..self.config.frames)
            .map(|i| TimedPose {
                timestamp: self.config.timestamp(i),
                t_wc: self.path.pose(i as f64),
            })
            .collect()
    }

    /// Renders frame `i` into `out` (colour and grey).
    pub fn render_frame(&self, i: usize, out: &mut Frame) {
        out.ensure_size(self.config.width, self.config.height);
        self.render_scenario(i, out, None);
        sdslam_camera::frame::gray_from_rgb(out);
        out.has_color = true;
        out.timestamp = self.config.timestamp(i);
        out.index = i as u64;
    }

    /// Renders the scene from any pose `t_wc` (for tests of unusual motion); `seed` varies the
    /// noise. Timestamp and index are left to the caller.
    pub fn render_pose(&self, t_wc: &WorldFromCamera, seed: u64, out: &mut Frame) {
        out.ensure_size(self.config.width, self.config.height);
        self.renderer.render(t_wc, seed, &mut out.rgb, None);
        sdslam_camera::frame::gray_from_rgb(out);
        out.has_color = true;
    }

    /// Renders frame `i` with its planar depth (metres along the optical axis, 0 = none).
    pub fn render_with_depth(&self, i: usize, out: &mut Frame, depth: &mut [f32]) {
        out.ensure_size(self.config.width, self.config.height);
        self.render_scenario(i, out, Some(depth));
        sdslam_camera::frame::gray_from_rgb(out);
        out.has_color = true;
        out.timestamp = self.config.timestamp(i);
        out.index = i as u64;
    }
}

impl SyntheticSequence {
    /// Frame `i` of the scenario into `out.rgb`: blur samples averaged around the frame's
    /// pose (depth from the pose itself), then the scenario's gain.
    fn render_scenario(&self, i: usize, out: &mut Frame, depth: Option<&mut [f32]>) {
        let s = self.config.scenario;
        self.renderer.render_at(
            &self.path.pose(i as f64),
            i as f64,
            i as u64,
            &mut out.rgb,
            depth,
        );
        let n = s.blur_samples();
        if n > 1 {
            // The shutter open over the second half of the frame interval, centred on the pose.
            let mut sum: Vec<f32> = out.rgb.iter().map(|&v| v as f32).collect();
            let mut sample = vec![0u8; out.rgb.len()];
            for k in (0..n).filter(|&k| 2 * k + 1 != n) {
                let dt = 0.5 * (k as f64 / (n - 1) as f64 - 0.5);
                let pose = self.path.pose(i as f64 + dt);
                self.renderer.render_at(
                    &pose,
                    i as f64 + dt,
                    i as u64 * 7 + k as u64,
                    &mut sample,
                    None,
                );
                for (a, &b) in sum.iter_mut().zip(&sample) {
                    *a += b as f32;
                }
            }
            for (o, a) in out.rgb.iter_mut().zip(&sum) {
                *o = (a / n as f32).round() as u8;
            }
        }
        let gain = s.gain(i, self.config.frames);
        if gain != 1.0 {
            for v in out.rgb.iter_mut() {
                *v = (*v as f32 * gain).round().min(255.0) as u8;
            }
        }
        let sigma = s.noise_after_gain();
        if sigma > 0.0 {
            let seed =
                texture::mix64(self.config.seed ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
            for (k, v) in out.rgb.iter_mut().enumerate() {
                let n = render::gaussian(texture::mix64(seed ^ k as u64)) * sigma;
                *v = (*v as f64 + n).round().clamp(0.0, 255.0) as u8;
            }
        }
    }
}

impl FrameSource for SyntheticSequence {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn next_frame(&mut self, out: &mut Frame) -> Result<FrameStatus, SourceError> {
        if self.next >= self.config.frames {
            return Ok(FrameStatus::End);
        }
        self.render_frame(self.next, out);
        out.arrival = Some(std::time::Instant::now());
        self.next += 1;
        Ok(FrameStatus::Ready)
    }
}
