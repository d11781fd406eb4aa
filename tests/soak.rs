//! Soak: the built-in orbit (periodic: frame 300 is frame 0) replayed twenty times in one
//! process (6,000 frames) with a small map (40 keyframes, 5,000 points) so that eviction runs:
//! tracking keeps up, the map stays within its capacity, and resident memory stays flat after
//! the first loop. Frames are rendered once (grey) and replayed from memory.

use sdslam::camera::Frame;
use sdslam::config::Config;
use sdslam::io::current_rss_mb;
use sdslam::runtime::System;
use sdslam::synthetic::{SyntheticConfig, SyntheticSequence};
use sdslam::tracking::TrackingState;

#[test]
fn twenty_loops_keep_memory_flat_and_the_map_bounded() {
    const LAPS: usize = 20;
    let seq = SyntheticSequence::new(SyntheticConfig::default());
    let c = &seq.config;
    let mut config = Config::default();
    config.semidense.enabled = false;
    config.map.max_keyframes = 40;
    config.map.max_map_points = 5_000;
    config.map.final_global_ba = false;
    let mut system = System::new(&c.calibration(), &config, 300 * LAPS, false);
    let mut f = Frame::new(c.width, c.height);
    let frames: Vec<Vec<u8>> = (0..300)
        .map(|i| {
            seq.render_frame(i, &mut f);
            f.gray.clone()
        })
        .collect();
    let mut rss = Vec::new();
    let mut index = 0u64;
    for lap in 0..LAPS {
        let mut tracked = 0;
        for gray in &frames {
            let t = c.t0 + index as f64 / c.fps;
            let r = system.process(gray, None, t, index);
            index += 1;
            if r.state == TrackingState::Ok {
                tracked += 1;
            }
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
        // Eviction ran (more keyframes made than the map has slots) and left a usable map,
        // not an emptied one: the arena's capacity alone is not the check.
        let (kfs, pts) = system.map_size();
        if lap >= 1 {
            assert!(
                system.stats.keyframes_created > 40,
                "lap {lap}: only {} keyframes made in all: eviction never ran",
                system.stats.keyframes_created
            );
            assert!(
                kfs >= 10 && pts >= 500,
                "lap {lap}: eviction emptied the map ({kfs} keyframes, {pts} points)"
            );
        }
    }
    // After the first lap (buffers warmed up, map at capacity): flat within 5%.
    let growth = (rss[LAPS - 1] - rss[1]) / rss[1];
    eprintln!(
        "RSS lap 1 {:.1} MB, lap {} {:.1} MB: growth {:.2}%",
        rss[1],
        LAPS - 1,
        rss[LAPS - 1],
        growth * 100.0
    );
    assert!(
        growth < 0.05,
        "resident memory grew {:.1}% from lap 1 to {}: {rss:?}",
        growth * 100.0,
        LAPS - 1
    );
}
