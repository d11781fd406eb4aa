//! sdslam as a library: replay a TUM RGB-D folder (or the built-in sequence) and receive poses
//! on a channel as they are computed, as a robot's controller would, then take the semi-dense
//! cloud at the end.
//!
//!     cargo run --release --example replay                        # built-in sequence, 150 frames
//!     cargo run --release --example replay -- ../shared/data/synthetic/desk
//!
//! The frame source, the SLAM system and the consumer are three independent pieces: swap the
//! source for `sdslam::camera::device::open_live("v4l2:/dev/video0", ...)` to run on a camera.

use std::error::Error;
use std::path::Path;

use sdslam::camera::{Frame, FrameSource, FrameStatus, ImageListSource};
use sdslam::config::Config;
use sdslam::geometry::WorldFromCamera;
use sdslam::io::load_calibration;
use sdslam::runtime::System;
use sdslam::synthetic::{SyntheticConfig, SyntheticSequence};

fn main() -> Result<(), Box<dyn Error>> {
    // 1. A frame source and its calibration.
    let (mut source, calib): (Box<dyn FrameSource>, _) = match std::env::args().nth(1) {
        Some(dir) => {
            let calib = load_calibration(&Path::new(&dir).join("camera.yaml"))?;
            (Box::new(ImageListSource::open(Path::new(&dir))?), calib)
        }
        None => {
            let cfg = SyntheticConfig {
                frames: 150,
                ..SyntheticConfig::default()
            };
            let calib = cfg.calibration();
            (Box::new(SyntheticSequence::new(cfg)), calib)
        }
    };
    let info = source.info().clone();

    // 2. The SLAM system: local mapping and semi-dense mapping on their own threads.
    let mut system = System::new(&calib, &Config::default(), info.len.unwrap_or(10_000), true);
    // Frames come faster than real time: initialisation is attempted on every frame (a
    // camera would leave this off, keeping attempts off the tracking thread).
    system.set_replay(true);

    // 3. A consumer of poses on its own thread, fed through a bounded channel.
    let (tx, rx) = crossbeam_channel::bounded::<(f64, WorldFromCamera)>(64);
    let consumer = std::thread::spawn(move || {
        let mut n = 0;
        let mut last = None;
        for (t, t_wc) in rx {
            n += 1;
            last = Some((t, t_wc.position()));
        }
        (n, last)
    });

    let mut frame = Frame::new(info.width, info.height);
    loop {
        match source.next_frame(&mut frame)? {
            FrameStatus::Ready => {}
            FrameStatus::Skipped { .. } => continue,
            FrameStatus::End => break,
        }
        // Undistorted inside (the calibration's distortion), then tracked.
        let result = system.process_frame(&frame);
        if let Some(t_wc) = result.t_wc {
            // try_send: a slow consumer must never hold up tracking.
            let _ = tx.try_send((frame.timestamp, t_wc));
        }
    }
    drop(tx);
    let threads_ok = system.finish();
    let (poses, last) = consumer.join().map_err(|_| "consumer thread panicked")?;
    let cloud = system.semidense_cloud();
    let (keyframes, points) = system.map_size();
    println!("{poses} poses received; last {last:?}");
    println!(
        "map: {keyframes} keyframes, {points} points; semi-dense cloud: {} points",
        cloud.len()
    );
    if !threads_ok {
        return Err("a worker thread failed".into());
    }
    Ok(())
}
