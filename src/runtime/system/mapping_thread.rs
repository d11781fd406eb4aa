//! The local-mapping thread and the loop-closing thread it feeds (ORB-SLAM's thread model):
//! each keyframe is mapped, then handed over for loop detection, so a loop correction never
//! meets a half-mapped keyframe, and local mapping goes on while a loop is being closed.

use super::*;
use std::time::Duration;

/// Where local mapping runs.
pub(super) enum Mapping {
    /// On the tracking thread, right after the keyframe is made (deterministic mode).
    Inline(Box<(LocalMapper, LoopWorker)>),
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

/// Longest a replayed frame waits for local mapping ([`Mapping::wait_until_idle`]); a
/// keyframe's mapping takes tens of milliseconds.
pub(super) const REPLAY_MAPPING_WAIT: Duration = Duration::from_secs(2);

impl Mapping {
    /// Threaded mode: waits (at most `limit`, and not for a thread that has ended) until
    /// local mapping has processed every keyframe sent. For a replayed recording, which has
    /// no frame deadline: tracking far ahead of mapping decides keyframes as an overloaded
    /// robot would (ORB-SLAM's rule makes one only when mapping is idle or after many
    /// frames). Replayed back to back, kitti06_51 kept 15-18 keyframes instead of 31-34 and
    /// its keyframe error rose from 0.045-0.063% of the path (real time, deterministic) to
    /// 0.10-0.18%.
    pub(super) fn wait_until_idle(&self, limit: Duration) {
        let Mapping::Thread { idle, handle, .. } = self else {
            return;
        };
        let t0 = Instant::now();
        while !idle.load(Ordering::Acquire)
            && t0.elapsed() < limit
            && handle.as_ref().is_some_and(|h| !h.is_finished())
        {
            std::thread::sleep(Duration::from_micros(200));
        }
    }

    /// Threaded mode: stops the mapping thread after it has processed every queued keyframe
    /// (it then hangs up on the loop-closing thread, which drains its own queue) and joins
    /// both. Returns whether neither had panicked, the local-mapping timer and the loop
    /// figures; `None` inline.
    pub(super) fn join(&mut self) -> Option<(bool, Option<StageTimer>, LoopStats)> {
        let (tx, handle, closer, idle) = match self {
            Mapping::Inline(m) => return Some((true, None, m.1.take_stats())),
            Mapping::Thread {
                tx,
                handle,
                closer,
                idle,
            } => (tx, handle, closer, idle),
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
    pub global_ba_iterations: usize,
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

    /// Local mapping and loop closing on the caller's thread (deterministic mode).
    pub fn inline(&self) -> Mapping {
        Mapping::Inline(Box::new((self.local_mapper(), LoopWorker::new(self))))
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
    let gates = YieldGates { gate, map_wanted };
    let mut mapper = setup.local_mapper();
    let (tx, rx) = bounded::<KeyFrameId>(8);
    let (loop_tx, closer) = match spawn_loop_closer(
        setup,
        Arc::clone(&map),
        cpus.clone(),
        Arc::clone(&places),
        gates.clone(),
    ) {
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
                let has_ba = mapper.prepare_in_steps(kf, &mut |step: &mut dyn FnMut(&mut Map)| {
                    gates.wait();
                    step(&mut lock(&map))
                });
                if has_ba {
                    mapper.solve();
                }
                gates.wait();
                mapper.finish(&mut lock(&map), kf);
                timer.record(t.elapsed());
                match (&loop_tx, &mut own) {
                    // Blocks only while 8 keyframes wait for loop detection (a correction
                    // takes tens of ms); a dead loop thread is reported by `failed_thread`.
                    (Some(t), _) => {
                        let _ = t.send(kf);
                    }
                    (None, Some(w)) => w.process_shared(&map, &places, kf, &gates),
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
        None => setup.inline(),
    }
}

/// What a background step waits for before taking the map: tracking wanting the lock, and,
/// with frames paced in real time, a frame being tracked (steps run in the gaps; back to
/// back, mapping runs alongside).
#[derive(Clone)]
pub(super) struct YieldGates {
    gate: crate::runtime::ForegroundGate,
    map_wanted: crate::runtime::ForegroundGate,
}

impl YieldGates {
    fn wait(&self) {
        if self.gate.paced() {
            self.gate.wait();
        }
        self.map_wanted.wait();
    }
}

/// The loop-closing thread: detection (and correction) per mapped keyframe, then, after a
/// loop, a full BA on a background thread of its own.
fn spawn_loop_closer(
    setup: &MapperSetup,
    map: Arc<Mutex<Map>>,
    cpus: Vec<usize>,
    places: Arc<Mutex<PlaceIndex>>,
    gates: YieldGates,
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
                worker.process_shared(&map, &places, kf, &gates);
            }
            worker.finish()
        })
        .ok()?;
    Some((tx, handle))
}

/// "Close loops, then global BA" for one mapped keyframe at a time: the one implementation
/// behind both modes. Inline (deterministic) the full BA runs at once on the caller's
/// thread; threaded it runs on a background thread of its own while tracking and mapping
/// go on.
pub(super) struct LoopWorker {
    closer: LoopCloser,
    camera: PinholeRadtan,
    scales: Vec<f64>,
    global_ba_after_loop: bool,
    global_ba_iterations: usize,
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
            global_ba_iterations: setup.global_ba_iterations,
            timer: StageTimer::with_capacity(64),
            gba: None,
        }
    }

    /// Loop detection and, when a loop is found, its correction; true when one was closed.
    fn close(&mut self, map: &mut Map, places: &PlaceIndex, kf: KeyFrameId) -> bool {
        let t = Instant::now();
        let closed = self.closer.process(map, places, kf).is_some();
        if closed {
            self.timer.record(t.elapsed());
        }
        closed
    }

    fn global_ba_job(&self, map: &Map) -> Option<GlobalBaJob> {
        GlobalBaJob::prepare(map, &self.camera, &self.scales, self.global_ba_iterations)
    }

    /// Deterministic mode, with the map already locked by the caller: close, then the full
    /// BA inline. Returns whether a loop was closed.
    pub(super) fn process_inline(
        &mut self,
        map: &mut Map,
        places: &PlaceIndex,
        kf: KeyFrameId,
    ) -> bool {
        let closed = self.close(map, places, kf);
        if closed && self.global_ba_after_loop {
            if let Some(mut job) = self.global_ba_job(map) {
                job.solve();
                job.merge(map);
            }
        }
        closed
    }

    /// Threaded mode: detection under the map and place-index locks, then the closing in
    /// short steps, each under the map lock and none started while tracking waits for it (or,
    /// paced in real time, while a frame is tracked); then the full BA on its own thread,
    /// copied under a short lock, solved without it, merged under a short lock (dropped if
    /// another loop moved the map meanwhile).
    fn process_shared(
        &mut self,
        map: &Arc<Mutex<Map>>,
        places: &Mutex<PlaceIndex>,
        kf: KeyFrameId,
        gates: &YieldGates,
    ) {
        let candidates = {
            let m = lock(map);
            let p = places.lock().unwrap_or_else(|e| e.into_inner());
            self.closer.candidates(&m, &p, kf)
        };
        let t = Instant::now();
        let closed = self
            .closer
            .close_in_steps(kf, candidates, &mut |step: &mut dyn FnMut(&mut Map)| {
                gates.wait();
                step(&mut lock(map))
            })
            .is_some();
        if closed {
            self.timer.record(t.elapsed());
        }
        if !(closed && self.global_ba_after_loop) {
            return;
        }
        if let Some(h) = self.gba.take() {
            let _ = h.join();
        }
        let job_map = Arc::clone(map);
        let job = self.global_ba_job(&lock(map));
        self.gba = std::thread::Builder::new()
            .name("global-ba".into())
            .spawn(move || {
                if let Some(mut job) = job {
                    job.solve();
                    job.merge(&mut lock(&job_map));
                }
            })
            .ok();
    }

    /// The loop figures so far (live in the inline mode).
    pub(super) fn counts(&self) -> (usize, usize) {
        (self.closer.loops_closed, self.closer.revisits_closed)
    }

    pub(super) fn history(&self) -> &[crate::loop_closing::LoopRecord] {
        &self.closer.history
    }

    /// Waits for a running full BA and hands over the figures (the timer is taken).
    fn take_stats(&mut self) -> LoopStats {
        if let Some(h) = self.gba.take() {
            let _ = h.join();
        }
        LoopStats {
            timer: Some(std::mem::replace(
                &mut self.timer,
                StageTimer::with_capacity(0),
            )),
            loops_closed: self.closer.loops_closed,
            revisits_closed: self.closer.revisits_closed,
            history: self.closer.history.clone(),
        }
    }

    fn finish(mut self) -> LoopStats {
        self.take_stats()
    }
}
