//! The local-mapping thread (local mapping, then loop closing, per keyframe).

use super::*;

/// Starts the local-mapping thread: per keyframe, prepare under the lock, BA without it, write
/// back under the lock. Exits when the channel closes (after draining it).
pub(super) fn spawn_mapper(
    camera: PinholeRadtan,
    scales: &[f64],
    map: Arc<Mutex<Map>>,
    expected: usize,
    cpus: Vec<usize>,
    places: Arc<Mutex<PlaceIndex>>,
) -> Mapping {
    let mut mapper = LocalMapper::new(camera, scales);
    let mut closer = LoopCloser::new(camera, scales);
    let (tx, rx) = bounded::<KeyFrameId>(8);
    let idle = Arc::new(AtomicBool::new(true));
    let idle_t = Arc::clone(&idle);
    let handle = std::thread::Builder::new()
        .name("local-mapping".into())
        .spawn(move || {
            crate::runtime::pin_current_thread(&cpus);
            let mut timer = StageTimer::with_capacity(expected.max(16));
            let mut loop_timer = StageTimer::with_capacity(64);
            while let Ok(kf) = rx.recv() {
                idle_t.store(false, Ordering::Release);
                let t = Instant::now();
                let has_ba = mapper.prepare(&mut lock(&map), kf);
                if has_ba {
                    mapper.solve();
                }
                mapper.finish(&mut lock(&map), kf);
                timer.record(t.elapsed());
                {
                    let mut m = lock(&map);
                    let p = places.lock().unwrap_or_else(|e| e.into_inner());
                    let tl = Instant::now();
                    if closer.process(&mut m, &p, kf).is_some() {
                        loop_timer.record(tl.elapsed());
                    }
                }
                idle_t.store(rx.is_empty(), Ordering::Release);
            }
            (timer, loop_timer, closer.loops_closed)
        })
        .ok();
    match handle {
        Some(h) => Mapping::Thread {
            tx: Some(tx),
            handle: Some(h),
            idle,
        },
        // No thread could be started: fall back to inline mapping (still correct).
        None => Mapping::Inline(Box::new((
            LocalMapper::new(camera, scales),
            LoopCloser::new(camera, scales),
        ))),
    }
}
