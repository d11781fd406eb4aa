//! Fault injection for tests of the failure paths: `SDSLAM_FAULT=panic:local_mapping` (or
//! `panic:semidense`) makes that thread panic at its fifth keyframe, so tests can check that a
//! dying thread is reported, the run stops cleanly and every output is still written;
//! `interrupt:semidense_final` sends the CLI a Ctrl-C as its end-of-session pass starts. Read once;
//! costs one comparison per keyframe otherwise.

use std::sync::OnceLock;

/// True when the environment asks for fault `point`.
pub fn injected(point: &str) -> bool {
    static FAULT: OnceLock<Option<String>> = OnceLock::new();
    FAULT
        .get_or_init(|| std::env::var("SDSLAM_FAULT").ok())
        .as_deref()
        == Some(point)
}

/// Panics when fault `point` is injected and `count` reached the fifth keyframe.
pub fn maybe_panic(point: &str, count: usize) {
    if count == 5 && injected(point) {
        panic!("injected fault `{point}` (SDSLAM_FAULT)");
    }
}
