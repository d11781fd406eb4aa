//! Tests against a real camera. The build machines have no `/dev/video*` and cannot load a
//! video driver, so these are ignored by default; on a robot run
//! `SDSLAM_TEST_CAMERA=v4l2:/dev/video0 cargo test -p sdslam-camera --test real_device -- --ignored`.

use std::time::Duration;

use sdslam_camera::device::{open_live, LiveOptions};
use sdslam_camera::{Frame, FrameStatus};

fn camera() -> String {
    std::env::var("SDSLAM_TEST_CAMERA").unwrap_or_else(|_| "v4l2:/dev/video0".into())
}

#[test]
#[ignore = "needs a camera (set SDSLAM_TEST_CAMERA)"]
fn streams_thirty_frames_with_increasing_timestamps() {
    let opts = LiveOptions {
        timeout: Duration::from_secs(5),
        ..Default::default()
    };
    let mut src = open_live(&camera(), &opts).expect("open the camera").source;
    let info = src.info().clone();
    let mut f = Frame::new(info.width, info.height);
    let mut stamps = Vec::new();
    while stamps.len() < 30 {
        match src.next_frame(&mut f).expect("frame") {
            FrameStatus::Ready => stamps.push(f.timestamp),
            FrameStatus::Skipped { .. } => {}
            FrameStatus::End => panic!("a camera does not end"),
        }
    }
    assert!(stamps.windows(2).all(|w| w[1] > w[0]));
    let rate = 29.0 / (stamps[29] - stamps[0]);
    assert!(
        rate > info.fps * 0.5,
        "{rate} fps against {} nominal",
        info.fps
    );
    assert!(
        f.gray.iter().any(|&g| g != f.gray[0]),
        "a uniform image: is the lens covered?"
    );
}

#[test]
#[ignore = "needs a camera (set SDSLAM_TEST_CAMERA)"]
fn lists_the_camera() {
    let cams = sdslam_camera::device::list_cameras();
    assert!(cams.iter().any(|c| c.spec == camera()), "{cams:?}");
}
