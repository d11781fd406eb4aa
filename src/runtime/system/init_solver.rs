//! The threaded mode's initialisation solver: the costly half of an attempt (H and F,
//! reconstruction, two-view BA) on its own thread, so a frame before the map exists costs the
//! tracking thread only its features and the window search. One attempt is in flight at a
//! time; its result is concluded on the first frame after it arrives, and the frames that come
//! while it runs are not attempted (nor kept for backfilling).

use std::thread::JoinHandle;
use std::time::Instant;

use crossbeam_channel::{bounded, Receiver, Sender};
use nalgebra::Matrix3;

use crate::geometry::two_view::{TwoViewConfig, TwoViewError, TwoViewMotion};
use crate::tracking::{solve_initialisation, InitProblem, KeptImages, TrackedFrame};

/// A solved attempt: the generation it was asked in, the problem, the outcome, solve time.
pub(super) type Solved = (u64, InitProblem, Result<TwoViewMotion, TwoViewError>, f64);

/// The frame an attempt in flight was made from (features and images, to conclude it and to
/// become keyframe 1), preallocated and reused.
pub(super) struct Candidate {
    pub frame: TrackedFrame,
    pub images: KeptImages,
}

pub(super) struct InitSolver {
    jobs: Option<Sender<(u64, InitProblem)>>,
    results: Receiver<Solved>,
    thread: Option<JoinHandle<()>>,
    /// Jobs sent whose result has not been received (0 or 1).
    pub outstanding: usize,
    /// Bumped by a reset: results asked before it are dropped.
    pub generation: u64,
    pub candidate: Option<Box<Candidate>>,
}

impl InitSolver {
    /// Starts the solver thread for a pinhole `k` (undistorted images of `width` x `height`).
    pub fn spawn(
        k: Matrix3<f64>,
        config: TwoViewConfig,
        max_features: usize,
        width: usize,
        height: usize,
    ) -> Option<Self> {
        let (job_tx, job_rx) = bounded::<(u64, InitProblem)>(1);
        let (res_tx, res_rx) = bounded::<Solved>(1);
        let thread = std::thread::Builder::new()
            .name("sdslam-init".into())
            .spawn(move || {
                for (generation, problem) in job_rx {
                    let t = Instant::now();
                    let solved = solve_initialisation(&problem, &k, &config);
                    let ms = t.elapsed().as_secs_f64() * 1e3;
                    if res_tx.send((generation, problem, solved, ms)).is_err() {
                        break;
                    }
                }
            })
            .ok()?;
        Some(InitSolver {
            jobs: Some(job_tx),
            results: res_rx,
            thread: Some(thread),
            outstanding: 0,
            generation: 0,
            candidate: Some(Box::new(Candidate {
                frame: TrackedFrame::new(max_features, width, height),
                images: KeptImages::with_capacity(width * height),
            })),
        })
    }

    /// Sends `problem` for the current generation. False when the thread is gone.
    pub fn send(&mut self, problem: InitProblem) -> bool {
        let ok = self
            .jobs
            .as_ref()
            .is_some_and(|j| j.try_send((self.generation, problem)).is_ok());
        if ok {
            self.outstanding += 1;
        }
        ok
    }

    /// A result if one has arrived (`Err(())` when the thread is gone with a job outstanding).
    pub fn try_result(&mut self) -> Result<Option<Solved>, ()> {
        match self.results.try_recv() {
            Ok(r) => {
                self.outstanding = self.outstanding.saturating_sub(1);
                Ok(Some(r))
            }
            Err(crossbeam_channel::TryRecvError::Empty) => Ok(None),
            Err(crossbeam_channel::TryRecvError::Disconnected) => Err(()),
        }
    }

    /// Closes the job channel and joins the thread (it finishes the job it has).
    pub fn join(&mut self) {
        self.jobs = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for InitSolver {
    fn drop(&mut self) {
        self.join();
    }
}
