//! Semi-dense accuracy on the built-in synthetic sequence (exact poses and depth), by the
//! evaluation protocol: offline from ground-truth poses, and online behind SLAM.

use sdslam::camera::{Frame, FrameSource, FrameStatus};
use sdslam::config::Config;
use sdslam::eval::{cloud_accuracy, pose_alignment, CloudAccuracy, DepthFrame, TimedPose};
use sdslam::geometry::Sim3;
use sdslam::io::CloudPoint;
use sdslam::runtime::System;
use sdslam::semidense::Densifier;
use sdslam::synthetic::{SyntheticConfig, SyntheticSequence};

fn sequence(frames: usize) -> SyntheticSequence {
    scene_sequence(sdslam::synthetic::Scenario::Desk, frames)
}

fn scene_sequence(scenario: sdslam::synthetic::Scenario, frames: usize) -> SyntheticSequence {
    SyntheticSequence::new(SyntheticConfig {
        frames,
        scenario,
        ..SyntheticConfig::default()
    })
}

/// Ground-truth depth rendered exactly at each keyframe of the cloud.
fn depth_frames(seq: &SyntheticSequence, cloud: &[CloudPoint]) -> Vec<DepthFrame> {
    let c = &seq.config;
    let gt = seq.ground_truth();
    let mut stamps: Vec<f64> = cloud.iter().map(|p| p.timestamp).collect();
    stamps.dedup();
    let mut f = Frame::new(c.width, c.height);
    stamps
        .iter()
        .map(|&t| {
            let i = ((t - c.t0) * c.fps).round() as usize;
            let mut depth = vec![0.0f32; (c.width * c.height) as usize];
            seq.render_with_depth(i, &mut f, &mut depth);
            DepthFrame {
                timestamp: t,
                t_wc: gt[i].t_wc,
                depth,
            }
        })
        .collect()
}

fn check(label: &str, a: &CloudAccuracy) {
    eprintln!(
        "{label}: {} points, {:.0} per keyframe, median {:.3}%, within 2% {:.1}%, beyond 10% {:.2}%",
        a.points,
        a.points_per_keyframe,
        a.median_relative_error * 100.0,
        a.within_2pct * 100.0,
        a.outliers_10pct * 100.0
    );
    assert!(a.evaluated as f64 > 0.95 * a.points as f64, "{a:?}");
    assert!(a.median_relative_error <= 0.01, "{a:?}");
    assert!(a.within_2pct >= 0.85, "{a:?}");
    assert!(a.outliers_10pct <= 0.01, "{a:?}");
    assert!(a.points_per_keyframe >= 8000.0, "{a:?}");
}

#[test]
fn offline_densify_from_ground_truth_poses_is_accurate() {
    let seq = sequence(300);
    let cam = seq.config.camera();
    let gt = seq.ground_truth();
    let mut d = Densifier::new(&cam, &Config::default(), 64);
    let mut f = Frame::new(cam.width, cam.height);
    for i in (0..200).step_by(8) {
        seq.render_frame(i, &mut f);
        d.add_keyframe(&f.gray, Some(&f.rgb), f.timestamp, i as u64, &gt[i].t_wc);
    }
    let n = d.finish().stats.keyframes_reconstructed;
    assert!(n >= 20, "{n} keyframes reconstructed");
    let mut cloud = Vec::new();
    d.cloud(&mut cloud);
    let frames = depth_frames(&seq, &cloud);
    check(
        "densify (ground-truth poses)",
        &cloud_accuracy(&cloud, &Sim3::identity(), &cam, &frames),
    );
}

#[test]
fn online_cloud_behind_slam_is_accurate() {
    let mut seq = sequence(300);
    let calib = seq.config.calibration();
    let mut system = System::new(&calib, &Config::default(), 300, false);
    let mut f = Frame::new(seq.config.width, seq.config.height);
    while let Ok(FrameStatus::Ready) = seq.next_frame(&mut f) {
        system.process(&f.gray, Some(&f.rgb), f.timestamp, f.index);
    }
    assert!(system.finish());
    let sd = system
        .semidense()
        .expect("semi-dense mapping is on by default");
    assert!(sd.stats.keyframes_reconstructed >= 10);
    let cloud = system.semidense_cloud();
    let keyframes: Vec<TimedPose> = system.keyframe_trajectory();
    let align = pose_alignment(&seq.ground_truth(), &keyframes, 0.02).expect("aligned");
    let frames = depth_frames(&seq, &cloud);
    check(
        "online (SLAM keyframe poses)",
        &cloud_accuracy(&cloud, &align, &seq.config.camera(), &frames),
    );
}

/// A Sim3 correction of the map (what loop closing applies around a loop) moves the cloud with
/// it, scale included: each keyframe's depths follow its map points.
#[test]
fn cloud_follows_a_sim3_correction_of_the_map() {
    let mut seq = sequence(120);
    let calib = seq.config.calibration();
    let mut system = System::new(&calib, &Config::default(), 120, false);
    let mut f = Frame::new(seq.config.width, seq.config.height);
    while let Ok(FrameStatus::Ready) = seq.next_frame(&mut f) {
        system.process(&f.gray, Some(&f.rgb), f.timestamp, f.index);
    }
    assert!(system.finish());
    let before = system.semidense_cloud();
    assert!(before.len() > 10_000, "{} points", before.len());
    // x' = s R x + t for every map point; camera poses follow (T_cw' = [R_cw R^T | s t_cw - R_cw R^T t]).
    let (s, r, t) = (
        1.3,
        nalgebra::UnitQuaternion::from_euler_angles(0.1, -0.2, 0.3),
        nalgebra::Vector3::new(0.5, -0.2, 0.1),
    );
    {
        let mut map = system.map();
        let kfs: Vec<_> = map.keyframes().map(|(id, _)| id).collect();
        for id in kfs {
            let kf = map.keyframe_mut(id).unwrap();
            let iso = kf.t_cw.0;
            let rot = iso.rotation * r.inverse();
            let tr = iso.translation.vector * s - rot * t;
            kf.t_cw.0 = nalgebra::Isometry3::from_parts(tr.into(), rot);
        }
        let pts: Vec<_> = map.points().map(|(id, _)| id).collect();
        for id in pts {
            let p = map.point_mut(id).unwrap();
            p.position = r * p.position * s + t;
        }
    }
    let after = system.semidense_cloud();
    assert_eq!(before.len(), after.len());
    let mut worst = 0.0f64;
    for (a, b) in before.iter().zip(&after) {
        let pa = nalgebra::Vector3::new(
            a.position[0] as f64,
            a.position[1] as f64,
            a.position[2] as f64,
        );
        let pb = nalgebra::Vector3::new(
            b.position[0] as f64,
            b.position[1] as f64,
            b.position[2] as f64,
        );
        let want = r * pa * s + t;
        worst = worst.max((pb - want).norm() / (want - t).norm().max(1e-3));
    }
    assert!(
        worst < 1e-3,
        "a point moved {worst:.2e} (relative) away from the corrected map"
    );
}

/// The online and end-of-session clouds of one deterministic run of the built-in sequence
/// with `config`, each evaluated by the protocol.
fn online_and_final(frames: usize, config: &Config) -> (CloudAccuracy, CloudAccuracy) {
    scene_online_and_final(sdslam::synthetic::Scenario::Desk, frames, config)
}

fn scene_online_and_final(
    scenario: sdslam::synthetic::Scenario,
    frames: usize,
    config: &Config,
) -> (CloudAccuracy, CloudAccuracy) {
    let mut seq = scene_sequence(scenario, frames);
    let calib = seq.config.calibration();
    let mut system = System::new(&calib, config, frames, false);
    let mut f = Frame::new(seq.config.width, seq.config.height);
    while let Ok(FrameStatus::Ready) = seq.next_frame(&mut f) {
        system.process(&f.gray, Some(&f.rgb), f.timestamp, f.index);
    }
    assert!(system.finish());
    let final_keyframes = system
        .reconstruct_semidense_final()
        .expect("semi-dense mapping is on")
        .stats
        .keyframes_reconstructed;
    let (online, last) = (system.semidense_cloud(), system.semidense_final_cloud());
    assert!(final_keyframes >= 10, "{final_keyframes} keyframes");
    let keyframes: Vec<TimedPose> = system.keyframe_trajectory();
    let align = pose_alignment(&seq.ground_truth(), &keyframes, 0.02).expect("aligned");
    let cam = seq.config.camera();
    let acc =
        |cloud: &[CloudPoint]| cloud_accuracy(cloud, &align, &cam, &depth_frames(&seq, cloud));
    (acc(&online), acc(&last))
}

/// The paper's end-of-session reconstruction after the final BA: every keyframe with its
/// neighbours in the final map, at least as accurate as the online cloud.
#[test]
fn end_of_session_reconstruction_is_as_accurate_as_the_online_one() {
    let (online, last) = online_and_final(300, &Config::default());
    check("online", &online);
    check("end of session", &last);
    assert!(
        last.median_relative_error <= online.median_relative_error * 1.05,
        "median {:.4}% end of session vs {:.4}% online",
        last.median_relative_error * 100.0,
        online.median_relative_error * 100.0
    );
    assert!(
        last.outliers_10pct <= online.outliers_10pct + 0.001,
        "outliers {:.3}% end of session vs {:.3}% online",
        last.outliers_10pct * 100.0,
        online.outliers_10pct * 100.0
    );
}

/// Paper mode: the inter-keyframe consistency check removes outliers preferentially (the
/// paper's claim of few outliers rests on it): their share falls. (The paper's qualitative
/// "few outliers" is measured per scene in docs/PERFORMANCE.md: a third or less on desk,
/// a half on this orbit, whose first keyframes are a few frames apart.)
#[test]
fn paper_mode_inter_keyframe_check_removes_outliers() {
    let paper = |inter_check| {
        let mut c = Config::default();
        c.semidense.mode = sdslam::config::SemiDenseMode::Paper;
        c.semidense.inter_check = inter_check;
        online_and_final(240, &c).0
    };
    let (with, without) = (paper(true), paper(false));
    eprintln!(
        "paper mode: outliers {:.3}% with the inter-keyframe check, {:.3}% without ({} / {} points)",
        with.outliers_10pct * 100.0,
        without.outliers_10pct * 100.0,
        with.points,
        without.points
    );
    assert!(with.points < without.points, "the check removed nothing");
    assert!(
        with.outliers_10pct < without.outliers_10pct,
        "{:.3}% with the check vs {:.3}% without",
        with.outliers_10pct * 100.0,
        without.outliers_10pct * 100.0
    );
    assert!(with.median_relative_error <= without.median_relative_error);
}

/// Scenes the defaults were not tuned on (issue 31's kind): every surface a repetitive
/// pattern (many similar pixels along an epipolar segment), boxes moving through the scene,
/// and a camera's auto exposure changing the image gain from frame to frame. The online
/// cloud keeps few outliers: at most 0.5% off by more than 10%, a median of at most 0.15%,
/// at least 10k points per keyframe.
#[test]
fn repetitive_textures_moving_objects_and_auto_exposure_keep_the_cloud_clean() {
    use sdslam::synthetic::Scenario;
    for scenario in [
        Scenario::Repetitive,
        Scenario::MovingObjects,
        Scenario::AutoExposure,
    ] {
        let (online, _) = scene_online_and_final(scenario, 200, &Config::default());
        let label = scenario.name();
        check(label, &online);
        assert!(online.outliers_10pct <= 0.005, "{label}: {online:?}");
        assert!(
            online.median_relative_error <= 0.0015,
            "{label}: {online:?}"
        );
        assert!(
            online.points_per_keyframe >= 10_000.0,
            "{label}: {online:?}"
        );
    }
}
