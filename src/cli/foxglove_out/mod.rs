//! The run as Foxglove channels: written to an MCAP file (`--mcap OUT.mcap`) and, in a build
//! with `--features foxglove`, served live over Foxglove's WebSocket protocol (`--foxglove`).
//! Every channel uses a Foxglove well-known schema (protobuf, from the official SDK) except
//! the tracking status, which is JSON with its JSON Schema; opening the file in Foxglove shows
//! the run after choosing the panels (3D: `/tf`, `/sdslam/keyframes`, the clouds; Plot:
//! `/sdslam/tracking`; Image: `/camera/image`).
//!
//! The tracking thread only builds the messages and hands them over a bounded channel; a
//! writer thread logs them (MCAP chunk compression of an image costs 4-14 ms, more than a
//! third of a 30 fps frame). When the writer falls behind, per-frame messages are dropped and
//! counted rather than delaying tracking.

use std::path::{Path, PathBuf};
use std::thread::JoinHandle;

use crossbeam_channel::{bounded, Sender, TrySendError};
use foxglove::messages::RawImage;

use sdslam::camera::Frame;
use sdslam::camera_model::Calibration;
use sdslam::eval::TimedPose;
use sdslam::geometry::{CloudPoint, WorldFromCamera};
use sdslam::runtime::{FrameResult, System};
use sdslam::Result;

mod sinks;

use sinks::{stamp, Sinks, Status};

/// Per-frame messages the writer may be behind by before new ones are dropped.
const QUEUE: usize = 32;

/// What the tracking thread hands to the writer thread.
enum Job {
    Frame(Box<FrameJob>),
    Keyframes {
        t: f64,
        poses: Vec<WorldFromCamera>,
    },
    MapPoints {
        t: f64,
        points: Vec<[f32; 3]>,
    },
    Trajectory {
        t: f64,
        poses: Vec<WorldFromCamera>,
    },
    Cloud {
        t: f64,
        points: Vec<CloudPoint>,
        online: bool,
    },
}

/// One frame's messages.
struct FrameJob {
    t: f64,
    t_wc: Option<WorldFromCamera>,
    status: Status,
    calibration: bool,
    image: Option<RawImage>,
}

/// The tracking thread's end: builds messages and queues them for the writer thread.
pub struct Publisher {
    tx: Option<Sender<Job>>,
    writer: Option<JoinHandle<(Option<PathBuf>, Result<()>)>>,
    images: bool,
    frames: u64,
    dropped: u64,
}

impl Publisher {
    /// Opens the sinks (the MCAP file under a temporary name, the live server) and starts
    /// the writer thread. `None` when neither sink is asked for.
    pub fn open(
        mcap: Option<&Path>,
        live: Option<&str>,
        images: bool,
        calib: &Calibration,
    ) -> Result<Option<Publisher>> {
        if mcap.is_none() && live.is_none() {
            return Ok(None);
        }
        let mut sinks = Sinks::open(mcap, live, images, calib)?;
        let (tx, rx) = bounded::<Job>(QUEUE);
        let writer = std::thread::Builder::new()
            .name("sdslam-mcap".into())
            .spawn(move || {
                for job in rx {
                    sinks.log(job);
                }
                sinks.finish()
            })
            .map_err(|e| sdslam::Error::Invalid(format!("MCAP writer thread: {e}")))?;
        Ok(Some(Publisher {
            tx: Some(tx),
            writer: Some(writer),
            images,
            frames: 0,
            dropped: 0,
        }))
    }

    /// One frame: the calibration (first frame and keyframes, so a live viewer connecting
    /// late gets it too), the pose and transform when tracked, the status, the image on
    /// request, and on a new keyframe the keyframes and the sparse map.
    pub fn frame(&mut self, frame: &Frame, out: &FrameResult, latency_ms: f64, system: &System) {
        let t = frame.timestamp;
        let (keyframes, map_points) = system.map_size();
        let image = self.images.then(|| {
            let (data, encoding, step) = if frame.has_color {
                (&frame.rgb, "rgb8", frame.width * 3)
            } else {
                (&frame.gray, "mono8", frame.width)
            };
            RawImage {
                timestamp: Some(stamp(t)),
                frame_id: "camera".into(),
                width: frame.width,
                height: frame.height,
                encoding: encoding.into(),
                step,
                data: foxglove::bytes::Bytes::copy_from_slice(data),
            }
        });
        let job = FrameJob {
            t,
            t_wc: out.t_wc,
            status: Status {
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
            },
            calibration: self.frames == 0 || out.new_keyframe,
            image,
        };
        self.frames += 1;
        self.offer(Job::Frame(Box::new(job)));
        if out.new_keyframe {
            self.offer(Job::Keyframes {
                t,
                poses: poses(&system.keyframe_trajectory()),
            });
            self.offer(Job::MapPoints {
                t,
                points: map_points_of(system),
            });
        }
    }

    /// Queues without waiting; a full queue drops the job (counted).
    fn offer(&mut self, job: Job) {
        if let Some(tx) = &self.tx {
            if let Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) = tx.try_send(job) {
                self.dropped += 1;
            }
        }
    }

    /// Queues, waiting for room: the end-of-run messages are not dropped.
    fn send(&mut self, job: Job) {
        if let Some(tx) = &self.tx {
            if tx.send(job).is_err() {
                self.dropped += 1;
            }
        }
    }

    /// The end of the run: the final trajectory (every tracked frame after the last BA and
    /// loop closure), keyframes, sparse map and semi-dense clouds.
    pub fn end_of_run(
        &mut self,
        trajectory: &[TimedPose],
        keyframes: &[TimedPose],
        system: &System,
        cloud: &[CloudPoint],
        online: Option<&[CloudPoint]>,
    ) {
        let t = trajectory.last().map_or(0.0, |k| k.timestamp);
        self.send(Job::Trajectory {
            t,
            poses: poses(trajectory),
        });
        self.send(Job::Keyframes {
            t,
            poses: poses(keyframes),
        });
        self.send(Job::MapPoints {
            t,
            points: map_points_of(system),
        });
        self.send(Job::Cloud {
            t,
            points: cloud.to_vec(),
            online: false,
        });
        if let Some(online) = online {
            self.send(Job::Cloud {
                t,
                points: online.to_vec(),
                online: true,
            });
        }
    }

    /// Waits for the writer to log everything queued, then finishes the MCAP file under its
    /// temporary name and stops the server. Returns that file, for the caller to rename into
    /// place, how finishing went, and how many messages were dropped on the way.
    pub fn finish(mut self) -> (Option<PathBuf>, Result<()>, u64) {
        drop(self.tx.take());
        let (tmp, result) = match self.writer.take().map(JoinHandle::join) {
            Some(Ok(r)) => r,
            Some(Err(_)) => (
                None,
                Err(sdslam::Error::Invalid(
                    "the MCAP writer thread panicked".into(),
                )),
            ),
            None => (None, Ok(())),
        };
        (tmp, result, self.dropped)
    }
}

/// A run that ends before `finish` (an error while starting) leaves no temporary file.
impl Drop for Publisher {
    fn drop(&mut self) {
        drop(self.tx.take());
        if let Some(Ok((Some(tmp), _))) = self.writer.take().map(JoinHandle::join) {
            let _ = std::fs::remove_file(tmp);
        }
    }
}

fn poses(p: &[TimedPose]) -> Vec<WorldFromCamera> {
    p.iter().map(|k| k.t_wc).collect()
}

fn map_points_of(system: &System) -> Vec<[f32; 3]> {
    system
        .map()
        .points()
        .map(|(_, p)| p.position.map(|v| v as f32).into())
        .collect()
}
