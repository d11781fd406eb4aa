//! Soak: the built-in orbit (periodic: frame 300 is frame 0) replayed four times in one
//! process with a small map (40 keyframes, 5,000 points) so that eviction runs: tracking
//! keeps up, the map stays within its capacity, and resident memory stays flat after the
//! first loop.

use sdslam::camera::Frame;
use sdslam::config::Config;
use sdslam::io::current_rss_mb;
use sdslam::runtime::System;
use sdslam::synthetic::{SyntheticConfig, SyntheticSequence};
use sdslam::tracking::TrackingState;

#[test]
fn four_loops_keep_memory_flat_and_the_map_bounded() {
    let seq = SyntheticSequence::new(SyntheticConfig::default());
    let c = &seq.config;
    let mut config = Config::default();
    config.semidense.enabled = false;
    config.map.max_keyframes = 40;
    config.map.max_map_points = 5_000;
    config.map.final_global_ba = false;
    let mut system = System::new(&c.calibration(), &config, 1200, false);
    let mut f = Frame::new(c.width, c.height);
    let mut rss = Vec::new();
    let mut index = 0u64;
    for lap in 0..4 {
        let mut tracked = 0;
        for i in 0..300 {
            seq.render_frame(i, &mut f);
            let t = c.t0 + index as f64 / c.fps;
            let r = system.process(&f.gray, Some(&f.rgb), t, index);
            index += 1;
            if r.state == TrackingState::Ok {
                tracked += 1;
            }
            let (kfs, pts) = system.map_size();
            assert!(
                kfs <= 40 && pts <= 5_000,
                "map grew to {kfs} keyframes, {pts} points"
            );
        }
        rss.push(current_rss_mb());
        eprintln!(
            "lap {lap}: {tracked}/300 tracked, map {:?}, RSS {:.1} MB",
            system.map_size(),
            rss[lap]
        );
        assert!(
            tracked >= 285,
            "lap {lap}: only {tracked} of 300 frames tracked"
        );
    }
    // After the first lap (buffers warmed up, map at capacity): flat within 5%.
    let growth = (rss[3] - rss[1]) / rss[1];
    assert!(
        growth < 0.05,
        "resident memory grew {:.1}% from lap 1 to 3: {rss:?}",
        growth * 100.0
    );
}
