//! Monocular initialisation: match a reference frame to later frames in a window, recover the
//! two-view motion (H/F), refine it by two-view BA, and build the first two keyframes.

use nalgebra::{Matrix3, Vector2};

use super::frame::{KeptImages, TrackedFrame};
use crate::features::FeatureView;
use crate::features::Features;
use crate::geometry::two_view::{initialize, TwoViewConfig, TwoViewError, TwoViewMotion};
use crate::matching::search::{search_for_initialization, WindowSearch};
use crate::matching::FeatureGrid;
use crate::optimize::refine_two_view;

/// Frames kept for backfilling (2 s at 30 fps).
pub const PENDING_CAPACITY: usize = 60;

/// Why an initialisation attempt did not produce a map (a state, not an error).
#[derive(Clone, Debug, PartialEq)]
pub enum InitAttempt {
    /// The frame became the new reference.
    NewReference,
    TooFewMatches(usize),
    Failed(TwoViewError),
    Ready,
}

pub struct Initializer {
    pub reference: Option<Features>,
    pub reference_index: u64,
    pub reference_timestamp: f64,
    pub reference_images: KeptImages,
    grid: FeatureGrid,
    matches: Vec<Option<u32>>,
    /// Where each reference keypoint was last matched: the centre of its next search window.
    prev_matched: Vec<[f32; 2]>,
    pub config: TwoViewConfig,
    /// Frames seen since the reference (features kept so they can be tracked once the map
    /// exists); a fixed ring of `pending_capacity` slots, reused.
    pub pending: Vec<PendingFrame>,
    pending_len: usize,
    /// Of the pending frames, how many (the oldest) came before the current reference: the
    /// earlier references and their frames, kept when the reference is renewed so the new
    /// map can pose them too (the backfill chains back past the first keyframe); the oldest
    /// make room for newer frames when the ring is full.
    retained: usize,
    /// Attempts against the current reference refused for a reason other than too little
    /// parallax (ambiguous motion, too few triangulated points).
    refused: usize,
    /// After this many refused attempts in a row the current frame becomes the reference.
    /// Not ORB-SLAM's policy, which keeps the reference while matches last: an ambiguity
    /// comes from the geometry of the two views and does not go away as the camera moves on,
    /// so a fixed reference can refuse for ever (seen after a map reset on `posters`).
    pub max_refused_attempts: usize,
}

/// The matched pixels of one attempt (reference `x1`, current `x2`) and the keypoint pairs.
pub struct InitProblem {
    pub x1: Vec<Vector2<f64>>,
    pub x2: Vec<Vector2<f64>>,
    pub pairs: Vec<(u32, u32)>,
}

/// What [`Initializer::prepare`] leaves to do.
pub enum Prepared {
    /// Nothing to solve (a new reference, too few matches).
    Done(InitAttempt),
    Solve(InitProblem),
}

/// The costly part of an attempt (H and F, reconstruction, two-view BA: 10-25 ms here, more
/// on a small ARM core): needs nothing but the problem, so it can run on another thread.
pub fn solve(
    problem: &InitProblem,
    k: &Matrix3<f64>,
    config: &TwoViewConfig,
) -> Result<TwoViewMotion, TwoViewError> {
    let mut m = initialize(&problem.x1, &problem.x2, k, config)?;
    refine_two_view(&mut m, &problem.x1, &problem.x2, k, config.sigma);
    Ok(m)
}

/// A frame between the reference and initialisation, kept for backfilling its pose.
#[derive(Clone, Default)]
pub struct PendingFrame {
    pub index: u64,
    pub timestamp: f64,
    pub features: Features,
}

impl Initializer {
    pub fn new(max_features: usize, width: usize, height: usize) -> Self {
        Initializer {
            reference: None,
            reference_index: 0,
            reference_timestamp: 0.0,
            reference_images: KeptImages::with_capacity(width * height),
            grid: FeatureGrid::new(
                (width / 10).max(1),
                (height / 10).max(1),
                (0.0, 0.0, width as f32, height as f32),
                max_features,
            ),
            matches: Vec::with_capacity(max_features),
            prev_matched: Vec::with_capacity(max_features),
            config: TwoViewConfig::default(),
            pending: (0..PENDING_CAPACITY)
                .map(|_| PendingFrame {
                    features: Features::with_capacity(max_features),
                    ..Default::default()
                })
                .collect(),
            pending_len: 0,
            retained: 0,
            refused: 0,
            max_refused_attempts: 15,
        }
    }

    /// Two-view parameters in force (ORB-SLAM's by default).
    pub fn with_config(mut self, config: TwoViewConfig) -> Self {
        self.config = config;
        self
    }

    /// Matches an attempt from the current reference needs (no reference: `min_matches`):
    /// [`TwoViewConfig::required_matches`].
    pub fn required_matches(&self) -> usize {
        match &self.reference {
            Some(r) => self.config.required_matches(r.len()),
            None => self.config.min_matches,
        }
    }

    /// Points a map initialised from the current reference must keep:
    /// [`TwoViewConfig::required_map_points`].
    pub fn required_map_points(&self) -> usize {
        match &self.reference {
            Some(r) => self.config.required_map_points(r.len()),
            None => self.config.min_initial_map_points,
        }
    }

    /// Frames kept since the reference, oldest first.
    pub fn pending(&self) -> &[PendingFrame] {
        &self.pending[..self.pending_len]
    }

    fn keep_pending(&mut self, f: &TrackedFrame) {
        if !self.make_room() {
            return; // beyond the window: those frames stay untracked
        }
        let p = &mut self.pending[self.pending_len];
        p.index = f.index;
        p.timestamp = f.timestamp;
        p.features.copy_from(&f.features);
        self.pending_len += 1;
    }

    /// A free slot at the end of the pending frames: the oldest frame from before the
    /// reference goes when the ring is full. False when full of frames since the reference.
    fn make_room(&mut self) -> bool {
        if self.pending_len < self.pending.len() {
            return true;
        }
        if self.retained == 0 {
            return false;
        }
        self.pending[..self.pending_len].rotate_left(1);
        self.pending_len -= 1;
        self.retained -= 1;
        true
    }

    pub fn reset(&mut self) {
        self.reference = None;
        self.pending_len = 0;
        self.retained = 0;
        self.refused = 0;
    }

    fn set_reference(&mut self, f: &TrackedFrame, gray: &[u8], rgb: Option<&[u8]>) {
        // The old reference joins the pending frames, in time order (after the frames kept
        // from before it, before those seen since): every pending frame is now older than
        // the new reference.
        let old = self.reference.take();
        if let Some(old) = &old {
            if self.make_room() {
                let at = self.retained;
                self.pending[at..=self.pending_len].rotate_right(1);
                let p = &mut self.pending[at];
                p.index = self.reference_index;
                p.timestamp = self.reference_timestamp;
                p.features.copy_from(old);
                self.pending_len += 1;
            }
        }
        self.retained = self.pending_len;
        self.refused = 0;
        // The old reference's buffers take the new one (no allocation once warm).
        self.reference = Some(match old {
            Some(mut r) => {
                r.copy_from(&f.features);
                r
            }
            None => f.features.clone(),
        });
        self.reference_index = f.index;
        self.reference_timestamp = f.timestamp;
        self.reference_images.set(gray, rgb);
        if let Some(r) = &self.reference {
            self.grid.assign(&r.keypoints);
            self.prev_matched.clear();
            self.prev_matched
                .extend(r.keypoints.iter().map(|k| [k.ux, k.uy]));
        }
    }

    /// Tries to initialise from the reference to `f`. On `Ready`, returns the motion and the
    /// matches (reference keypoint -> current keypoint) through `out`. The three steps below
    /// in a row: the deterministic mode, and the model of the asynchronous one.
    pub fn attempt(
        &mut self,
        f: &TrackedFrame,
        gray: &[u8],
        rgb: Option<&[u8]>,
        k: &Matrix3<f64>,
        out: &mut Option<(TwoViewMotion, Vec<(u32, u32)>)>,
    ) -> InitAttempt {
        *out = None;
        match self.prepare(f, gray, rgb) {
            Prepared::Done(a) => a,
            Prepared::Solve(problem) => {
                let solved = solve(&problem, k, &self.config);
                self.conclude(f, gray, rgb, problem, solved, out)
            }
        }
    }

    /// The cheap part of an attempt, on the tracking thread: the reference, the window search
    /// and the matched pixels (or why there is nothing to solve).
    pub fn prepare(&mut self, f: &TrackedFrame, gray: &[u8], rgb: Option<&[u8]>) -> Prepared {
        let Some(r) = &self.reference else {
            if f.features.len() > self.config.min_matches {
                self.set_reference(f, gray, rgb);
            }
            return Prepared::Done(InitAttempt::NewReference);
        };
        // ORB-SLAM's initialisation search: a 100 px window, ratio 0.9, rotation check.
        let search = WindowSearch {
            window: 100.0,
            ratio: 0.9,
            check_orientation: true,
        };
        let n = search_for_initialization(
            FeatureView::new(&r.keypoints, &r.descriptors),
            &self.prev_matched,
            f.features.view(),
            &f.grid,
            search,
            &mut self.matches,
        );
        for (c, m) in self.prev_matched.iter_mut().zip(&self.matches) {
            if let Some(j) = m {
                let k = &f.features.keypoints[*j as usize];
                *c = [k.ux, k.uy];
            }
        }
        if n < self.required_matches() {
            // Too far from the reference: start over from this frame (ORB-SLAM's policy).
            if f.features.len() > self.config.min_matches {
                self.set_reference(f, gray, rgb);
            } else {
                self.reset();
            }
            return Prepared::Done(InitAttempt::TooFewMatches(n));
        }
        let pairs: Vec<(u32, u32)> = self
            .matches
            .iter()
            .enumerate()
            .filter_map(|(i, m)| m.map(|j| (i as u32, j)))
            .collect();
        let x1 = pairs
            .iter()
            .map(|&(i, _)| {
                let k = &r.keypoints[i as usize];
                Vector2::new(k.ux as f64, k.uy as f64)
            })
            .collect();
        let x2 = pairs
            .iter()
            .map(|&(_, j)| {
                let k = &f.features.keypoints[j as usize];
                Vector2::new(k.ux as f64, k.uy as f64)
            })
            .collect();
        Prepared::Solve(InitProblem { x1, x2, pairs })
    }

    /// The outcome of a solved attempt for frame `f` (the frame [`prepare`](Self::prepare)
    /// matched): keeps or renews the reference and the frames kept for backfilling.
    pub fn conclude(
        &mut self,
        f: &TrackedFrame,
        gray: &[u8],
        rgb: Option<&[u8]>,
        problem: InitProblem,
        solved: Result<TwoViewMotion, TwoViewError>,
        out: &mut Option<(TwoViewMotion, Vec<(u32, u32)>)>,
    ) -> InitAttempt {
        *out = None;
        match solved {
            Ok(m) => {
                *out = Some((m, problem.pairs));
                InitAttempt::Ready
            }
            Err(e) => {
                if matches!(
                    e,
                    TwoViewError::Degenerate { .. } | TwoViewError::Unconfirmed { .. }
                ) {
                    // Too little parallax yet (or too little to confirm the homography): keep
                    // the reference, the baseline grows.
                    self.keep_pending(f);
                    return InitAttempt::Failed(e);
                }
                self.refused += 1;
                if self.refused >= self.max_refused_attempts {
                    self.set_reference(f, gray, rgb);
                } else {
                    self.keep_pending(f);
                }
                InitAttempt::Failed(e)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::KeyPoint;

    /// A frame of 150 features at random places with random descriptors: nothing matches
    /// another frame, so each one renews the reference.
    fn unmatched_frame(index: u64, seed: u64) -> TrackedFrame {
        let mut f = TrackedFrame::new(200, 640, 480);
        f.index = index;
        f.timestamp = index as f64 / 30.0;
        let mut h = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        let mut next = move || {
            h ^= h << 13;
            h ^= h >> 7;
            h ^= h << 17;
            h
        };
        for _ in 0..150 {
            let (x, y) = ((next() % 620) as f32 + 10.0, (next() % 460) as f32 + 10.0);
            f.features.keypoints.push(KeyPoint {
                x,
                y,
                ux: x,
                uy: y,
                ..Default::default()
            });
            f.features
                .descriptors
                .push([next(), next(), next(), next()]);
        }
        f.reset_matches();
        f
    }

    #[test]
    fn renewed_references_stay_pending_in_time_order_and_the_oldest_go_first() {
        let mut init = Initializer::new(200, 640, 480);
        let gray = vec![0u8; 640 * 480];
        let n = PENDING_CAPACITY as u64 + 10;
        for i in 0..n {
            let f = unmatched_frame(i, i + 1);
            let _ = init.prepare(&f, &gray, None);
            assert_eq!(init.reference_index, i, "frame {i} should be the reference");
            let kept: Vec<u64> = init.pending().iter().map(|p| p.index).collect();
            // Every earlier frame, oldest first, as many as the ring holds.
            let from = i.saturating_sub(PENDING_CAPACITY as u64);
            assert_eq!(kept, (from..i).collect::<Vec<_>>(), "after frame {i}");
        }
        init.reset();
        assert!(init.pending().is_empty());
    }

    /// The reference `r` seen again: the first `shared` of its keypoints one pixel to the
    /// right, with the same descriptors, then unrelated ones up to 150 features.
    fn seen_again(r: &TrackedFrame, shared: usize) -> TrackedFrame {
        let mut f = unmatched_frame(1, 99);
        for i in 0..shared {
            let k = &mut f.features.keypoints[i];
            *k = r.features.keypoints[i];
            k.x += 1.0;
            k.ux += 1.0;
            f.features.descriptors[i] = r.features.descriptors[i];
        }
        f.reset_matches();
        f
    }

    #[test]
    fn a_weakly_textured_reference_lowers_the_bars_to_its_share() {
        let c = TwoViewConfig::default();
        let fixed = TwoViewConfig {
            min_match_share: 1.0,
            ..c.clone()
        };
        // (bars, reference features, expected matches and initial map points):
        let cases = [
            // ORB-SLAM's fixed bars from 334 features up;
            (&c, 1000, (100, 100)),
            (&c, 334, (100, 100)),
            // a blank wall's 200 features: 30% of them;
            (&c, 200, (60, 60)),
            // never under what the solver triangulates;
            (&c, 150, (50, 50)),
            // a share of 1 restores the fixed bars.
            (&fixed, 150, (100, 100)),
        ];
        for (bars, features, expected) in cases {
            let got = (
                bars.required_matches(features),
                bars.required_map_points(features),
            );
            assert_eq!(got, expected, "{features} features");
        }
        // A stricter initial-map bar holds on texture.
        let strict = TwoViewConfig {
            min_initial_map_points: 150,
            ..c.clone()
        };
        assert_eq!(strict.required_map_points(1000), 150);

        // 70 matches with a reference of 150 features: an attempt, where ORB-SLAM's fixed 100
        // would renew the reference instead.
        let gray = vec![0u8; 640 * 480];
        let r = unmatched_frame(0, 1);
        let again = seen_again(&r, 70);
        let mut init = Initializer::new(200, 640, 480);
        let _ = init.prepare(&r, &gray, None);
        assert_eq!(
            (init.required_matches(), init.required_map_points()),
            (50, 50)
        );
        match init.prepare(&again, &gray, None) {
            Prepared::Solve(p) => assert_eq!(p.pairs.len(), 70),
            Prepared::Done(a) => panic!("no attempt: {a:?}"),
        }
        let mut init = Initializer::new(200, 640, 480).with_config(fixed);
        let _ = init.prepare(&r, &gray, None);
        match init.prepare(&again, &gray, None) {
            Prepared::Done(InitAttempt::TooFewMatches(70)) => {}
            Prepared::Done(a) => panic!("expected too few matches, got {a:?}"),
            Prepared::Solve(p) => panic!("an attempt on {} matches", p.pairs.len()),
        }
        assert_eq!(init.reference_index, 1, "the reference was not renewed");
    }

    #[test]
    fn the_match_bar_comes_from_the_config() {
        let gray = vec![0u8; 640 * 480];
        let f = unmatched_frame(0, 1);
        // 150 features: enough for ORB-SLAM's 100, not for a bar of 200.
        let mut init = Initializer::new(200, 640, 480);
        let _ = init.prepare(&f, &gray, None);
        assert!(init.reference.is_some());
        let mut init = Initializer::new(200, 640, 480).with_config(TwoViewConfig {
            min_matches: 200,
            ..TwoViewConfig::default()
        });
        let _ = init.prepare(&f, &gray, None);
        assert!(
            init.reference.is_none(),
            "a frame of 150 features became the reference"
        );
    }
}
