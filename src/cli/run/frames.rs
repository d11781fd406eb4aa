//! Stage 3 of `sdslam run`: the frame loop, until the source ends, `--frames` is reached, a
//! worker thread fails, the source fails or the user interrupts.

use std::time::Instant;

use sdslam::camera::{Frame, FrameSource, FrameStatus};
use sdslam::tracking::TrackingState;

use super::session::{Running, Session};

/// Feeds every frame to the pipeline; each way out sets `report.stopped_early` when it is not
/// the end of the input, so the outputs say why they end where they do. The source is
/// dropped on return (a paced source's reader thread stops before the finishing work).
pub fn track(s: &Session, r: &mut Running, mut source: Box<dyn FrameSource>) {
    let mut frame = Frame::new(s.info.width, s.info.height);
    let mut warned_skip = false;
    loop {
        if let Some(t) = r.system.failed_thread() {
            r.report.stopped_early = Some(format!(
                "the {t} thread failed (panicked); outputs written from the run so far"
            ));
            note!("error: the {t} thread failed; stopping and writing the outputs computed so far");
            break;
        }
        // `--frames N` also bounds live cameras (replays are cut at the source).
        if s.args.frames.is_some_and(|n| r.report.frames >= n) {
            break;
        }
        if crate::signal::interrupted() {
            r.report.stopped_early =
                Some("interrupted (Ctrl-C); outputs written from the run so far".into());
            note!(
                "sdslam: interrupted; stopping the threads and writing the outputs computed so far"
            );
            break;
        }
        match source.next_frame(&mut frame) {
            Ok(FrameStatus::Ready) => {}
            Ok(FrameStatus::Skipped { index, reason }) => {
                r.report.skipped_frames += 1;
                if !warned_skip {
                    note!("warning: skipping unreadable frame {index}: {reason} (further skips are counted in report.json)");
                    warned_skip = true;
                }
                continue;
            }
            Ok(FrameStatus::End) => break,
            Err(e) => {
                r.report.stopped_early = Some(e.to_string());
                note!("error: {e}; writing the outputs computed so far");
                break;
            }
        }
        if let Some((start, count)) = s.args.drop {
            if frame.index >= start && frame.index < start + count {
                r.report.blackout_frames += 1;
                continue;
            }
        }
        process(s, r, &frame);
    }
}

/// One frame through the pipeline, with its latency, deadline and progress bookkeeping.
fn process(s: &Session, r: &mut Running, frame: &Frame) {
    let t0 = frame.arrival.unwrap_or_else(Instant::now);
    let out = r.system.process_frame(frame);
    if let (Some((start, count)), None) = (s.args.drop, r.report.frames_to_recover) {
        if frame.index >= start + count && out.state == TrackingState::Ok {
            r.report.frames_to_recover = Some(frame.index - (start + count));
        }
    }
    let ms = t0.elapsed().as_secs_f64() * 1e3;
    r.frame_timer.record_ms(ms);
    if ms > s.deadline_ms {
        r.report.deadline_misses += 1;
        tracing::debug!(
            frame = frame.index,
            latency_ms = ms,
            state = ?out.state,
            keyframe = out.new_keyframe,
            "deadline missed"
        );
    }
    r.report.frames += 1;
    if let Some(p) = &mut r.publish {
        p.frame(frame, &out, ms, &r.system);
    }
    #[cfg(feature = "rerun")]
    show(r, frame, &out);
    if let Some(pb) = &r.progress {
        pb.set_position(frame.index + 1);
        if r.report.frames.is_multiple_of(10) {
            let (k, p) = r.system.map_size();
            pb.set_message(format!("{:?}, {k} keyframes, {p} points", out.state));
        }
    }
}

/// The live viewer's share of a frame.
#[cfg(feature = "rerun")]
fn show(r: &Running, frame: &Frame, out: &sdslam::runtime::FrameResult) {
    let Some(v) = &r.viewer else { return };
    if let Some(t_wc) = &out.t_wc {
        v.frame(frame.timestamp, t_wc);
    }
    if out.new_keyframe {
        v.keyframes(frame.timestamp, &r.system.keyframe_trajectory());
        // The cloud so far is readable while running in the single-thread mode only
        // (the semi-dense thread hands its results over at the end).
        if r.system.semidense().is_some() && r.system.map_size().0.is_multiple_of(5) {
            v.cloud(frame.timestamp, &r.system.semidense_cloud());
        }
    }
}
