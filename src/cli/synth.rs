//! `sdslam synth`: writes the built-in sequence as a TUM RGB-D folder, so it can be replayed
//! through the file-backed mock exactly like recorded data.

use std::fmt::Write as _;
use std::path::PathBuf;

use clap::Args;

use sdslam::camera::Frame;
use sdslam::io::{write_atomic, write_depth_png, write_rgb_png, write_tum_trajectory};
use sdslam::synthetic::{Scenario, SyntheticConfig, SyntheticSequence};
use sdslam::{Error, Result};

#[derive(Args, Debug)]
pub struct SynthArgs {
    /// Output folder (created).
    #[arg(long)]
    out: PathBuf,
    /// Number of frames (the orbit always closes after the last frame).
    #[arg(long, default_value_t = 300)]
    frames: usize,
    /// Scene and motion: desk (the default orbit), rotation, outward-loop (weakly textured
    /// walls), forward, fast-blur, exposure-step, blackout, repetitive (patterned surfaces),
    /// moving-objects, low-light (a dim room: a quarter of the light, noisier), auto-exposure
    /// (the image gain hunting +-25% and jittering from frame to frame).
    /// `sdslam run synthetic:NAME` runs the same scene without writing it.
    #[arg(long, default_value = "desk", value_parser = parse_scene)]
    scene: Scenario,
    /// Lens: `pinhole` (520 px focal, 63 degrees across) or `fisheye` (Kannala-Brandt, 170
    /// degrees across, more than 180 across the diagonal; camera.yaml is ORB-SLAM3's
    /// KannalaBrandt8). Depth maps are in the frames' own (fisheye) geometry.
    #[arg(long, default_value = "pinhole", value_parser = ["pinhole", "fisheye"])]
    camera: String,
    /// Write a ground-truth depth map every K frames (0: none).
    #[arg(long, default_value_t = 10)]
    depth_every: usize,
    /// Instead of the sequence: 15 views of a 9x6 chessboard (25 mm squares) through a
    /// distorted 640x480 camera (or the fisheye with `--camera fisheye`), with that camera in
    /// `truth.yaml`, to try `sdslam calibrate`.
    #[arg(long)]
    chessboard: bool,
}

/// Renders the chessboard calibration set through the distorted webcam, or the fisheye.
fn synth_chessboard(out: &std::path::Path, fisheye: bool) -> Result<()> {
    use sdslam::calibrate::{Board, BoardSize};
    use sdslam::camera_model::{Calibration, CameraModel, Lens, PinholeRadtan};
    use sdslam::synthetic::chessboard::{calibration_poses, render_chessboard};
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let truth = if fisheye {
        let cfg = SyntheticConfig {
            fisheye: true,
            ..SyntheticConfig::default()
        };
        Lens::KannalaBrandt(cfg.fisheye_lens())
    } else {
        Lens::Pinhole(PinholeRadtan {
            k1: -0.28,
            k2: 0.09,
            p1: 0.0012,
            p2: -0.0008,
            ..PinholeRadtan::pinhole(520.0, 517.0, 318.0, 244.0, 640, 480)
        })
    };
    let board = Board {
        size: BoardSize { cols: 9, rows: 6 },
        square: 0.025,
    };
    let (w, h) = truth.size();
    let mut img = vec![0u8; (w * h) as usize];
    for (k, pose) in calibration_poses(&truth, &board, 15, 11).iter().enumerate() {
        render_chessboard(&truth, pose, &board, 2.0, 100 + k as u64, &mut img);
        sdslam::io::write_gray_png(&out.join(format!("board_{k:02}.png")), w, h, &img)?;
    }
    let calib = match truth {
        Lens::Pinhole(c) => Calibration::pinhole(c, 30.0),
        Lens::KannalaBrandt(k) => Calibration::fisheye(k, 30.0),
    };
    let yaml = calib.to_orbslam_yaml("The camera the chessboard views were rendered with.");
    write_atomic(&out.join("truth.yaml"), yaml.as_bytes())
}

pub fn synth(a: SynthArgs) -> Result<()> {
    if a.chessboard {
        return synth_chessboard(&a.out, a.camera == "fisheye");
    }
    if a.frames < 2 {
        return Err(Error::Invalid("--frames must be at least 2".into()));
    }
    let cfg = SyntheticConfig {
        frames: a.frames,
        scenario: a.scene,
        fisheye: a.camera == "fisheye",
        ..SyntheticConfig::default()
    };
    let seq = SyntheticSequence::new(cfg.clone());
    for sub in ["rgb", "depth"] {
        std::fs::create_dir_all(a.out.join(sub)).map_err(|e| Error::io(a.out.join(sub), e))?;
    }
    let mut frame = Frame::new(cfg.width, cfg.height);
    let mut depth = vec![0f32; frame.len()];
    let mut rgb_txt =
        String::from("# color images\n# file: 'sdslam synthetic'\n# timestamp filename\n");
    let mut depth_txt = String::from("# depth maps (planar depth, metres * 5000)\n# file: 'sdslam synthetic'\n# timestamp filename\n");
    for i in 0..cfg.frames {
        let with_depth = a.depth_every > 0 && i % a.depth_every == 0;
        if with_depth {
            seq.render_with_depth(i, &mut frame, &mut depth);
        } else {
            seq.render_frame(i, &mut frame);
        }
        let name = format!("{:.6}.png", frame.timestamp);
        write_rgb_png(
            &a.out.join("rgb").join(&name),
            cfg.width,
            cfg.height,
            &frame.rgb,
        )?;
        let _ = writeln!(rgb_txt, "{:.6} rgb/{name}", frame.timestamp);
        if with_depth {
            write_depth_png(
                &a.out.join("depth").join(&name),
                cfg.width,
                cfg.height,
                &depth,
                5000.0,
            )?;
            let _ = writeln!(depth_txt, "{:.6} depth/{name}", frame.timestamp);
        }
    }
    write_atomic(&a.out.join("rgb.txt"), rgb_txt.as_bytes())?;
    write_atomic(&a.out.join("depth.txt"), depth_txt.as_bytes())?;
    write_tum_trajectory(&a.out.join("groundtruth.txt"), &seq.ground_truth())?;
    let calib = cfg.calibration().to_orbslam_yaml(if cfg.fisheye {
        "sdslam built-in synthetic fisheye (Kannala-Brandt, 170 degrees across)"
    } else {
        "sdslam built-in synthetic camera (no distortion)"
    });
    write_atomic(&a.out.join("camera.yaml"), calib.as_bytes())?;
    out!("wrote {} frames to {}", cfg.frames, a.out.display());
    Ok(())
}

fn parse_scene(s: &str) -> std::result::Result<Scenario, String> {
    Scenario::from_name(s)
}
