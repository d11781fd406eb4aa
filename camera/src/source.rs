//! The `FrameSource` trait every input implements.

use crate::{Frame, SourceError};

/// Static description of a source, known before the first frame.
#[derive(Clone, Debug, PartialEq)]
pub struct SourceInfo {
    /// Human-readable name (folder, device path, `synthetic`).
    pub name: String,
    pub width: u32,
    pub height: u32,
    /// Nominal frame rate (frames per second), used for deadlines and real-time pacing.
    pub fps: f64,
    /// True when frames carry colour.
    pub has_color: bool,
    /// Number of frames when known (replays), `None` for live devices.
    pub len: Option<usize>,
}

/// What a call to [`FrameSource::next_frame`] produced.
#[derive(Clone, Debug, PartialEq)]
pub enum FrameStatus {
    /// `out` holds a new frame.
    Ready,
    /// One frame could not be read (corrupt or unreadable image): the replay goes on, the
    /// caller counts it. `out` is unchanged.
    Skipped { index: u64, reason: String },
    /// No more frames.
    End,
}

/// A stream of timestamped frames written into caller-owned buffers.
///
/// Implementations must not allocate per frame once warmed up beyond what their decoder needs,
/// and must report a frame-local failure as [`FrameStatus::Skipped`] rather than an error.
pub trait FrameSource: Send {
    fn info(&self) -> &SourceInfo;
    /// Writes the next frame into `out` (resized if needed).
    fn next_frame(&mut self, out: &mut Frame) -> Result<FrameStatus, SourceError>;
}

impl<S: FrameSource + ?Sized> FrameSource for Box<S> {
    fn info(&self) -> &SourceInfo {
        (**self).info()
    }
    fn next_frame(&mut self, out: &mut Frame) -> Result<FrameStatus, SourceError> {
        (**self).next_frame(out)
    }
}
