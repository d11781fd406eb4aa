//! Resolution of a SOURCE argument into a frame source, its calibration and ground truth.

use std::path::Path;

use std::sync::Arc;

use sdslam::camera::device::fake::FakeDevice;
use sdslam::camera::device::{
    self, Exposure, LiveOptions, LiveSource, LiveStats, ModeRequest, PixelFormat,
};
use sdslam::camera::mcap::{is_mcap, CameraInfo, McapSource, StampSource};
use sdslam::camera::{files::euroc_cam_dir, FrameSource, ImageListSource};
use sdslam::camera_model::{Calibration, PinholeRadtan};
use sdslam::eval::TimedPose;
use sdslam::io::{load_calibration, read_tum_trajectory};
use sdslam::synthetic::{Scenario, SyntheticConfig, SyntheticSequence};
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
    /// Set for cameras (and the fake camera): frames come as the device delivers them.
    pub live: Option<Arc<LiveStats>>,
}

/// Camera settings from the command line (for live sources only).
#[derive(clap::Args, Debug, Clone, Default)]
pub struct CameraArgs {
    /// Fixed exposure time in microseconds (recommended for SLAM: auto exposure changes the
    /// brightness between frames). Default: leave the camera's setting.
    #[arg(long, value_name = "MICROSECONDS")]
    pub exposure_us: Option<u32>,
    /// Turn the camera's auto exposure on.
    #[arg(long, conflicts_with = "exposure_us")]
    pub auto_exposure: bool,
    /// Fixed gain in device units (auto gain off).
    #[arg(long)]
    pub gain: Option<i64>,
    /// Pixel format to stream (GREY, YUYV or MJPG); default: the best the camera offers at
    /// the calibration's size and frame rate.
    #[arg(long, value_parser = parse_pixel_format)]
    pub pixel_format: Option<PixelFormat>,
    /// MCAP replays: the image topic (default: the file's only image topic).
    #[arg(long)]
    pub topic: Option<String>,
    /// MCAP replays: timestamps from the image header's stamp (the driver's capture time,
    /// the default) or from the MCAP log time (when the recorder got the message).
    #[arg(long, value_enum, default_value_t = McapTime::Header)]
    pub mcap_time: McapTime,
}

/// Which clock stamps MCAP frames.
#[derive(clap::ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum McapTime {
    #[default]
    Header,
    Log,
}

impl CameraArgs {
    fn options(&self, size: Option<(u32, u32)>, fps: Option<f64>) -> LiveOptions {
        LiveOptions {
            request: ModeRequest {
                size,
                fps,
                format: self.pixel_format,
            },
            exposure: match (self.exposure_us, self.auto_exposure) {
                (Some(micros), _) => Some(Exposure::Manual { micros }),
                (None, true) => Some(Exposure::Auto),
                _ => None,
            },
            gain: self.gain,
            ..LiveOptions::default()
        }
    }
}

fn parse_pixel_format(s: &str) -> std::result::Result<PixelFormat, String> {
    let up = match s.to_ascii_uppercase().as_str() {
        "MJPEG" => "MJPG".to_string(),
        "Y8" | "GRAY" => "GREY".to_string(),
        u => u.to_string(),
    };
    let mut code = [b' '; 4];
    for (c, b) in code.iter_mut().zip(up.bytes()) {
        *c = b;
    }
    match PixelFormat::from_fourcc(code) {
        PixelFormat::Other(_) => Err(format!("`{s}`: expected GREY, YUYV or MJPG")),
        f => Ok(f),
    }
}

fn warn_all(warnings: &[String]) {
    for w in warnings {
        note!("warning: {w}");
    }
}

/// Ground-truth depth of a source.
pub enum DepthTruth {
    None,
    /// A TUM folder with `depth.txt` (metres x 5000).
    TumFolder(std::path::PathBuf),
    /// The built-in sequence: rendered exactly at the requested times (its scene built once,
    /// on the first request: a run asks keyframe by keyframe).
    Synthetic(SyntheticConfig, std::cell::OnceCell<Box<SyntheticSequence>>),
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
            DepthTruth::TumFolder(dir) => sdslam::io::load_tum_depth_frames(
                dir,
                groundtruth,
                width,
                height,
                5000.0,
                Some(timestamps),
            ),
            DepthTruth::Synthetic(cfg, seq) => {
                let seq = seq.get_or_init(|| Box::new(SyntheticSequence::new(cfg.clone())));
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

/// The built-in sequence, or one of its stress scenes (`synthetic:NAME`), through the
/// pinhole camera or a fisheye lens (`synthetic:fisheye`, `synthetic:NAME,fisheye`).
fn open_synthetic(
    scene: Option<&str>,
    calib: Option<&Path>,
    frames: Option<usize>,
) -> Result<OpenedSource> {
    let mut cfg = SyntheticConfig::default();
    for part in scene.into_iter().flat_map(|s| s.split(',')) {
        if part == "fisheye" {
            cfg.fisheye = true;
        } else {
            cfg.scenario = Scenario::from_name(part).map_err(Error::Invalid)?;
        }
    }
    if let Some(n) = frames {
        cfg.frames = n.min(cfg.frames);
    }
    let calibration = match calib {
        Some(p) => {
            let c = load_calibration(p)?;
            c.check_image_size(cfg.width, cfg.height, &p.display().to_string())?;
            c
        }
        None => cfg.calibration(),
    };
    let seq = SyntheticSequence::new(cfg.clone());
    let gt = seq.ground_truth();
    Ok(OpenedSource {
        source: Box::new(seq),
        calibration,
        calibration_name: calib
            .map(|p| p.display().to_string())
            .unwrap_or_else(|| "built-in synthetic camera".into()),
        groundtruth: Some(gt),
        depth_truth: DepthTruth::Synthetic(cfg, Default::default()),
        live: None,
    })
}

/// Opens SOURCE: `synthetic` (or none), `synthetic:NAME` (a stress scene, `sdslam synth
/// --help`), `v4l2:/dev/videoN`, an MCAP file, a TUM folder, a EuRoC folder, or an image
/// folder with a timestamps file. A TUM folder's `camera.yaml` and EuRoC's
/// `sensor.yaml` are used when `calib` is not given.
pub fn open(
    spec: Option<&str>,
    calib: Option<&Path>,
    frames: Option<usize>,
    camera: &CameraArgs,
) -> Result<OpenedSource> {
    match spec {
        Some(s) if s.starts_with("fakecam") => open_fake_camera(s, calib, frames, camera),
        None | Some("synthetic") => open_synthetic(None, calib, frames),
        Some(s) if s.starts_with("synthetic:") => open_synthetic(Some(&s[10..]), calib, frames),
        Some(s) if s.starts_with("v4l2:") || s.starts_with("libcamera:") => {
            let Some(calib_path) = calib else {
                return Err(Error::Invalid(format!(
                    "{s}: a live camera needs its calibration: pass --calib FILE (make one with `sdslam calibrate`)"
                )));
            };
            let calibration = load_calibration(calib_path)?;
            let size = (calibration.camera.width, calibration.camera.height);
            let options = camera.options(Some(size), Some(calibration.fps));
            let cam = device::open_live(s, &options).map_err(sdslam::camera::SourceError::from)?;
            warn_all(&cam.warnings);
            Ok(OpenedSource {
                source: cam.source,
                calibration,
                calibration_name: calib_path.display().to_string(),
                groundtruth: None,
                depth_truth: DepthTruth::None,
                live: Some(cam.stats),
            })
        }
        Some(s) if s.ends_with(".mcap") || is_mcap(Path::new(s)) => {
            open_mcap(Path::new(s), calib, frames, camera)
        }
        Some(s) => {
            let dir = Path::new(s);
            let mut src = ImageListSource::open(dir)?;
            if let Some(n) = frames {
                src.limit(0, Some(n));
            }
            let default_calib =
                if dir.join("rgb.txt").is_file() || dir.join("camera.yaml").is_file() {
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
            let gt = if gt.is_file() {
                Some(read_tum_trajectory(&gt)?)
            } else {
                None
            };
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
                live: None,
            })
        }
    }
}

/// An MCAP file (ROS 2 bag or Foxglove recording); its `CameraInfo` is the calibration when
/// `--calib` is not given.
fn open_mcap(
    path: &Path,
    calib: Option<&Path>,
    frames: Option<usize>,
    camera: &CameraArgs,
) -> Result<OpenedSource> {
    let stamps = match camera.mcap_time {
        McapTime::Header => StampSource::Header,
        McapTime::Log => StampSource::LogTime,
    };
    let mut src = McapSource::open(path, camera.topic.as_deref(), stamps)?;
    src.limit(frames);
    let info = src.info().clone();
    let (mut calibration, name) = match (calib, src.camera_info()) {
        (Some(p), _) => (load_calibration(p)?, p.display().to_string()),
        (None, Some(ci)) => {
            let name = format!("{} (CameraInfo beside {})", path.display(), src.topic());
            (calibration_from_camera_info(ci, &name)?, name)
        }
        (None, None) => {
            return Err(Error::Invalid(format!(
                "{}: topic {} has no CameraInfo beside it: pass --calib FILE",
                path.display(),
                src.topic()
            )))
        }
    };
    calibration.check_image_size(info.width, info.height, &name)?;
    if calib.is_none() {
        calibration.fps = info.fps;
    }
    Ok(OpenedSource {
        source: Box::new(src),
        calibration,
        calibration_name: name,
        groundtruth: None,
        depth_truth: DepthTruth::None,
        live: None,
    })
}

/// A ROS `CameraInfo` as a calibration: `plumb_bob` / `rational_polynomial` (k4..k6 zero) are
/// the pinhole radial-tangential model, `equidistant` the Kannala-Brandt fisheye (`d` = k1..k4);
/// an empty `d` means no distortion.
pub fn calibration_from_camera_info(ci: &CameraInfo, name: &str) -> Result<Calibration> {
    let bad = |m: String| Error::Invalid(format!("{name}: {m}"));
    let d = &ci.d;
    let model = ci.distortion_model.as_str();
    let k = &ci.k;
    if !(k[0] > 0.0 && k[4] > 0.0) || k.iter().any(|v| !v.is_finite()) {
        return Err(bad(format!("K {k:?} has no positive focal lengths")));
    }
    let at = |i: usize| d.get(i).copied().unwrap_or(0.0);
    match model {
        "plumb_bob" | "rational_polynomial" | "" => {}
        "equidistant" | "fisheye" | "kannala_brandt" => {
            if d.len() > 4 || d.iter().any(|v| !v.is_finite()) {
                return Err(bad(format!("equidistant distortion {d:?}: expected k1..k4")));
            }
            let lens = sdslam::camera_model::KannalaBrandt {
                fx: k[0],
                fy: k[4],
                cx: k[2],
                cy: k[5],
                k1: at(0),
                k2: at(1),
                k3: at(2),
                k4: at(3),
                width: ci.width,
                height: ci.height,
            };
            return Ok(Calibration::fisheye(lens, 30.0));
        }
        other => return Err(bad(format!("distortion model `{other}` is not supported (plumb_bob, rational_polynomial, equidistant)"))),
    }
    if d.iter().skip(5).any(|&v| v != 0.0) {
        return Err(bad(format!(
            "rational_polynomial coefficients k4..k6 {:?} are not zero; sdslam models k1 k2 p1 p2 k3",
            &d[5..]
        )));
    }
    Ok(Calibration::pinhole(
        PinholeRadtan {
            k1: at(0),
            k2: at(1),
            p1: at(2),
            p2: at(3),
            k3: at(4),
            ..PinholeRadtan::pinhole(k[0], k[4], k[2], k[5], ci.width, ci.height)
        },
        30.0,
    ))
}

/// A calibration as a ROS `CameraInfo` (`plumb_bob`, or `equidistant` for a fisheye).
pub fn camera_info_from_calibration(c: &Calibration) -> CameraInfo {
    if let Some(k) = &c.fisheye {
        return CameraInfo {
            width: k.width,
            height: k.height,
            distortion_model: "equidistant".into(),
            d: vec![k.k1, k.k2, k.k3, k.k4],
            k: [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0],
            p: [
                k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0,
            ],
        };
    }
    let m = &c.camera;
    CameraInfo {
        width: m.width,
        height: m.height,
        distortion_model: "plumb_bob".into(),
        d: vec![m.k1, m.k2, m.p1, m.p2, m.k3],
        k: [m.fx, 0.0, m.cx, 0.0, m.fy, m.cy, 0.0, 0.0, 1.0],
        p: [
            m.fx, 0.0, m.cx, 0.0, 0.0, m.fy, m.cy, 0.0, 0.0, 0.0, 1.0, 0.0,
        ],
    }
}

/// `fakecam[:FORMAT][,unplug=N]`: the built-in sequence played through the fake camera device
/// in the given pixel format (GREY, YUYV, MJPG), in real time: the whole live path (mode
/// choice, conversion, kernel-style timestamps, newest-frame-wins) without a device, with
/// ground truth. `unplug=N` makes the device vanish (ENODEV) at frame N.
fn open_fake_camera(
    spec: &str,
    calib: Option<&Path>,
    frames: Option<usize>,
    camera: &CameraArgs,
) -> Result<OpenedSource> {
    let mut camera = camera.clone();
    let bad = |m: String| {
        Error::Invalid(format!(
            "{spec}: {m} (expected fakecam[:FORMAT][,unplug=N])"
        ))
    };
    let mut parts = spec.split(',');
    match parts.next().unwrap_or_default().strip_prefix("fakecam") {
        Some("") => {}
        Some(f) if f.starts_with(':') => {
            camera.pixel_format = Some(parse_pixel_format(&f[1..]).map_err(bad)?)
        }
        _ => return Err(bad("not a fake camera".into())),
    }
    let mut faults = device::fake::Faults::default();
    for p in parts {
        match p.split_once('=') {
            Some(("unplug", n)) => {
                faults.unplug_at = Some(
                    n.parse()
                        .map_err(|_| bad(format!("`{n}` is not a frame number")))?,
                )
            }
            _ => return Err(bad(format!("unknown option `{p}`"))),
        }
    }
    let mut opened = open(None, calib, frames, &CameraArgs::default())?;
    let size = (
        opened.calibration.camera.width,
        opened.calibration.camera.height,
    );
    let t0 = SyntheticConfig::default().t0;
    let mut dev = FakeDevice::new("fakecam", opened.source)
        .with_scene_origin(t0)
        .with_faults(faults);
    dev.real_time = true;
    let options = camera.options(Some(size), Some(opened.calibration.fps));
    let src = LiveSource::start(dev, &options).map_err(sdslam::camera::SourceError::from)?;
    warn_all(&src.warnings);
    // Ground truth onto the device clock, so ATE still matches poses by timestamp.
    if let Some(gt) = opened.groundtruth.as_mut() {
        for p in gt.iter_mut() {
            p.timestamp = src.device().device_time(p.timestamp).unwrap_or(p.timestamp);
        }
    }
    if let DepthTruth::Synthetic(cfg, _) = &mut opened.depth_truth {
        cfg.t0 = src.device().device_time(cfg.t0).unwrap_or(cfg.t0);
    }
    opened.live = Some(src.stats());
    opened.source = Box::new(src);
    Ok(opened)
}
