//! A point of the semi-dense cloud: produced by `semidense`, evaluated by `eval`, written by
//! `io` (PLY), so it lives below all three.

/// One cloud point as written to `semidense.ply`: world position, colour, the inverse-depth
/// standard deviation of its estimate, and the timestamp of the keyframe that made it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CloudPoint {
    pub position: [f32; 3],
    pub rgb: [u8; 3],
    pub sigma: f32,
    pub timestamp: f64,
}
