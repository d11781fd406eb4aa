//! Resolution of a SOURCE argument into a frame source, its calibration and ground truth.

use std::path::Path;

use sdslam::camera::{files::euroc_cam_dir, FrameSource, ImageListSource};
use sdslam::camera_model::Calibration;
use sdslam::eval::TimedPose;
use sdslam::io::{load_calibration, read_tum_trajectory};
use sdslam::synthetic::{SyntheticConfig, SyntheticSequence};
use sdslam::{Error, Result};

/// An opened source with what the run needs to know about it.
pub struct OpenedSource {
    pub source: Box<dyn FrameSource>,
    pub calibration: Calibration,
    /// Where the calibration came from (for messages and the report).
    pub calibration_name: String,
    /// Ground truth (`T_wc` per frame) when the source has it: the synthetic sequence, or a
    /// TUM folder's `groundtruth.txt`.
    pub groundtruth: Option<Vec<TimedPose>>,
    /// Where ground-truth depth comes from, to evaluate the semi-dense cloud.
    pub depth_truth: DepthTruth,
}

/// Ground-truth depth of a source.
pub enum DepthTruth {
    None,
    /// A TUM folder with `depth.txt` (metres x 5000).
    TumFolder(std::path::PathBuf),
    /// The built-in sequence: rendered exactly at the requested times.
    Synthetic(SyntheticConfig),
}

impl DepthTruth {
    /// Depth maps with their ground-truth poses, for keyframes at `timestamps`.
    pub fn load(
        &self,
        timestamps: &[f64],
        groundtruth: &[TimedPose],
        width: u32,
        height: u32,
    ) -> Result<Vec<sdslam::eval::DepthFrame>> {
        match self {
            DepthTruth::None => Ok(Vec::new()),
            DepthTruth::TumFolder(dir) => {
                sdslam::io::load_tum_depth_frames(dir, groundtruth, width, height, 5000.0)
            }
            DepthTruth::Synthetic(cfg) => {
                let seq = SyntheticSequence::new(cfg.clone());
                let gt = seq.ground_truth();
                let mut frame = sdslam::camera::Frame::new(cfg.width, cfg.height);
                let mut out = Vec::with_capacity(timestamps.len());
                for &t in timestamps {
                    let i = ((t - cfg.t0) * cfg.fps).round();
                    if !(i >= 0.0 && (i as usize) < cfg.frames) {
                        continue;
                    }
                    let i = i as usize;
                    let mut depth = vec![0.0f32; (cfg.width * cfg.height) as usize];
                    seq.render_with_depth(i, &mut frame, &mut depth);
                    out.push(sdslam::eval::DepthFrame {
                        timestamp: gt[i].timestamp,
                        t_wc: gt[i].t_wc,
                        depth,
                    });
                }
                out.sort_by(|a, b| a.timestamp.total_cmp(&b.timestamp));
                Ok(out)
            }
        }
    }
}

/// Opens SOURCE: `synthetic` (or none), `v4l2:/dev/videoN`, a TUM folder, a EuRoC folder, or an
/// image folder with a timestamps file. A TUM folder's `camera.yaml` and EuRoC's
/// `sensor.yaml` are used when `calib` is not given.
pub fn open(
    spec: Option<&str>,
    calib: Option<&Path>,
    frames: Option<usize>,
) -> Result<OpenedSource> {
    match spec {
        None | Some("synthetic") => {
            let mut cfg = SyntheticConfig::default();
            if let Some(n) = frames {
                cfg.frames = n.min(cfg.frames);
            }
            let calibration = match calib {
                Some(p) => load_calibration(p)?,
                None => cfg.calibration(),
            };
            let seq = SyntheticSequence::new(cfg.clone());
            let gt = seq.ground_truth();
            Ok(OpenedSource {
                source: Box::new(seq),
                calibration,
                calibration_name: calib.map(|p| p.display().to_string()).unwrap_or_else(|| "built-in synthetic camera".into()),
                groundtruth: Some(gt),
                depth_truth: DepthTruth::Synthetic(cfg),
            })
        }
        Some(s) if s.starts_with("v4l2:") || s.starts_with("libcamera:") => Err(Error::Invalid(format!(
            "{s}: live camera sources are not available in this build yet; replay a recording (TUM/EuRoC folder) instead"
        ))),
        Some(s) => {
            let dir = Path::new(s);
            let mut src = ImageListSource::open(dir)?;
            if let Some(n) = frames {
                src.limit(0, Some(n));
            }
            let default_calib = if dir.join("rgb.txt").is_file() {
                Some(dir.join("camera.yaml"))
            } else {
                euroc_cam_dir(dir).map(|c| c.join("sensor.yaml"))
            };
            let calib_path = match (calib, default_calib) {
                (Some(p), _) => p.to_path_buf(),
                (None, Some(p)) if p.is_file() => p,
                _ => {
                    return Err(Error::Invalid(format!(
                        "{s}: no calibration: pass --calib FILE (the folder has no camera.yaml or sensor.yaml)"
                    )))
                }
            };
            let calibration = load_calibration(&calib_path)?;
            let name = calib_path.display().to_string();
            let info = src.info();
            calibration.check_image_size(info.width, info.height, &name)?;
            let gt = dir.join("groundtruth.txt");
            let gt = if gt.is_file() { Some(read_tum_trajectory(&gt)?) } else { None };
            Ok(OpenedSource {
                source: Box::new(src),
                calibration,
                calibration_name: name,
                groundtruth: gt,
                depth_truth: if dir.join("depth.txt").is_file() {
                    DepthTruth::TumFolder(dir.to_path_buf())
                } else {
                    DepthTruth::None
                },
            })
        }
    }
}
