//! Map files: what a map is built with (camera, vocabulary), saving it, and loading it in
//! place of the current one (checked against this system's camera and vocabulary).

use super::*;

impl System {
    /// What this system's maps are built with (camera and vocabulary), for map files.
    pub fn map_origin(&self) -> MapOrigin {
        let c = &self.camera;
        let (words, crc) = self.vocabulary.as_ref().map_or((0, 0), |v| {
            (
                v.n_words() as u32,
                crc32fast::hash(&crate::place_recognition::encode_vocabulary(v)),
            )
        });
        MapOrigin {
            intrinsics: [c.fx, c.fy, c.cx, c.cy],
            width: c.width,
            height: c.height,
            vocabulary_words: words,
            vocabulary_crc: crc,
        }
    }

    /// The map as it is now, for saving (see [`MapSnapshot::encode`]).
    pub fn save_map(&self) -> MapSnapshot {
        MapSnapshot::capture(&lock(&self.map), self.map_origin())
    }

    /// Replaces the map with a saved one (before the first frame). The camera and the
    /// vocabulary must be the ones it was built with. Tracking starts Lost, so the first frames
    /// relocalise against it. Returns the number of keyframes loaded.
    pub fn load_map(&mut self, snap: &MapSnapshot) -> Result<usize, MapFileError> {
        let here = self.map_origin();
        let there = &snap.origin;
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-6 * a.abs().max(1.0);
        if (there.width, there.height) != (here.width, here.height)
            || !there
                .intrinsics
                .iter()
                .zip(&here.intrinsics)
                .all(|(a, b)| close(*a, *b))
        {
            return Err(MapFileError::Incompatible {
                what: "another camera",
                map: format!("{}x{} {:?}", there.width, there.height, there.intrinsics),
                run: format!("{}x{} {:?}", here.width, here.height, here.intrinsics),
            });
        }
        if (there.vocabulary_words, there.vocabulary_crc)
            != (here.vocabulary_words, here.vocabulary_crc)
        {
            return Err(MapFileError::Incompatible {
                what: "another vocabulary",
                map: format!(
                    "{} words, crc {:08x}",
                    there.vocabulary_words, there.vocabulary_crc
                ),
                run: format!(
                    "{} words, crc {:08x}",
                    here.vocabulary_words, here.vocabulary_crc
                ),
            });
        }
        let map_arc = Arc::clone(&self.map);
        let mut map = lock(&map_arc);
        let ids = snap.restore(&mut map)?;
        {
            let n = self.vocabulary.as_ref().map_or(0, |v| v.n_words());
            let mut places = self.places.lock().unwrap_or_else(|e| e.into_inner());
            places.database = KeyFrameDatabase::new(n);
            places.keys.clear();
        }
        for &kf in &ids {
            self.index_keyframe(&map, kf);
        }
        self.tracker.reset(TrackingState::Lost);
        Ok(ids.len())
    }
}
