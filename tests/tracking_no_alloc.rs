//! The tracking step allocates nothing per frame after warm-up: frames that make no keyframe
//! (ORB extraction, motion-model prediction and matching, pose optimisation, local-map
//! tracking, trajectory bookkeeping) are counted with a counting global allocator (this
//! thread only; mapping runs inline, semi-dense off).

mod common;

use common::counting_alloc::{allocations_in, Counting};
use sdslam::camera::Frame;
use sdslam::config::Config;
use sdslam::runtime::System;
use sdslam::synthetic::{SyntheticConfig, SyntheticSequence};
use sdslam::tracking::TrackingState;

#[global_allocator]
static A: Counting = Counting;

#[test]
fn tracking_frames_allocate_nothing_after_warm_up() {
    let seq = SyntheticSequence::new(SyntheticConfig::default());
    let c = &seq.config;
    let mut config = Config::default();
    config.semidense.enabled = false;
    let mut system = System::new(&c.calibration(), &config, 300, false);
    let frames: Vec<Frame> = (0..140)
        .map(|i| {
            let mut f = Frame::new(c.width, c.height);
            seq.render_frame(i, &mut f);
            f
        })
        .collect();
    let (mut counted, mut allocating) = (0, Vec::new());
    for (i, f) in frames.iter().enumerate() {
        let (r, n) =
            allocations_in(|| system.process(&f.gray, Some(&f.rgb), f.timestamp, i as u64));
        // Warm-up: initialisation and the first 100 frames (buffers reach their sizes).
        if i >= 100 && r.state == TrackingState::Ok && !r.new_keyframe {
            counted += 1;
            if n > 0 {
                allocating.push((i, n));
            }
        }
    }
    assert!(counted >= 20, "only {counted} tracking-only frames counted");
    assert!(
        allocating.is_empty(),
        "frames that allocated (frame, count): {allocating:?}"
    );
}
