//! Semi-dense accuracy by the project's protocol: the cloud is brought into the ground-truth
//! frame with the keyframe trajectory's Sim3 alignment, each point is projected into the
//! ground-truth depth map nearest in time to its reference keyframe, the best-agreeing ground
//! truth in the 3x3 pixels around the projection is taken (ground truth mixes depths at
//! edges, where semi-dense points live), and the relative depth errors are summarised.

use serde::Serialize;

use crate::camera_model::CameraModel;
use crate::geometry::CloudPoint;
use crate::geometry::{Sim3, WorldFromCamera};

/// A ground-truth depth map (metres along the optical axis, 0 = none) and its camera pose.
pub struct DepthFrame {
    pub timestamp: f64,
    pub t_wc: WorldFromCamera,
    pub depth: Vec<f32>,
}

/// Summary of the relative depth errors.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct CloudAccuracy {
    pub points: usize,
    /// Points with ground truth around their projection.
    pub evaluated: usize,
    pub median_relative_error: f64,
    /// Share of evaluated points within 2% of the ground-truth depth.
    pub within_2pct: f64,
    /// Share of evaluated points off by more than 10% (outliers).
    pub outliers_10pct: f64,
    /// Keyframes contributing points, and points per such keyframe.
    pub keyframes: usize,
    pub points_per_keyframe: f64,
}

/// Evaluates `points` (estimate frame) against `frames` (sorted by time) seen by `camera`
/// (the lens of the raw images the depth maps are registered to), with `align` mapping the
/// estimate into the ground-truth frame.
pub fn cloud_accuracy(
    points: &[CloudPoint],
    align: &Sim3,
    camera: &impl CameraModel,
    frames: &[DepthFrame],
) -> CloudAccuracy {
    let mut acc = CloudAccuracyBuilder::with_capacity(points.len());
    acc.add(points, align, camera, frames);
    acc.finish()
}

/// [`cloud_accuracy`] a part of the cloud at a time: a caller that adds each keyframe's
/// points with only that keyframe's depth map holds one depth map, not one per keyframe
/// (a 70-keyframe desk run: 86 MB of float maps at once, the largest share of the run's
/// peak memory). Each point is still compared with the depth map nearest in time among
/// the frames given with it.
#[derive(Default)]
pub struct CloudAccuracyBuilder {
    errors: Vec<f64>,
    points: usize,
    /// Reference keyframes (timestamp bits) seen so far, sorted and unique.
    keyframes: Vec<u64>,
    scratch: Vec<u64>,
    /// Some points came with depth maps (without any, the summary stays all zero).
    had_frames: bool,
}

impl CloudAccuracyBuilder {
    /// Room for `points` errors.
    pub fn with_capacity(points: usize) -> Self {
        CloudAccuracyBuilder {
            errors: Vec::with_capacity(points),
            ..Self::default()
        }
    }

    /// Adds `points`, each compared with the frame of `frames` (sorted by time) nearest to
    /// its reference keyframe; no frames: the points count but are not evaluated.
    pub fn add<'p>(
        &mut self,
        points: impl IntoIterator<Item = &'p CloudPoint>,
        align: &Sim3,
        camera: &impl CameraModel,
        frames: &[DepthFrame],
    ) {
        let (w, h) = camera.size();
        let (w, h) = (w as i64, h as i64);
        self.had_frames |= !frames.is_empty();
        self.scratch.clear();
        for p in points {
            self.points += 1;
            let bits = p.timestamp.to_bits();
            if self.scratch.last() != Some(&bits) {
                self.scratch.push(bits);
            }
            if frames.is_empty() {
                continue;
            }
            let f = nearest(frames, p.timestamp);
            let x_w = align.transform(&nalgebra::Vector3::new(
                p.position[0] as f64,
                p.position[1] as f64,
                p.position[2] as f64,
            ));
            let x_c = f.t_wc.inverse().transform(&x_w);
            if x_c.z <= 0.0 {
                continue;
            }
            let Some(uv) = camera.project_raw(&x_c) else {
                continue;
            };
            let (u, v) = (uv.x.round() as i64, uv.y.round() as i64);
            let mut best: Option<f64> = None;
            for dv in -1..=1 {
                for du in -1..=1 {
                    let (x, y) = (u + du, v + dv);
                    if x < 0 || y < 0 || x >= w || y >= h {
                        continue;
                    }
                    let d = f.depth[(y * w + x) as usize] as f64;
                    if d <= 0.0 || !d.is_finite() {
                        continue;
                    }
                    let e = (x_c.z - d).abs() / d;
                    if best.is_none_or(|b| e < b) {
                        best = Some(e);
                    }
                }
            }
            if let Some(e) = best {
                self.errors.push(e);
            }
        }
        self.keyframes.append(&mut self.scratch);
        self.keyframes.sort_unstable();
        self.keyframes.dedup();
    }

    /// The summary of everything added.
    pub fn finish(mut self) -> CloudAccuracy {
        let errors = &mut self.errors;
        let n = errors.len();
        let share = |pred: &dyn Fn(f64) -> bool| {
            if n == 0 {
                0.0
            } else {
                errors.iter().filter(|e| pred(**e)).count() as f64 / n as f64
            }
        };
        let within = share(&|e| e <= 0.02);
        let outliers = share(&|e| e > 0.10);
        let median = if !self.had_frames {
            0.0
        } else if n == 0 {
            f64::NAN
        } else {
            let mid = n / 2;
            *errors.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1
        };
        let keyframes = self.keyframes.len();
        CloudAccuracy {
            points: self.points,
            evaluated: n,
            median_relative_error: median,
            within_2pct: within,
            outliers_10pct: outliers,
            keyframes,
            points_per_keyframe: if keyframes == 0 {
                0.0
            } else {
                self.points as f64 / keyframes as f64
            },
        }
    }
}

fn nearest(frames: &[DepthFrame], t: f64) -> &DepthFrame {
    let i = frames.partition_point(|f| f.timestamp < t);
    match (i.checked_sub(1).map(|j| &frames[j]), frames.get(i)) {
        (Some(a), Some(b)) => {
            if (t - a.timestamp).abs() <= (b.timestamp - t).abs() {
                a
            } else {
                b
            }
        }
        (Some(a), None) => a,
        (None, Some(b)) => b,
        (None, None) => &frames[0],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera_model::PinholeRadtan;

    #[test]
    fn exact_points_have_zero_error_and_scaled_ones_are_outliers() {
        let cam = PinholeRadtan::pinhole(100.0, 100.0, 20.0, 15.0, 40, 30);
        let frames = vec![DepthFrame {
            timestamp: 1.0,
            t_wc: WorldFromCamera::identity(),
            depth: vec![2.0; 40 * 30],
        }];
        let mut pts = Vec::new();
        for i in 0..10 {
            let r = cam.unproject(5.0 + i as f64, 10.0) * 2.0;
            pts.push(CloudPoint {
                position: [r.x as f32, r.y as f32, r.z as f32],
                rgb: [0; 3],
                sigma: 0.0,
                timestamp: 1.01,
            });
        }
        let a = cloud_accuracy(&pts, &Sim3::identity(), &cam, &frames);
        assert_eq!(a.evaluated, 10);
        assert!(a.median_relative_error < 1e-6 && a.within_2pct == 1.0);
        let scaled = Sim3 {
            scale: 1.2,
            ..Sim3::identity()
        };
        let a = cloud_accuracy(&pts, &scaled, &cam, &frames);
        assert!(a.outliers_10pct == 1.0 && (a.median_relative_error - 0.2).abs() < 1e-6);
        assert_eq!(a.keyframes, 1);
    }

    #[test]
    fn keyframe_by_keyframe_with_its_own_depth_map_equals_all_at_once() {
        let cam = PinholeRadtan::pinhole(100.0, 100.0, 20.0, 15.0, 40, 30);
        // Three keyframes, each with its own depth map (a wall at 2, 3 and 4 m); each
        // point's depth is off by a different amount.
        let frames: Vec<DepthFrame> = (0..3)
            .map(|k| DepthFrame {
                timestamp: k as f64,
                t_wc: WorldFromCamera::identity(),
                depth: vec![2.0 + k as f32; 40 * 30],
            })
            .collect();
        let mut pts = Vec::new();
        for k in 0..3 {
            for i in 0..9 {
                let d = (2.0 + k as f64) * (1.0 + 0.03 * (i as f64 - 4.0));
                let r = cam.unproject(5.0 + 3.0 * i as f64, 10.0) * d;
                pts.push(CloudPoint {
                    position: [r.x as f32, r.y as f32, r.z as f32],
                    rgb: [0; 3],
                    sigma: 0.0,
                    timestamp: k as f64 + 0.004,
                });
            }
        }
        let all = cloud_accuracy(&pts, &Sim3::identity(), &cam, &frames);
        let mut acc = CloudAccuracyBuilder::default();
        for (k, points) in pts.chunks(9).enumerate() {
            acc.add(points, &Sim3::identity(), &cam, &frames[k..k + 1]);
        }
        let parts = acc.finish();
        assert_eq!(parts, all);
        assert_eq!((all.points, all.evaluated, all.keyframes), (27, 27, 3));
        assert!(all.outliers_10pct > 0.0 && all.within_2pct < 1.0);
        // Without any depth map the points count and nothing is evaluated.
        let mut none = CloudAccuracyBuilder::default();
        none.add(&pts, &Sim3::identity(), &cam, &[]);
        let none = none.finish();
        assert_eq!((none.points, none.evaluated, none.keyframes), (27, 0, 3));
    }
}
