//! The writer thread's end: the Foxglove context with its channels and sinks (the MCAP file,
//! the live server), and the messages built from a [`Job`].

use std::path::{Path, PathBuf};
use std::sync::Arc;

use foxglove::messages::{
    packed_element_field::NumericType, CameraCalibration, FrameTransform, PackedElementField,
    PointCloud, Pose, PoseInFrame, PosesInFrame, Quaternion, RawImage, Timestamp, Vector3,
};
use foxglove::{Channel, Context, McapWriterHandle, PartialMetadata, RawChannel, Schema};

use sdslam::camera::mcap::write::to_ns;
use sdslam::camera_model::Calibration;
use sdslam::geometry::{CloudPoint, WorldFromCamera};
use sdslam::{Error, Result};

use super::{FrameJob, Job};

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

/// One frame's tracking status (`/sdslam/tracking`, JSON).
#[derive(serde::Serialize)]
pub struct Status {
    pub frame: u64,
    pub state: String,
    pub degraded: Option<String>,
    pub map: Option<u32>,
    pub new_keyframe: bool,
    pub latency_ms: f64,
    pub inliers: Option<usize>,
    pub centre_sigma_m: Option<f64>,
    pub keyframes: usize,
    pub map_points: usize,
}

type McapFile = McapWriterHandle<std::io::BufWriter<std::fs::File>>;

/// The channels of a run and the sinks they go to.
pub struct Sinks {
    /// Owns the sinks the channels log to.
    _ctx: Arc<Context>,
    mcap: Option<(McapFile, PathBuf, PathBuf)>,
    #[cfg(feature = "foxglove")]
    server: Option<foxglove::WebSocketServerHandle>,
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
}

fn err(what: &str, e: impl std::fmt::Display) -> Error {
    Error::Invalid(format!("{what}: {e}"))
}

pub fn stamp(t: f64) -> Timestamp {
    let ns = to_ns(t);
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

impl Sinks {
    /// The MCAP file (zstd chunks; lz4 with images, whose zstd compression costs ~14 ms a
    /// 640x480 frame against ~4 ms) under a temporary name, the live server, the channels.
    pub fn open(
        mcap: Option<&Path>,
        live: Option<&str>,
        images: bool,
        calib: &Calibration,
    ) -> Result<Sinks> {
        let ctx = Context::new();
        let mcap = match mcap {
            Some(path) => {
                let tmp = temporary_name(path)?;
                let _ = std::fs::remove_file(&tmp);
                let compression = if images {
                    foxglove::McapCompression::Lz4
                } else {
                    foxglove::McapCompression::Zstd
                };
                let opts = foxglove::McapWriteOptions::new().compression(Some(compression));
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
        Ok(Sinks {
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
            _ctx: ctx,
            mcap,
            #[cfg(feature = "foxglove")]
            server,
        })
    }

    /// Logs one job's messages.
    pub fn log(&mut self, job: Job) {
        match job {
            Job::Frame(f) => self.frame(*f),
            Job::Keyframes { t, poses } => self
                .keyframes
                .log_with_time(&poses_msg(t, &poses), to_ns(t)),
            Job::Trajectory { t, poses } => self
                .trajectory
                .log_with_time(&poses_msg(t, &poses), to_ns(t)),
            Job::MapPoints { t, points } => {
                let msg = cloud_msg(t, points.iter().map(|p| (*p, None, None)));
                self.map_points.log_with_time(&msg, to_ns(t));
            }
            Job::Cloud { t, points, online } => {
                let msg = cloud_msg(t, points.iter().map(cloud_point));
                let ch = if online {
                    &self.semidense_online
                } else {
                    &self.semidense
                };
                ch.log_with_time(&msg, to_ns(t));
            }
        }
    }

    fn frame(&mut self, f: FrameJob) {
        let ns = to_ns(f.t);
        if f.calibration {
            let mut m = self.calib_msg.clone();
            m.timestamp = Some(stamp(f.t));
            self.calibration.log_with_time(&m, ns);
        }
        if let Some(t_wc) = &f.t_wc {
            let pose = pose_of(t_wc);
            self.tf.log_with_time(
                &FrameTransform {
                    timestamp: Some(stamp(f.t)),
                    parent_frame_id: "world".into(),
                    child_frame_id: "camera".into(),
                    translation: pose.position,
                    rotation: pose.orientation,
                },
                ns,
            );
            self.pose.log_with_time(
                &PoseInFrame {
                    timestamp: Some(stamp(f.t)),
                    frame_id: "world".into(),
                    pose: Some(pose),
                },
                ns,
            );
        }
        if let Ok(json) = serde_json::to_vec(&f.status) {
            self.status
                .log_with_meta(&json, PartialMetadata { log_time: Some(ns) });
        }
        if let Some(image) = &f.image {
            self.image.log_with_time(image, ns);
        }
    }

    /// Stops the server (after a moment for connected viewers to receive the final map and
    /// cloud) and finishes the MCAP file under its temporary name (summary, sync).
    pub fn finish(mut self) -> (Option<PathBuf>, Result<()>) {
        #[cfg(feature = "foxglove")]
        if let Some(s) = self.server.take() {
            if s.client_count() > 0 {
                std::thread::sleep(std::time::Duration::from_secs(2));
            }
            s.stop().wait_blocking();
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

fn poses_msg(t: f64, poses: &[WorldFromCamera]) -> PosesInFrame {
    PosesInFrame {
        timestamp: Some(stamp(t)),
        frame_id: "world".into(),
        poses: poses.iter().map(pose_of).collect(),
    }
}

fn cloud_point(p: &CloudPoint) -> ([f32; 3], Option<[u8; 3]>, Option<f32>) {
    (p.position, Some(p.rgb), Some(p.sigma))
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
fn cloud_msg(
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
