//! `sdslam calibrate`: intrinsics and radial-tangential (or Kannala-Brandt fisheye) distortion
//! from chessboard views, from a folder of images or a live camera, written as the YAML
//! `sdslam run --calib` reads.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use clap::Args;
use nalgebra::Vector2;

use sdslam::calibrate::{self, Board, BoardSize, CalibrateConfig, DetectorConfig, LensModel};
use sdslam::camera::decode::ImageDecoderBuf;
use sdslam::camera::device::{self, LiveOptions, ModeRequest};
use sdslam::camera::{Frame, FrameStatus};
use sdslam::camera_model::Lens;
use sdslam::io::write_atomic;
use sdslam::{Error, Result};

use super::source::CameraArgs;

#[derive(Args, Debug)]
pub struct CalibrateArgs {
    /// A folder of chessboard images (PNG/JPEG), or a camera (`v4l2:/dev/videoN`, `libcamera:N`).
    pub input: String,
    /// Inner corners of the board, COLSxROWS (a board of 10x7 squares has 9x6).
    #[arg(long, value_parser = parse_board)]
    pub board: BoardSize,
    /// Side of one square in metres (sets the unit of nothing in the intrinsics, but of the
    /// board poses printed).
    #[arg(long)]
    pub square: f64,
    /// Output calibration file (ORB-SLAM YAML), written atomically.
    #[arg(long)]
    pub out: PathBuf,
    /// Also estimate k3 (wide-angle lenses; radial-tangential model).
    #[arg(long)]
    pub k3: bool,
    /// Camera model: `radtan` (pinhole with radial-tangential distortion) or `kannala-brandt`
    /// (fisheye, k1..k4; written as ORB-SLAM3's KannalaBrandt8).
    #[arg(long, default_value = "radtan", value_parser = parse_model)]
    pub model: LensModel,
    /// Camera input: number of distinct views to collect.
    #[arg(long, default_value_t = 20)]
    pub views: usize,
    /// Camera input: give up after this many seconds.
    #[arg(long, default_value_t = 120.0)]
    pub timeout: f64,
    /// Camera input: image size WxH (default: the mode nearest 640x480).
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(u32, u32)>,
    /// Frame rate written into the calibration (default: the camera's, or 30 for images).
    #[arg(long)]
    pub fps: Option<f64>,
    #[command(flatten)]
    pub camera: CameraArgs,
}

fn parse_model(s: &str) -> std::result::Result<LensModel, String> {
    match s {
        "radtan" | "pinhole" | "radial-tangential" => Ok(LensModel::RadialTangential),
        "kannala-brandt" | "fisheye" | "equidistant" => Ok(LensModel::KannalaBrandt),
        _ => Err(format!("`{s}`: expected radtan or kannala-brandt")),
    }
}

fn parse_board(s: &str) -> std::result::Result<BoardSize, String> {
    let (c, r) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("`{s}`: expected COLSxROWS, e.g. 9x6"))?;
    let n = |v: &str| v.trim().parse::<usize>().ok().filter(|n| *n >= 2);
    match (n(c), n(r)) {
        (Some(cols), Some(rows)) => Ok(BoardSize {
            cols: cols.max(rows),
            rows: cols.min(rows),
        }),
        _ => Err(format!(
            "`{s}`: expected COLSxROWS with at least 2 inner corners each, e.g. 9x6"
        )),
    }
}

fn parse_size(s: &str) -> std::result::Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("`{s}`: expected WxH, e.g. 640x480"))?;
    match (w.trim().parse(), h.trim().parse()) {
        (Ok(w), Ok(h)) => Ok((w, h)),
        _ => Err(format!("`{s}`: expected WxH, e.g. 640x480")),
    }
}

pub fn calibrate(a: CalibrateArgs) -> Result<()> {
    if !(a.square.is_finite() && a.square > 0.0) {
        return Err(Error::Invalid(format!(
            "--square {}: must be a positive length in metres",
            a.square
        )));
    }
    let board = Board {
        size: a.board,
        square: a.square,
    };
    let detector = DetectorConfig::default();
    let is_camera = a.input.starts_with("v4l2:") || a.input.starts_with("libcamera:");
    let (names, views, (w, h), cam_fps) = if is_camera {
        from_camera(&a, &board, &detector)?
    } else {
        from_folder(Path::new(&a.input), &board, &detector)?
    };
    let found: Vec<Vec<Vector2<f64>>> = views.iter().flatten().cloned().collect();
    note!(
        "sdslam: board {}x{} found in {} of {} images",
        a.board.cols,
        a.board.rows,
        found.len(),
        views.len()
    );
    let cfg = CalibrateConfig {
        model: a.model,
        estimate_k3: a.k3,
        ..CalibrateConfig::default()
    };
    let r =
        calibrate::calibrate(&found, &board, w, h, &cfg).map_err(|e| Error::format(&a.input, e))?;
    let fps = a.fps.or(cam_fps).unwrap_or(30.0);
    let c = r.camera;
    let s = r.std_dev;
    let mut k = 0;
    for (name, v) in names.iter().zip(&views) {
        match v {
            None => note!("  {name}: board not found"),
            Some(_) => {
                match r.view_rms_px[k] {
                    Some(rms) => note!("  {name}: RMS {rms:.3} px"),
                    None => {
                        note!("  {name}: dropped (reprojection error far above the others)")
                    }
                }
                k += 1;
            }
        }
    }
    let (params, one_sigma) = match &c {
        Lens::Pinhole(c) => (
            format!(
                "fx {:.3} fy {:.3} cx {:.3} cy {:.3} k1 {:.5} k2 {:.5} p1 {:.6} p2 {:.6} k3 {:.5}",
                c.fx, c.fy, c.cx, c.cy, c.k1, c.k2, c.p1, c.p2, c.k3
            ),
            format!(
                "fx {:.2} fy {:.2} cx {:.2} cy {:.2} k1 {:.4} k2 {:.4} p1 {:.5} p2 {:.5}{}",
                s[0],
                s[1],
                s[2],
                s[3],
                s[4],
                s[5],
                s[6],
                s[7],
                if a.k3 { format!(" k3 {:.4}", s[8]) } else { ", k3 fixed at 0".into() }
            ),
        ),
        Lens::KannalaBrandt(k) => (
            format!(
                "Kannala-Brandt fx {:.3} fy {:.3} cx {:.3} cy {:.3} k1 {:.5} k2 {:.5} k3 {:.5} k4 {:.6} ({:.0} degrees across)",
                k.fx, k.fy, k.cx, k.cy, k.k1, k.k2, k.k3, k.k4, k.horizontal_fov_deg()
            ),
            format!(
                "fx {:.2} fy {:.2} cx {:.2} cy {:.2} k1 {:.4} k2 {:.4} k3 {:.4} k4 {:.5}",
                s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7]
            ),
        ),
    };
    let summary = format!(
        "Calibrated by sdslam {} from {} views of a {}x{} board ({} m squares) in {}.\n\
         Reprojection RMS {:.3} px. One-sigma: {one_sigma}.",
        env!("CARGO_PKG_VERSION"),
        r.poses.len(),
        a.board.cols,
        a.board.rows,
        a.square,
        a.input,
        r.rms_px,
    );
    let yaml = r.calibration(fps).to_orbslam_yaml(&summary);
    write_atomic(&a.out, yaml.as_bytes())?;
    out!(
        "{params}\nreprojection RMS {:.3} px over {} views; written to {}",
        r.rms_px,
        r.poses.len(),
        a.out.display()
    );
    Ok(())
}

type Views = (
    Vec<String>,
    Vec<Option<Vec<Vector2<f64>>>>,
    (u32, u32),
    Option<f64>,
);

fn from_folder(dir: &Path, board: &Board, detector: &DetectorConfig) -> Result<Views> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension().and_then(|e| e.to_str()).is_some_and(|e| {
                ["png", "jpg", "jpeg", "pgm"].contains(&e.to_ascii_lowercase().as_str())
            })
        })
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(Error::Invalid(format!(
            "{}: no PNG or JPEG images",
            dir.display()
        )));
    }
    let mut dec = ImageDecoderBuf::new();
    let mut frame = Frame::new(1, 1);
    let mut size: Option<(u32, u32)> = None;
    let (mut names, mut views) = (Vec::new(), Vec::new());
    for f in &files {
        dec.read_file(f, size, &mut frame)?;
        size.get_or_insert((frame.width, frame.height));
        names.push(
            f.file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
        );
        views.push(calibrate::detect(
            &frame.gray,
            frame.width as usize,
            frame.height as usize,
            board.size,
            detector,
        ));
    }
    Ok((names, views, size.unwrap_or((0, 0)), None))
}

fn from_camera(a: &CalibrateArgs, board: &Board, detector: &DetectorConfig) -> Result<Views> {
    let mut opts: LiveOptions = LiveOptions {
        request: ModeRequest {
            size: a.size,
            fps: None,
            format: a.camera.pixel_format,
        },
        ..LiveOptions::default()
    };
    if let Some(us) = a.camera.exposure_us {
        opts.exposure = Some(device::Exposure::Manual { micros: us });
    }
    opts.gain = a.camera.gain;
    let cam = device::open_live(&a.input, &opts).map_err(sdslam::camera::SourceError::from)?;
    for w in &cam.warnings {
        note!("warning: {w}");
    }
    let mut src = cam.source;
    let info = src.info().clone();
    super::signal::install();
    note!(
        "sdslam: {}: show the board at different tilts and positions; collecting {} views (Ctrl-C to finish early)",
        info.name, a.views
    );
    let mut frame = Frame::new(info.width, info.height);
    let (mut names, mut views) = (Vec::new(), Vec::new());
    let mut last: Option<Vec<Vector2<f64>>> = None;
    let started = Instant::now();
    let diag = ((info.width * info.width + info.height * info.height) as f64).sqrt();
    let mut last_kept = Instant::now() - Duration::from_secs(10);
    while views.len() < a.views
        && started.elapsed().as_secs_f64() < a.timeout
        && !super::signal::interrupted()
    {
        match src.next_frame(&mut frame)? {
            FrameStatus::Ready => {}
            FrameStatus::Skipped { .. } => continue,
            FrameStatus::End => break,
        }
        if last_kept.elapsed() < Duration::from_millis(500) {
            continue;
        }
        let Some(c) = calibrate::detect(
            &frame.gray,
            info.width as usize,
            info.height as usize,
            board.size,
            detector,
        ) else {
            continue;
        };
        // A new view only when the board moved: mean corner shift over 10% of the diagonal.
        let moved = last.as_ref().is_none_or(|l| {
            l.iter().zip(&c).map(|(p, q)| (p - q).norm()).sum::<f64>() / c.len() as f64 > 0.1 * diag
        });
        if moved {
            note!("  view {} of {}", views.len() + 1, a.views);
            names.push(format!("frame {:.3}", frame.timestamp));
            last = Some(c.clone());
            views.push(Some(c));
            last_kept = Instant::now();
        }
    }
    Ok((names, views, (info.width, info.height), Some(info.fps)))
}
