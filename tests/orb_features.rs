//! ORB invariances and quality: rotation (30 and 90 degrees), scale across pyramid levels, and
//! repeatability under a known homography on real EuRoC images.

mod common;

use nalgebra::Matrix3;
use sdslam::camera::Frame;
use sdslam::config::{OrbConfig, OrbDistribution, OrbScore};
use sdslam::eval::orb_quality::warp_quality;
use sdslam::features::{Features, OrbExtractor};
use sdslam::image::warp::{apply_homography, rotation_about, warp_perspective};
use sdslam::matching::hamming;
use sdslam::synthetic::{SyntheticConfig, SyntheticSequence};

fn synthetic_frame(i: usize) -> Vec<u8> {
    let seq = SyntheticSequence::new(SyntheticConfig::default());
    let mut f = Frame::new(640, 480);
    seq.render_frame(i, &mut f);
    f.gray
}

fn extract(img: &[u8], w: usize, h: usize) -> Features {
    extract_with(img, w, h, &OrbConfig::default())
}

fn extract_with(img: &[u8], w: usize, h: usize, config: &OrbConfig) -> Features {
    let mut ex = OrbExtractor::new(w, h, config);
    let mut f = Features::default();
    ex.extract(img, None, &mut f);
    f
}

/// Pairs (i in A, j in B) whose positions agree under `h_ba` within 2 px and whose octaves
/// differ by `octave_shift` (B octave = A octave - shift).
fn geometric_pairs(
    a: &Features,
    b: &Features,
    h_ba: &Matrix3<f64>,
    keep: impl Fn(f64, f64) -> bool,
    octave_shift: i32,
) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    for (i, ka) in a.keypoints.iter().enumerate() {
        let Some((x, y)) = apply_homography(h_ba, ka.x as f64, ka.y as f64) else {
            continue;
        };
        if !keep(x, y) {
            continue;
        }
        let best = b
            .keypoints
            .iter()
            .enumerate()
            .filter(|(_, kb)| kb.octave as i32 == ka.octave as i32 - octave_shift)
            .map(|(j, kb)| {
                (
                    j,
                    ((kb.x as f64 - x).powi(2) + (kb.y as f64 - y).powi(2)).sqrt(),
                )
            })
            .min_by(|p, q| p.1.total_cmp(&q.1));
        if let Some((j, d)) = best {
            if d <= 2.0 {
                out.push((i, j));
            }
        }
    }
    out
}

fn angle_diff(a: f32, b: f32) -> f32 {
    let d = (a - b).rem_euclid(360.0);
    d.min(360.0 - d)
}

fn check_rotation(deg: f64) {
    let (w, h) = (640usize, 480usize);
    let a_img = synthetic_frame(40);
    let hm = rotation_about(319.5, 239.5, deg);
    let mut b_img = vec![0u8; w * h];
    assert!(warp_perspective(&a_img, w, h, &hm, &mut b_img));
    let (a, b) = (extract(&a_img, w, h), extract(&b_img, w, h));
    // Compare inside a central disk that stays inside both images.
    let keep = |x: f64, y: f64| (x - 319.5).powi(2) + (y - 239.5).powi(2) < 200.0f64.powi(2);
    let pairs = geometric_pairs(&a, &b, &hm, keep, 0);
    assert!(
        pairs.len() >= 100,
        "{deg} deg: only {} repeated keypoints",
        pairs.len()
    );
    // Image y points down, so a counter-clockwise rotation by deg lowers keypoint angles by deg.
    let mut errs: Vec<f32> = pairs
        .iter()
        .map(|&(i, j)| angle_diff(a.keypoints[i].angle - deg as f32, b.keypoints[j].angle))
        .collect();
    errs.sort_by(|x, y| x.total_cmp(y));
    let median = errs[errs.len() / 2];
    let within = errs.iter().filter(|&&e| e < 15.0).count() as f64 / errs.len() as f64;
    assert!(median < 5.0, "{deg} deg: median angle error {median}");
    assert!(
        within > 0.8,
        "{deg} deg: only {within:.2} within 15 degrees"
    );
    // Steered descriptors of the same points stay close.
    let close = pairs
        .iter()
        .filter(|&&(i, j)| hamming(&a.descriptors[i], &b.descriptors[j]) <= 64)
        .count() as f64
        / pairs.len() as f64;
    assert!(
        close > 0.6,
        "{deg} deg: only {close:.2} of descriptors within 64 bits"
    );
    eprintln!("rotation {deg}: {} pairs, median angle error {median:.2}, {within:.2} within 15 deg, {close:.2} descriptors close", pairs.len());
}

#[test]
fn orientation_follows_a_30_degree_rotation() {
    check_rotation(30.0);
}

#[test]
fn orientation_follows_a_90_degree_rotation() {
    check_rotation(90.0);
}

#[test]
fn a_downscaled_image_finds_the_same_points_two_levels_lower() {
    let (w, h) = (640usize, 480usize);
    let a_img = synthetic_frame(80);
    let s = 1.2f64 * 1.2;
    let hm = Matrix3::new(1.0 / s, 0.0, 0.0, 0.0, 1.0 / s, 0.0, 0.0, 0.0, 1.0);
    let mut b_img = vec![0u8; w * h];
    warp_perspective(&a_img, w, h, &hm, &mut b_img);
    let (a, b) = (extract(&a_img, w, h), extract(&b_img, w, h));
    let keep =
        |x: f64, y: f64| x > 20.0 && y > 20.0 && x < w as f64 / s - 20.0 && y < h as f64 / s - 20.0;
    let same_level = geometric_pairs(&a, &b, &hm, keep, 2);
    let total_a = a.keypoints.iter().filter(|k| k.octave >= 2).count();
    assert!(
        same_level.len() >= 80,
        "only {} points found two levels lower (of {total_a})",
        same_level.len()
    );
    let close = same_level
        .iter()
        .filter(|&&(i, j)| hamming(&a.descriptors[i], &b.descriptors[j]) <= 64)
        .count() as f64
        / same_level.len() as f64;
    assert!(
        close > 0.6,
        "descriptors across scales: {close:.2} within 64 bits"
    );
    // The octave shift is what the scale predicts: more pairs at shift 2 than at shift 0 or 4.
    let shift0 = geometric_pairs(&a, &b, &hm, keep, 0).len();
    let shift4 = geometric_pairs(&a, &b, &hm, keep, 4).len();
    assert!(
        same_level.len() > shift0 && same_level.len() > shift4,
        "shift2 {} shift0 {shift0} shift4 {shift4}",
        same_level.len()
    );
    eprintln!("scale 1.44: {} pairs two levels down ({close:.2} descriptors close); shift0 {shift0}, shift4 {shift4}", same_level.len());
}

/// Mean repeatability and matching score of `config` over every 6th EuRoC micro frame under
/// the homography of docs/PERFORMANCE.md.
fn euroc_warp_quality(config: &OrbConfig) -> Option<(f64, f64)> {
    let data = common::shared_data()?;
    let dir = data.join("euroc_v101_micro/mav0/cam0/data");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    let hm = Matrix3::from_row_slice(&[0.9, 0.1, 30.0, -0.08, 0.95, 40.0, 0.0001, 0.00005, 1.0]);
    let (mut rep, mut ms) = (0.0, 0.0);
    for p in files.iter().step_by(6) {
        let img = image::open(p).unwrap().to_luma8();
        let (w, h) = (img.width() as usize, img.height() as usize);
        let mut warped = vec![0u8; w * h];
        warp_perspective(img.as_raw(), w, h, &hm, &mut warped);
        let (a, b) = (
            extract_with(img.as_raw(), w, h, config),
            extract_with(&warped, w, h, config),
        );
        let q = warp_quality(&a, &b, &hm, w as f64, h as f64, 16.0, 2.5);
        assert!(q.comparable > 500, "{}", q.comparable);
        rep += q.repeatability / 5.0;
        ms += q.matching_score / 5.0;
    }
    Some((rep, ms))
}

#[test]
fn repeatability_under_a_homography_on_real_euroc_images() {
    let Some((rep, ms)) = euroc_warp_quality(&OrbConfig::default()) else {
        return;
    };
    eprintln!("EuRoC repeatability {rep:.3}, matching score {ms:.3}");
    // Regression guards below the measured 0.75 / 0.50 (docs/PERFORMANCE.md).
    assert!(rep > 0.70, "repeatability {rep}");
    assert!(ms > 0.42, "matching score {ms}");
}

/// The OpenCV-style selection (globally strongest, Harris-ranked) stays above OpenCV ORB's
/// own 0.932 on these frames (measured with tools/opencv_orb.py, docs/PERFORMANCE.md).
#[test]
fn strongest_selection_repeats_better_than_opencv_on_real_euroc_images() {
    let config = OrbConfig {
        distribution: OrbDistribution::Strongest,
        score_type: OrbScore::Harris,
        ..OrbConfig::default()
    };
    let Some((rep, ms)) = euroc_warp_quality(&config) else {
        return;
    };
    eprintln!("EuRoC strongest: repeatability {rep:.3}, matching score {ms:.3}");
    assert!(rep > 0.932, "repeatability {rep} (OpenCV 0.932)");
    assert!(ms > 0.36, "matching score {ms}");
}

/// `[orb] starved_th_fast`: a blank wall with faint blobs (contrast 5 grey levels) gives no
/// FAST corner at ORB-SLAM's thresholds (20, then 7), and many with the third pass at 4; a
/// textured image, where every level finds its share, is unchanged.
#[test]
fn the_starved_pass_finds_faint_corners_and_leaves_textured_images_alone() {
    let (w, h) = (640, 480);
    let mut wall = vec![120u8; w * h];
    for (i, p) in wall.iter_mut().enumerate() {
        let (x, y) = (i % w, i / w);
        // A grid of 10 px squares, 5 grey levels darker, on a 40 px pitch.
        if x % 40 < 10 && y % 40 < 10 {
            *p = 115;
        }
    }
    let starved = OrbConfig {
        starved_th_fast: 4,
        ..OrbConfig::default()
    };
    let plain = extract_with(
        &wall,
        w,
        h,
        &OrbConfig {
            starved_th_fast: 0,
            ..OrbConfig::default()
        },
    );
    let faint = extract_with(&wall, w, h, &starved);
    assert_eq!(
        plain.len(),
        0,
        "{} corners at thresholds 20 and 7",
        plain.len()
    );
    assert!(faint.len() >= 200, "{} faint corners", faint.len());
    let img = synthetic_frame(0);
    let a = extract_with(
        &img,
        w,
        h,
        &OrbConfig {
            starved_th_fast: 0,
            ..OrbConfig::default()
        },
    );
    let b = extract_with(&img, w, h, &starved);
    assert_eq!(a.keypoints.len(), b.keypoints.len());
    assert!(a
        .keypoints
        .iter()
        .zip(&b.keypoints)
        .all(|(p, q)| (p.x, p.y, p.octave) == (q.x, q.y, q.octave)));
}
