//! The place index of a running map: what tracking (adding keyframes, relocalising) and loop
//! closing share.

use std::collections::HashMap;

use super::KeyFrameDatabase;
use crate::map::KeyFrameId;

/// The place-recognition index shared by tracking (adds keyframes, relocalises) and loop
/// closing: the database keyed by keyframe serial, and serial -> keyframe.
#[derive(Default)]
pub struct PlaceIndex {
    pub database: KeyFrameDatabase,
    pub keys: HashMap<u32, KeyFrameId>,
}
