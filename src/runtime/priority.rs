//! Thread priorities: tracking keeps the default priority; background work (semi-dense
//! mapping) runs "nicer" so that on a 2-core robot computer the scheduler always prefers the
//! frame-rate-bound tracking thread. The semi-dense thread degrades first, never tracking.

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
}
