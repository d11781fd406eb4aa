//! The library's error type. Messages name the file and line or field at fault.

use std::path::PathBuf;

use crate::camera_model::CalibError;
use sdslam_camera::SourceError;

#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}:{line}: {message}")]
    Parse {
        path: PathBuf,
        line: usize,
        message: String,
    },
    #[error(transparent)]
    Calibration(#[from] CalibError),
    #[error(transparent)]
    Source(#[from] SourceError),
    #[error("{path}: {message}")]
    Config { path: PathBuf, message: String },
    /// A file whose content a typed decoder refused (a map file, a vocabulary, ...). The
    /// decoder's own error is kept as the source (downcast it to tell the cases apart); it is
    /// boxed because those decoders live in higher layers than this type.
    #[error("{path}: {source}")]
    Format {
        path: PathBuf,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    #[error("{0}")]
    Invalid(String),
}

impl Error {
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }

    /// A typed decoding error of the file at `path`.
    pub fn format(
        path: impl Into<PathBuf>,
        source: impl std::error::Error + Send + Sync + 'static,
    ) -> Self {
        Error::Format {
            path: path.into(),
            source: Box::new(source),
        }
    }
}

pub type Result<T, E = Error> = std::result::Result<T, E>;
