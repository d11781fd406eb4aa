//! The built-in synthetic sequence: a deterministic ray-cast rendering of a textured room
//! along a smooth orbit that returns to its start, with exact poses and depth. It is the
//! default input of `sdslam run` and the data of self-contained tests.

pub mod chessboard;

mod path;
mod render;
mod scene;
mod texture;

pub use path::OrbitPath;
pub use render::Renderer;
pub use scene::Scene;

use sdslam_camera::{Frame, FrameSource, FrameStatus, SourceError, SourceInfo};

use crate::camera_model::{Calibration, PinholeRadtan};
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

    pub fn calibration(&self) -> Calibration {
        Calibration {
            camera: self.camera(),
            fps: self.fps,
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
    path: OrbitPath,
    info: SourceInfo,
    next: usize,
}

impl SyntheticSequence {
    pub fn new(config: SyntheticConfig) -> Self {
        let scene = Scene::desk(config.seed);
        let renderer = Renderer::new(scene, config.camera(), config.noise_sigma, config.seed);
        let path = OrbitPath::desk(config.frames);
        let info = SourceInfo {
            name: "synthetic".into(),
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
                t_wc: self.path.pose(i),
            })
            .collect()
    }

    /// Renders frame `i` into `out` (colour and grey).
    pub fn render_frame(&self, i: usize, out: &mut Frame) {
        out.ensure_size(self.config.width, self.config.height);
        self.renderer
            .render(&self.path.pose(i), i as u64, &mut out.rgb, None);
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
        self.renderer
            .render(&self.path.pose(i), i as u64, &mut out.rgb, Some(depth));
        sdslam_camera::frame::gray_from_rgb(out);
        out.has_color = true;
        out.timestamp = self.config.timestamp(i);
        out.index = i as u64;
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
