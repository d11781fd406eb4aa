//! The V4L2 back end on the `v4l` crate: only the ioctl calls live here (enumerate, set format
//! and rate, query and set controls, memory-mapped streaming). Policy is in [`super::live`].

use std::time::Duration;

use v4l::buffer::{Flags, Type};
use v4l::capability::Flags as CapFlags;
use v4l::control::{Control, Value};
use v4l::frameinterval::FrameIntervalEnum;
use v4l::io::mmap::Stream;
use v4l::io::traits::{CaptureStream, Stream as _};
use v4l::video::capture::Parameters;
use v4l::video::Capture;
use v4l::{Device, Format, FourCC, Fraction};

use super::controls::{CameraControl, ControlInfo};
use super::format::{ChosenMode, Mode, PixelFormat};
use super::timestamp::BufferMeta;
use super::{CameraSummary, CaptureDevice, DeviceError};

/// An open V4L2 capture device.
pub struct V4l2Device {
    path: String,
    dev: Device,
    stream: Option<Stream<'static>>,
}

impl V4l2Device {
    /// Opens `path` and checks it can capture video by streaming I/O.
    pub fn open(path: &str) -> Result<Self, DeviceError> {
        let dev = Device::with_path(path).map_err(|e| DeviceError::from_io(path, "open", e))?;
        let caps = dev
            .query_caps()
            .map_err(|e| DeviceError::from_io(path, "VIDIOC_QUERYCAP", e))?;
        if !caps.capabilities.contains(CapFlags::VIDEO_CAPTURE)
            || !caps.capabilities.contains(CapFlags::STREAMING)
        {
            return Err(DeviceError::Other {
                device: path.to_string(),
                message: format!(
                    "{} ({}) is not a streaming video capture device",
                    caps.card, caps.driver
                ),
            });
        }
        Ok(V4l2Device {
            path: path.to_string(),
            dev,
            stream: None,
        })
    }

    fn err(&self, op: &'static str) -> impl Fn(std::io::Error) -> DeviceError + '_ {
        move |e| DeviceError::from_io(&self.path, op, e)
    }

    /// Frame rates offered for one format and size.
    fn rates(&self, fourcc: FourCC, w: u32, h: u32) -> Vec<f64> {
        let fps =
            |f: Fraction| (f.numerator > 0).then(|| f.denominator as f64 / f.numerator as f64);
        let mut out = Vec::new();
        for iv in self
            .dev
            .enum_frameintervals(fourcc, w, h)
            .unwrap_or_default()
        {
            match iv.interval {
                FrameIntervalEnum::Discrete(f) => out.extend(fps(f)),
                FrameIntervalEnum::Stepwise(s) => {
                    // Fastest and slowest; the chooser takes the fastest that is enough.
                    out.extend(fps(s.min));
                    out.extend(fps(s.max));
                }
            }
        }
        out.sort_by(|a, b| b.total_cmp(a));
        out.dedup_by(|a, b| (*a - *b).abs() < 1e-3);
        out
    }
}

impl CaptureDevice for V4l2Device {
    fn name(&self) -> &str {
        &self.path
    }

    fn modes(&mut self) -> Result<Vec<Mode>, DeviceError> {
        let mut modes = Vec::new();
        for desc in self
            .dev
            .enum_formats()
            .map_err(self.err("VIDIOC_ENUM_FMT"))?
        {
            let format = PixelFormat::from_fourcc(desc.fourcc.repr);
            let sizes = self
                .dev
                .enum_framesizes(desc.fourcc)
                .map_err(self.err("VIDIOC_ENUM_FRAMESIZES"))?;
            for size in sizes {
                for d in size.size.to_discrete() {
                    let fps = self.rates(desc.fourcc, d.width, d.height);
                    modes.push(Mode {
                        format,
                        width: d.width,
                        height: d.height,
                        fps,
                    });
                }
            }
        }
        Ok(modes)
    }

    fn configure(&mut self, mode: &ChosenMode) -> Result<(ChosenMode, usize), DeviceError> {
        let fourcc = FourCC::new(&mode.format.fourcc());
        let set = self
            .dev
            .set_format(&Format::new(mode.width, mode.height, fourcc))
            .map_err(self.err("VIDIOC_S_FMT"))?;
        let interval = Fraction::new(1000, (mode.fps * 1000.0).round().max(1.0) as u32);
        // Not every driver supports setting the rate: keep its own then.
        let fps = match self.dev.set_params(&Parameters::new(interval)) {
            Ok(p) if p.interval.numerator > 0 => {
                p.interval.denominator as f64 / p.interval.numerator as f64
            }
            _ => mode.fps,
        };
        let got = ChosenMode {
            format: PixelFormat::from_fourcc(set.fourcc.repr),
            width: set.width,
            height: set.height,
            fps,
        };
        Ok((got, set.stride as usize))
    }

    fn controls(&mut self) -> Result<Vec<ControlInfo>, DeviceError> {
        let all = self
            .dev
            .query_controls()
            .map_err(self.err("VIDIOC_QUERYCTRL"))?;
        Ok(all
            .iter()
            .filter_map(|d| {
                CameraControl::from_v4l2_id(d.id).map(|control| ControlInfo {
                    control,
                    min: d.minimum,
                    max: d.maximum,
                    default: d.default,
                })
            })
            .collect())
    }

    fn set_control(&mut self, control: CameraControl, value: i64) -> Result<(), DeviceError> {
        let value = match control {
            CameraControl::AutoGain => Value::Boolean(value != 0),
            _ => Value::Integer(value),
        };
        self.dev
            .set_control(Control {
                id: control.v4l2_id(),
                value,
            })
            .map_err(self.err("VIDIOC_S_CTRL"))
    }

    fn start(&mut self, buffers: u32) -> Result<(), DeviceError> {
        let stream = Stream::with_buffers(&self.dev, Type::VideoCapture, buffers)
            .map_err(self.err("VIDIOC_REQBUFS"))?;
        self.stream = Some(stream);
        Ok(())
    }

    fn next_buffer(
        &mut self,
        timeout: Duration,
        f: &mut dyn FnMut(&[u8], &BufferMeta),
    ) -> Result<(), DeviceError> {
        let path = self.path.clone();
        let Some(stream) = self.stream.as_mut() else {
            return Err(DeviceError::Other {
                device: path,
                message: "not streaming".into(),
            });
        };
        stream.set_timeout(timeout);
        match CaptureStream::next(stream) {
            Ok((data, meta)) => {
                let flags = meta.flags;
                // time_t is 32-bit on 32-bit ARM boards (Raspberry Pi OS 32-bit).
                #[allow(clippy::unnecessary_cast)]
                let bm = BufferMeta {
                    sequence: meta.sequence,
                    sec: meta.timestamp.sec as i64,
                    usec: meta.timestamp.usec as i64,
                    monotonic: (flags & Flags::TIMESTAMP_MASK) == Flags::TIMESTAMP_MONOTONIC,
                    bytes_used: meta.bytesused as usize,
                    error: flags.contains(Flags::ERROR),
                };
                f(data, &bm);
                Ok(())
            }
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => Err(DeviceError::Timeout {
                device: path,
                seconds: timeout.as_secs_f64(),
            }),
            Err(e) => Err(DeviceError::from_io(&path, "VIDIOC_DQBUF", e)),
        }
    }

    fn stop(&mut self) {
        if let Some(mut s) = self.stream.take() {
            // The crate's Drop panics when STREAMOFF fails with anything but ENODEV: stop here
            // and, if that fails, leak the mapping rather than panic during shutdown.
            if s.stop().is_ok() {
                drop(s);
            } else {
                std::mem::forget(s);
            }
        }
    }
}

impl Drop for V4l2Device {
    fn drop(&mut self) {
        self.stop();
    }
}

/// Every V4L2 node that can capture, with its modes.
pub fn list() -> Vec<CameraSummary> {
    let mut out = Vec::new();
    for node in v4l::context::enum_devices() {
        let path = node.path().display().to_string();
        let name = node.name().unwrap_or_else(|| path.clone());
        let mut summary = CameraSummary {
            spec: format!("v4l2:{path}"),
            name,
            modes: Vec::new(),
            error: None,
        };
        match V4l2Device::open(&path).and_then(|mut d| d.modes()) {
            Ok(modes) => summary.modes = modes,
            // Metadata nodes of UVC cameras are not capture devices: leave them out.
            Err(DeviceError::Other { .. }) => continue,
            Err(e) => summary.error = Some(e.to_string()),
        }
        out.push(summary);
    }
    out.sort_by(|a, b| a.spec.cmp(&b.spec));
    out
}
