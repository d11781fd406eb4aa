//! Errors of frame sources. Every message names the file (and line) at fault.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    #[error("{path}: cannot read: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}:{line}: {message}")]
    List {
        path: PathBuf,
        line: usize,
        message: String,
    },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
    #[error("{path}: cannot decode image: {message}")]
    Decode { path: PathBuf, message: String },
    #[error("{path}: image is {got_w}x{got_h}, expected {want_w}x{want_h}")]
    Size {
        path: PathBuf,
        got_w: u32,
        got_h: u32,
        want_w: u32,
        want_h: u32,
    },
    #[error(transparent)]
    Device(#[from] crate::device::DeviceError),
    #[error("source thread failed: {0}")]
    Thread(String),
}

impl SourceError {
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        SourceError::Io {
            path: path.into(),
            source,
        }
    }

    /// True for errors that concern one frame only (a corrupt or missing image), after which
    /// a replay can go on with the next frame.
    pub fn is_frame_local(&self) -> bool {
        matches!(
            self,
            SourceError::Decode { .. } | SourceError::Io { .. } | SourceError::Size { .. }
        )
    }
}
