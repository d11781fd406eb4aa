//! The run as Foxglove channels: written to an MCAP file (`--mcap OUT.mcap`) and, in a build
//! with `--features foxglove`, served live over Foxglove's WebSocket protocol (`--foxglove`).
//! Every channel uses a Foxglove well-known schema (protobuf, from the official SDK) except
//! the tracking status, which is JSON with its JSON Schema; opening the file in Foxglove shows
//! the run after choosing the panels (3D: `/tf`, `/sdslam/keyframes`, the clouds; Plot:
//! `/sdslam/tracking`; Image: `/camera/image`).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use foxglove::messages::{
    packed_element_field::NumericType, CameraCalibration, FrameTransform, PackedElementField,
    PointCloud, Pose, PoseInFrame, PosesInFrame, Quaternion, RawImage, Timestamp, Vector3,
};
use foxglove::{Channel, Context, McapWriterHandle, PartialMetadata, RawChannel, Schema};

use sdslam::camera::Frame;
use sdslam::camera_model::Calibration;
use sdslam::eval::TimedPose;
use sdslam::geometry::{CloudPoint, WorldFromCamera};
use sdslam::runtime::FrameResult;
use sdslam::{Error, Result};

/// The tracking status channel's JSON Schema (the one non-Foxglove schema).
const STATUS_SCHEMA: &str = r#"{
  "title": "sdslam.TrackingStatus",
  "type": "object",
  "properties": {
    "frame": {"type": "integer", "description": "index of the frame in its source"},
    "state": {"type": "string", "enum": ["NotInitialised", "Ok", "Degraded", "Lost"]},
    "degraded": {"type": ["string", "null"], "description": "why the pose is Degraded"},
    "map": {"type": ["integer", "null"], "description": "atlas map the pose is in"},
    "new_keyframe": {"type": "boolean"},
    "latency_ms": {"type": "number", "description": "frame arrival to pose out"},
    "inliers": {"type": ["integer", "null"]},
    "centre_sigma_m": {"type": ["number", "null"], "description": "1-sigma camera centre uncertainty (map units)"},
    "keyframes": {"type": "integer"},
    "map_points": {"type": "integer"}
  }
}"#;

#[derive(serde::Serialize)]
struct Status<'a> {
    frame: u64,
    state: String,
    degraded: Option<String>,
    map: Option<u32>,
    new_keyframe: bool,
    latency_ms: f64,
    inliers: Option<usize>,
    centre_sigma_m: Option<f64>,
    keyframes: usize,
    map_points: usize,
    #[serde(skip)]
    _p: std::marker::PhantomData<&'a ()>,
}

/// The channels of a run and the sinks they go to.
pub struct Publisher {
    /// Owns the sinks the channels log to (the MCAP writer, the server).
    _ctx: Arc<Context>,
    mcap: Option<(
        McapWriterHandle<std::io::BufWriter<std::fs::File>>,
        PathBuf,
        PathBuf,
    )>,
    #[cfg(feature = "foxglove")]
    server: Option<foxglove::WebSocketServerHandle>,
    images: bool,
    pose: Channel<PoseInFrame>,
    tf: Channel<FrameTransform>,
    keyframes: Channel<PosesInFrame>,
    trajectory: Channel<PosesInFrame>,
    map_points: Channel<PointCloud>,
    semidense: Channel<PointCloud>,
    semidense_online: Channel<PointCloud>,
    image: Channel<RawImage>,
    calibration: Channel<CameraCalibration>,
    status: Arc<RawChannel>,
    calib_msg: CameraCalibration,
    /// Frames published so far (the calibration goes with the first and every keyframe, so a
    /// live viewer connecting late gets it too).
    frames: std::cell::Cell<u64>,
}

fn err(what: &str, e: impl std::fmt::Display) -> Error {
    Error::Invalid(format!("{what}: {e}"))
}

fn stamp(t: f64) -> Timestamp {
    let ns = sdslam::camera::mcap::write::to_ns(t);
    Timestamp::new((ns / 1_000_000_000) as u32, (ns % 1_000_000_000) as u32)
}

fn pose_of(t_wc: &WorldFromCamera) -> Pose {
    let p = t_wc.position();
    let q = t_wc.0.rotation;
    Pose {
        position: Some(Vector3 {
            x: p.x,
            y: p.y,
            z: p.z,
        }),
        orientation: Some(Quaternion {
            x: q.i,
            y: q.j,
            z: q.k,
            w: q.w,
        }),
    }
}

impl Publisher {
    /// Opens the sinks: the MCAP file (written to a temporary name, renamed by `close`) and
    /// the live server. `None` when neither is asked for.
    pub fn open(
        mcap: Option<&Path>,
        live: Option<&str>,
        images: bool,
        calib: &Calibration,
    ) -> Result<Option<Publisher>> {
        if mcap.is_none() && live.is_none() {
            return Ok(None);
        }
        let ctx = Context::new();
        let mcap = match mcap {
            Some(path) => {
                let tmp = temporary_name(path)?;
                let _ = std::fs::remove_file(&tmp);
                let opts = foxglove::McapWriteOptions::new()
                    .compression(Some(foxglove::McapCompression::Zstd));
                let handle = ctx
                    .mcap_writer_with_options(opts)
                    .create_new_buffered_file(&tmp)
                    .map_err(|e| err(&path.display().to_string(), e))?;
                Some((handle, tmp, path.to_path_buf()))
            }
            None => None,
        };
        #[cfg(feature = "foxglove")]
        let server = match live {
            Some(addr) => Some(start_server(&ctx, addr)?),
            None => None,
        };
        #[cfg(not(feature = "foxglove"))]
        if live.is_some() {
            return Err(Error::Invalid(
                "--foxglove needs a build with the live view: cargo build --release --features foxglove".into(),
            ));
        }
        let status = ctx
            .channel_builder("/sdslam/tracking")
            .message_encoding("json")
            .schema(Schema::new(
                "sdslam.TrackingStatus",
                "jsonschema",
                STATUS_SCHEMA.as_bytes(),
            ))
            .build_raw()
            .map_err(|e| err("foxglove channel /sdslam/tracking", e))?;
        let c = &calib.camera;
        let calib_msg = CameraCalibration {
            timestamp: None,
            frame_id: "camera".into(),
            width: c.width,
            height: c.height,
            distortion_model: "plumb_bob".into(),
            d: vec![c.k1, c.k2, c.p1, c.p2, c.k3],
            k: vec![c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0],
            r: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            p: vec![
                c.fx, 0.0, c.cx, 0.0, 0.0, c.fy, c.cy, 0.0, 0.0, 0.0, 1.0, 0.0,
            ],
        };
        Ok(Some(Publisher {
            pose: ctx.channel_builder("/sdslam/camera_pose").build(),
            tf: ctx.channel_builder("/tf").build(),
            keyframes: ctx.channel_builder("/sdslam/keyframes").build(),
            trajectory: ctx.channel_builder("/sdslam/trajectory").build(),
            map_points: ctx.channel_builder("/sdslam/map_points").build(),
            semidense: ctx.channel_builder("/sdslam/semidense").build(),
            semidense_online: ctx.channel_builder("/sdslam/semidense_online").build(),
            image: ctx.channel_builder("/camera/image").build(),
            calibration: ctx.channel_builder("/camera/calibration").build(),
            status,
            calib_msg,
            frames: std::cell::Cell::new(0),
            _ctx: ctx,
            mcap,
            #[cfg(feature = "foxglove")]
            server,
            images,
        }))
    }

    /// One frame: the calibration (first frame and keyframes), the pose and transform when tracked, the
    /// status, the image on request, and on a new keyframe the keyframes and the sparse map.
    pub fn frame(
        &self,
        frame: &Frame,
        out: &FrameResult,
        latency_ms: f64,
        system: &sdslam::runtime::System,
    ) {
        let t = frame.timestamp;
        let ns = sdslam::camera::mcap::write::to_ns(t);
        let first = self.frames.replace(self.frames.get() + 1) == 0;
        if first || out.new_keyframe {
            let mut m = self.calib_msg.clone();
            m.timestamp = Some(stamp(t));
            self.calibration.log_with_time(&m, ns);
        }
        if let Some(t_wc) = &out.t_wc {
            let pose = pose_of(t_wc);
            self.tf.log_with_time(
                &FrameTransform {
                    timestamp: Some(stamp(t)),
                    parent_frame_id: "world".into(),
                    child_frame_id: "camera".into(),
                    translation: pose.position,
                    rotation: pose.orientation,
                },
                ns,
            );
            self.pose.log_with_time(
                &PoseInFrame {
                    timestamp: Some(stamp(t)),
                    frame_id: "world".into(),
                    pose: Some(pose),
                },
                ns,
            );
        }
        let (keyframes, map_points) = system.map_size();
        let status = Status {
            frame: frame.index,
            state: format!("{:?}", out.state),
            degraded: out.degraded.map(|d| format!("{d:?}")),
            map: out.map,
            new_keyframe: out.new_keyframe,
            latency_ms,
            inliers: out.quality.as_ref().map(|q| q.inliers),
            centre_sigma_m: out.quality.as_ref().map(|q| q.centre_sigma),
            keyframes,
            map_points,
            _p: std::marker::PhantomData,
        };
        if let Ok(json) = serde_json::to_vec(&status) {
            self.status
                .log_with_meta(&json, PartialMetadata { log_time: Some(ns) });
        }
        if self.images {
            let (data, encoding, step) = if frame.has_color {
                (&frame.rgb, "rgb8", frame.width * 3)
            } else {
                (&frame.gray, "mono8", frame.width)
            };
            self.image.log_with_time(
                &RawImage {
                    timestamp: Some(stamp(t)),
                    frame_id: "camera".into(),
                    width: frame.width,
                    height: frame.height,
                    encoding: encoding.into(),
                    step,
                    data: foxglove::bytes::Bytes::copy_from_slice(data),
                },
                ns,
            );
        }
        if out.new_keyframe {
            self.keyframes(t, &system.keyframe_trajectory());
            self.map_points(t, system);
        }
    }

    /// The sparse map as it is now.
    pub fn map_points(&self, t: f64, system: &sdslam::runtime::System) {
        let map = system.map();
        let msg = cloud_xyz(
            t,
            map.points()
                .map(|(_, p)| (p.position.map(|v| v as f32).into(), None, None)),
        );
        self.map_points
            .log_with_time(&msg, sdslam::camera::mcap::write::to_ns(t));
    }

    /// The keyframe trajectory as it is now (BA and loop closure move it).
    pub fn keyframes(&self, t: f64, kfs: &[TimedPose]) {
        self.keyframes.log_with_time(
            &PosesInFrame {
                timestamp: Some(stamp(t)),
                frame_id: "world".into(),
                poses: kfs.iter().map(|k| pose_of(&k.t_wc)).collect(),
            },
            sdslam::camera::mcap::write::to_ns(t),
        );
    }

    /// A semi-dense cloud (the final one on `/sdslam/semidense`, the online one beside it when
    /// the end-of-session reconstruction replaced it), with colour and sigma fields.
    pub fn cloud(&self, t: f64, cloud: &[CloudPoint], online: bool) {
        let msg = cloud_xyz(
            t,
            cloud
                .iter()
                .map(|p| (p.position, Some(p.rgb), Some(p.sigma))),
        );
        let ch = if online {
            &self.semidense_online
        } else {
            &self.semidense
        };
        ch.log_with_time(&msg, sdslam::camera::mcap::write::to_ns(t));
    }

    /// The run's final trajectory (every tracked frame, after the last BA and loop closure).
    pub fn trajectory(&self, t: f64, poses: &[TimedPose]) {
        self.trajectory.log_with_time(
            &PosesInFrame {
                timestamp: Some(stamp(t)),
                frame_id: "world".into(),
                poses: poses.iter().map(|k| pose_of(&k.t_wc)).collect(),
            },
            sdslam::camera::mcap::write::to_ns(t),
        );
    }

    /// Stops the server and finishes the MCAP file under its temporary name (summary, sync).
    /// Returns that file, for the caller to rename into place, and how finishing went.
    pub fn finish(mut self) -> (Option<PathBuf>, Result<()>) {
        #[cfg(feature = "foxglove")]
        if let Some(s) = self.server.take() {
            let _ = s.stop();
        }
        let Some((handle, tmp, path)) = self.mcap.take() else {
            return (None, Ok(()));
        };
        let finished = (|| {
            let name = path.display().to_string();
            let w = handle.close().map_err(|e| err(&name, e))?;
            let f = w.into_inner().map_err(|e| err(&name, e.into_error()))?;
            f.sync_all().map_err(|e| Error::io(&path, e))
        })();
        (Some(tmp), finished)
    }
}

/// A run that ends before `finish` (an error while starting) leaves no temporary file.
impl Drop for Publisher {
    fn drop(&mut self) {
        if let Some((handle, tmp, _)) = self.mcap.take() {
            drop(handle);
            let _ = std::fs::remove_file(tmp);
        }
    }
}

/// `.NAME.tmpPID` beside `path`: the file is only renamed to `path` once complete.
fn temporary_name(path: &Path) -> Result<PathBuf> {
    let name = path
        .file_name()
        .ok_or_else(|| Error::Invalid(format!("{}: not a file path", path.display())))?;
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    Ok(dir.join(format!(
        ".{}.tmp{}",
        name.to_string_lossy(),
        std::process::id()
    )))
}

/// A `foxglove.PointCloud` in the world frame: x, y, z (float32), then red, green, blue,
/// alpha (uint8) and sigma (float32) when given.
fn cloud_xyz(
    t: f64,
    points: impl Iterator<Item = ([f32; 3], Option<[u8; 3]>, Option<f32>)>,
) -> PointCloud {
    let field = |name: &str, offset: u32, ty: NumericType| PackedElementField {
        name: name.into(),
        offset,
        r#type: ty as i32,
    };
    let mut data = Vec::new();
    let mut coloured = false;
    for (p, rgb, sigma) in points {
        for v in p {
            data.extend_from_slice(&v.to_le_bytes());
        }
        if let Some(c) = rgb {
            coloured = true;
            data.extend_from_slice(&[c[0], c[1], c[2], 255]);
            data.extend_from_slice(&sigma.unwrap_or(0.0).to_le_bytes());
        }
    }
    let mut fields = vec![
        field("x", 0, NumericType::Float32),
        field("y", 4, NumericType::Float32),
        field("z", 8, NumericType::Float32),
    ];
    let stride = if coloured {
        fields.extend([
            field("red", 12, NumericType::Uint8),
            field("green", 13, NumericType::Uint8),
            field("blue", 14, NumericType::Uint8),
            field("alpha", 15, NumericType::Uint8),
            field("sigma", 16, NumericType::Float32),
        ]);
        20
    } else {
        12
    };
    PointCloud {
        timestamp: Some(stamp(t)),
        frame_id: "world".into(),
        pose: None,
        point_stride: stride,
        fields,
        data: data.into(),
    }
}

/// Starts the Foxglove WebSocket server on `HOST:PORT`.
#[cfg(feature = "foxglove")]
fn start_server(ctx: &Arc<Context>, addr: &str) -> Result<foxglove::WebSocketServerHandle> {
    let (host, port) = addr
        .rsplit_once(':')
        .and_then(|(h, p)| Some((h, p.parse::<u16>().ok()?)))
        .ok_or_else(|| err("--foxglove", format!("`{addr}` is not HOST:PORT")))?;
    let handle = ctx
        .websocket_server()
        .name("sdslam")
        .bind(host, port)
        .start_blocking()
        .map_err(|e| err(&format!("foxglove server on {addr}"), e))?;
    note!(
        "sdslam: Foxglove live view on ws://{host}:{}: open Foxglove and connect to it",
        handle.port()
    );
    Ok(handle)
}
