//! A fake capture device for tests and for replaying a scene through the whole live path: it
//! offers modes like a webcam, encodes a scene's frames in the negotiated format (GREY, YUYV
//! with row padding, MJPEG without Huffman tables as UVC cameras send it), stamps them with a
//! monotonic clock and sequence numbers, and injects faults on request.

use std::time::{Duration, Instant};

use super::controls::{CameraControl, ControlInfo};
use super::convert::encode;
use super::format::{ChosenMode, Mode, PixelFormat};
use super::timestamp::BufferMeta;
use super::{CaptureDevice, DeviceError};
use crate::{Frame, FrameSource, FrameStatus};

/// Faults to inject, by frame number (0-based, counting every frame the scene produced).
#[derive(Clone, Debug, Default)]
pub struct Faults {
    /// The device disappears (ENODEV) when this frame is due.
    pub unplug_at: Option<u64>,
    /// These frames come with the driver's error flag.
    pub corrupt: Vec<u64>,
    /// These frames are truncated to half their size.
    pub truncated: Vec<u64>,
    /// The driver drops these frames (sequence numbers skip them).
    pub driver_drops: Vec<u64>,
    /// The device stops sending frames (timeout) from this frame on.
    pub stall_at: Option<u64>,
}

/// A scene played as a camera.
pub struct FakeDevice {
    name: String,
    scene: Box<dyn FrameSource>,
    modes: Vec<Mode>,
    mode: Option<ChosenMode>,
    /// Extra bytes at the end of each YUYV/GREY row, as some drivers pad.
    row_padding: usize,
    faults: Faults,
    /// Release frames at the camera rate (true) or as fast as asked (false).
    pub real_time: bool,
    /// Start of the device clock, seconds: the host's monotonic clock when streaming starts,
    /// as a V4L2 driver stamps.
    clock_origin: f64,
    /// Scene time that maps to `clock_origin` (default: the first frame's).
    scene_origin: Option<f64>,
    controls: Vec<(ControlInfo, i64)>,
    streaming: bool,
    produced: u64,
    frame: Frame,
    bytes: Vec<u8>,
    started: Option<Instant>,
}

impl FakeDevice {
    /// A webcam-like device over `scene`: GREY, YUYV and MJPEG at the scene's size and rate.
    pub fn new(name: &str, scene: Box<dyn FrameSource>) -> Self {
        let info = scene.info().clone();
        let modes = [PixelFormat::Grey, PixelFormat::Yuyv, PixelFormat::Mjpeg]
            .into_iter()
            .map(|format| Mode {
                format,
                width: info.width,
                height: info.height,
                fps: vec![info.fps],
            })
            .collect();
        let ctl = |control, min, max, default| {
            (
                ControlInfo {
                    control,
                    min,
                    max,
                    default,
                },
                default,
            )
        };
        FakeDevice {
            name: name.to_string(),
            frame: Frame::new(info.width, info.height),
            scene,
            modes,
            mode: None,
            row_padding: 32,
            faults: Faults::default(),
            real_time: false,
            clock_origin: 0.0,
            scene_origin: None,
            controls: vec![
                ctl(CameraControl::AutoExposure, 0, 3, 3),
                ctl(CameraControl::ExposureTime, 1, 5000, 156),
                ctl(CameraControl::Gain, 0, 255, 32),
            ],
            streaming: false,
            produced: 0,
            bytes: Vec::new(),
            started: None,
        }
    }

    /// Offers only these modes.
    pub fn with_modes(mut self, modes: Vec<Mode>) -> Self {
        self.modes = modes;
        self
    }

    pub fn with_faults(mut self, faults: Faults) -> Self {
        self.faults = faults;
        self
    }

    /// Stamps frames at `clock_origin + (scene time - t0)`, so the scene's ground truth can
    /// be moved onto the device clock with [`FakeDevice::device_time`].
    pub fn with_scene_origin(mut self, t0: f64) -> Self {
        self.scene_origin = Some(t0);
        self
    }

    /// Device-clock time of scene time `t` (known once streaming started).
    pub fn device_time(&self, t: f64) -> Option<f64> {
        Some(self.clock_origin + t - self.scene_origin?)
    }

    /// Current value of a control (for tests of the controls policy).
    pub fn control_value(&self, c: CameraControl) -> Option<i64> {
        self.controls
            .iter()
            .find(|(i, _)| i.control == c)
            .map(|(_, v)| *v)
    }

    fn encode(&mut self, mode: &ChosenMode) -> Result<(), DeviceError> {
        let (w, h) = (mode.width as usize, mode.height as usize);
        let f = &self.frame;
        match mode.format {
            PixelFormat::Grey => {
                let stride = w + self.row_padding;
                self.bytes.clear();
                self.bytes.resize(stride * h, 0);
                for y in 0..h {
                    self.bytes[y * stride..y * stride + w]
                        .copy_from_slice(&f.gray[y * w..(y + 1) * w]);
                }
            }
            PixelFormat::Yuyv => {
                encode::yuyv_from_rgb(&self.rgb(), w, h, 2 * w + self.row_padding, &mut self.bytes)
            }
            PixelFormat::Mjpeg => {
                let rgb = self.rgb();
                let mut jpeg = Vec::new();
                encode::jpeg_from_rgb(&rgb, mode.width, mode.height, &mut jpeg).map_err(
                    |message| DeviceError::Other {
                        device: self.name.clone(),
                        message,
                    },
                )?;
                self.bytes = encode::strip_huffman_tables(&jpeg);
            }
            PixelFormat::Other(_) => {}
        }
        Ok(())
    }

    /// The scene frame's colour, or its grey repeated when the scene has none.
    fn rgb(&self) -> Vec<u8> {
        if self.frame.has_color {
            self.frame.rgb.clone()
        } else {
            self.frame.gray.iter().flat_map(|&g| [g, g, g]).collect()
        }
    }
}

impl CaptureDevice for FakeDevice {
    fn name(&self) -> &str {
        &self.name
    }

    fn modes(&mut self) -> Result<Vec<Mode>, DeviceError> {
        Ok(self.modes.clone())
    }

    fn configure(&mut self, mode: &ChosenMode) -> Result<(ChosenMode, usize), DeviceError> {
        if !self
            .modes
            .iter()
            .any(|m| (m.format, m.width, m.height) == (mode.format, mode.width, mode.height))
        {
            return Err(DeviceError::Other {
                device: self.name.clone(),
                message: "EINVAL: mode not offered".into(),
            });
        }
        self.mode = Some(*mode);
        let stride = match mode.format {
            PixelFormat::Grey => mode.width as usize + self.row_padding,
            PixelFormat::Yuyv => 2 * mode.width as usize + self.row_padding,
            _ => 0,
        };
        Ok((*mode, stride))
    }

    fn controls(&mut self) -> Result<Vec<ControlInfo>, DeviceError> {
        Ok(self.controls.iter().map(|(i, _)| *i).collect())
    }

    fn set_control(&mut self, control: CameraControl, value: i64) -> Result<(), DeviceError> {
        match self.controls.iter_mut().find(|(i, _)| i.control == control) {
            Some((_, v)) => {
                *v = value;
                Ok(())
            }
            None => Err(DeviceError::Other {
                device: self.name.clone(),
                message: "EINVAL: no such control".into(),
            }),
        }
    }

    fn start(&mut self, _buffers: u32) -> Result<(), DeviceError> {
        if self.mode.is_none() {
            return Err(DeviceError::Other {
                device: self.name.clone(),
                message: "start before configure".into(),
            });
        }
        self.streaming = true;
        self.started = Some(Instant::now());
        self.clock_origin = super::timestamp::monotonic_now();
        Ok(())
    }

    fn next_buffer(
        &mut self,
        timeout: Duration,
        f: &mut dyn FnMut(&[u8], &BufferMeta),
    ) -> Result<(), DeviceError> {
        let device = self.name.clone();
        let Some(mode) = self.mode.filter(|_| self.streaming) else {
            return Err(DeviceError::Other {
                device,
                message: "not streaming".into(),
            });
        };
        loop {
            let n = self.produced;
            if self.faults.unplug_at.is_some_and(|u| n >= u) {
                return Err(DeviceError::from_io(
                    &device,
                    "VIDIOC_DQBUF",
                    std::io::Error::from_raw_os_error(19),
                ));
            }
            if self.faults.stall_at.is_some_and(|s| n >= s) {
                std::thread::sleep(timeout);
                return Err(DeviceError::Timeout {
                    device,
                    seconds: timeout.as_secs_f64(),
                });
            }
            match self.scene.next_frame(&mut self.frame) {
                Ok(FrameStatus::Ready) => {}
                Ok(FrameStatus::Skipped { .. }) => continue,
                Ok(FrameStatus::End) => return Err(DeviceError::EndOfStream { device }),
                Err(e) => {
                    return Err(DeviceError::Other {
                        device,
                        message: e.to_string(),
                    })
                }
            }
            self.produced += 1;
            let t = n as f64 / mode.fps.max(1.0);
            if self.real_time {
                if let Some(s) = self.started {
                    let due = s + Duration::from_secs_f64(t);
                    let now = Instant::now();
                    if due > now {
                        std::thread::sleep(due - now);
                    }
                }
            }
            if self.faults.driver_drops.contains(&n) {
                continue;
            }
            self.encode(&mode)?;
            let scene_t0 = *self.scene_origin.get_or_insert(self.frame.timestamp);
            let clock = self.clock_origin + (self.frame.timestamp - scene_t0);
            let mut meta = BufferMeta {
                sequence: n as u32,
                sec: clock.floor() as i64,
                usec: ((clock - clock.floor()) * 1e6) as i64,
                monotonic: true,
                bytes_used: self.bytes.len(),
                error: self.faults.corrupt.contains(&n),
            };
            if self.faults.truncated.contains(&n) {
                meta.bytes_used /= 2;
            }
            f(&self.bytes, &meta);
            return Ok(());
        }
    }

    fn stop(&mut self) {
        self.streaming = false;
    }
}
