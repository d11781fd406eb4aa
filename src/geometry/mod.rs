//! Geometry: typed poses and pure solvers over correspondences (no map types): two-view
//! initialisation (H/F), triangulation, PnP, Sim3, epipolar helpers, seeded RANSAC.

mod align;
mod cloud;
pub mod epipolar;
mod intrinsics;
pub mod pnp;
mod pose;
pub mod ransac;
pub mod sim3;
pub mod triangulate;
pub mod two_view;

pub use align::{horn, umeyama};
pub use cloud::CloudPoint;
pub use intrinsics::Intrinsics;
pub use pose::{CameraFromWorld, Se3, Sim3, WorldFromCamera};
