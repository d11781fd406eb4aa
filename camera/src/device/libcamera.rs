//! The libcamera back end (Raspberry Pi CSI cameras and other ISP pipelines), behind the
//! `libcamera` feature. libcamera's objects borrow one another (manager, camera, requests), so
//! a session thread owns them all; [`LibcameraDevice`] talks to it over bounded channels and
//! copies each completed buffer into a pooled vector (newest frame wins when the consumer is
//! behind, the gap shows as a driver drop).

use std::thread::JoinHandle;
use std::time::Duration;

use crossbeam_channel::{bounded, Receiver, RecvTimeoutError, Sender};
use libcamera::camera_manager::CameraManager;
use libcamera::control::ControlList;
use libcamera::framebuffer::AsFrameBuffer;
use libcamera::framebuffer_allocator::{FrameBuffer, FrameBufferAllocator};
use libcamera::framebuffer_map::MemoryMappedFrameBuffer;
use libcamera::geometry::Size;
use libcamera::pixel_format::PixelFormat as LcFormat;
use libcamera::request::ReuseFlag;
use libcamera::stream::StreamRole;

use super::controls::{CameraControl, ControlInfo};
use super::format::{ChosenMode, Mode, PixelFormat};
use super::timestamp::BufferMeta;
use super::{CameraSummary, CaptureDevice, DeviceError};

type Reply<T> = Sender<Result<T, String>>;

enum Cmd {
    Modes(Reply<Vec<Mode>>),
    Configure(ChosenMode, Reply<(ChosenMode, usize)>),
    SetControl(CameraControl, i64, Reply<()>),
    Start(Reply<()>),
    Stop,
}

struct Captured {
    data: Vec<u8>,
    meta: BufferMeta,
}

/// A camera driven through libcamera.
pub struct LibcameraDevice {
    id: String,
    cmd: Sender<Cmd>,
    frames: Receiver<Captured>,
    recycle: Sender<Vec<u8>>,
    thread: Option<JoinHandle<()>>,
}

const FRAME_QUEUE: usize = 2;

impl LibcameraDevice {
    /// Opens camera `id` (its libcamera id, or its index in `sdslam cameras`).
    pub fn open(id: &str) -> Result<Self, DeviceError> {
        let (cmd, cmd_rx) = bounded::<Cmd>(4);
        let (frame_tx, frames) = bounded::<Captured>(FRAME_QUEUE);
        let (recycle, recycle_rx) = bounded::<Vec<u8>>(FRAME_QUEUE + 2);
        let (ready_tx, ready_rx) = bounded::<Result<(), String>>(1);
        let (name, steal) = (id.to_string(), frames.clone());
        let thread = std::thread::Builder::new()
            .name("libcamera".into())
            .spawn(move || session(&name, cmd_rx, frame_tx, steal, recycle_rx, ready_tx))
            .map_err(|e| DeviceError::Other {
                device: id.into(),
                message: e.to_string(),
            })?;
        let dev = LibcameraDevice {
            id: id.to_string(),
            cmd,
            frames,
            recycle,
            thread: Some(thread),
        };
        match ready_rx.recv() {
            Ok(Ok(())) => Ok(dev),
            Ok(Err(message)) => Err(DeviceError::Other {
                device: id.into(),
                message,
            }),
            Err(_) => Err(DeviceError::Other {
                device: id.into(),
                message: "libcamera session ended".into(),
            }),
        }
    }

    fn ask<T>(&self, make: impl FnOnce(Reply<T>) -> Cmd) -> Result<T, DeviceError> {
        let (tx, rx) = bounded(1);
        let gone = || DeviceError::Unplugged {
            device: self.id.clone(),
        };
        self.cmd.send(make(tx)).map_err(|_| gone())?;
        match rx.recv() {
            Ok(r) => r.map_err(|message| DeviceError::Other {
                device: self.id.clone(),
                message,
            }),
            Err(_) => Err(gone()),
        }
    }
}

impl CaptureDevice for LibcameraDevice {
    fn name(&self) -> &str {
        &self.id
    }

    fn modes(&mut self) -> Result<Vec<Mode>, DeviceError> {
        self.ask(Cmd::Modes)
    }

    fn configure(&mut self, mode: &ChosenMode) -> Result<(ChosenMode, usize), DeviceError> {
        let m = *mode;
        self.ask(move |r| Cmd::Configure(m, r))
    }

    fn controls(&mut self) -> Result<Vec<ControlInfo>, DeviceError> {
        // libcamera takes exposure in microseconds and gain as a factor; expose them in the
        // V4L2 units the policy uses (100 us, gain x 100).
        Ok(vec![
            ControlInfo {
                control: CameraControl::AutoExposure,
                min: 0,
                max: 3,
                default: 3,
            },
            ControlInfo {
                control: CameraControl::ExposureTime,
                min: 1,
                max: 10_000,
                default: 100,
            },
            ControlInfo {
                control: CameraControl::AutoGain,
                min: 0,
                max: 1,
                default: 1,
            },
            ControlInfo {
                control: CameraControl::Gain,
                min: 100,
                max: 1600,
                default: 100,
            },
        ])
    }

    fn set_control(&mut self, control: CameraControl, value: i64) -> Result<(), DeviceError> {
        self.ask(move |r| Cmd::SetControl(control, value, r))
    }

    fn start(&mut self, _buffers: u32) -> Result<(), DeviceError> {
        self.ask(Cmd::Start)
    }

    fn next_buffer(
        &mut self,
        timeout: Duration,
        f: &mut dyn FnMut(&[u8], &BufferMeta),
    ) -> Result<(), DeviceError> {
        match self.frames.recv_timeout(timeout) {
            Ok(c) => {
                f(&c.data, &c.meta);
                let _ = self.recycle.try_send(c.data);
                Ok(())
            }
            Err(RecvTimeoutError::Timeout) => Err(DeviceError::Timeout {
                device: self.id.clone(),
                seconds: timeout.as_secs_f64(),
            }),
            Err(RecvTimeoutError::Disconnected) => Err(DeviceError::Unplugged {
                device: self.id.clone(),
            }),
        }
    }

    fn stop(&mut self) {
        let _ = self.cmd.send(Cmd::Stop);
        while self.frames.try_recv().is_ok() {}
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for LibcameraDevice {
    fn drop(&mut self) {
        self.stop();
    }
}

fn lc_format(f: PixelFormat) -> LcFormat {
    LcFormat::new(u32::from_le_bytes(f.fourcc()), 0)
}

fn our_format(f: LcFormat) -> PixelFormat {
    PixelFormat::from_fourcc(f.fourcc().to_le_bytes())
}

/// The session thread: owns the manager, the camera and its requests.
fn session(
    id: &str,
    cmd_rx: Receiver<Cmd>,
    frame_tx: Sender<Captured>,
    steal: Receiver<Captured>,
    recycle_rx: Receiver<Vec<u8>>,
    ready: Sender<Result<(), String>>,
) {
    let mgr = match CameraManager::new() {
        Ok(m) => m,
        Err(e) => {
            let _ = ready.send(Err(format!("cannot start libcamera: {e}")));
            return;
        }
    };
    let cameras = mgr.cameras();
    let found = (0..cameras.len())
        .filter_map(|i| cameras.get(i))
        .enumerate()
        .find(|(i, c)| c.id() == id || i.to_string() == id)
        .map(|(_, c)| c);
    let Some(cam) = found else {
        let _ = ready.send(Err("no such libcamera camera (see `sdslam cameras`)".into()));
        return;
    };
    let mut active = match cam.acquire() {
        Ok(a) => a,
        Err(e) => {
            let _ = ready.send(Err(format!("cannot acquire the camera: {e}")));
            return;
        }
    };
    let _ = ready.send(Ok(()));
    let mut config = None;
    let mut controls = ControlList::new();
    while let Ok(cmd) = cmd_rx.recv() {
        match cmd {
            Cmd::Modes(reply) => {
                let modes = cam
                    .generate_configuration(&[StreamRole::VideoRecording])
                    .and_then(|cfgs| {
                        let cfg = cfgs.get(0)?;
                        let formats = cfg.formats();
                        let mut modes = Vec::new();
                        for pf in &*formats.pixel_formats() {
                            for s in formats.sizes(pf) {
                                modes.push(Mode {
                                    format: our_format(pf),
                                    width: s.width,
                                    height: s.height,
                                    fps: vec![],
                                });
                            }
                        }
                        Some(modes)
                    })
                    .ok_or_else(|| "the camera offers no video configuration".to_string());
                let _ = reply.send(modes);
            }
            Cmd::Configure(mode, reply) => {
                let r = (|| {
                    let mut cfgs = cam
                        .generate_configuration(&[StreamRole::VideoRecording])
                        .ok_or("the camera offers no video configuration")?;
                    {
                        let mut s = cfgs.get_mut(0).ok_or("no stream")?;
                        s.set_pixel_format(lc_format(mode.format));
                        s.set_size(Size {
                            width: mode.width,
                            height: mode.height,
                        });
                    }
                    if cfgs.validate().is_invalid() {
                        return Err("configuration rejected".to_string());
                    }
                    active
                        .configure(&mut cfgs)
                        .map_err(|e| format!("configure: {e}"))?;
                    let s = cfgs.get(0).ok_or("no stream")?;
                    let size = s.get_size();
                    let got = ChosenMode {
                        format: our_format(s.get_pixel_format()),
                        width: size.width,
                        height: size.height,
                        fps: mode.fps,
                    };
                    let stride = s.get_stride() as usize;
                    config = Some(cfgs);
                    Ok((got, stride))
                })();
                let _ = reply.send(r);
            }
            Cmd::SetControl(c, v, reply) => {
                use libcamera::controls::{AeEnable, AnalogueGain, ExposureTime};
                let r = match c {
                    CameraControl::AutoExposure => controls.set(AeEnable(v != 1)),
                    CameraControl::ExposureTime => controls.set(ExposureTime((v * 100) as i32)),
                    CameraControl::AutoGain => Ok(()),
                    CameraControl::Gain => controls.set(AnalogueGain(v as f32 / 100.0)),
                };
                let _ = reply.send(r.map_err(|e| format!("{c:?}: {e:?}")));
            }
            Cmd::Start(reply) => {
                let Some(cfgs) = config.as_ref() else {
                    let _ = reply.send(Err("start before configure".into()));
                    continue;
                };
                stream(
                    &mut active,
                    cfgs,
                    &controls,
                    reply,
                    &cmd_rx,
                    &frame_tx,
                    &steal,
                    &recycle_rx,
                );
                return;
            }
            Cmd::Stop => return,
        }
    }
}

/// Streams until told to stop or the consumer goes away.
#[allow(clippy::too_many_arguments)]
fn stream(
    active: &mut libcamera::camera::ActiveCamera<'_>,
    cfgs: &libcamera::camera::CameraConfiguration,
    controls: &ControlList,
    reply: Reply<()>,
    cmd_rx: &Receiver<Cmd>,
    frame_tx: &Sender<Captured>,
    steal: &Receiver<Captured>,
    recycle_rx: &Receiver<Vec<u8>>,
) {
    let setup = (|| {
        let stream = cfgs.get(0).and_then(|c| c.stream()).ok_or("no stream")?;
        let mut alloc = FrameBufferAllocator::new(active);
        let buffers = alloc
            .alloc(&stream)
            .map_err(|e| format!("allocate buffers: {e}"))?;
        let mut reqs = Vec::new();
        for b in buffers {
            let mapped =
                MemoryMappedFrameBuffer::new(b).map_err(|e| format!("map buffer: {e:?}"))?;
            let mut req = active
                .create_request(None)
                .ok_or("cannot create a request")?;
            req.add_buffer(&stream, mapped)
                .map_err(|e| format!("add buffer: {e}"))?;
            reqs.push(req);
        }
        Ok::<_, String>((stream, reqs))
    })();
    let (stream, reqs) = match setup {
        Ok(s) => s,
        Err(e) => {
            let _ = reply.send(Err(e));
            return;
        }
    };
    let (done_tx, done_rx) = std::sync::mpsc::channel();
    active.on_request_completed(move |req| {
        let _ = done_tx.send(req);
    });
    if let Err(e) = active.start(Some(controls)) {
        let _ = reply.send(Err(format!("start: {e}")));
        return;
    }
    for r in reqs {
        if let Err(e) = active.queue_request(r) {
            let _ = reply.send(Err(format!("queue request: {e}")));
            let _ = active.stop();
            return;
        }
    }
    let _ = reply.send(Ok(()));
    loop {
        if let Ok(Cmd::Stop) | Err(crossbeam_channel::TryRecvError::Disconnected) =
            cmd_rx.try_recv()
        {
            break;
        }
        let mut req = match done_rx.recv_timeout(Duration::from_millis(100)) {
            Ok(r) => r,
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => continue,
            Err(_) => break,
        };
        if let Some(fb) = req.buffer::<MemoryMappedFrameBuffer<FrameBuffer>>(&stream) {
            if let Some(md) = fb.metadata() {
                let planes = fb.data();
                let used = md
                    .planes()
                    .get(0)
                    .map(|p| p.bytes_used as usize)
                    .unwrap_or(0);
                if let Some(plane) = planes.first() {
                    let used = if used == 0 {
                        plane.len()
                    } else {
                        used.min(plane.len())
                    };
                    let mut data = recycle_rx.try_recv().unwrap_or_default();
                    data.clear();
                    data.extend_from_slice(&plane[..used]);
                    let ns = md.timestamp();
                    let meta = BufferMeta {
                        sequence: md.sequence(),
                        sec: (ns / 1_000_000_000) as i64,
                        usec: ((ns % 1_000_000_000) / 1000) as i64,
                        monotonic: true,
                        bytes_used: used,
                        error: !matches!(
                            md.status(),
                            libcamera::framebuffer::FrameMetadataStatus::Success
                        ),
                    };
                    let mut msg = Captured { data, meta };
                    // Newest wins: a full queue loses its oldest frame.
                    loop {
                        match frame_tx.try_send(msg) {
                            Ok(()) => break,
                            Err(crossbeam_channel::TrySendError::Full(m)) => {
                                msg = m;
                                let _ = steal.try_recv();
                            }
                            Err(crossbeam_channel::TrySendError::Disconnected(_)) => {
                                let _ = active.stop();
                                return;
                            }
                        }
                    }
                }
            }
        }
        req.reuse(ReuseFlag::REUSE_BUFFERS);
        if active.queue_request(req).is_err() {
            break; // camera gone: the consumer sees the channel close as an unplug
        }
    }
    let _ = active.stop();
}

/// Cameras libcamera sees.
pub fn list() -> Vec<CameraSummary> {
    let Ok(mgr) = CameraManager::new() else {
        return Vec::new();
    };
    let cameras = mgr.cameras();
    let mut out = Vec::new();
    for i in 0..cameras.len() {
        let Some(cam) = cameras.get(i) else { continue };
        let id = cam.id().to_string();
        let mut modes = Vec::new();
        if let Some(cfgs) = cam.generate_configuration(&[StreamRole::VideoRecording]) {
            if let Some(cfg) = cfgs.get(0) {
                let formats = cfg.formats();
                for pf in &*formats.pixel_formats() {
                    for s in formats.sizes(pf) {
                        modes.push(Mode {
                            format: our_format(pf),
                            width: s.width,
                            height: s.height,
                            fps: vec![],
                        });
                    }
                }
            }
        }
        out.push(CameraSummary {
            spec: format!("libcamera:{i}"),
            name: id,
            modes,
            error: None,
        });
    }
    out
}
