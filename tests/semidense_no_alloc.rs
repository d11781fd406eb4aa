//! Semi-dense mapping allocates nothing per keyframe after warm-up, with its worker threads
//! (every thread of the process is counted; this binary holds this single test).

mod common;

use common::counting_alloc::{allocations_by_all_threads_in, Counting};
use sdslam::camera::Frame;
use sdslam::config::Config;
use sdslam::semidense::{Densifier, Intrinsics, SemiDenseMapper};
use sdslam::synthetic::{SyntheticConfig, SyntheticSequence};

#[global_allocator]
static A: Counting = Counting;

#[test]
fn semidense_keyframes_allocate_nothing_after_warm_up() {
    let seq = SyntheticSequence::new(SyntheticConfig::default());
    let cam = seq.config.camera();
    let config = Config::default();
    assert_eq!(config.semidense.threads, 2, "the default pool is measured");
    let mut d = Densifier::new(&cam, &config, 32);
    let gt = seq.ground_truth();
    let mut f = Frame::new(cam.width, cam.height);
    for i in (60..200).step_by(8) {
        seq.render_frame(i, &mut f);
        assert!(d.add_keyframe(&f.gray, Some(&f.rgb), f.timestamp, i as u64, &gt[i].t_wc));
    }
    d.connect();
    let k = Intrinsics {
        fx: cam.fx,
        fy: cam.fy,
        cx: cam.cx,
        cy: cam.cy,
    };
    let mut mapper = SemiDenseMapper::new(
        k,
        cam.width as usize,
        cam.height as usize,
        &config.semidense,
        64,
        config.orb.n_features * 2,
    );
    let kfs = d.keyframes().to_vec();
    // Warm-up: the first keyframes (thread pool start, first reconstructions and checks).
    let warm = config.semidense.keyframe_delay + 3;
    for &kf in &kfs[..warm] {
        mapper.on_keyframe(d.map(), kf);
    }
    let before = mapper.stats.keyframes_reconstructed;
    let ((), n) = allocations_by_all_threads_in(|| {
        for &kf in &kfs[warm..] {
            mapper.on_keyframe(d.map(), kf);
        }
    });
    let done = mapper.stats.keyframes_reconstructed - before;
    assert!(
        done >= 4,
        "only {done} keyframes reconstructed while counting"
    );
    assert_eq!(
        n, 0,
        "{n} allocations while reconstructing {done} keyframes"
    );
}
