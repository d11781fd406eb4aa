//! The threaded mode solves initialisation attempts on their own thread: the first map must
//! still come early and be right, keyframe 1 (the attempt's frame, older than the frame that
//! receives the result) and the frames after it must be in one world frame, and every thread
//! must be joined at the end.

use sdslam::camera::Frame;
use sdslam::config::Config;
use sdslam::eval::ate;
use sdslam::runtime::System;
use sdslam::synthetic::{SyntheticConfig, SyntheticSequence};
use sdslam::tracking::TrackingState;

#[test]
fn initialisation_solved_off_the_tracking_thread_gives_a_right_map() {
    let frames = 150;
    let seq = SyntheticSequence::new(SyntheticConfig {
        frames,
        ..SyntheticConfig::default()
    });
    let mut config = Config::default();
    config.semidense.enabled = false;
    let mut system = System::new(&seq.config.calibration(), &config, frames, true);
    let mut frame = Frame::new(seq.config.width, seq.config.height);
    for i in 0..frames {
        seq.render_frame(i, &mut frame);
        system.process(
            &frame.gray,
            Some(&frame.rgb),
            seq.config.timestamp(i),
            i as u64,
        );
    }
    assert_eq!(system.state(), TrackingState::Ok);
    assert!(system.finish(), "a thread panicked");
    assert!(
        system.stats.initialisation_solve.percentiles().count > 0,
        "no attempt was solved on the initialisation thread"
    );
    let traj = system.trajectory();
    let gt = seq.ground_truth();
    assert!(
        traj.len() as f64 >= 0.9 * frames as f64,
        "{} of {frames} frames have a pose",
        traj.len()
    );
    let first = traj.first().map_or(f64::MAX, |p| p.timestamp);
    assert!(
        first <= seq.config.timestamp(10),
        "first pose at t = {first}"
    );
    let e = ate(&gt, &traj, 0.02, true).expect("ATE");
    let path: f64 = gt
        .windows(2)
        .map(|w| (w[1].t_wc.position() - w[0].t_wc.position()).norm())
        .sum();
    // Every frame (keyframe 1 from the solved attempt included) in one frame, near the truth.
    assert!(
        e.max_m <= 0.01 * path,
        "worst frame {:.4} m on a {path:.2} m path (rmse {:.4} m)",
        e.max_m,
        e.rmse_m
    );
}
