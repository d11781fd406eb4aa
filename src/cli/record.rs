//! `sdslam record`: a camera's frames saved as a TUM RGB-D folder (`rgb/<t>.png`, `rgb.txt`,
//! and the calibration as `camera.yaml`), which replays through the file-backed mock, so a
//! robot run can be reproduced in tests. Each image is written atomically and `rgb.txt` grows
//! line by line, so an interrupted recording is still a valid sequence.

use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

use clap::Args;

use sdslam::camera::{Frame, FrameSource, FrameStatus, PacedSource, Pacing};
use sdslam::io::{self, write_atomic};
use sdslam::{Error, Result};

use super::source::{self, CameraArgs};

#[derive(Args, Debug)]
pub struct RecordArgs {
    /// The camera: `v4l2:/dev/videoN`, `libcamera:N`, or `fakecam[:FORMAT]` (the built-in
    /// sequence through the fake device).
    pub source: String,
    /// Output folder (created; must be empty or absent).
    #[arg(long)]
    pub out: PathBuf,
    /// Calibration of the camera, copied to OUT/camera.yaml (fixes the image size).
    #[arg(long)]
    pub calib: Option<PathBuf>,
    /// Stop after N frames.
    #[arg(long)]
    pub frames: Option<usize>,
    /// Stop after S seconds.
    #[arg(long)]
    pub seconds: Option<f64>,
    #[command(flatten)]
    pub camera: CameraArgs,
}

pub fn record(a: RecordArgs) -> Result<()> {
    let is_camera = ["v4l2:", "libcamera:", "fakecam"]
        .iter()
        .any(|p| a.source.starts_with(p));
    if !is_camera {
        return Err(Error::Invalid(format!(
            "{}: `record` takes a camera (v4l2:/dev/videoN, libcamera:N, fakecam[:FORMAT])",
            a.source
        )));
    }
    if a.out.exists()
        && std::fs::read_dir(&a.out)
            .map_err(|e| Error::io(&a.out, e))?
            .next()
            .is_some()
    {
        return Err(Error::Invalid(format!(
            "{}: not empty; record into a new folder",
            a.out.display()
        )));
    }
    let rgb_dir = a.out.join("rgb");
    std::fs::create_dir_all(&rgb_dir).map_err(|e| Error::io(&rgb_dir, e))?;
    let opened = source::open(Some(&a.source), a.calib.as_deref(), a.frames, &a.camera)?;
    if let Some(c) = &a.calib {
        let bytes = sdslam_camera::capped::read_capped(c, sdslam_camera::capped::SETTINGS_CAP)
            .map_err(|e| Error::io(c, e))?;
        write_atomic(&a.out.join("camera.yaml"), &bytes)?;
    }
    super::signal::install();
    let info = opened.source.info().clone();
    let mut src = PacedSource::spawn(opened.source, Pacing::Live)?;
    let stats = src.stats();
    let list_path = a.out.join("rgb.txt");
    let mut list = std::fs::File::create(&list_path).map_err(|e| Error::io(&list_path, e))?;
    let header = format!(
        "# color images\n# recorded by sdslam {} from {}\n# timestamp filename\n",
        env!("CARGO_PKG_VERSION"),
        info.name
    );
    list.write_all(header.as_bytes())
        .map_err(|e| Error::io(&list_path, e))?;
    note!(
        "sdslam: recording {} ({}x{} @ {} fps) to {}; Ctrl-C stops",
        info.name,
        info.width,
        info.height,
        info.fps,
        a.out.display()
    );
    let mut frame = Frame::new(info.width, info.height);
    let (started, mut saved, mut skipped) = (Instant::now(), 0usize, 0usize);
    let mut stop_reason = None;
    loop {
        if super::signal::interrupted() {
            stop_reason = Some("interrupted".to_string());
            break;
        }
        if a.frames.is_some_and(|n| saved >= n)
            || a.seconds
                .is_some_and(|s| started.elapsed().as_secs_f64() >= s)
        {
            break;
        }
        match src.next_frame(&mut frame) {
            Ok(FrameStatus::Ready) => {}
            Ok(FrameStatus::Skipped { .. }) => {
                skipped += 1;
                continue;
            }
            Ok(FrameStatus::End) => break,
            Err(e) => {
                stop_reason = Some(e.to_string());
                break;
            }
        }
        let name = format!("rgb/{:.6}.png", frame.timestamp);
        let path = a.out.join(&name);
        if frame.has_color {
            io::write_rgb_png(&path, frame.width, frame.height, &frame.rgb)?;
        } else {
            io::write_gray_png(&path, frame.width, frame.height, &frame.gray)?;
        }
        writeln!(list, "{:.6} {name}", frame.timestamp)
            .and_then(|_| list.flush())
            .map_err(|e| Error::io(&list_path, e))?;
        saved += 1;
    }
    drop(src);
    list.sync_all().map_err(|e| Error::io(&list_path, e))?;
    note!(
        "sdslam: recorded {saved} frames in {:.1} s ({skipped} corrupt skipped, {} dropped because writing was behind){}; replay with `sdslam run {}`",
        started.elapsed().as_secs_f64(),
        stats.dropped(),
        stop_reason.map(|r| format!("; stopped: {r}")).unwrap_or_default(),
        a.out.display()
    );
    Ok(())
}
