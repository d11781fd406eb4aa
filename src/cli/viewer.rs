//! Live viewer through Rerun (`--features rerun`): the camera pose per frame, the keyframe
//! trajectory as it is corrected, and the semi-dense cloud, either to a running viewer
//! (`--rerun`) or to a `.rrd` recording (`--rerun-save FILE`). Off by default: the SDK is large.

use sdslam::eval::TimedPose;
use sdslam::geometry::WorldFromCamera;
use sdslam::io::CloudPoint;
use sdslam::{Error, Result};

pub struct Viewer {
    rec: rerun::RecordingStream,
}

fn err(e: impl std::fmt::Display) -> Error {
    Error::Invalid(format!("rerun: {e}"))
}

impl Viewer {
    /// Connects to a viewer (spawning one if none runs) or records to `save`.
    pub fn open(save: Option<&std::path::Path>) -> Result<Viewer> {
        let b = rerun::RecordingStreamBuilder::new("sdslam");
        let rec = match save {
            Some(p) => b.save(p).map_err(err)?,
            None => b.spawn().map_err(err)?,
        };
        Ok(Viewer { rec })
    }

    fn at(&self, t: f64) {
        self.rec.set_duration_secs("time", t);
    }

    /// The camera at time `t`.
    pub fn frame(&self, t: f64, t_wc: &WorldFromCamera) {
        self.at(t);
        let p = t_wc.position();
        let q = t_wc.0.rotation;
        let _ = self.rec.log(
            "world/camera",
            &rerun::Transform3D::from_translation_rotation(
                [p.x as f32, p.y as f32, p.z as f32],
                rerun::Quaternion::from_xyzw([q.i as f32, q.j as f32, q.k as f32, q.w as f32]),
            ),
        );
    }

    /// The keyframe trajectory as it is now (loop closure and BA move it).
    pub fn keyframes(&self, t: f64, kfs: &[TimedPose]) {
        self.at(t);
        let pts: Vec<[f32; 3]> = kfs
            .iter()
            .map(|k| {
                let c = k.t_wc.position();
                [c.x as f32, c.y as f32, c.z as f32]
            })
            .collect();
        let _ = self.rec.log(
            "world/keyframes",
            &rerun::Points3D::new(pts.clone()).with_radii([0.01f32]),
        );
        let _ = self
            .rec
            .log("world/trajectory", &rerun::LineStrips3D::new([pts]));
    }

    /// The semi-dense cloud in its colours.
    pub fn cloud(&self, t: f64, cloud: &[CloudPoint]) {
        self.at(t);
        let _ = self.rec.log(
            "world/semidense",
            &rerun::Points3D::new(cloud.iter().map(|p| p.position))
                .with_colors(
                    cloud
                        .iter()
                        .map(|p| rerun::Color::from_rgb(p.rgb[0], p.rgb[1], p.rgb[2])),
                )
                .with_radii([0.003f32]),
        );
    }
}
