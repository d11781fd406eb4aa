//! Errors of live devices, mapped from the OS error of the failing call to what a user can act on.

use std::io;

/// What went wrong with a capture device. Every message names the device.
#[derive(Debug, thiserror::Error)]
pub enum DeviceError {
    #[error("{device}: no such camera")]
    NotFound { device: String },
    #[error("{device}: permission denied (add the user to the `video` group, or check the device's mode)")]
    Permission { device: String },
    #[error("{device}: busy (another program is using the camera)")]
    Busy { device: String },
    #[error("{device}: camera disconnected")]
    Unplugged { device: String },
    #[error("{device}: no frame for {seconds:.1} s (is the camera streaming?)")]
    Timeout { device: String, seconds: f64 },
    #[error("{device}: no usable mode: {message}")]
    NoUsableMode { device: String, message: String },
    #[error("{device}: {op} failed: {source}")]
    Os {
        device: String,
        op: &'static str,
        #[source]
        source: io::Error,
    },
    /// A finite device (the fake one replaying a scene) has no more frames.
    #[error("{device}: end of stream")]
    EndOfStream { device: String },
    #[error("{device}: {message}")]
    Other { device: String, message: String },
}

impl DeviceError {
    /// Maps the error of OS call `op` on `device` to the kind a user can act on: a device that
    /// went away (ENODEV, ENXIO, or EIO after streaming started) is an unplug, not a crash.
    pub fn from_io(device: &str, op: &'static str, e: io::Error) -> Self {
        let device = device.to_string();
        match e.raw_os_error() {
            Some(libc_errno::ENODEV) | Some(libc_errno::ENXIO) => DeviceError::Unplugged { device },
            Some(libc_errno::ENOENT) => DeviceError::NotFound { device },
            Some(libc_errno::EACCES) | Some(libc_errno::EPERM) => {
                DeviceError::Permission { device }
            }
            Some(libc_errno::EBUSY) => DeviceError::Busy { device },
            _ => match e.kind() {
                io::ErrorKind::NotFound => DeviceError::NotFound { device },
                io::ErrorKind::PermissionDenied => DeviceError::Permission { device },
                io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock => DeviceError::Timeout {
                    device,
                    seconds: 0.0,
                },
                _ => DeviceError::Os {
                    device,
                    op,
                    source: e,
                },
            },
        }
    }

    /// True when the device is gone: the run ends and writes its outputs.
    pub fn is_unplug(&self) -> bool {
        matches!(self, DeviceError::Unplugged { .. })
    }
}

/// The Linux errno values the mapping needs (stable ABI numbers; no libc dependency here).
mod libc_errno {
    pub const EPERM: i32 = 1;
    pub const ENOENT: i32 = 2;
    pub const ENXIO: i32 = 6;
    pub const EACCES: i32 = 13;
    pub const EBUSY: i32 = 16;
    pub const ENODEV: i32 = 19;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn os_errors_map_to_actionable_kinds() {
        let e = |n| {
            DeviceError::from_io(
                "/dev/video0",
                "VIDIOC_DQBUF",
                io::Error::from_raw_os_error(n),
            )
        };
        assert!(e(19).is_unplug());
        assert!(e(6).is_unplug());
        assert!(matches!(e(16), DeviceError::Busy { .. }));
        assert!(matches!(e(13), DeviceError::Permission { .. }));
        assert!(matches!(e(2), DeviceError::NotFound { .. }));
        let other = e(22);
        assert!(matches!(
            other,
            DeviceError::Os {
                op: "VIDIOC_DQBUF",
                ..
            }
        ));
        assert!(other
            .to_string()
            .starts_with("/dev/video0: VIDIOC_DQBUF failed"));
        assert!(e(16).to_string().contains("another program"));
    }
}
