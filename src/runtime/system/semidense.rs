//! The semi-dense results a `System` hands out: the online mapper and its cloud, and the
//! paper's end-of-session reconstruction ("after a full bundle adjustment") with its own
//! mapper over the final map.

use super::*;
use crate::config::SemiDenseConfig;
use crate::geometry::CloudPoint;

/// The end-of-session semi-dense reconstruction: its settings and, once run, its mapper.
pub(super) struct FinalSemiDense {
    config: SemiDenseConfig,
    max_keyframes: usize,
    max_features: usize,
    mapper: Option<Box<SemiDenseMapper>>,
}

impl FinalSemiDense {
    pub(super) fn new(config: &Config, max_features: usize) -> Self {
        FinalSemiDense {
            config: config.semidense.clone(),
            max_keyframes: config.map.max_keyframes,
            max_features,
            mapper: None,
        }
    }
}

impl System {
    /// Semi-dense results (after [`finish`](Self::finish), or inline mode at any time).
    pub fn semidense(&self) -> Option<&SemiDenseMapper> {
        self.semidense.mapper()
    }

    /// The semi-dense cloud of the primary map (see [`System::atlas`]) in world coordinates
    /// with the current keyframe poses.
    pub fn semidense_cloud(&self) -> Vec<CloudPoint> {
        self.primary_cloud(self.semidense())
    }

    /// The end-of-session results, once [`reconstruct_semidense_final`](Self::reconstruct_semidense_final) ran.
    pub fn semidense_final(&self) -> Option<&SemiDenseMapper> {
        self.final_semidense.mapper.as_deref()
    }

    /// The end-of-session cloud of the primary map; empty when it was not run.
    pub fn semidense_final_cloud(&self) -> Vec<CloudPoint> {
        self.primary_cloud(self.semidense_final())
    }

    /// `mapper`'s cloud of the primary map (empty without a mapper).
    fn primary_cloud(&self, mapper: Option<&SemiDenseMapper>) -> Vec<CloudPoint> {
        let mut out = Vec::new();
        let primary = self.atlas().primary;
        if let Some(m) = mapper {
            m.cloud_of(&lock(&self.map), primary, &mut out);
        }
        out
    }

    /// The paper's end-of-session reconstruction ("after a full bundle adjustment"): after
    /// [`finish`](Self::finish) (with the final BA on), every keyframe of the map now is
    /// reconstructed with its covisible neighbours of the final map (loop revisits
    /// included) and checked against all of them, at normal priority: two keyframes at a
    /// time (one per core) when `[semidense] threads` >= 2. The online results stay as they are. Call before
    /// [`release_working_memory`](Self::release_working_memory) (it needs the keyframe
    /// images). Returns the new results; `None` when semi-dense mapping is off or the run
    /// is not finished.
    pub fn reconstruct_semidense_final(&mut self) -> Option<&SemiDenseMapper> {
        self.reconstruct_semidense_final_until(&|| false)
    }

    /// [`reconstruct_semidense_final`](Self::reconstruct_semidense_final) that stops
    /// taking keyframes once `stop` says so (Ctrl-C): the incomplete pass is dropped and
    /// `None` returned; the online results stay as they are.
    pub fn reconstruct_semidense_final_until(
        &mut self,
        stop: &(dyn Fn() -> bool + Sync),
    ) -> Option<&SemiDenseMapper> {
        if !self.finished || !self.final_semidense.config.enabled {
            return None;
        }
        if let Some(m) = self.semidense.mapper_mut() {
            m.release_working_memory();
        }
        let f = &mut self.final_semidense;
        let config = SemiDenseConfig {
            // Tracking is over: the workers need not step aside.
            nice: 0,
            sched_idle: false,
            yield_to_tracking: false,
            ..f.config.clone()
        };
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        let mut mapper = Box::new(SemiDenseMapper::new(
            self.camera.intrinsics(),
            w,
            h,
            &config,
            f.max_keyframes,
            f.max_features,
        ));
        let keyframes: Vec<KeyFrameId> = {
            let m = lock(&self.map);
            let mut k: Vec<(u64, KeyFrameId)> =
                m.keyframes().map(|(id, k)| (k.serial, id)).collect();
            k.sort_unstable();
            k.into_iter().map(|(_, id)| id).collect()
        };
        // The online depth maps narrow the search (`final_seed_cell_px`).
        let done = mapper.reconstruct_all(&self.map, &keyframes, self.semidense.mapper(), stop);
        mapper.release_working_memory();
        if !done {
            return None;
        }
        f.mapper = Some(mapper);
        f.mapper.as_deref()
    }
}
