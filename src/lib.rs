//! sdslam: real-time monocular ORB SLAM with probabilistic semi-dense mapping.
//!
//! The core (everything but [`io`]) does no file or device IO: frames come in as buffers from
//! [`sdslam_camera`] sources, poses and clouds go out as values.

pub mod calibrate;
pub mod camera_model;
pub mod config;
pub mod error;
pub mod eval;
pub mod features;
pub mod geometry;
pub mod image;
pub mod io;
pub mod local_mapping;
pub mod loop_closing;
pub mod map;
pub mod matching;
pub mod optimize;
pub mod place_recognition;
pub mod runtime;
pub mod semidense;
pub mod simd;
pub mod synthetic;
pub mod threads;
pub mod timing;
pub mod tracking;

pub use config::Config;
pub use error::{Error, Result};
pub use sdslam_camera as camera;
