//! Ending a run: joining the mapping threads, the final full BA, the semi-dense backlog
//! (reconstructed, or cut on an interrupt), and what is freed before the outputs are written.

use super::*;

impl System {
    /// Ends the run: [`finish_tracking`](Self::finish_tracking), then
    /// [`finish_semidense`](Self::finish_semidense) with the whole backlog reconstructed.
    /// Returns false when a thread had panicked (what it had not finished is lost; the map
    /// and everything else are still usable).
    pub fn finish(&mut self) -> bool {
        let ok = self.finish_tracking();
        self.finish_semidense(false) && ok
    }

    /// Stops the mapping thread after it has processed every queued keyframe and joins it,
    /// tracks the frames still waiting for the initial backfill and runs the final full BA:
    /// afterwards the trajectory, keyframes and map are final. False when the mapping thread
    /// had panicked (the map is still usable).
    pub fn finish_tracking(&mut self) -> bool {
        let mut ok = true;
        if let Some((joined, timer, loops)) = self.mapping.join() {
            ok = joined;
            if let Some(t) = timer {
                self.stats.local_mapping = t;
            }
            if let Some(t) = loops.timer {
                self.stats.loop_closing = t;
            }
            self.stats.loops_closed = loops.loops_closed;
            self.stats.loops_closed_by_revisit = loops.revisits_closed;
            self.stats.loop_closures = loops.history;
        }
        if let Some(s) = self.init_solver.as_mut() {
            s.join();
        }
        if self.backfill.active() {
            let map_arc = Arc::clone(&self.map);
            let mut m = lock(&map_arc);
            self.backfill_step(&mut m, usize::MAX);
        }
        // Final full BA (every keyframe and point; the first keyframe fixed) before the last
        // semi-dense keyframes are reconstructed, so they and the cloud use the refined poses.
        if self.final_ba && !self.finished && !self.localize_only {
            let map_arc = Arc::clone(&self.map);
            let mut m = lock(&map_arc);
            if m.n_keyframes() >= 3 {
                let t = Instant::now();
                self.global_ba(&mut m, self.limits.final_ba_iterations);
                self.stats.final_ba_ms = t.elapsed().as_secs_f64() * 1e3;
            }
        }
        self.finished = true;
        ok
    }

    /// After [`finish_tracking`](Self::finish_tracking): reconstructs the keyframes still
    /// waiting for semi-dense mapping, or with `cut` (an interrupted run) drops them, counted
    /// in the semi-dense stats, and joins that thread. False when it had panicked.
    pub fn finish_semidense(&mut self, cut: bool) -> bool {
        if !self.finished {
            self.finish_tracking();
        }
        self.semidense.finish(&self.map, cut)
    }

    /// After [`finish`](Self::finish): frees what only running needed (the semi-dense
    /// gradient cache and per-pixel buffers, its worker threads, keyframe images), so writing
    /// the outputs does not add to the run's peak memory. Poses, map, cloud and depth maps
    /// stay readable; nothing can be processed afterwards.
    pub fn release_working_memory(&mut self) {
        if !self.finished {
            return;
        }
        if let Some(m) = self.semidense.mapper_mut() {
            m.release_working_memory();
        }
        lock(&self.map).release_images();
    }
}

impl Drop for System {
    /// Joins every thread. Not while unwinding from a panic: a second panic there would abort
    /// the process before the caller's outputs are written.
    fn drop(&mut self) {
        if !std::thread::panicking() {
            self.finish();
        }
    }
}
