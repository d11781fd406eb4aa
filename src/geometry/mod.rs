//! Geometry: typed poses now; two-view, triangulation, PnP and Sim3 solvers as pure functions
//! over correspondences.

mod pose;

pub use pose::{CameraFromWorld, Se3, Sim3, WorldFromCamera};
