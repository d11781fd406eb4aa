//! ORB extraction performs no heap allocation per frame once warmed up (a counting global
//! allocator, counting only this test's thread).

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use sdslam::camera::Frame;
use sdslam::camera_model::PinholeRadtan;
use sdslam::config::OrbConfig;
use sdslam::features::{Features, OrbExtractor};
use sdslam::synthetic::{SyntheticConfig, SyntheticSequence};

struct Counting;

thread_local! {
    static COUNT: Cell<Option<u64>> = const { Cell::new(None) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = COUNT.try_with(|c| {
            if let Some(n) = c.get() {
                c.set(Some(n + 1));
            }
        });
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let _ = COUNT.try_with(|c| {
            if let Some(n) = c.get() {
                c.set(Some(n + 1));
            }
        });
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static A: Counting = Counting;

#[test]
fn extraction_allocates_nothing_after_the_first_frame() {
    let seq = SyntheticSequence::new(SyntheticConfig {
        frames: 300,
        ..SyntheticConfig::default()
    });
    let frames: Vec<Frame> = [0usize, 50, 100, 150, 200]
        .iter()
        .map(|&i| {
            let mut f = Frame::new(640, 480);
            seq.render_frame(i, &mut f);
            f
        })
        .collect();
    // A distorted camera so undistortion of keypoints runs too.
    let cam = PinholeRadtan {
        k1: -0.2,
        k2: 0.05,
        ..PinholeRadtan::pinhole(520.0, 520.0, 319.5, 239.5, 640, 480)
    };
    let mut ex = OrbExtractor::new(640, 480, &OrbConfig::default());
    let mut out = Features::with_capacity(1000);
    ex.extract(&frames[0].gray, Some(&cam), &mut out); // warm-up
    COUNT.with(|c| c.set(Some(0)));
    for f in &frames[1..] {
        ex.extract(&f.gray, Some(&cam), &mut out);
        assert!(out.len() > 900, "{}", out.len());
    }
    let n = COUNT.with(|c| c.replace(None)).unwrap_or(0);
    assert_eq!(n, 0, "{n} heap allocations in 4 extractions after warm-up");
}
