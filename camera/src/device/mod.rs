//! Live cameras. The OS calls (V4L2 ioctls, libcamera requests) sit behind [`CaptureDevice`];
//! everything else (mode choice, pixel conversion, timestamps, controls policy, error mapping)
//! is plain code in [`LiveSource`] and tested with [`fake::FakeDevice`].

pub mod controls;
pub mod convert;
pub mod error;
pub mod fake;
pub mod format;
#[cfg(feature = "libcamera")]
pub mod libcamera;
pub mod live;
pub mod timestamp;
#[cfg(feature = "v4l2")]
pub mod v4l2;

use std::time::Duration;

pub use controls::{CameraControl, ControlInfo, Exposure};
pub use error::DeviceError;
pub use format::{ChosenMode, Mode, ModeRequest, PixelFormat};
pub use live::{LiveOptions, LiveSource, LiveStats};
pub use timestamp::BufferMeta;

/// The calls a capture back end makes to the OS. Implementations do no policy: they list, set
/// and stream what they are told.
pub trait CaptureDevice: Send {
    /// Device path or id, used in every message.
    fn name(&self) -> &str;
    /// Every format, size and frame rate the device offers.
    fn modes(&mut self) -> Result<Vec<Mode>, DeviceError>;
    /// Sets `mode`; returns what the driver actually set and the row stride in bytes.
    fn configure(&mut self, mode: &ChosenMode) -> Result<(ChosenMode, usize), DeviceError>;
    /// The controls among [`CameraControl`] the device has.
    fn controls(&mut self) -> Result<Vec<ControlInfo>, DeviceError>;
    fn set_control(&mut self, control: CameraControl, value: i64) -> Result<(), DeviceError>;
    /// Allocates `buffers` memory-mapped buffers and starts streaming.
    fn start(&mut self, buffers: u32) -> Result<(), DeviceError>;
    /// Waits up to `timeout` for the next filled buffer, hands it to `f`, and gives it back to
    /// the driver.
    fn next_buffer(
        &mut self,
        timeout: Duration,
        f: &mut dyn FnMut(&[u8], &BufferMeta),
    ) -> Result<(), DeviceError>;
    /// Stops streaming; safe to call twice and after an unplug.
    fn stop(&mut self);
}

/// One camera found on the system.
#[derive(Clone, Debug)]
pub struct CameraSummary {
    /// What to pass to `sdslam run`: `v4l2:/dev/video0`, `libcamera:<id>`.
    pub spec: String,
    pub name: String,
    pub modes: Vec<Mode>,
    /// Set when the device could not be opened or queried (the listing goes on).
    pub error: Option<String>,
}

/// Every camera the enabled back ends can see.
pub fn list_cameras() -> Vec<CameraSummary> {
    #[allow(unused_mut)]
    let mut all = Vec::new();
    #[cfg(feature = "v4l2")]
    all.extend(v4l2::list());
    #[cfg(feature = "libcamera")]
    all.extend(libcamera::list());
    all
}

/// An opened camera: the stream, its counters and what could not be set as asked.
pub struct OpenedCamera {
    pub source: Box<dyn crate::FrameSource>,
    pub stats: std::sync::Arc<LiveStats>,
    pub warnings: Vec<String>,
}

impl OpenedCamera {
    #[allow(dead_code)] // unused when built without any device back end
    fn new<D: CaptureDevice + 'static>(src: LiveSource<D>) -> Self {
        OpenedCamera {
            stats: src.stats(),
            warnings: src.warnings.clone(),
            source: Box::new(src),
        }
    }
}

/// Opens a live source from a spec (`v4l2:/dev/videoN`, `libcamera:<id>`).
pub fn open_live(spec: &str, options: &LiveOptions) -> Result<OpenedCamera, DeviceError> {
    let _ = options; // unused when built without any device back end
    if let Some(path) = spec.strip_prefix("v4l2:") {
        #[cfg(feature = "v4l2")]
        {
            let dev = v4l2::V4l2Device::open(path)?;
            return Ok(OpenedCamera::new(LiveSource::start(dev, options)?));
        }
        #[cfg(not(feature = "v4l2"))]
        return Err(DeviceError::Other {
            device: path.to_string(),
            message: "this build has no V4L2 support (build with the `v4l2` feature)".into(),
        });
    }
    if let Some(id) = spec.strip_prefix("libcamera:") {
        #[cfg(feature = "libcamera")]
        {
            let dev = libcamera::LibcameraDevice::open(id)?;
            return Ok(OpenedCamera::new(LiveSource::start(dev, options)?));
        }
        #[cfg(not(feature = "libcamera"))]
        return Err(DeviceError::Other {
            device: id.to_string(),
            message: "this build has no libcamera support (build with `--features libcamera`)"
                .into(),
        });
    }
    Err(DeviceError::Other {
        device: spec.to_string(),
        message: "not a camera (expected v4l2:/dev/videoN or libcamera:ID)".into(),
    })
}
