//! Thread priorities: tracking keeps the default priority; background work (semi-dense
//! mapping) runs "nicer" so that on a 2-core robot computer the scheduler always prefers the
//! frame-rate-bound tracking thread. The semi-dense thread degrades first, never tracking.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Lowers the calling thread's scheduling priority by `nice` (Linux: per-thread nice value;
/// 0 leaves it; no effect on other systems). Failure (e.g. a sandbox forbidding it) is not
/// an error: the thread simply keeps its priority.
pub fn lower_current_thread_priority(nice: i32) {
    if nice <= 0 {
        return;
    }
    #[cfg(target_os = "linux")]
    // SAFETY: gettid and setpriority only read their integer arguments; on Linux,
    // PRIO_PROCESS with a thread id applies to that thread alone.
    unsafe {
        let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
        let _ = libc::setpriority(libc::PRIO_PROCESS, tid, nice);
    }
}

/// Puts the calling thread in Linux's SCHED_IDLE class: it runs only on a CPU nothing else
/// wants, and a waking tracking thread preempts it at once instead of waiting for the fair
/// scheduler to balance a niced thread out (measured on desk: the 40-47 ms spikes and the
/// deadline misses went away). No effect elsewhere; failure leaves the priority as it was.
pub fn set_current_thread_idle() {
    #[cfg(target_os = "linux")]
    // SAFETY: gettid reads nothing; sched_setscheduler reads the param struct we pass, and a
    // thread id applies to that thread alone.
    unsafe {
        let tid = libc::syscall(libc::SYS_gettid) as libc::pid_t;
        let param = libc::sched_param { sched_priority: 0 };
        let _ = libc::sched_setscheduler(tid, libc::SCHED_IDLE, &param);
    }
}

/// Lets background workers step aside while the frame-rate-bound thread works. The two vCPUs
/// of the target machines share execution units like SMT siblings, so a semi-dense worker on
/// the other core slows ORB extraction from ~5 to ~9 ms; scheduling classes cannot help with
/// that, only not running. Tracking holds the gate for a frame ([`ForegroundGate::busy`]);
/// workers call [`ForegroundGate::wait`] between units of work (rows).
#[derive(Clone, Debug, Default)]
pub struct ForegroundGate(Arc<GateState>);

#[derive(Debug)]
struct GateState {
    busy: AtomicBool,
    origin: Instant,
    /// When the last busy period ended, microseconds after `origin` (0: none yet).
    last_end_us: AtomicU64,
    /// The idle time before the current (or last) busy period, microseconds.
    last_gap_us: AtomicU64,
}

impl Default for GateState {
    fn default() -> Self {
        GateState {
            busy: AtomicBool::new(false),
            origin: Instant::now(),
            last_end_us: AtomicU64::new(0),
            last_gap_us: AtomicU64::new(0),
        }
    }
}

impl GateState {
    fn now_us(&self) -> u64 {
        (self.origin.elapsed().as_micros() as u64).max(1)
    }
}

/// Longest a worker waits for one frame (more than a frame budget): a stalled tracking thread
/// does not stall the background for good.
const MAX_GATE_WAIT: Duration = Duration::from_millis(40);

/// Idle time between busy periods above which the foreground is paced (frames arrive in real
/// time, leaving gaps), not saturated (frames back to back).
const PACED_GAP: Duration = Duration::from_millis(2);

impl ForegroundGate {
    /// Marks the foreground busy until the returned guard is dropped.
    pub fn busy(&self) -> ForegroundBusy<'_> {
        let g = &self.0;
        let end = g.last_end_us.load(Ordering::Relaxed);
        if end > 0 {
            let gap = g.now_us().saturating_sub(end);
            g.last_gap_us.store(gap, Ordering::Relaxed);
        }
        g.busy.store(true, Ordering::Release);
        ForegroundBusy(g)
    }

    /// Whether the foreground left a gap of more than 2 ms before its current or last busy
    /// period: work that waits for the gap then still progresses. With frames back to back
    /// (offline replay), waiting for each frame would hold background work back instead.
    pub fn paced(&self) -> bool {
        self.0.last_gap_us.load(Ordering::Relaxed) > PACED_GAP.as_micros() as u64
    }

    /// Returns once the foreground is idle (sleeping 100 us at a time, at most 40 ms).
    pub fn wait(&self) {
        let busy = &self.0.busy;
        if !busy.load(Ordering::Acquire) {
            return;
        }
        let t = Instant::now();
        while busy.load(Ordering::Acquire) && t.elapsed() < MAX_GATE_WAIT {
            std::thread::sleep(Duration::from_micros(100));
        }
    }
}

/// The foreground is busy while this lives.
pub struct ForegroundBusy<'a>(&'a GateState);

impl Drop for ForegroundBusy<'_> {
    fn drop(&mut self) {
        self.0.last_end_us.store(self.0.now_us(), Ordering::Relaxed);
        self.0.busy.store(false, Ordering::Release);
    }
}

/// Pins the calling thread to the given CPUs (Linux; empty = leave it; threads it spawns
/// afterwards inherit the set). Returns false when the system refused (e.g. a CPU that does
/// not exist), leaving the affinity as it was.
pub fn pin_current_thread(cpus: &[usize]) -> bool {
    if cpus.is_empty() {
        return true;
    }
    #[cfg(target_os = "linux")]
    {
        // SAFETY: cpu_set_t is plain data; CPU_ZERO/CPU_SET write within it (indices checked
        // against its size); sched_setaffinity(0, ..) reads it for the calling thread.
        unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            libc::CPU_ZERO(&mut set);
            for &c in cpus {
                if c >= 8 * std::mem::size_of::<libc::cpu_set_t>() {
                    return false;
                }
                libc::CPU_SET(c, &mut set);
            }
            libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) == 0
        }
    }
    #[cfg(not(target_os = "linux"))]
    {
        false
    }
}

#[cfg(test)]
mod tests {
    #[test]
    #[cfg(target_os = "linux")]
    fn lowers_only_the_calling_thread() {
        let before = unsafe { libc::getpriority(libc::PRIO_PROCESS, 0) };
        let inside = std::thread::spawn(|| {
            super::lower_current_thread_priority(5);
            let tid = unsafe { libc::syscall(libc::SYS_gettid) } as libc::id_t;
            unsafe { libc::getpriority(libc::PRIO_PROCESS, tid) }
        })
        .join()
        .unwrap();
        assert_eq!(inside, (before + 5).min(19));
        assert_eq!(unsafe { libc::getpriority(libc::PRIO_PROCESS, 0) }, before);
    }

    #[test]
    #[cfg(target_os = "linux")]
    fn pins_a_thread_to_cpu_0_and_refuses_impossible_cpus() {
        std::thread::spawn(|| {
            assert!(super::pin_current_thread(&[0]));
            assert_eq!(unsafe { libc::sched_getcpu() }, 0);
            assert!(!super::pin_current_thread(&[1 << 20]));
        })
        .join()
        .unwrap();
    }

    #[test]
    #[cfg(target_os = "linux")]
    fn idle_class_applies_to_the_calling_thread_only() {
        let policy = std::thread::spawn(|| {
            super::set_current_thread_idle();
            unsafe { libc::sched_getscheduler(0) }
        })
        .join()
        .unwrap();
        assert_eq!(policy, libc::SCHED_IDLE);
        assert_ne!(unsafe { libc::sched_getscheduler(0) }, libc::SCHED_IDLE);
    }

    #[test]
    fn gate_waits_while_the_foreground_is_busy() {
        use std::time::{Duration, Instant};
        let gate = super::ForegroundGate::default();
        let t = Instant::now();
        gate.wait();
        // An idle gate does not wait at all (a wrong wait would last its 40 ms bound).
        assert!(
            t.elapsed() < Duration::from_millis(30),
            "idle gate: no wait"
        );
        let g2 = gate.clone();
        let (tx, rx) = std::sync::mpsc::channel();
        let fg = std::thread::spawn(move || {
            let _busy = g2.busy();
            tx.send(Instant::now()).unwrap();
            std::thread::sleep(Duration::from_millis(15));
        });
        // The wait ends when the foreground's 15 ms are over, measured from when it became
        // busy (this thread may start waiting late: under emulation it does).
        let busy_since = rx.recv().unwrap();
        gate.wait();
        let since = busy_since.elapsed();
        fg.join().unwrap();
        assert!(
            since >= Duration::from_millis(14),
            "returned after {since:?}"
        );
        // Bounded: a foreground that never finishes holds workers for at most 40 ms.
        let _stuck = gate.busy();
        let t = Instant::now();
        gate.wait();
        assert!(t.elapsed() < Duration::from_secs(1));
    }

    #[test]
    fn gate_tells_paced_frames_from_back_to_back_ones() {
        use std::time::Duration;
        let gate = super::ForegroundGate::default();
        assert!(!gate.paced(), "no frame yet");
        for _ in 0..3 {
            drop(gate.busy());
        }
        assert!(!gate.paced(), "back to back");
        std::thread::sleep(Duration::from_millis(5));
        let busy = gate.busy();
        assert!(gate.paced(), "after a 5 ms gap");
        drop(busy);
        drop(gate.busy());
        assert!(!gate.paced(), "back to back again");
    }
}
