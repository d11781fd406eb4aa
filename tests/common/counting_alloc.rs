//! A global allocator that counts allocations made by the current thread while counting is on,
//! for the no-allocation-per-frame tests (other test threads do not interfere).
#![allow(dead_code)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

pub struct Counting;

thread_local! {
    static COUNT: Cell<Option<u64>> = const { Cell::new(None) };
}

/// Allocations by any thread while [`ALL_ON`] is set (for code with worker threads; use in a
/// test binary with a single test so other tests do not interfere).
static ALL: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
static ALL_ON: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

fn bump() {
    if ALL_ON.load(std::sync::atomic::Ordering::Relaxed) {
        ALL.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    }
    let _ = COUNT.try_with(|c| {
        if let Some(n) = c.get() {
            c.set(Some(n + 1));
        }
    });
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        bump();
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        bump();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

/// Counts heap allocations made by this thread while running `f`.
pub fn allocations_in<R>(f: impl FnOnce() -> R) -> (R, u64) {
    COUNT.with(|c| c.set(Some(0)));
    let r = f();
    let n = COUNT.with(|c| c.replace(None)).unwrap_or(0);
    (r, n)
}

/// Counts heap allocations made by every thread of the process while running `f`.
pub fn allocations_by_all_threads_in<R>(f: impl FnOnce() -> R) -> (R, u64) {
    use std::sync::atomic::Ordering;
    ALL.store(0, Ordering::SeqCst);
    ALL_ON.store(true, Ordering::SeqCst);
    let r = f();
    ALL_ON.store(false, Ordering::SeqCst);
    (r, ALL.load(Ordering::SeqCst))
}
