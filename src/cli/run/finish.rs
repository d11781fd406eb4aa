//! The last stages of `sdslam run`: finish (tracking outputs as soon as the mapping threads
//! are joined, then the semi-dense backlog and its cloud) and write (pictures, the final
//! report, the summary line, the exit status).

use std::time::Instant;

use sdslam::eval::{AteResult, TimedPose};
use sdslam::geometry::CloudPoint;
use sdslam::io::{self, write_json_atomic, write_ply, write_tum_trajectory};
use sdslam::runtime::{Report, StageTimer, System};
use sdslam::semidense::SemiDenseMapper;
use sdslam::Result;

use super::session::{Running, Session};
use super::RunOutcome;

/// What the finish stage hands to the write stage.
pub struct Finished {
    keyframes: Vec<TimedPose>,
    alignment: Option<AteResult>,
    cloud: Vec<CloudPoint>,
    threads_ok: bool,
}

/// Stage 4. Tracking outputs first (trajectory, keyframes, a first report.json): they are
/// final once the mapping threads are joined, and must not wait for the semi-dense backlog.
pub fn finish(s: &mut Session, r: &mut Running) -> Finished {
    if let Some(pb) = r.progress.take() {
        pb.finish_and_clear();
    }
    note_capture_stats(s, r);
    r.report.wall_time_s = s.started.elapsed().as_secs_f64();
    let interrupted = crate::signal::interrupted();
    if interrupted {
        r.report.stopped_early.get_or_insert_with(|| {
            "interrupted (Ctrl-C); outputs written from the run so far".into()
        });
    }
    let finishing = Instant::now();
    let mapping_ok = r.system.finish_tracking();
    let mut threads_ok = mapping_ok;
    fill_tracking_report(&mut r.report, &r.system, &r.frame_timer);
    let trajectory = r.system.trajectory();
    let keyframes = r.system.keyframe_trajectory();
    let alignment = s
        .groundtruth
        .as_ref()
        .and_then(|gt| sdslam::eval::ate(gt, &keyframes, 0.02, true));
    r.report.keyframe_ate_rmse_m = alignment.as_ref().map(|a| a.rmse_m);
    s.outputs
        .write("trajectory.txt", |p| write_tum_trajectory(p, &trajectory));
    s.outputs
        .write("keyframes.txt", |p| write_tum_trajectory(p, &keyframes));
    // The other maps of the atlas, each in its own frame.
    let atlas = r.system.atlas();
    for &(id, _, _) in atlas.maps.iter().filter(|m| Some(m.0) != atlas.primary) {
        let (t, k) = (
            r.system.trajectory_of(id),
            r.system.keyframe_trajectory_of(id),
        );
        s.outputs.write(&format!("trajectory_map{id}.txt"), |p| {
            write_tum_trajectory(p, &t)
        });
        s.outputs.write(&format!("keyframes_map{id}.txt"), |p| {
            write_tum_trajectory(p, &k)
        });
    }
    if let Some(path) = &s.args.save_map {
        let system = &r.system;
        s.outputs.write_at("map", path, |p| save_map(system, p));
    }
    r.report.peak_rss_mb = io::peak_rss_mb();
    s.outputs
        .write("report.json", |p| write_json_atomic(p, &r.report));
    if interrupted && s.config.semidense.enabled {
        note!("sdslam: tracking outputs written; cutting the semi-dense backlog");
    }

    threads_ok &= r.system.finish_semidense(interrupted);
    let final_started = Instant::now();
    let run_final = s.args.semidense_final && !interrupted && threads_ok;
    if run_final {
        note!("sdslam: end-of-session semi-dense reconstruction of every keyframe");
        if sdslam::runtime::faults::injected("interrupt:semidense_final") {
            // A Ctrl-C as the pass starts, through the real handler (tests).
            // SAFETY: raise(3) on this process; the handler only sets an atomic.
            unsafe { libc::raise(libc::SIGINT) };
        }
        let stop = crate::signal::interrupted;
        let done = r.system.reconstruct_semidense_final_until(&stop).is_some();
        if !done && crate::signal::interrupted() {
            note!("sdslam: interrupted; the end-of-session pass is dropped, semidense.ply holds the online cloud");
            r.report.stopped_early.get_or_insert_with(|| {
                "interrupted (Ctrl-C) during the end-of-session reconstruction; semidense.ply is the online cloud".into()
            });
        }
    }
    let final_s = final_started.elapsed().as_secs_f64();
    r.system.release_working_memory();
    sdslam::io::return_freed_memory();
    if !threads_ok {
        // Named here too: under full CPU load the semi-dense thread (SCHED_IDLE) may die
        // only after the last frame, when the frame loop no longer asks.
        let which = if mapping_ok {
            "the semi-dense thread"
        } else {
            "the local-mapping or loop-closing thread"
        };
        r.report.stopped_early.get_or_insert_with(|| {
            format!("{which} panicked; outputs written from the map as it was")
        });
    }
    // `cloud` is what semidense.ply holds; with the end-of-session reconstruction the online
    // cloud is kept beside it (`online`) until its file and accuracy are written.
    let (cloud, online) = match r.system.semidense_final() {
        Some(_) => (
            r.system.semidense_final_cloud(),
            Some(r.system.semidense_cloud()),
        ),
        None => (r.system.semidense_cloud(), None),
    };
    if let Some(online) = &online {
        s.outputs
            .write("semidense_online.ply", |p| write_ply(p, online));
    }
    #[cfg(feature = "rerun")]
    if let Some(v) = &r.viewer {
        let t = keyframes.last().map_or(0.0, |k| k.timestamp);
        v.keyframes(t, &keyframes);
        v.cloud(t, &cloud);
    }
    s.outputs.write("semidense.ply", |p| write_ply(p, &cloud));
    finish_publishing(s, r, &trajectory, &keyframes, &cloud, online.as_deref());
    r.report.semidense_points = cloud.len();
    if s.config.semidense.enabled {
        let c = &s.config.semidense;
        r.report.semidense_mode = Some(c.mode);
        r.report.semidense_non_paper_settings = c.non_paper_settings().into_iter().collect();
        r.report.semidense_paper_readings = sdslam::config::SemiDenseConfig::PAPER_READINGS
            .iter()
            .map(|x| x.to_string())
            .collect();
    }
    if let Some(sd) = r.system.semidense() {
        fill_semidense_report(&mut r.report, sd, finishing);
        note_cut(sd);
        let cloud_sd = r.system.semidense_final().unwrap_or(sd);
        write_depth_maps(s, cloud_sd);
        r.report.semidense_accuracy = cloud_accuracy(s, &cloud, &keyframes);
        r.report.semidense_pixels = cloud_sd.stats.pixels.clone();
        if let (Some(fin), Some(online)) = (r.system.semidense_final(), online) {
            r.report.semidense_final = Some(sdslam::runtime::SemiDenseFinalReport {
                keyframes: fin.stats.keyframes_reconstructed,
                skipped_keyframes: fin.stats.keyframes_skipped,
                points: cloud.len(),
                online_pixels: sd.stats.pixels.clone(),
                total_s: final_s,
                keyframe_ms: fin.t_keyframe.percentiles(),
                depth_ms: fin.t_depth.percentiles(),
                intra_ms: fin.t_intra.percentiles(),
                inter_ms: fin.t_inter.percentiles(),
                online_accuracy: cloud_accuracy(s, &online, &keyframes),
                online_points: online.len(),
            });
        }
    }
    Finished {
        keyframes,
        alignment,
        cloud,
        threads_ok,
    }
}

/// Stage 5: pictures, the final report, the summary, and an error when an output or a thread
/// failed (every other output is written by then).
pub fn write(mut s: Session, mut r: Running, f: Finished) -> Result<RunOutcome> {
    if !s.args.no_plots {
        let aligned = s.groundtruth.as_ref().zip(f.alignment.as_ref());
        s.outputs.write("trajectory.png", |p| {
            crate::plots::trajectory(
                p,
                &f.keyframes,
                aligned.map(|(gt, a)| (gt.as_slice(), &a.alignment, a.rmse_m)),
            )
        });
        s.outputs
            .write("cloud.png", |p| crate::plots::cloud(p, &f.cloud));
        s.outputs.write("timing.png", |p| {
            crate::plots::timing(p, r.frame_timer.samples_ms(), s.deadline_ms)
        });
    }
    // Last, so the peak covers the whole run (finishing, the cloud, evaluation, plots).
    r.report.peak_rss_mb = io::peak_rss_mb();
    s.outputs
        .write("report.json", |p| write_json_atomic(p, &r.report));
    note_summary(&s, &r);
    if !s.outputs.failures().is_empty() {
        return Err(sdslam::Error::Invalid(format!(
            "{} output(s) not written ({}); the others are in {}",
            s.outputs.failures().len(),
            s.outputs.failures().join("; "),
            s.outputs.dir().display()
        )));
    }
    if !f.threads_ok {
        return Err(sdslam::Error::Invalid(format!(
            "{}; every output was written to {}",
            r.report
                .stopped_early
                .as_deref()
                .unwrap_or("a worker thread failed"),
            s.outputs.dir().display()
        )));
    }
    Ok(RunOutcome {
        latencies_ms: r.frame_timer.samples_ms().to_vec(),
        report: r.report,
    })
}

/// The final keyframes and clouds on the Foxglove channels, then the MCAP file finished
/// (a failure is one more failed output) and the live server stopped.
fn finish_publishing(
    s: &mut Session,
    r: &mut Running,
    trajectory: &[TimedPose],
    keyframes: &[TimedPose],
    cloud: &[CloudPoint],
    online: Option<&[CloudPoint]>,
) {
    let Some(mut publish) = r.publish.take() else {
        return;
    };
    publish.end_of_run(trajectory, keyframes, &r.system, cloud, online);
    let (tmp, finished, dropped) = publish.finish();
    if dropped > 0 {
        note!("warning: {dropped} messages left out of the MCAP file / live view (the writer fell behind)");
    }
    if let (Some(path), Some(tmp)) = (s.args.mcap.clone(), tmp) {
        s.outputs.write_at("mcap", &path, |p| {
            finished?;
            std::fs::rename(&tmp, p).map_err(|e| sdslam::Error::io(p, e))
        });
        // Not there after the rename; an unfinished file when finishing or renaming failed.
        let _ = std::fs::remove_file(&tmp);
    }
}

/// The map file, encoded and written atomically.
fn save_map(system: &System, p: &std::path::Path) -> Result<()> {
    let bytes = system
        .save_map()
        .encode()
        .map_err(|e| sdslam::Error::format(p, e))?;
    io::write_atomic(p, &bytes)?;
    note!(
        "sdslam: map saved to {} ({} kB)",
        p.display(),
        bytes.len() / 1024
    );
    Ok(())
}

/// Frames the pacing or the camera driver dropped, and how old frames were when dequeued.
fn note_capture_stats(s: &Session, r: &mut Running) {
    if let Some(p) = &r.pacing_stats {
        r.report.dropped_frames = p.dropped();
    }
    if let Some(l) = &s.live {
        use std::sync::atomic::Ordering::Relaxed;
        r.report.driver_dropped_frames = l.driver_drops.load(Relaxed);
        let age = l.mean_age_us.load(Relaxed);
        r.report.capture_to_dequeue_ms = (age > 0).then_some(age as f64 / 1e3);
    }
}

/// The tracking and mapping figures of a finished run.
fn fill_tracking_report(report: &mut Report, system: &System, frame_timer: &StageTimer) {
    report.timing_ms.tracking = frame_timer.percentiles();
    report.timing_ms.orb_extraction = system.stats.orb_extraction.percentiles();
    report.timing_ms.initialisation = system.stats.initialisation.percentiles();
    report.timing_ms.initialisation_solve = system.stats.initialisation_solve.percentiles();
    report.timing_ms.local_ba = system.stats.local_mapping.percentiles();
    report.timing_ms.pose_prediction = system.tracker.t_prediction.percentiles();
    report.timing_ms.local_map_tracking = system.tracker.t_local_map.percentiles();
    report.timing_ms.relocalisation = system.tracker.t_relocalisation.percentiles();
    report.timing_ms.keyframe_insertion = system.stats.keyframe_insertion.percentiles();
    report.timing_ms.map_lock_wait = system.stats.map_lock_wait.percentiles();
    report.tracked_frames = system.stats.tracked_frames;
    report.backfilled_frames = system.stats.backfilled_frames;
    report.map_resets = system.stats.resets;
    report.poses_discarded_by_reset = system.stats.poses_discarded_by_reset;
    report.divergences = system.stats.divergences.clone();
    report.degraded_frames = system.stats.degraded_frames.iter().sum();
    report.degraded_reasons = sdslam::tracking::DegradedReason::ALL
        .iter()
        .map(|r| {
            (
                r.name().to_string(),
                system.stats.degraded_frames[*r as usize],
            )
        })
        .collect();
    report.centre_sigma_pct_of_depth = system.stats.centre_sigma_pct.percentiles();
    report.lost_episodes = system.tracker.lost_episodes;
    report.relocalisations = system.tracker.relocalisations;
    report.recoveries = system.tracker.recoveries;
    report.relocalisation_budget_cuts = system.tracker.relocalisation_budget_cuts;
    report.loops_closed = system.stats.loops_closed;
    report.loops_closed_by_revisit = system.stats.loops_closed_by_revisit;
    report.loop_closures.clone_from(&system.stats.loop_closures);
    report.final_ba_ms = system.stats.final_ba_ms;
    report.timing_ms.loop_closing = system.stats.loop_closing.percentiles();
    (report.keyframes, report.map_points) = system.map_size();
    let atlas = system.atlas();
    // The counts of trajectory.txt and keyframes.txt (the primary map); every map's in `maps`.
    report.tracked_frames_all_maps = report.tracked_frames;
    if let Some(&(_, frames, keyframes)) = atlas.maps.iter().find(|m| Some(m.0) == atlas.primary) {
        report.tracked_frames = frames;
        report.keyframes = keyframes;
    }
    report.maps_made = system.stats.maps_made;
    report.maps_merged = system.map().maps_merged() as usize;
    report.primary_map = atlas.primary;
    report.maps = atlas
        .maps
        .iter()
        .map(
            |&(id, tracked_frames, keyframes)| sdslam::runtime::MapRecord {
                id,
                tracked_frames,
                keyframes,
            },
        )
        .collect();
}

/// The semi-dense mapper's counts and timings.
fn fill_semidense_report(report: &mut Report, sd: &SemiDenseMapper, finishing: Instant) {
    report.semidense_keyframes = sd.stats.keyframes_reconstructed;
    report.semidense_skipped_keyframes = sd.stats.keyframes_skipped;
    report.semidense_skipped_culled = sd.stats.skipped_culled;
    report.semidense_skipped_no_neighbours = sd.stats.skipped_no_neighbours;
    report.semidense_skipped_overload = sd.stats.skipped_overload;
    report.semidense_skipped_cut = sd.stats.skipped_cut;
    report.semidense_busy_s = sd.stats.busy_s;
    report.semidense_finish_s = finishing.elapsed().as_secs_f64();
    report.timing_ms.semidense_keyframe = sd.t_keyframe.percentiles();
    report.timing_ms.semidense_depth = sd.t_depth.percentiles();
    report.timing_ms.semidense_intra = sd.t_intra.percentiles();
    report.timing_ms.semidense_inter = sd.t_inter.percentiles();
}

/// Tells how much of the semi-dense backlog an interrupt cut.
fn note_cut(sd: &SemiDenseMapper) {
    if sd.stats.skipped_cut > 0 {
        note!(
            "sdslam: interrupted: {} keyframes of the semi-dense backlog were cut (not reconstructed, or not verified by the inter-keyframe check; semidense_skipped_cut in report.json)",
            sd.stats.skipped_cut
        );
    }
}

/// The depth maps of `sd`'s keyframes, on request.
fn write_depth_maps(s: &mut Session, sd: &SemiDenseMapper) {
    if s.args.depth_maps {
        let (width, height) = (s.info.width, s.info.height);
        let out = s.args.out.clone();
        s.outputs.write("depth", |_| {
            crate::densify::write_depth_maps(&out, sd, width, height)
        });
    }
}

/// The accuracy of `cloud` where there is ground-truth depth.
fn cloud_accuracy(
    s: &mut Session,
    cloud: &[CloudPoint],
    keyframes: &[TimedPose],
) -> Option<sdslam::eval::CloudAccuracy> {
    let (width, height) = (s.info.width, s.info.height);
    let (Some(gt), false) = (&s.groundtruth, cloud.is_empty()) else {
        return None;
    };
    // The evaluation protocol's alignment: keyframe centres plus axis points (positions alone
    // leave the rotation about a near-straight path free).
    let alignment = sdslam::eval::pose_alignment(gt, keyframes, 0.02)?;
    // One reference keyframe's points at a time, each group with its own depth map only: all
    // keyframes' maps at once were the largest share of a run's peak memory (desk: 86 MB).
    let mut order: Vec<u32> = (0..cloud.len() as u32).collect();
    order.sort_by(|&a, &b| {
        cloud[a as usize]
            .timestamp
            .total_cmp(&cloud[b as usize].timestamp)
    });
    let lens = s.calib.lens();
    let mut acc = sdslam::eval::CloudAccuracyBuilder::with_capacity(cloud.len());
    let mut any_depth = false;
    for group in order.chunk_by(|&a, &b| cloud[a as usize].timestamp == cloud[b as usize].timestamp)
    {
        let t = cloud[group[0] as usize].timestamp;
        let frames = match s.depth_truth.load(&[t], gt, width, height) {
            Ok(frames) => frames,
            Err(e) => {
                note!("warning: semi-dense accuracy not evaluated: {e}");
                return None;
            }
        };
        any_depth |= !frames.is_empty();
        let points = group.iter().map(|&i| &cloud[i as usize]);
        acc.add(points, &alignment, &lens, &frames);
    }
    any_depth.then(|| acc.finish())
}

/// The run's result on stderr.
fn note_summary(s: &Session, r: &Running) {
    let report = &r.report;
    if let Some(acc) = &report.semidense_accuracy {
        note!(
            "sdslam: semi-dense {} points ({:.0} per keyframe): median relative depth error {}, {:.1}% within 2%, {:.2}% off by > 10%",
            acc.points,
            acc.points_per_keyframe,
            crate::percent(acc.median_relative_error),
            acc.within_2pct * 100.0,
            acc.outliers_10pct * 100.0
        );
    }
    if let Some(f) = &report.semidense_final {
        if let Some(acc) = &f.online_accuracy {
            note!(
                "sdslam: semi-dense online cloud (semidense_online.ply) {} points: median {}, {:.2}% off by > 10%; end-of-session reconstruction of {} keyframes took {:.1} s",
                acc.points,
                crate::percent(acc.median_relative_error),
                acc.outliers_10pct * 100.0,
                f.keyframes,
                f.total_s
            );
        }
    }
    note!(
        "sdslam: {} frames ({} skipped), {} tracked{}, {} keyframes, {} points{}, {:.1} s; state {:?}; outputs in {}",
        report.frames,
        report.skipped_frames,
        report.tracked_frames,
        if report.maps.len() > 1 {
            format!(
                " in the primary map ({} in {} maps)",
                report.tracked_frames_all_maps,
                report.maps.len()
            )
        } else {
            String::new()
        },
        report.keyframes,
        report.map_points,
        report.keyframe_ate_rmse_m.map(|a| format!(", keyframe ATE {:.4} (Sim3-aligned)", a)).unwrap_or_default(),
        report.wall_time_s,
        r.system.state(),
        s.outputs.dir().display()
    );
}
