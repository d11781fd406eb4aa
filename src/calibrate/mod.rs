//! Camera calibration from chessboard views: detection with sub-pixel corners
//! ([`chessboard`]), Zhang's closed-form initialisation ([`zhang`]) and Levenberg-Marquardt
//! refinement ([`refine`]) of pinhole + radial-tangential or Kannala-Brandt fisheye
//! parameters. The result is a [`Calibration`] that `sdslam run` reads.

pub mod chessboard;
pub mod refine;
pub mod zhang;

use nalgebra::{Matrix3, Vector2, Vector3};

use crate::camera_model::{Calibration, KannalaBrandt, Lens, PinholeRadtan};
use crate::geometry::Se3;
pub use chessboard::{detect, BoardSize, DetectorConfig};

/// The calibration board: inner-corner counts and square size (metres).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Board {
    pub size: BoardSize,
    pub square: f64,
}

impl Board {
    /// Board coordinates of the inner corners, in detection order.
    pub fn points(&self) -> Vec<Vector3<f64>> {
        (0..self.size.rows)
            .flat_map(|j| (0..self.size.cols).map(move |i| (i, j)))
            .map(|(i, j)| Vector3::new(i as f64 * self.square, j as f64 * self.square, 0.0))
            .collect()
    }
}

/// The camera model to calibrate.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LensModel {
    /// Pinhole with radial-tangential distortion (k1 k2 p1 p2, and k3 on request).
    #[default]
    RadialTangential,
    /// Kannala-Brandt fisheye (k1..k4).
    KannalaBrandt,
}

/// Options of the solver.
#[derive(Clone, Debug)]
pub struct CalibrateConfig {
    pub model: LensModel,
    /// Estimate the sixth-order radial term k3 (wide-angle lenses); fixed at 0 otherwise, which
    /// is more stable for ordinary webcams.
    pub estimate_k3: bool,
    pub max_iterations: usize,
    /// A view whose RMS exceeds this many times the median (and 1 px) is dropped and the
    /// solution refined again (a misdetected board or a motion-blurred frame).
    pub outlier_view_factor: f64,
}

impl Default for CalibrateConfig {
    fn default() -> Self {
        CalibrateConfig {
            model: LensModel::RadialTangential,
            estimate_k3: false,
            max_iterations: 100,
            outlier_view_factor: 3.0,
        }
    }
}

/// The calibration and how well it fits.
#[derive(Clone, Debug)]
pub struct CalibrationResult {
    pub camera: Lens,
    /// Reprojection RMS over all kept corners (pixels).
    pub rms_px: f64,
    /// Per input view: its RMS, or `None` when it was dropped as an outlier.
    pub view_rms_px: Vec<Option<f64>>,
    /// One standard deviation of fx, fy, cx, cy, k1, k2, p1, p2, k3 (radial-tangential) or
    /// fx, fy, cx, cy, k1, k2, k3, k4, 0 (Kannala-Brandt).
    pub std_dev: [f64; refine::INTRINSICS],
    /// Camera-from-board pose per kept view.
    pub poses: Vec<Se3>,
    pub iterations: usize,
}

impl CalibrationResult {
    pub fn calibration(&self, fps: f64) -> Calibration {
        match self.camera {
            Lens::Pinhole(c) => Calibration::pinhole(c, fps),
            Lens::KannalaBrandt(k) => Calibration::fisheye(k, fps),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum CalibrateError {
    #[error("the board was found in {found} views; at least {needed} are needed (vary the board's tilt and position)")]
    TooFewViews { found: usize, needed: usize },
    #[error("the views do not determine the intrinsics (tilt the board more between views)")]
    Degenerate,
}

/// Calibrates a `width` x `height` camera from corner sets (each in [`Board::points`] order).
pub fn calibrate(
    views: &[Vec<Vector2<f64>>],
    board: &Board,
    width: u32,
    height: u32,
    cfg: &CalibrateConfig,
) -> Result<CalibrationResult, CalibrateError> {
    const MIN_VIEWS: usize = 3;
    let n = board.size.cols * board.size.rows;
    let usable: Vec<usize> = (0..views.len()).filter(|&i| views[i].len() == n).collect();
    if usable.len() < MIN_VIEWS {
        return Err(CalibrateError::TooFewViews {
            found: usable.len(),
            needed: MIN_VIEWS,
        });
    }
    let pts = board.points();
    let kept_views: Vec<Vec<Vector2<f64>>> = usable.iter().map(|&i| views[i].clone()).collect();
    let (init, poses) = match cfg.model {
        LensModel::RadialTangential => initial_pinhole(&pts, &kept_views, width, height)?,
        LensModel::KannalaBrandt => initial_fisheye(&pts, &kept_views, width, height)?,
    };

    let mut kept = usable.clone();
    let mut refined = refine::refine(
        &init,
        &poses,
        &pts,
        &kept_views,
        cfg.estimate_k3,
        cfg.max_iterations,
    );
    // Drop outlier views once and refine again from the first solution.
    let rms_of = |r: &refine::Refined, idx: &[usize]| -> Vec<f64> {
        idx.iter()
            .zip(&r.poses)
            .map(|(&i, p)| view_rms(&r.camera, p, &pts, &views[i]))
            .collect()
    };
    let rms = rms_of(&refined, &kept);
    let mut sorted = rms.clone();
    sorted.sort_by(|a, b| a.total_cmp(b));
    let median = sorted[sorted.len() / 2];
    let limit = (cfg.outlier_view_factor * median).max(1.0);
    let keep: Vec<bool> = rms.iter().map(|r| *r <= limit).collect();
    if keep.iter().any(|k| !k) && keep.iter().filter(|k| **k).count() >= MIN_VIEWS {
        let poses2: Vec<Se3> = refined
            .poses
            .iter()
            .zip(&keep)
            .filter(|(_, k)| **k)
            .map(|(p, _)| *p)
            .collect();
        kept = kept
            .iter()
            .zip(&keep)
            .filter(|(_, k)| **k)
            .map(|(i, _)| *i)
            .collect();
        let views2: Vec<Vec<Vector2<f64>>> = kept.iter().map(|&i| views[i].clone()).collect();
        refined = refine::refine(
            &refined.camera,
            &poses2,
            &pts,
            &views2,
            cfg.estimate_k3,
            cfg.max_iterations,
        );
    }
    let rms = rms_of(&refined, &kept);
    let mut view_rms_px = vec![None; views.len()];
    for (&i, r) in kept.iter().zip(&rms) {
        view_rms_px[i] = Some(*r);
    }
    let total =
        (rms.iter().map(|r| r * r * n as f64).sum::<f64>() / (n * kept.len()) as f64).sqrt();
    Ok(CalibrationResult {
        camera: refined.camera,
        rms_px: total,
        view_rms_px,
        std_dev: refined.std_dev,
        poses: refined.poses,
        iterations: refined.iterations,
    })
}

/// Zhang's closed form: intrinsics and poses from the views' homographies, then k1, k2 by
/// linear least squares.
fn initial_pinhole(
    pts: &[Vector3<f64>],
    views: &[Vec<Vector2<f64>>],
    width: u32,
    height: u32,
) -> Result<(Lens, Vec<Se3>), CalibrateError> {
    let plane: Vec<Vector2<f64>> = pts.iter().map(|p| p.xy()).collect();
    let hs: Vec<Matrix3<f64>> = views
        .iter()
        .map(|v| zhang::homography(&plane, v))
        .collect::<Option<_>>()
        .ok_or(CalibrateError::Degenerate)?;
    let (fx, fy, cx, cy) = zhang::intrinsics(&hs).ok_or(CalibrateError::Degenerate)?;
    let k = Matrix3::new(fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0);
    let poses: Vec<Se3> = hs
        .iter()
        .map(|h| zhang::pose(h, &k))
        .collect::<Option<_>>()
        .ok_or(CalibrateError::Degenerate)?;
    let with_poses: Vec<(Se3, Vec<Vector2<f64>>)> =
        poses.iter().cloned().zip(views.iter().cloned()).collect();
    let (k1, k2) = zhang::radial_distortion(&with_poses, pts, (fx, fy, cx, cy));
    let init = PinholeRadtan {
        k1,
        k2,
        ..PinholeRadtan::pinhole(fx, fy, cx, cy, width, height)
    };
    Ok((Lens::Pinhole(init), poses))
}

/// A fisheye has no homographies to start from (straight lines are curved): start from an
/// equidistant lens whose 180 degrees span the image's longer side, centred, without
/// higher-order terms (as OpenCV's fisheye calibration does), take each view's pose from the
/// homography of its corners' rays under that lens, and let the refinement find the rest.
fn initial_fisheye(
    pts: &[Vector3<f64>],
    views: &[Vec<Vector2<f64>>],
    width: u32,
    height: u32,
) -> Result<(Lens, Vec<Se3>), CalibrateError> {
    let f = width.max(height) as f64 / std::f64::consts::PI;
    let lens = KannalaBrandt {
        fx: f,
        fy: f,
        cx: (width as f64 - 1.0) / 2.0,
        cy: (height as f64 - 1.0) / 2.0,
        k1: 0.0,
        k2: 0.0,
        k3: 0.0,
        k4: 0.0,
        width,
        height,
    };
    let plane: Vec<Vector2<f64>> = pts.iter().map(|p| p.xy()).collect();
    let poses: Vec<Se3> = views
        .iter()
        .map(|v| {
            let rays: Vec<Vector2<f64>> = v
                .iter()
                .map(|c| {
                    let r = lens.unproject(c.x, c.y);
                    Vector2::new(r.x / r.z.max(0.05), r.y / r.z.max(0.05))
                })
                .collect();
            zhang::pose(&zhang::homography(&plane, &rays)?, &Matrix3::identity())
        })
        .collect::<Option<_>>()
        .ok_or(CalibrateError::Degenerate)?;
    Ok((Lens::KannalaBrandt(lens), poses))
}

/// RMS reprojection error of one view (pixels).
pub fn view_rms(cam: &Lens, pose: &Se3, pts: &[Vector3<f64>], obs: &[Vector2<f64>]) -> f64 {
    let s: f64 = pts
        .iter()
        .zip(obs)
        .map(|(p, o)| (refine::project(cam, pose, p) - o).norm_squared())
        .sum();
    (s / pts.len().max(1) as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::chessboard::{calibration_poses, render_chessboard};

    fn webcam() -> PinholeRadtan {
        PinholeRadtan {
            k1: -0.28,
            k2: 0.09,
            p1: 0.0012,
            p2: -0.0008,
            ..PinholeRadtan::pinhole(520.0, 517.0, 318.0, 244.0, 640, 480)
        }
    }

    fn board() -> Board {
        Board {
            size: BoardSize { cols: 9, rows: 6 },
            square: 0.025,
        }
    }

    #[test]
    fn detects_every_corner_of_a_rendered_board_to_subpixel() {
        let cam = webcam();
        let b = board();
        let pts = b.points();
        let mut img = vec![0u8; 640 * 480];
        let poses = calibration_poses(&Lens::Pinhole(cam), &b, 6, 3);
        for (k, pose) in poses.iter().enumerate() {
            render_chessboard(&cam, pose, &b, 2.0, k as u64, &mut img);
            let corners = detect(&img, 640, 480, b.size, &DetectorConfig::default())
                .unwrap_or_else(|| panic!("board not found in view {k}"));
            assert_eq!(corners.len(), 54);
            let err = view_rms(&Lens::Pinhole(cam), pose, &pts, &corners);
            assert!(
                err < 0.15,
                "view {k}: corner RMS {err} px against the truth"
            );
        }
    }

    #[test]
    fn finds_nothing_without_a_board() {
        let mut img = vec![110u8; 320 * 240];
        for (i, p) in img.iter_mut().enumerate() {
            *p = ((i * 7919) % 251) as u8 / 4 + 100;
        }
        assert!(detect(&img, 320, 240, board().size, &DetectorConfig::default()).is_none());
        assert!(detect(&[], 0, 0, board().size, &DetectorConfig::default()).is_none());
    }

    #[test]
    fn too_few_views_is_a_clear_error() {
        let e = calibrate(
            &[vec![], vec![]],
            &board(),
            640,
            480,
            &CalibrateConfig::default(),
        )
        .unwrap_err();
        assert!(e.to_string().contains("found in 0 views"), "{e}");
    }
}

/// End to end on rendered images: the acceptance figures (fx, fy, cx, cy within 0.5%,
/// k1 within 0.01).
#[cfg(test)]
mod end_to_end {
    use super::*;
    use crate::synthetic::chessboard::{calibration_poses, render_chessboard};

    /// The acceptance figures: fx, fy, cx, cy within 0.5%, k1 within 0.01, RMS under 0.3 px.
    fn assert_recovers(name: &str, got: [f64; 5], want: [f64; 5], r: &CalibrationResult) {
        for (i, what) in ["fx", "fy", "cx", "cy"].iter().enumerate() {
            let (g, w) = (got[i], want[i]);
            assert!(((g - w) / w).abs() < 0.005, "{name}: {what} {g} vs {w}");
        }
        assert!(
            (got[4] - want[4]).abs() < 0.01,
            "{name}: k1 {} vs {}",
            got[4],
            want[4]
        );
        assert!(r.rms_px < 0.3, "{name}: RMS {}", r.rms_px);
    }

    #[test]
    fn recovers_intrinsics_and_distortion_from_rendered_views() {
        for (name, truth) in [
            (
                "webcam",
                PinholeRadtan {
                    k1: -0.28,
                    k2: 0.09,
                    p1: 0.0012,
                    p2: -0.0008,
                    ..PinholeRadtan::pinhole(520.0, 517.0, 318.0, 244.0, 640, 480)
                },
            ),
            (
                "narrow",
                PinholeRadtan {
                    k1: 0.05,
                    k2: -0.02,
                    p1: -0.0005,
                    p2: 0.001,
                    ..PinholeRadtan::pinhole(810.0, 805.0, 330.0, 236.0, 640, 480)
                },
            ),
        ] {
            let b = Board {
                size: BoardSize { cols: 9, rows: 6 },
                square: 0.025,
            };
            let mut img = vec![0u8; 640 * 480];
            let views: Vec<Vec<Vector2<f64>>> =
                calibration_poses(&Lens::Pinhole(truth), &b, 15, 11)
                    .iter()
                    .enumerate()
                    .filter_map(|(k, pose)| {
                        render_chessboard(&truth, pose, &b, 2.0, 100 + k as u64, &mut img);
                        detect(&img, 640, 480, b.size, &DetectorConfig::default())
                    })
                    .collect();
            assert!(
                views.len() >= 14,
                "{name}: board found in {} of 15 views",
                views.len()
            );
            let r = calibrate(&views, &b, 640, 480, &CalibrateConfig::default()).unwrap();
            let Lens::Pinhole(c) = r.camera else {
                panic!("{name}: not a pinhole")
            };
            eprintln!(
                "{name}: fx {:.3} fy {:.3} cx {:.3} cy {:.3} k1 {:.5} k2 {:.5} p1 {:.6} p2 {:.6}, RMS {:.3} px, {} views, std fx {:.3}",
                c.fx, c.fy, c.cx, c.cy, c.k1, c.k2, c.p1, c.p2, r.rms_px, views.len(), r.std_dev[0]
            );
            let got = [c.fx, c.fy, c.cx, c.cy, c.k1];
            assert_recovers(
                name,
                got,
                [truth.fx, truth.fy, truth.cx, truth.cy, truth.k1],
                &r,
            );
        }
    }

    #[test]
    fn recovers_a_fisheye_lens_from_rendered_views() {
        let truth = crate::synthetic::SyntheticConfig {
            fisheye: true,
            ..Default::default()
        }
        .fisheye_lens();
        let lens = Lens::KannalaBrandt(truth);
        let b = Board {
            size: BoardSize { cols: 9, rows: 6 },
            square: 0.025,
        };
        let mut img = vec![0u8; 640 * 480];
        let views: Vec<Vec<Vector2<f64>>> = calibration_poses(&lens, &b, 15, 11)
            .iter()
            .enumerate()
            .filter_map(|(k, pose)| {
                render_chessboard(&lens, pose, &b, 2.0, 100 + k as u64, &mut img);
                detect(&img, 640, 480, b.size, &DetectorConfig::default())
            })
            .collect();
        assert!(
            views.len() >= 10,
            "board found in {} of 15 views",
            views.len()
        );
        let cfg = CalibrateConfig {
            model: LensModel::KannalaBrandt,
            ..CalibrateConfig::default()
        };
        let r = calibrate(&views, &b, 640, 480, &cfg).unwrap();
        let Lens::KannalaBrandt(c) = r.camera else {
            panic!("not a fisheye")
        };
        eprintln!(
            "fisheye: fx {:.3} ({:.3}) fy {:.3} cx {:.3} cy {:.3} k1 {:.5} ({}) k2 {:.5} k3 {:.5} k4 {:.6}, RMS {:.3} px, {} views",
            c.fx, truth.fx, c.fy, c.cx, c.cy, c.k1, truth.k1, c.k2, c.k3, c.k4, r.rms_px, views.len()
        );
        let want = [truth.fx, truth.fy, truth.cx, truth.cy, truth.k1];
        assert_recovers("fisheye", [c.fx, c.fy, c.cx, c.cy, c.k1], want, &r);
    }
}
