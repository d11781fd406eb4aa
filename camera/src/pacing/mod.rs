//! Pacing of a source on its own thread: as fast as possible (every frame, in order) or in
//! real time (frames released at their timestamps; a slow consumer loses the oldest queued
//! frames and the source never blocks). Frame buffers circulate through a fixed pool, so
//! steady-state pacing allocates nothing.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crossbeam_channel::{bounded, Receiver, RecvTimeoutError, Sender, TryRecvError, TrySendError};

use crate::{Frame, FrameSource, FrameStatus, SourceError, SourceInfo};

/// How frames are released to the consumer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Pacing {
    /// Every frame, as soon as it is decoded; the source waits for the consumer.
    AsFastAsPossible,
    /// Frames released at their timestamps divided by `speed` (1.0 = recorded rate).
    RealTime { speed: f64 },
    /// A live camera: frames released as the device delivers them; a slow consumer loses the
    /// oldest queued frames (the newest always wins) and the device is never held up.
    Live,
}

impl Pacing {
    /// True when a slow consumer loses the oldest frames rather than holding up the source.
    pub fn drops_oldest(self) -> bool {
        !matches!(self, Pacing::AsFastAsPossible)
    }
}

/// Counters shared with the source thread.
#[derive(Debug, Default)]
pub struct PacingStats {
    dropped: AtomicU64,
    delivered: AtomicU64,
}

impl PacingStats {
    /// Frames the consumer never saw because it was too slow (real-time pacing only).
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
    pub fn delivered(&self) -> u64 {
        self.delivered.load(Ordering::Relaxed)
    }
}

enum Msg {
    Frame(Frame),
    Skipped { index: u64, reason: String },
    End,
    Error(SourceError),
}

/// A source running on its own thread behind a bounded queue.
pub struct PacedSource {
    info: SourceInfo,
    rx: Receiver<Msg>,
    pool_tx: Sender<Frame>,
    stats: Arc<PacingStats>,
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<()>>,
    ended: bool,
    /// Polled while waiting for a frame: true ends the stream (Ctrl-C while a replay waits
    /// for a far-off timestamp, or a camera that stopped delivering).
    interrupt: Option<fn() -> bool>,
}

/// Longest single sleep or wait, so a stop request or an interrupt is seen within it.
const POLL: Duration = Duration::from_millis(50);

/// Sleeps until `at` in slices of [`POLL`]; false when `stop` was raised meanwhile.
fn sleep_until(at: Instant, stop: &AtomicBool) -> bool {
    loop {
        if stop.load(Ordering::Relaxed) {
            return false;
        }
        let now = Instant::now();
        if at <= now {
            return true;
        }
        std::thread::sleep((at - now).min(POLL));
    }
}

/// Queue capacity between source and consumer: small, so the consumer always gets a fresh frame.
pub const QUEUE_CAPACITY: usize = 2;

impl PacedSource {
    /// Starts `source` on a thread named `source`.
    pub fn spawn<S: FrameSource + 'static>(
        mut source: S,
        pacing: Pacing,
    ) -> Result<Self, SourceError> {
        let info = source.info().clone();
        let (tx, rx) = bounded::<Msg>(QUEUE_CAPACITY);
        // Pool: queue + one being filled + one spare, so the producer rarely waits.
        let pool_size = QUEUE_CAPACITY + 2;
        let (pool_tx, pool_rx) = bounded::<Frame>(pool_size + 1);
        for _ in 0..pool_size {
            let _ = pool_tx.send(Frame::new(info.width, info.height));
        }
        let stats = Arc::new(PacingStats::default());
        let stop = Arc::new(AtomicBool::new(false));
        let (st, sp, steal_rx) = (stats.clone(), stop.clone(), rx.clone());
        let handle = std::thread::Builder::new()
            .name("source".into())
            .spawn(move || produce(&mut source, pacing, tx, steal_rx, pool_rx, &st, &sp))
            .map_err(|e| SourceError::Thread(e.to_string()))?;
        Ok(PacedSource {
            info,
            rx,
            pool_tx,
            stats,
            stop,
            handle: Some(handle),
            ended: false,
            interrupt: None,
        })
    }

    /// Ends the stream (`next_frame` returns `End`) as soon as `interrupted` returns true,
    /// even while waiting for a frame that is not due yet.
    pub fn set_interrupt(&mut self, interrupted: fn() -> bool) {
        self.interrupt = Some(interrupted);
    }

    pub fn stats(&self) -> Arc<PacingStats> {
        self.stats.clone()
    }

    /// Stops the source thread and joins it.
    pub fn shutdown(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        while self.rx.try_recv().is_ok() {}
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

impl Drop for PacedSource {
    fn drop(&mut self) {
        self.shutdown();
    }
}

fn produce<S: FrameSource>(
    source: &mut S,
    pacing: Pacing,
    tx: Sender<Msg>,
    steal_rx: Receiver<Msg>,
    pool_rx: Receiver<Frame>,
    stats: &PacingStats,
    stop: &AtomicBool,
) {
    let start = Instant::now();
    let mut t0: Option<f64> = None;
    let mut recycled: Option<Frame> = None;
    // Real time: when to start reading (decoding) the next frame, and how long a read takes.
    let mut read_at: Option<Instant> = None;
    let mut last_due: Option<Instant> = None;
    let mut read_time = Duration::from_millis(5);
    loop {
        if stop.load(Ordering::Relaxed) {
            return;
        }
        // A buffer: recycled from a dropped frame, from the pool, or (real time) steal the
        // oldest queued frame rather than wait for the consumer.
        let mut buf = match recycled.take() {
            Some(b) => b,
            None => match acquire(&pool_rx, &steal_rx, pacing, stats, stop) {
                Some(b) => b,
                None => return,
            },
        };
        // A camera's frame costs the consumer nothing before it is due, so a replay decodes
        // the next frame just before then, not right after releasing this one, when the
        // consumer is busiest with it (decoding a 640x480 JPEG takes a core for ~4 ms).
        if let Some(at) = read_at.take() {
            if !sleep_until(at, stop) {
                return;
            }
        }
        let t_read = Instant::now();
        let msg = match source.next_frame(&mut buf) {
            Ok(FrameStatus::Ready) => {
                if let Pacing::RealTime { speed } = pacing {
                    read_time = (read_time * 3 + t_read.elapsed()) / 4;
                    let t0 = *t0.get_or_insert(buf.timestamp);
                    let due = start
                        + Duration::from_secs_f64(
                            ((buf.timestamp - t0) / speed.max(1e-6)).max(0.0),
                        );
                    if !sleep_until(due, stop) {
                        return;
                    }
                    // The next frame is expected one interval later; its read starts twice
                    // a read's time (plus 2 ms for jitter) before that.
                    if let Some(prev) = last_due.filter(|p| due > *p) {
                        let lead = read_time * 2 + Duration::from_millis(2);
                        read_at = (due + (due - prev)).checked_sub(lead);
                    }
                    last_due = Some(due);
                }
                buf.arrival = Some(Instant::now());
                Msg::Frame(buf)
            }
            Ok(FrameStatus::Skipped { index, reason }) => {
                recycled = Some(buf);
                Msg::Skipped { index, reason }
            }
            Ok(FrameStatus::End) => Msg::End,
            Err(e) => Msg::Error(e),
        };
        let last = matches!(msg, Msg::End | Msg::Error(_));
        if !deliver(msg, &tx, &steal_rx, pacing, stats, stop, &mut recycled) || last {
            return;
        }
    }
}

fn acquire(
    pool_rx: &Receiver<Frame>,
    steal_rx: &Receiver<Msg>,
    pacing: Pacing,
    stats: &PacingStats,
    stop: &AtomicBool,
) -> Option<Frame> {
    loop {
        match pool_rx.try_recv() {
            Ok(b) => return Some(b),
            Err(TryRecvError::Disconnected) => return None,
            Err(TryRecvError::Empty) => {}
        }
        if pacing.drops_oldest() {
            if let Ok(Msg::Frame(old)) = steal_rx.try_recv() {
                stats.dropped.fetch_add(1, Ordering::Relaxed);
                return Some(old);
            }
        }
        match pool_rx.recv_timeout(Duration::from_millis(20)) {
            Ok(b) => return Some(b),
            Err(RecvTimeoutError::Disconnected) => return None,
            Err(RecvTimeoutError::Timeout) if stop.load(Ordering::Relaxed) => return None,
            Err(RecvTimeoutError::Timeout) => {}
        }
    }
}

/// Sends `msg`; in real time a full queue loses its oldest frame instead of blocking.
fn deliver(
    mut msg: Msg,
    tx: &Sender<Msg>,
    steal_rx: &Receiver<Msg>,
    pacing: Pacing,
    stats: &PacingStats,
    stop: &AtomicBool,
    recycled: &mut Option<Frame>,
) -> bool {
    let is_frame = matches!(msg, Msg::Frame(_));
    loop {
        match tx.try_send(msg) {
            Ok(()) => {
                if is_frame {
                    stats.delivered.fetch_add(1, Ordering::Relaxed);
                }
                return true;
            }
            Err(TrySendError::Disconnected(_)) => return false,
            Err(TrySendError::Full(m)) => {
                msg = m;
                if pacing.drops_oldest() {
                    if let Ok(old) = steal_rx.try_recv() {
                        if let Msg::Frame(f) = old {
                            stats.dropped.fetch_add(1, Ordering::Relaxed);
                            if recycled.is_none() {
                                *recycled = Some(f);
                            }
                        }
                        continue;
                    }
                }
                if stop.load(Ordering::Relaxed) {
                    return false;
                }
                match tx.send_timeout(msg, Duration::from_millis(20)) {
                    Ok(()) => {
                        if is_frame {
                            stats.delivered.fetch_add(1, Ordering::Relaxed);
                        }
                        return true;
                    }
                    Err(crossbeam_channel::SendTimeoutError::Timeout(m)) => msg = m,
                    Err(crossbeam_channel::SendTimeoutError::Disconnected(_)) => return false,
                }
            }
        }
    }
}

impl FrameSource for PacedSource {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    /// Swaps the next queued frame into `out` and returns `out`'s old buffer to the pool.
    fn next_frame(&mut self, out: &mut Frame) -> Result<FrameStatus, SourceError> {
        if self.ended {
            return Ok(FrameStatus::End);
        }
        let received = loop {
            match self.rx.recv_timeout(POLL) {
                Ok(m) => break Ok(m),
                Err(RecvTimeoutError::Disconnected) => break Err(()),
                Err(RecvTimeoutError::Timeout) => {
                    if self.interrupt.is_some_and(|f| f()) {
                        self.ended = true;
                        return Ok(FrameStatus::End);
                    }
                }
            }
        };
        match received {
            Ok(Msg::Frame(mut f)) => {
                std::mem::swap(out, &mut f);
                if f.len() == out.len() {
                    let _ = self.pool_tx.try_send(f);
                }
                Ok(FrameStatus::Ready)
            }
            Ok(Msg::Skipped { index, reason }) => Ok(FrameStatus::Skipped { index, reason }),
            Ok(Msg::End) => {
                self.ended = true;
                Ok(FrameStatus::End)
            }
            // The source thread went away without saying End: it panicked.
            Err(_) => {
                self.ended = true;
                let why = match self.handle.take().map(|h| h.join()) {
                    Some(Err(p)) => p
                        .downcast_ref::<&str>()
                        .map(|s| s.to_string())
                        .or_else(|| p.downcast_ref::<String>().cloned())
                        .unwrap_or_else(|| "unknown panic".into()),
                    _ => "it stopped without ending the stream".into(),
                };
                Err(SourceError::Thread(format!(
                    "the source thread failed: {why}"
                )))
            }
            Ok(Msg::Error(e)) => {
                self.ended = true;
                Err(e)
            }
        }
    }
}

#[cfg(test)]
mod tests;
