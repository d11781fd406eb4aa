//! The tracking step (frame in, pose out) with local mapping on its own thread, as deployed.
//! Run pinned to two cores: `taskset -c 0,1 cargo bench --bench tracking`.
//!
//! The camera walks the built-in sequence forwards and backwards over frames 40-119 (continuous
//! motion, so every step is an ordinary tracking step against a map built in warm-up).

use criterion::{criterion_group, criterion_main, Criterion};
use sdslam::camera::Frame;
use sdslam::config::Config;
use sdslam::runtime::System;
use sdslam::synthetic::{SyntheticConfig, SyntheticSequence};

fn tracking(c: &mut Criterion) {
    let seq = SyntheticSequence::new(SyntheticConfig::default());
    let sc = &seq.config;
    let frames: Vec<Frame> = (0..120)
        .map(|i| {
            let mut f = Frame::new(sc.width, sc.height);
            seq.render_frame(i, &mut f);
            f
        })
        .collect();
    for (name, semidense) in [
        ("track_frame_640x480", false),
        ("track_frame_640x480_semidense", true),
    ] {
        let mut config = Config::default();
        config.semidense.enabled = semidense;
        let mut system = System::new(&sc.calibration(), &config, 100_000, true);
        for (i, f) in frames.iter().enumerate() {
            system.process(&f.gray, Some(&f.rgb), f.timestamp, i as u64);
        }
        // Ping-pong over frames 40..120 with increasing timestamps.
        let order: Vec<usize> = (40..120).rev().chain(40..120).collect();
        let dt = 1.0 / sc.fps;
        let mut step = 0usize;
        let mut t = frames[119].timestamp;
        c.bench_function(name, |b| {
            b.iter(|| {
                let f = &frames[order[step % order.len()]];
                step += 1;
                t += dt;
                system.process(&f.gray, Some(&f.rgb), t, 120 + step as u64)
            })
        });
        system.finish();
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(30);
    targets = tracking
}
criterion_main!(benches);
