//! A second thread for one borrowed job at a time: [`Helper::join`] runs one closure on the
//! helper while the caller runs the other, and returns when both are done, like
//! `std::thread::scope` but without spawning a thread (or allocating) per call. A thread pool
//! entered from outside (rayon's `install`/`join`) queues each call in a segmented injector
//! that allocates a new segment every 63 calls, which breaks tracking's zero-allocation rule.

use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;

/// A job on the caller's stack, type- and lifetime-erased. Only [`Helper::join`] makes one,
/// and it does not return before the helper has finished with it.
struct JobPtr(*mut (dyn FnMut() + Send + 'static));

// SAFETY: the pointee is `Send` (enforced by `join`'s bound), and it is only touched by the
// helper between being posted and `done` being set, while the caller waits.
unsafe impl Send for JobPtr {}

#[derive(Default)]
struct Slot {
    job: Option<JobPtr>,
    done: bool,
    panicked: bool,
    quit: bool,
}

#[derive(Default)]
struct Shared {
    slot: Mutex<Slot>,
    posted: Condvar,
    finished: Condvar,
}

fn lock(m: &Mutex<Slot>) -> MutexGuard<'_, Slot> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

pub struct Helper {
    shared: Arc<Shared>,
    handle: Option<JoinHandle<()>>,
}

impl Helper {
    /// Starts the helper thread; `None` when no thread can be started.
    pub fn spawn(name: &str) -> Option<Self> {
        let shared = Arc::new(Shared::default());
        let s = Arc::clone(&shared);
        let handle = std::thread::Builder::new()
            .name(name.into())
            .spawn(move || loop {
                let job = {
                    let mut slot = lock(&s.slot);
                    loop {
                        if slot.quit {
                            return;
                        }
                        if let Some(j) = slot.job.take() {
                            break j;
                        }
                        slot = s.posted.wait(slot).unwrap_or_else(|e| e.into_inner());
                    }
                };
                // SAFETY: `join` keeps the closure alive and untouched until `done` is set.
                let f = unsafe { &mut *job.0 };
                let ok = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).is_ok();
                let mut slot = lock(&s.slot);
                slot.done = true;
                slot.panicked = !ok;
                s.finished.notify_all();
            })
            .ok()?;
        Some(Helper {
            shared,
            handle: Some(handle),
        })
    }

    /// Runs `on_helper` on the helper thread and `here` on the calling thread; returns when
    /// both have finished. A panic in either is resumed here, after both have finished.
    /// (`&mut self`: one job at a time.)
    pub fn join<A: FnOnce() + Send, B: FnOnce()>(&mut self, on_helper: A, here: B) {
        let mut once = Some(on_helper);
        let mut call = move || {
            if let Some(f) = once.take() {
                f()
            }
        };
        let ptr: *mut (dyn FnMut() + Send + '_) = &mut call;
        // SAFETY: only the lifetime is erased; `Wait` below blocks until the helper has
        // finished with the closure, on every way out of this function (unwinding included).
        let ptr: *mut (dyn FnMut() + Send + 'static) = unsafe { std::mem::transmute(ptr) };
        {
            let mut slot = lock(&self.shared.slot);
            slot.job = Some(JobPtr(ptr));
            slot.done = false;
            self.shared.posted.notify_one();
        }
        /// Waits for the helper's `done` when dropped (so also when `here` panics). A job the
        /// helper has not picked up yet (its thread not scheduled: both cores busy with local
        /// BA, say) is taken back and run here instead of waited for.
        struct Wait<'a>(&'a Shared);
        impl Drop for Wait<'_> {
            fn drop(&mut self) {
                let mut slot = lock(&self.0.slot);
                if let Some(job) = slot.job.take() {
                    drop(slot);
                    // After a panic in `here` the other half is not run, only released.
                    let ok = std::thread::panicking() || {
                        // SAFETY: taken back from the slot, so the helper never sees it; the
                        // closure lives on `join`'s stack until this guard is dropped.
                        let f = unsafe { &mut *job.0 };
                        std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).is_ok()
                    };
                    let mut slot = lock(&self.0.slot);
                    slot.done = true;
                    slot.panicked = !ok;
                    return;
                }
                while !slot.done {
                    slot = self
                        .0
                        .finished
                        .wait(slot)
                        .unwrap_or_else(|e| e.into_inner());
                }
            }
        }
        let wait = Wait(&self.shared);
        here();
        drop(wait);
        if lock(&self.shared.slot).panicked {
            panic!("ORB helper thread panicked");
        }
    }
}

impl Drop for Helper {
    fn drop(&mut self) {
        lock(&self.shared.slot).quit = true;
        self.shared.posted.notify_all();
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_halves_run_and_borrow_the_callers_data() {
        let mut h = Helper::spawn("test-helper").unwrap();
        let mut a = vec![0u32; 1000];
        let mut b = vec![0u32; 1000];
        for round in 1..=100u32 {
            let (x, y) = (&mut a, &mut b);
            h.join(
                || x.iter_mut().for_each(|v| *v += round),
                || y.iter_mut().for_each(|v| *v += 2 * round),
            );
        }
        assert!(a.iter().all(|&v| v == 5050));
        assert!(b.iter().all(|&v| v == 10100));
    }

    #[test]
    fn a_job_the_helper_has_not_started_runs_on_the_caller() {
        // A helper whose thread never runs: every job is taken back by the caller.
        let mut h = Helper {
            shared: Arc::new(Shared::default()),
            handle: None,
        };
        let (mut a, mut b) = (0, 0);
        for _ in 0..3 {
            h.join(|| a += 1, || b += 1);
        }
        assert_eq!((a, b), (3, 3));
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            h.join(|| panic!("boom"), || {})
        }));
        assert!(r.is_err(), "a panic in the stolen half reaches the caller");
    }

    #[test]
    fn a_panic_on_the_helper_reaches_the_caller_and_the_helper_survives() {
        let mut h = Helper::spawn("test-helper").unwrap();
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            h.join(|| panic!("boom"), || {})
        }));
        assert!(r.is_err());
        let mut ran = false;
        h.join(|| ran = true, || {});
        assert!(ran);
    }
}
