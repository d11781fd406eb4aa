//! A capture device as a [`FrameSource`]: choose the mode, set controls, stream, convert each
//! buffer into the caller's frame and stamp it. Run it behind [`crate::PacedSource`] with
//! [`crate::Pacing::Live`] so the newest frame always wins.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use super::controls::{self, Exposure};
use super::convert::Converter;
use super::format::{choose_mode, ChosenMode, ModeRequest};
use super::timestamp::{monotonic_now, Timestamper};
use super::{CaptureDevice, DeviceError};
use crate::{Frame, FrameSource, FrameStatus, SourceError, SourceInfo};

/// How to open a live camera.
#[derive(Clone, Debug)]
pub struct LiveOptions {
    pub request: ModeRequest,
    /// Memory-mapped driver buffers: few, so a frame never waits long in the kernel.
    pub buffers: u32,
    pub exposure: Option<Exposure>,
    pub gain: Option<i64>,
    /// Also convert colour (for colouring the semi-dense cloud).
    pub colour: bool,
    /// A camera silent this long is an error (the run stops and writes its outputs).
    pub timeout: Duration,
}

impl Default for LiveOptions {
    fn default() -> Self {
        LiveOptions {
            request: ModeRequest::default(),
            buffers: 4,
            exposure: None,
            gain: None,
            colour: true,
            timeout: Duration::from_secs(3),
        }
    }
}

/// Counters of a live stream, readable from another thread.
#[derive(Debug, Default)]
pub struct LiveStats {
    pub frames: AtomicU64,
    /// Frames the driver dropped before we saw them (sequence gaps).
    pub driver_drops: AtomicU64,
    /// Buffers flagged corrupt by the driver or that failed to convert (skipped).
    pub corrupt: AtomicU64,
    /// Timestamps repaired to stay increasing.
    pub repaired_timestamps: AtomicU64,
    /// Mean capture-to-dequeue latency, microseconds (0 when unknown).
    pub mean_age_us: AtomicU64,
}

/// A live camera stream.
pub struct LiveSource<D: CaptureDevice> {
    dev: D,
    info: SourceInfo,
    mode: ChosenMode,
    converter: Converter,
    stamper: Timestamper,
    timeout: Duration,
    index: u64,
    stats: Arc<LiveStats>,
    /// Warnings from setting controls, for the caller to print.
    pub warnings: Vec<String>,
}

impl<D: CaptureDevice> LiveSource<D> {
    /// Chooses the mode, configures the device, applies controls and starts streaming.
    pub fn start(mut dev: D, options: &LiveOptions) -> Result<Self, DeviceError> {
        let name = dev.name().to_string();
        let modes = dev.modes()?;
        let wanted = choose_mode(&name, &modes, &options.request)?;
        let (mode, stride) = dev.configure(&wanted)?;
        if (mode.width, mode.height, mode.format) != (wanted.width, wanted.height, wanted.format) {
            return Err(DeviceError::NoUsableMode {
                device: name,
                message: format!(
                    "asked for {} {}x{}, the driver set {} {}x{}",
                    wanted.format,
                    wanted.width,
                    wanted.height,
                    mode.format,
                    mode.width,
                    mode.height
                ),
            });
        }
        let warnings = controls::apply(&mut dev, options.exposure, options.gain)?;
        dev.start(options.buffers.max(2))?;
        let colour = options.colour && mode.format.has_color();
        Ok(LiveSource {
            info: SourceInfo {
                name: format!(
                    "{name} ({} {}x{} @ {} fps)",
                    mode.format, mode.width, mode.height, mode.fps
                ),
                width: mode.width,
                height: mode.height,
                fps: mode.fps,
                has_color: colour,
                len: None,
            },
            converter: Converter::new(&name, mode.format, mode.width, mode.height, stride, colour),
            mode,
            dev,
            stamper: Timestamper::default(),
            timeout: options.timeout,
            index: 0,
            stats: Arc::new(LiveStats::default()),
            warnings,
        })
    }

    pub fn mode(&self) -> ChosenMode {
        self.mode
    }

    /// The device (for back-end specific queries).
    pub fn device(&self) -> &D {
        &self.dev
    }

    pub fn stats(&self) -> Arc<LiveStats> {
        self.stats.clone()
    }
}

impl<D: CaptureDevice> FrameSource for LiveSource<D> {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn next_frame(&mut self, out: &mut Frame) -> Result<FrameStatus, SourceError> {
        let LiveSource {
            dev,
            converter,
            stamper,
            stats,
            ..
        } = self;
        let index = self.index;
        let mut outcome: Result<(), String> = Ok(());
        let r = dev.next_buffer(self.timeout, &mut |data, meta| {
            let now = monotonic_now();
            out.timestamp = stamper.stamp(meta, now);
            out.index = index;
            outcome = if meta.error {
                Err("the driver flagged the buffer as corrupt".into())
            } else {
                let used = if meta.bytes_used == 0 {
                    data.len()
                } else {
                    meta.bytes_used.min(data.len())
                };
                converter
                    .convert(&data[..used], out)
                    .map_err(|e| e.to_string())
            };
        });
        match r {
            Ok(()) => {}
            Err(DeviceError::Timeout { device, .. }) => {
                return Err(DeviceError::Timeout {
                    device,
                    seconds: self.timeout.as_secs_f64(),
                }
                .into())
            }
            Err(DeviceError::EndOfStream { .. }) => return Ok(FrameStatus::End),
            Err(e) => return Err(e.into()),
        }
        self.index += 1;
        stats
            .driver_drops
            .store(stamper.driver_drops, Ordering::Relaxed);
        stats
            .repaired_timestamps
            .store(stamper.repaired, Ordering::Relaxed);
        if let Some(age) = stamper.mean_age_ms() {
            stats
                .mean_age_us
                .store((age * 1e3) as u64, Ordering::Relaxed);
        }
        match outcome {
            Ok(()) => {
                stats.frames.fetch_add(1, Ordering::Relaxed);
                Ok(FrameStatus::Ready)
            }
            Err(reason) => {
                stats.corrupt.fetch_add(1, Ordering::Relaxed);
                Ok(FrameStatus::Skipped { index, reason })
            }
        }
    }
}

impl<D: CaptureDevice> Drop for LiveSource<D> {
    fn drop(&mut self) {
        self.dev.stop();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::device::controls::CameraControl;
    use crate::device::fake::{FakeDevice, Faults};
    use crate::device::format::{Mode, PixelFormat};
    use crate::{PacedSource, Pacing};

    /// A moving colour gradient, `n` frames of `w` x `h` at 30 fps.
    struct Pattern {
        info: SourceInfo,
        i: u64,
    }

    impl Pattern {
        fn boxed(w: u32, h: u32, n: usize) -> Box<dyn FrameSource> {
            Box::new(Pattern {
                info: SourceInfo {
                    name: "pattern".into(),
                    width: w,
                    height: h,
                    fps: 30.0,
                    has_color: true,
                    len: Some(n),
                },
                i: 0,
            })
        }
    }

    impl FrameSource for Pattern {
        fn info(&self) -> &SourceInfo {
            &self.info
        }
        fn next_frame(&mut self, out: &mut Frame) -> Result<FrameStatus, SourceError> {
            if self.i as usize >= self.info.len.unwrap_or(0) {
                return Ok(FrameStatus::End);
            }
            let (w, h) = (self.info.width as usize, self.info.height as usize);
            out.ensure_size(w as u32, h as u32);
            for y in 0..h {
                for x in 0..w {
                    let k = y * w + x;
                    let (r, g, b) = (
                        (x * 3 + self.i as usize) as u8,
                        (y * 4) as u8,
                        ((x + y) * 2) as u8,
                    );
                    out.rgb[3 * k..3 * k + 3].copy_from_slice(&[r, g, b]);
                    out.gray[k] = crate::frame::luma(r, g, b);
                }
            }
            out.has_color = true;
            out.timestamp = self.i as f64 / 30.0;
            out.index = self.i;
            self.i += 1;
            Ok(FrameStatus::Ready)
        }
    }

    fn options(format: Option<PixelFormat>) -> LiveOptions {
        LiveOptions {
            request: ModeRequest {
                format,
                ..Default::default()
            },
            timeout: Duration::from_millis(200),
            ..Default::default()
        }
    }

    fn collect(src: &mut dyn FrameSource) -> (Vec<FrameStatus>, Vec<Frame>, Option<SourceError>) {
        let (mut statuses, mut frames) = (Vec::new(), Vec::new());
        let mut f = Frame::new(src.info().width, src.info().height);
        loop {
            match src.next_frame(&mut f) {
                Ok(FrameStatus::End) => return (statuses, frames, None),
                Ok(s) => {
                    if s == FrameStatus::Ready {
                        frames.push(f.clone());
                    }
                    statuses.push(s);
                }
                Err(e) => return (statuses, frames, Some(e)),
            }
        }
    }

    #[test]
    fn grey_is_preferred_and_exact() {
        let dev = FakeDevice::new("fake0", Pattern::boxed(64, 48, 5));
        let mut src = LiveSource::start(dev, &options(None)).unwrap();
        assert_eq!(src.mode().format, PixelFormat::Grey);
        assert!(!src.info().has_color);
        let (_, frames, err) = collect(&mut src);
        assert!(err.is_none());
        assert_eq!(frames.len(), 5);
        let mut scene = Pattern::boxed(64, 48, 5);
        let mut want = Frame::new(64, 48);
        for got in &frames {
            scene.next_frame(&mut want).unwrap();
            assert_eq!(got.gray, want.gray);
        }
    }

    #[test]
    fn yuyv_and_mjpeg_give_the_scene_in_grey_and_colour() {
        for (format, tol) in [(PixelFormat::Yuyv, 0.0), (PixelFormat::Mjpeg, 3.0)] {
            let dev = FakeDevice::new("fake0", Pattern::boxed(64, 48, 3));
            let mut src = LiveSource::start(dev, &options(Some(format))).unwrap();
            assert!(src.info().has_color);
            let (_, frames, err) = collect(&mut src);
            assert!(err.is_none(), "{format}: {err:?}");
            assert_eq!(frames.len(), 3);
            let mut scene = Pattern::boxed(64, 48, 3);
            let mut want = Frame::new(64, 48);
            scene.next_frame(&mut want).unwrap();
            // Limited-range luma from YUYV, plus JPEG loss for MJPEG.
            let err: f64 = want
                .gray
                .iter()
                .zip(&frames[0].gray)
                .map(|(a, b)| ((16.0 + *a as f64 * 219.0 / 255.0) - *b as f64).abs())
                .sum::<f64>()
                / want.gray.len() as f64;
            let limit = if format == PixelFormat::Mjpeg {
                20.0
            } else {
                1.5 + tol
            };
            // MJPEG goes through RGB (full-range luma), so compare it against the full range.
            let err = if format == PixelFormat::Mjpeg {
                want.gray
                    .iter()
                    .zip(&frames[0].gray)
                    .map(|(a, b)| (*a as f64 - *b as f64).abs())
                    .sum::<f64>()
                    / want.gray.len() as f64
            } else {
                err
            };
            assert!(err < limit, "{format}: mean grey error {err}");
            assert!(frames[0].has_color);
        }
    }

    #[test]
    fn timestamps_are_monotonic_seconds_at_the_camera_rate() {
        let dev = FakeDevice::new("fake0", Pattern::boxed(32, 16, 6));
        let mut src = LiveSource::start(dev, &options(Some(PixelFormat::Yuyv))).unwrap();
        let (_, frames, _) = collect(&mut src);
        for (i, w) in frames.windows(2).enumerate() {
            let dt = w[1].timestamp - w[0].timestamp;
            assert!((dt - 1.0 / 30.0).abs() < 1e-5, "dt {dt}");
            assert_eq!(w[0].index, i as u64);
        }
    }

    #[test]
    fn glitches_are_skipped_drops_counted_and_unplug_is_an_error() {
        let faults = Faults {
            corrupt: vec![1],
            truncated: vec![2],
            driver_drops: vec![4, 5],
            unplug_at: Some(8),
            ..Default::default()
        };
        let dev = FakeDevice::new("/dev/video7", Pattern::boxed(32, 16, 20)).with_faults(faults);
        let mut src = LiveSource::start(dev, &options(Some(PixelFormat::Yuyv))).unwrap();
        let stats = src.stats();
        let (statuses, frames, err) = collect(&mut src);
        let skipped = statuses
            .iter()
            .filter(|s| matches!(s, FrameStatus::Skipped { .. }))
            .count();
        assert_eq!(skipped, 2);
        assert_eq!(frames.len(), 4); // 0, 3, 6, 7
        let err = err.expect("unplug is an error");
        assert!(
            matches!(&err, SourceError::Device(d) if d.is_unplug()),
            "{err}"
        );
        assert!(
            err.to_string().contains("/dev/video7") && err.to_string().contains("disconnected")
        );
        assert_eq!(stats.driver_drops.load(Ordering::Relaxed), 2);
        assert_eq!(stats.corrupt.load(Ordering::Relaxed), 2);
    }

    #[test]
    fn a_silent_camera_times_out_with_its_name() {
        let faults = Faults {
            stall_at: Some(2),
            ..Default::default()
        };
        let dev = FakeDevice::new("/dev/video3", Pattern::boxed(32, 16, 20)).with_faults(faults);
        let mut src = LiveSource::start(dev, &options(None)).unwrap();
        let (_, frames, err) = collect(&mut src);
        assert_eq!(frames.len(), 2);
        let msg = err.unwrap().to_string();
        assert!(
            msg.contains("/dev/video3") && msg.contains("no frame for 0.2 s"),
            "{msg}"
        );
    }

    #[test]
    fn fixed_exposure_and_gain_are_set_and_clamped() {
        let dev = FakeDevice::new("fake0", Pattern::boxed(32, 16, 1));
        let opts = LiveOptions {
            exposure: Some(Exposure::Manual { micros: 8000 }),
            gain: Some(1000),
            ..options(None)
        };
        let src = LiveSource::start(dev, &opts).unwrap();
        assert_eq!(src.dev.control_value(CameraControl::AutoExposure), Some(1));
        assert_eq!(src.dev.control_value(CameraControl::ExposureTime), Some(80));
        assert_eq!(src.dev.control_value(CameraControl::Gain), Some(255));
        assert_eq!(src.warnings.len(), 1, "{:?}", src.warnings);
        assert!(src.warnings[0].contains("gain 1000"));
    }

    #[test]
    fn a_mode_of_another_size_is_refused() {
        let dev = FakeDevice::new("fake0", Pattern::boxed(32, 16, 1));
        let opts = LiveOptions {
            request: ModeRequest {
                size: Some((640, 480)),
                ..Default::default()
            },
            ..options(None)
        };
        let e = LiveSource::start(dev, &opts).err().unwrap();
        assert!(e.to_string().contains("640x480"), "{e}");
        // H.264-only cameras are refused with the modes listed.
        let dev = FakeDevice::new("fake0", Pattern::boxed(32, 16, 1)).with_modes(vec![Mode {
            format: PixelFormat::Other(*b"H264"),
            width: 32,
            height: 16,
            fps: vec![30.0],
        }]);
        let e = LiveSource::start(dev, &options(None)).err().unwrap();
        assert!(e.to_string().contains("H264 32x16@30"), "{e}");
    }

    #[test]
    fn behind_live_pacing_a_slow_consumer_gets_the_newest_frames() {
        let mut dev = FakeDevice::new("fake0", Pattern::boxed(32, 16, 40));
        dev.real_time = true;
        let src = LiveSource::start(dev, &options(Some(PixelFormat::Yuyv))).unwrap();
        let mut paced = PacedSource::spawn(src, Pacing::Live).unwrap();
        let stats = paced.stats();
        let mut f = Frame::new(32, 16);
        let mut seen = Vec::new();
        loop {
            match paced.next_frame(&mut f).unwrap() {
                FrameStatus::Ready => seen.push(f.index),
                FrameStatus::End => break,
                FrameStatus::Skipped { .. } => {}
            }
            // A consumer at ~10 fps against a 30 fps camera.
            std::thread::sleep(Duration::from_millis(100));
        }
        assert!(stats.dropped() > 10, "dropped {}", stats.dropped());
        assert!(seen.windows(2).all(|w| w[0] < w[1]));
        assert!(
            *seen.last().unwrap() >= 36,
            "last frame seen {:?}",
            seen.last()
        );
        paced.shutdown();
    }
}
