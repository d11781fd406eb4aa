//! sdslam: real-time monocular ORB SLAM with probabilistic semi-dense mapping.
//!
//! The core (everything but [`io`]) does no file or device IO: frames come in as buffers from
//! [`sdslam_camera`] sources, poses and clouds go out as values.

pub mod camera_model;

pub use sdslam_camera as camera;
pub mod error;
pub mod eval;
pub mod geometry;
pub mod io;
pub mod synthetic;

pub use error::{Error, Result};
pub mod config;
pub mod runtime;

pub use config::Config;
