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
    global_ba_after_loop: bool,
) -> Mapping {
    let mut mapper = LocalMapper::new(camera, scales);
    let mut closer = LoopCloser::new(camera, scales);
    let scales_owned = scales.to_vec();
    let (tx, rx) = bounded::<KeyFrameId>(8);
    let idle = Arc::new(AtomicBool::new(true));
    let idle_t = Arc::clone(&idle);
    let handle = std::thread::Builder::new()
        .name("local-mapping".into())
        .spawn(move || {
            crate::runtime::pin_current_thread(&cpus);
            let mut timer = StageTimer::with_capacity(expected.max(16));
            let mut loop_timer = StageTimer::with_capacity(64);
            let mut gba: Option<std::thread::JoinHandle<()>> = None;
            let mut n = 0;
            while let Ok(kf) = rx.recv() {
                n += 1;
                crate::runtime::faults::maybe_panic("panic:local_mapping", n);
                idle_t.store(false, Ordering::Release);
                let t = Instant::now();
                let has_ba = mapper.prepare(&mut lock(&map), kf);
                if has_ba {
                    mapper.solve();
                }
                mapper.finish(&mut lock(&map), kf);
                timer.record(t.elapsed());
                let closed = {
                    let mut m = lock(&map);
                    let p = places.lock().unwrap_or_else(|e| e.into_inner());
                    let tl = Instant::now();
                    let closed = closer.process(&mut m, &p, kf).is_some();
                    if closed {
                        loop_timer.record(tl.elapsed());
                    }
                    closed
                };
                if closed && global_ba_after_loop {
                    // A full BA on its own thread: copied under a short lock, solved without
                    // it, merged under a short lock; tracking and mapping go on meanwhile.
                    if let Some(h) = gba.take() {
                        let _ = h.join();
                    }
                    let (map2, scales2) = (Arc::clone(&map), scales_owned.clone());
                    gba = std::thread::Builder::new()
                        .name("global-ba".into())
                        .spawn(move || {
                            let job = GlobalBaJob::prepare(&lock(&map2), &camera, &scales2, 10);
                            if let Some(mut job) = job {
                                job.solve();
                                job.merge(&mut lock(&map2));
                            }
                        })
                        .ok();
                }
                idle_t.store(rx.is_empty(), Ordering::Release);
            }
            if let Some(h) = gba.take() {
                let _ = h.join();
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
