//! Where semi-dense mapping runs: inline on the tracking thread (deterministic mode) or on its
//! own thread fed by a bounded channel. The thread is the first to degrade under overload:
//! when its queue is full, keyframes are not reconstructed (counted), tracking never waits.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use crossbeam_channel::{bounded, Sender, TrySendError};

use crate::map::{KeyFrameId, Map};
use crate::semidense::SemiDenseMapper;

/// Keyframe notifications buffered for the semi-dense thread (about a minute of keyframes
/// at typical rates; each message is a few bytes).
const QUEUE_CAPACITY: usize = 64;

pub(crate) enum Message {
    KeyFrame(KeyFrameId),
    /// The map was reset: drop everything reconstructed so far.
    Reset,
}

pub(crate) enum SemiDenseWorker {
    Off,
    Inline(Box<SemiDenseMapper>),
    Thread {
        tx: Option<Sender<Message>>,
        handle: Option<JoinHandle<Box<SemiDenseMapper>>>,
        /// Keyframes not sent because the queue was full.
        dropped: usize,
        /// Raised by an interrupted `finish`: the thread drops its backlog instead of
        /// reconstructing it.
        cut: Arc<AtomicBool>,
    },
    /// After [`finish`](SemiDenseWorker::finish): the mapper with every result.
    Done(Box<SemiDenseMapper>),
    /// The thread panicked: its results are lost, the rest of the run is not.
    Failed,
}

impl SemiDenseWorker {
    pub fn spawn(
        mut mapper: Box<SemiDenseMapper>,
        map: Arc<Mutex<Map>>,
        nice: i32,
        idle: bool,
        cpus: Vec<usize>,
    ) -> Self {
        let (tx, rx) = bounded::<Message>(QUEUE_CAPACITY);
        let cut = Arc::new(AtomicBool::new(false));
        let cutting = Arc::clone(&cut);
        let handle = std::thread::Builder::new()
            .name("semidense".into())
            .spawn(move || {
                super::lower_current_thread_priority(nice);
                if idle {
                    super::set_current_thread_idle();
                }
                super::pin_current_thread(&cpus);
                let mut n = 0;
                while let Ok(m) = rx.recv() {
                    match m {
                        Message::KeyFrame(_) if cutting.load(Ordering::Relaxed) => mapper.cut(1),
                        Message::KeyFrame(kf) => {
                            n += 1;
                            super::faults::maybe_panic("panic:semidense", n);
                            mapper.on_keyframe(&map, kf)
                        }
                        Message::Reset => mapper.reset(),
                    }
                }
                if cutting.load(Ordering::Relaxed) {
                    mapper.flush_cut(&map);
                } else {
                    mapper.flush(&map);
                }
                mapper
            });
        match handle {
            Ok(h) => SemiDenseWorker::Thread {
                tx: Some(tx),
                handle: Some(h),
                dropped: 0,
                cut,
            },
            Err(_) => SemiDenseWorker::Failed,
        }
    }

    /// A keyframe was made (call without holding the map lock).
    pub fn keyframe(&mut self, map: &Mutex<Map>, kf: KeyFrameId) {
        match self {
            SemiDenseWorker::Inline(m) => m.on_keyframe(map, kf),
            SemiDenseWorker::Thread {
                tx: Some(tx),
                dropped,
                ..
            } => {
                if let Err(TrySendError::Full(_)) = tx.try_send(Message::KeyFrame(kf)) {
                    *dropped += 1;
                }
            }
            _ => {}
        }
    }

    pub fn reset(&mut self) {
        match self {
            SemiDenseWorker::Inline(m) => m.reset(),
            SemiDenseWorker::Thread { tx: Some(tx), .. } => {
                // Blocking: a reset must not be lost (it is rare and the queue drains).
                let _ = tx.send(Message::Reset);
            }
            _ => {}
        }
    }

    /// True when the thread has died before `finish` (it only ends early by panicking).
    pub fn has_failed(&self) -> bool {
        match self {
            SemiDenseWorker::Thread {
                handle: Some(h), ..
            } => h.is_finished(),
            SemiDenseWorker::Failed => true,
            _ => false,
        }
    }

    /// Reconstructs what is pending (or, with `cut`, drops the backlog and only checks what
    /// is reconstructed: an interrupted run ends within about one keyframe's time), joins the
    /// thread. False when the thread had panicked.
    pub fn finish(&mut self, map: &Mutex<Map>, cut: bool) -> bool {
        let state = std::mem::replace(self, SemiDenseWorker::Off);
        let (next, ok) = match state {
            SemiDenseWorker::Inline(mut m) => {
                if cut {
                    m.flush_cut(map);
                } else {
                    m.flush(map);
                }
                (SemiDenseWorker::Done(m), true)
            }
            SemiDenseWorker::Thread {
                tx,
                handle,
                dropped,
                cut: cutting,
            } => {
                cutting.store(cut, Ordering::Relaxed);
                drop(tx);
                match handle.map(|h| h.join()) {
                    Some(Ok(mut m)) => {
                        m.stats.keyframes_skipped += dropped;
                        m.stats.skipped_overload += dropped;
                        (SemiDenseWorker::Done(m), true)
                    }
                    _ => (SemiDenseWorker::Failed, false),
                }
            }
            SemiDenseWorker::Failed => (SemiDenseWorker::Failed, false),
            other => (other, true),
        };
        *self = next;
        ok
    }

    /// The mapper's results, once finished.
    pub fn mapper_mut(&mut self) -> Option<&mut SemiDenseMapper> {
        match self {
            SemiDenseWorker::Done(m) | SemiDenseWorker::Inline(m) => Some(m),
            _ => None,
        }
    }

    pub fn mapper(&self) -> Option<&SemiDenseMapper> {
        match self {
            SemiDenseWorker::Done(m) | SemiDenseWorker::Inline(m) => Some(m),
            _ => None,
        }
    }
}
