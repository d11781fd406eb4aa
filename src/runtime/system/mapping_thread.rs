//! The local-mapping thread and the loop-closing thread it feeds (ORB-SLAM's thread model):
//! each keyframe is mapped, then handed over for loop detection, so a loop correction never
//! meets a half-mapped keyframe, and local mapping goes on while a loop is being closed.

use super::*;

/// Where local mapping runs.
pub(super) enum Mapping {
    /// On the tracking thread, right after the keyframe is made (deterministic mode).
    Inline(Box<(LocalMapper, LoopCloser)>),
    /// On its own thread, fed by a bounded channel; never holds the map during BA. Loop
    /// closing runs on a third thread fed by the mapping thread (`None`: it could not be
    /// started, and the mapping thread closes loops itself).
    Thread {
        tx: Option<Sender<KeyFrameId>>,
        /// Returns the local-mapping timer (and the loop figures when it closed loops itself).
        handle: Option<JoinHandle<(StageTimer, LoopStats)>>,
        closer: Option<JoinHandle<LoopStats>>,
        idle: Arc<AtomicBool>,
    },
}

/// What loop closing did in a run.
#[derive(Default)]
pub(super) struct LoopStats {
    pub(super) timer: Option<StageTimer>,
    pub(super) loops_closed: usize,
    pub(super) revisits_closed: usize,
    pub(super) history: Vec<crate::loop_closing::LoopRecord>,
}

impl Mapping {
    /// Threaded mode: stops the mapping thread after it has processed every queued keyframe
    /// (it then hangs up on the loop-closing thread, which drains its own queue) and joins
    /// both. Returns whether neither had panicked, the local-mapping timer and the loop
    /// figures; `None` inline.
    pub(super) fn join(&mut self) -> Option<(bool, Option<StageTimer>, LoopStats)> {
        let Mapping::Thread {
            tx,
            handle,
            closer,
            idle,
        } = self
        else {
            return None;
        };
        tx.take();
        let (mut ok, mut timer, mut loops) = (true, None, LoopStats::default());
        match handle.take().map(|h| h.join()) {
            Some(Ok((t, l))) => {
                timer = Some(t);
                loops = l;
            }
            Some(Err(_)) => ok = false,
            None => {}
        }
        match closer.take().map(|h| h.join()) {
            Some(Ok(l)) => loops = l,
            Some(Err(_)) => ok = false,
            None => {}
        }
        idle.store(true, Ordering::Release);
        Some((ok, timer, loops))
    }
}

/// What local mapping and loop closing are built from (the same for the inline and the
/// threaded mode).
pub(super) struct MapperSetup {
    pub camera: PinholeRadtan,
    pub scales: Vec<f64>,
    pub local_mapping: crate::config::LocalMappingConfig,
    pub loop_closing: crate::config::LoopClosingConfig,
    pub global_ba_after_loop: bool,
}

impl MapperSetup {
    pub fn local_mapper(&self) -> LocalMapper {
        let mut m = LocalMapper::new(self.camera, &self.scales);
        m.config = self.local_mapping.clone();
        m
    }

    pub fn loop_closer(&self) -> LoopCloser {
        let mut c = LoopCloser::new(self.camera, &self.scales);
        c.config = self.loop_closing.clone();
        c
    }
}

/// Starts the local-mapping thread: per keyframe, prepare in short steps under the lock (none
/// started while tracking waits for it, or, paced in real time, while a frame is tracked), BA
/// without it, write back under the lock, then pass the keyframe to loop closing. Exits when the channel closes
/// (after draining it), hanging up on the loop-closing thread.
pub(super) fn spawn_mapper(
    setup: &MapperSetup,
    map: Arc<Mutex<Map>>,
    expected: usize,
    cpus: Vec<usize>,
    places: Arc<Mutex<PlaceIndex>>,
    gate: crate::runtime::ForegroundGate,
    map_wanted: crate::runtime::ForegroundGate,
) -> Mapping {
    let mut mapper = setup.local_mapper();
    let (tx, rx) = bounded::<KeyFrameId>(8);
    let (loop_tx, closer) =
        match spawn_loop_closer(setup, Arc::clone(&map), cpus.clone(), Arc::clone(&places)) {
            Some((t, h)) => (Some(t), Some(h)),
            None => (None, None),
        };
    // Without a loop-closing thread, the mapping thread closes loops itself.
    let mut own = loop_tx.is_none().then(|| LoopWorker::new(setup));
    let idle = Arc::new(AtomicBool::new(true));
    let idle_t = Arc::clone(&idle);
    let map_t = Arc::clone(&map);
    let handle = std::thread::Builder::new()
        .name("local-mapping".into())
        .spawn(move || {
            let map = map_t;
            crate::runtime::pin_current_thread(&cpus);
            let mut timer = StageTimer::with_capacity(expected.max(16));
            let mut n = 0;
            while let Ok(kf) = rx.recv() {
                n += 1;
                crate::runtime::faults::maybe_panic("panic:local_mapping", n);
                idle_t.store(false, Ordering::Release);
                let t = Instant::now();
                // The map is locked per step. No step starts while tracking waits for the
                // lock, and with frames paced in real time none starts while a frame is being
                // tracked (steps run in the gaps); back to back, mapping runs alongside.
                let yield_to_tracking = || {
                    if gate.paced() {
                        gate.wait();
                    }
                    map_wanted.wait();
                };
                let has_ba = mapper.prepare_in_steps(kf, &mut |step: &mut dyn FnMut(&mut Map)| {
                    yield_to_tracking();
                    step(&mut lock(&map))
                });
                if has_ba {
                    mapper.solve();
                }
                yield_to_tracking();
                mapper.finish(&mut lock(&map), kf);
                timer.record(t.elapsed());
                match (&loop_tx, &mut own) {
                    // Blocks only while 8 keyframes wait for loop detection (a correction
                    // takes tens of ms); a dead loop thread is reported by `failed_thread`.
                    (Some(t), _) => {
                        let _ = t.send(kf);
                    }
                    (None, Some(w)) => w.process(&map, &places, kf),
                    (None, None) => {}
                }
                idle_t.store(rx.is_empty(), Ordering::Release);
            }
            drop(loop_tx);
            (timer, own.map(LoopWorker::finish).unwrap_or_default())
        })
        .ok();
    match handle {
        Some(h) => Mapping::Thread {
            tx: Some(tx),
            handle: Some(h),
            closer,
            idle,
        },
        // No thread could be started: fall back to inline mapping (still correct).
        None => Mapping::Inline(Box::new((setup.local_mapper(), setup.loop_closer()))),
    }
}

/// The loop-closing thread: detection (and correction) per mapped keyframe, then, after a
/// loop, a full BA on a background thread of its own.
fn spawn_loop_closer(
    setup: &MapperSetup,
    map: Arc<Mutex<Map>>,
    cpus: Vec<usize>,
    places: Arc<Mutex<PlaceIndex>>,
) -> Option<(Sender<KeyFrameId>, JoinHandle<LoopStats>)> {
    let mut worker = LoopWorker::new(setup);
    let (tx, rx) = bounded::<KeyFrameId>(8);
    let handle = std::thread::Builder::new()
        .name("loop-closing".into())
        .spawn(move || {
            crate::runtime::pin_current_thread(&cpus);
            let mut n = 0;
            while let Ok(kf) = rx.recv() {
                n += 1;
                crate::runtime::faults::maybe_panic("panic:loop_closing", n);
                worker.process(&map, &places, kf);
            }
            worker.finish()
        })
        .ok()?;
    Some((tx, handle))
}

/// Loop detection and correction for one keyframe at a time, and the full BA after a loop.
struct LoopWorker {
    closer: LoopCloser,
    camera: PinholeRadtan,
    scales: Vec<f64>,
    global_ba_after_loop: bool,
    timer: StageTimer,
    gba: Option<JoinHandle<()>>,
}

impl LoopWorker {
    fn new(setup: &MapperSetup) -> Self {
        LoopWorker {
            closer: setup.loop_closer(),
            camera: setup.camera,
            scales: setup.scales.clone(),
            global_ba_after_loop: setup.global_ba_after_loop,
            timer: StageTimer::with_capacity(64),
            gba: None,
        }
    }

    fn process(&mut self, map: &Arc<Mutex<Map>>, places: &Mutex<PlaceIndex>, kf: KeyFrameId) {
        let closed = {
            let mut m = lock(map);
            let p = places.lock().unwrap_or_else(|e| e.into_inner());
            let tl = Instant::now();
            let closed = self.closer.process(&mut m, &p, kf).is_some();
            if closed {
                self.timer.record(tl.elapsed());
            }
            closed
        };
        if closed && self.global_ba_after_loop {
            // A full BA on its own thread: copied under a short lock, solved without it,
            // merged under a short lock (dropped if another loop moved the map meanwhile);
            // tracking and mapping go on.
            if let Some(h) = self.gba.take() {
                let _ = h.join();
            }
            let (map2, scales2, camera) = (Arc::clone(map), self.scales.clone(), self.camera);
            self.gba = std::thread::Builder::new()
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
    }

    fn finish(mut self) -> LoopStats {
        if let Some(h) = self.gba.take() {
            let _ = h.join();
        }
        LoopStats {
            timer: Some(self.timer),
            loops_closed: self.closer.loops_closed,
            revisits_closed: self.closer.revisits_closed,
            history: self.closer.history,
        }
    }
}
