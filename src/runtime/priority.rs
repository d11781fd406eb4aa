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
}
