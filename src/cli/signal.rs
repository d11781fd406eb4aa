//! Ctrl-C, SIGTERM and SIGHUP (an SSH session closing): the first one asks the run to stop
//! cleanly (join threads, write every output); a second one kills the process as usual.
//! SIGXFSZ is ignored, so a file size limit (`ulimit -f`) makes a write fail with an error
//! (reported, the other outputs still written) instead of killing the process.

use std::sync::atomic::{AtomicBool, Ordering};

static INTERRUPTED: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(sig: libc::c_int) {
    if INTERRUPTED.swap(true, Ordering::SeqCst) {
        // Second signal: back to the default action (terminate).
        // SAFETY: signal() and raise() are async-signal-safe.
        unsafe {
            libc::signal(sig, libc::SIG_DFL);
            libc::raise(sig);
        }
    }
}

/// Installs the handler for SIGINT, SIGTERM and SIGHUP, and ignores SIGXFSZ.
pub fn install() {
    // SAFETY: the handler only touches an atomic and async-signal-safe calls.
    unsafe {
        let handler = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
        libc::signal(libc::SIGINT, handler);
        libc::signal(libc::SIGTERM, handler);
        libc::signal(libc::SIGHUP, handler);
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
}

/// True once Ctrl-C (or SIGTERM, SIGHUP) arrived.
pub fn interrupted() -> bool {
    INTERRUPTED.load(Ordering::Relaxed)
}
