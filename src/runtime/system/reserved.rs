//! What a configuration reserves up front (the preallocated map and semi-dense store), so a
//! caller can refuse a configuration the machine cannot hold before allocating it.

use super::*;

/// What a configuration reserves up front, by part, in bytes (per-frame buffers, pyramids and
/// other fixed-size buffers are not included: a few tens of MB at 640x480).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReservedMemory {
    pub keyframes: u64,
    pub map_points: u64,
    pub semidense_store: u64,
}

impl ReservedMemory {
    pub fn total(&self) -> u64 {
        self.keyframes + self.map_points + self.semidense_store
    }

    /// The configuration field behind the largest part, for a message asking to lower it.
    pub fn largest_field(&self) -> &'static str {
        if self.keyframes >= self.map_points && self.keyframes >= self.semidense_store {
            "[map] max_keyframes (or [orb] n_features)"
        } else if self.map_points >= self.semidense_store {
            "[map] max_map_points"
        } else {
            "[semidense] max_points"
        }
    }
}

impl System {
    /// The memory `System::new` would reserve for `calib` and `config`, computed without
    /// reserving it (one keyframe and one map-point slot are measured), so a caller can refuse
    /// a configuration the machine cannot hold before allocating.
    pub fn reserved_memory(calib: &Calibration, config: &Config) -> ReservedMemory {
        let (w, h) = (calib.camera.width as usize, calib.camera.height as usize);
        let (kf, mp) = Map::slot_bytes(&MapConfig {
            max_features: config.orb.n_features.saturating_mul(2),
            width: w,
            height: h,
            ..MapConfig::default()
        });
        let sd = if config.semidense.enabled {
            crate::semidense::STORED_PIXEL_BYTES as u64 * config.semidense.max_points as u64
        } else {
            0
        };
        ReservedMemory {
            keyframes: kf as u64 * config.map.max_keyframes as u64,
            map_points: mp as u64 * config.map.max_map_points as u64,
            semidense_store: sd,
        }
    }
}
