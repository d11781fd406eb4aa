//! The ORB extractor: owns the pyramid and every scratch buffer for one image size.

use super::brief::{describe, Descriptor, PatternPoints};
use super::distribute::{distribute, QuadtreeScratch};
use super::fast::{detect, Corner};
use super::harris::harris_response;
use super::helper::Helper;
use super::orientation::{circle_umax, ic_angle, MomentWeights};
use super::spread::{spread_by_radius, SpreadScratch};
use super::{Features, KeyPoint};
use crate::camera_model::PinholeRadtan;
use crate::config::{OrbConfig, OrbDistribution, OrbScore};
use crate::image::{gaussian_blur_7x7, PaddedImage, Pyramid, PyramidConfig};

/// Keypoints stay this far (level pixels) from the level's edge; the padded border covers the
/// orientation patch and the rotated BRIEF pattern beyond it.
const MIN_BORDER: usize = 16;
/// FAST threshold cells, level pixels (ORB-SLAM's 30 x 30).
const CELL: usize = 30;
/// Padding of pyramid levels: FAST's wide loads (3 + LANES) and the rotated pattern (< 22 px).
const PAD: usize = 3 + super::fast::LANES;
/// Border pixels whose values are read: the 7x7 blur (3 px) and the rotated BRIEF pattern
/// (< 19 px from a keypoint at least `MIN_BORDER` inside, so < 3 px). FAST's wide loads past
/// the region only need the memory.
const FILLED: usize = 8;

/// Features wanted per level: a geometric series over levels summing to `n` (ORB-SLAM's rule).
pub fn features_per_level(n: usize, scale_factor: f64, levels: usize) -> Vec<usize> {
    let f = 1.0 / scale_factor;
    let mut desired = n as f64 * (1.0 - f) / (1.0 - f.powi(levels as i32));
    let mut out = Vec::with_capacity(levels);
    let mut sum = 0;
    for _ in 0..levels.saturating_sub(1) {
        let k = desired.round() as usize;
        out.push(k);
        sum += k;
        desired *= f;
    }
    out.push(n.saturating_sub(sum));
    out
}

/// Most pyramid levels (the config's bound).
const MAX_LEVELS: usize = 16;

/// One worker's scratch and output: the levels it was given are detected, distributed and
/// described into `out`, `ranges[l]` marking each level's keypoints.
struct Lane {
    corners: Vec<Corner>,
    score_map: Vec<u8>,
    cell_counts: Vec<u32>,
    scratch: QuadtreeScratch,
    selected: Vec<u32>,
    /// Response of each selected corner, and the selected corners kept (indices into both).
    responses: Vec<f32>,
    order: Vec<u32>,
    kept: Vec<u32>,
    pts: Vec<(f32, f32)>,
    spread: SpreadScratch,
    blur_tmp: Vec<u16>,
    out: Features,
    ranges: [(u32, u32); MAX_LEVELS],
}

impl Lane {
    fn new(width: usize, height: usize, n_features: usize) -> Self {
        let cells = (width / CELL + 2) * (height / CELL + 2);
        Lane {
            // Bounded by construction: at most one corner per pixel of level 0.
            corners: Vec::with_capacity(width * height),
            score_map: vec![0; width * height],
            cell_counts: vec![0; cells],
            scratch: QuadtreeScratch::with_capacity(width * height, n_features),
            selected: Vec::with_capacity(n_features * 2),
            responses: Vec::with_capacity(n_features * 2),
            order: Vec::with_capacity(n_features * 4),
            kept: Vec::with_capacity(n_features * 4),
            pts: Vec::with_capacity(n_features * 4),
            spread: SpreadScratch::new(width, height, n_features * 4),
            blur_tmp: Vec::with_capacity((width + 16) * (height + 16)),
            out: Features::with_capacity(n_features),
            ranges: [(0, 0); MAX_LEVELS],
        }
    }
}

/// What every lane reads.
struct Shared<'a> {
    config: &'a OrbConfig,
    per_level: &'a [usize],
    moments: &'a MomentWeights,
    pattern: &'a PatternPoints,
    to_level0: &'a [(f64, f64)],
    scales: &'a [f64],
    levels: &'a [PaddedImage],
}

/// ORB extraction for images of one size. With `[orb] threads = 2` the levels are shared out
/// between two lanes (balanced by area) that run at once; the output is the same as on one
/// thread (levels are merged in order).
pub struct OrbExtractor {
    config: OrbConfig,
    pyramid: Pyramid,
    per_level: Vec<usize>,
    moments: Box<MomentWeights>,
    pattern: Box<PatternPoints>,
    /// Per level: level -> level-0 coordinate scale (x, y), from the actual level sizes.
    to_level0: Vec<(f64, f64)>,
    lanes: Vec<Lane>,
    /// The lane of each level.
    lane_of: [usize; MAX_LEVELS],
    /// Runs the second lane while the caller runs the first (`None`: one thread).
    helper: Option<Helper>,
}

impl OrbExtractor {
    /// Allocates everything for `width` x `height` images.
    pub fn new(width: usize, height: usize, config: &OrbConfig) -> Self {
        let pyramid = Pyramid::new(
            width,
            height,
            PyramidConfig {
                levels: config.n_levels,
                scale_factor: config.scale_factor,
                pad: PAD,
                filled: FILLED,
            },
        );
        let to_level0: Vec<(f64, f64)> = pyramid
            .levels
            .iter()
            .map(|l| {
                (
                    width as f64 / l.width as f64,
                    height as f64 / l.height as f64,
                )
            })
            .collect();
        let helper = (config.threads > 1 && pyramid.n_levels() > 1)
            .then(|| Helper::spawn("orb-helper"))
            .flatten();
        // Largest level first, each to the lane with less area so far.
        let mut lane_of = [0; MAX_LEVELS];
        if helper.is_some() {
            let mut area = [0usize; 2];
            for (l, lv) in pyramid.levels.iter().enumerate().take(MAX_LEVELS) {
                let lane = usize::from(area[1] < area[0]);
                lane_of[l] = lane;
                area[lane] += lv.width * lv.height;
            }
        }
        let n_lanes = if helper.is_some() { 2 } else { 1 };
        OrbExtractor {
            per_level: features_per_level(config.n_features, config.scale_factor, config.n_levels),
            config: config.clone(),
            moments: Box::new(MomentWeights::new(&circle_umax())),
            pattern: Box::new(PatternPoints::new()),
            lanes: (0..n_lanes)
                .map(|_| Lane::new(width, height, config.n_features))
                .collect(),
            lane_of,
            helper,
            pyramid,
            to_level0,
        }
    }

    pub fn pyramid(&self) -> &Pyramid {
        &self.pyramid
    }

    pub fn config(&self) -> &OrbConfig {
        &self.config
    }

    /// Extracts ORB features of a tightly packed grey image into `out` (cleared first). With a
    /// camera, keypoints also get undistorted coordinates.
    pub fn extract(&mut self, gray: &[u8], camera: Option<&PinholeRadtan>, out: &mut Features) {
        #[cfg(target_arch = "x86_64")]
        if crate::simd::avx2() {
            // SAFETY: the CPU supports AVX2 (checked just above); the function is otherwise safe.
            unsafe { self.build_avx2(gray) };
        } else {
            self.pyramid.build(gray);
        }
        #[cfg(not(target_arch = "x86_64"))]
        self.pyramid.build(gray);
        let n = self.pyramid.n_levels().min(MAX_LEVELS);
        let Pyramid {
            levels,
            blurred,
            scales,
            ..
        } = &mut self.pyramid;
        let shared = Shared {
            config: &self.config,
            per_level: &self.per_level,
            moments: &self.moments,
            pattern: &self.pattern,
            to_level0: &self.to_level0,
            scales,
            levels,
        };
        // Each lane gets the blurred images of its levels (disjoint borrows, on the stack).
        let mut mine: [[Option<&mut PaddedImage>; MAX_LEVELS]; 2] = Default::default();
        for (l, b) in blurred.iter_mut().enumerate().take(n) {
            mine[self.lane_of[l]][l] = Some(b);
        }
        let [m0, m1] = mine;
        match (&mut self.helper, self.lanes.as_mut_slice()) {
            (Some(helper), [a, b]) => {
                let s = &shared;
                helper.join(|| run_lane(s, m1, b), || run_lane(s, m0, a));
            }
            (_, lanes) => {
                if let Some(a) = lanes.first_mut() {
                    run_lane(&shared, m0, a);
                }
            }
        }
        out.clear();
        for l in 0..n {
            let lane = &self.lanes[self.lane_of[l]];
            let (s, e) = lane.ranges[l];
            let (s, e) = (s as usize, e as usize);
            out.keypoints.extend_from_slice(&lane.out.keypoints[s..e]);
            out.descriptors
                .extend_from_slice(&lane.out.descriptors[s..e]);
        }
        if let Some(cam) = camera.filter(|c| !c.is_distortion_free()) {
            for k in &mut out.keypoints {
                let u = cam.undistort_pixel(k.x as f64, k.y as f64);
                k.ux = u.x as f32;
                k.uy = u.y as f32;
            }
        }
    }

    /// The pyramid compiled for AVX2 (the resampling loops vectorise 32 bytes wide).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn build_avx2(&mut self, gray: &[u8]) {
        self.pyramid.build(gray)
    }
}

/// Detects, distributes and describes the levels whose blurred image `mine` holds.
fn run_lane(s: &Shared, mine: [Option<&mut PaddedImage>; MAX_LEVELS], lane: &mut Lane) {
    #[cfg(target_arch = "x86_64")]
    if crate::simd::avx2() {
        // SAFETY: the CPU supports AVX2 (checked just above); the function is otherwise safe.
        unsafe { run_lane_avx2(s, mine, lane) };
        return;
    }
    run_lane_portable(s, mine, lane)
}

/// The lane's work compiled for AVX2: blur, FAST, orientation and descriptor loops inline
/// into it and vectorise 32 bytes wide.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn run_lane_avx2(s: &Shared, mine: [Option<&mut PaddedImage>; MAX_LEVELS], lane: &mut Lane) {
    run_lane_portable(s, mine, lane)
}

#[inline(always)]
fn run_lane_portable(s: &Shared, mine: [Option<&mut PaddedImage>; MAX_LEVELS], lane: &mut Lane) {
    lane.out.clear();
    for (l, blurred) in mine.into_iter().enumerate() {
        let Some(blurred) = blurred else { continue };
        let start = lane.out.keypoints.len() as u32;
        extract_level(s, l, blurred, lane);
        lane.ranges[l] = (start, lane.out.keypoints.len() as u32);
    }
}

/// The steered descriptor with AVX2 gathers where the CPU has them (the same bits).
#[inline(always)]
fn describe_any(b: &PaddedImage, p: &PatternPoints, x: isize, y: isize, a: f32) -> Descriptor {
    #[cfg(target_arch = "x86_64")]
    if crate::simd::avx2() {
        // SAFETY: the CPU supports AVX2 (checked just above).
        return unsafe { super::brief::describe_avx2(b, p, x, y, a) };
    }
    describe(b, p, x, y, a)
}

/// The detection cells of one level (`CELL` px squares over the bordered region).
struct CellGrid {
    origin: (usize, usize),
    end: (usize, usize),
    cols: usize,
    rows: usize,
}

impl CellGrid {
    /// Adds `corners` to the per-cell counts.
    fn count(&self, corners: &[Corner], counts: &mut [u32]) {
        let (x0, y0) = self.origin;
        for c in corners {
            counts[(c.y as usize - y0) / CELL * self.cols + (c.x as usize - x0) / CELL] += 1;
        }
    }

    /// Runs FAST at `threshold` in every cell with no corner yet.
    fn fill_empty(
        &self,
        level: &PaddedImage,
        threshold: u8,
        counts: &[u32],
        corners: &mut Vec<Corner>,
        score_map: &mut [u8],
    ) {
        let ((x0, y0), (x1, y1)) = (self.origin, self.end);
        for cy in 0..self.rows {
            for cx in 0..self.cols {
                if counts[cy * self.cols + cx] == 0 {
                    let r = (
                        x0 + cx * CELL,
                        y0 + cy * CELL,
                        (x0 + (cx + 1) * CELL).min(x1),
                        (y0 + (cy + 1) * CELL).min(y1),
                    );
                    detect(level, threshold, r, corners, score_map);
                }
            }
        }
    }
}

#[inline(always)]
fn extract_level(s: &Shared, l: usize, blurred: &mut PaddedImage, lane: &mut Lane) {
    let level = &s.levels[l];
    let (w, h) = (level.width, level.height);
    if w <= 2 * MIN_BORDER + 8 || h <= 2 * MIN_BORDER + 8 {
        return;
    }
    let (x0, y0, x1, y1) = (MIN_BORDER, MIN_BORDER, w - MIN_BORDER, h - MIN_BORDER);
    let score_map = &mut lane.score_map[..w * h];
    score_map.fill(0);
    lane.corners.clear();
    // FAST (with non-maximum suppression) at the initial threshold everywhere, then the low
    // threshold in cells left empty.
    detect(
        level,
        s.config.ini_th_fast,
        (x0, y0, x1, y1),
        &mut lane.corners,
        score_map,
    );
    let (cols, rows) = ((x1 - x0).div_ceil(CELL), (y1 - y0).div_ceil(CELL));
    let grid = CellGrid {
        origin: (x0, y0),
        end: (x1, y1),
        cols,
        rows,
    };
    let counts = &mut lane.cell_counts[..cols * rows];
    counts.fill(0);
    grid.count(&lane.corners, counts);
    let first_pass = lane.corners.len();
    if s.config.min_th_fast < s.config.ini_th_fast {
        grid.fill_empty(
            level,
            s.config.min_th_fast,
            counts,
            &mut lane.corners,
            score_map,
        );
    }
    let wanted = s.per_level[l];
    let starved = s.config.starved_th_fast;
    if starved > 0 && starved < s.config.min_th_fast && lane.corners.len() < wanted {
        grid.count(&lane.corners[first_pass..], counts);
        grid.fill_empty(level, starved, counts, &mut lane.corners, score_map);
    }
    select_corners(s, level, (x0, y0, x1, y1), wanted, lane);
    if lane.order.is_empty() {
        return;
    }
    gaussian_blur_7x7(level, blurred, &mut lane.blur_tmp, FILLED);
    let (sx, sy) = s.to_level0[l];
    let scale = s.scales[l] as f32;
    for &o in &lane.order {
        let c = lane.corners[lane.selected[o as usize] as usize];
        let response = lane.responses[o as usize];
        let (x, y) = (c.x as isize, c.y as isize);
        let angle = ic_angle(level, x, y, s.moments);
        lane.out
            .descriptors
            .push(describe_any(blurred, s.pattern, x, y, angle));
        // Level pixel centres map to level-0 positions through the resampling geometry.
        let px = ((c.x as f64 + 0.5) * sx - 0.5) as f32;
        let py = ((c.y as f64 + 0.5) * sy - 0.5) as f32;
        lane.out.keypoints.push(KeyPoint {
            x: px,
            y: py,
            ux: px,
            uy: py,
            octave: l as u8,
            angle,
            response,
            size: 31.0 * scale,
        });
    }
}

/// Chooses the level's `wanted` corners: `lane.order` indexes `lane.selected` (indices into
/// `lane.corners`) and `lane.responses`.
#[inline(always)]
fn select_corners(
    s: &Shared,
    level: &PaddedImage,
    (x0, y0, x1, y1): (usize, usize, usize, usize),
    wanted: usize,
    lane: &mut Lane,
) {
    let region = (x0 as f32, y0 as f32, x1 as f32, y1 as f32);
    let corners = &lane.corners;
    let by_score = |a: &u32, b: &u32| {
        corners[*b as usize]
            .score
            .cmp(&corners[*a as usize].score)
            .then(a.cmp(b))
    };
    match s.config.distribution {
        OrbDistribution::Quadtree => {
            // More nodes than wanted, then the strongest node winners: spread like ORB-SLAM's
            // quadtree, but strong (repeatable) corners survive node boundaries moving.
            let nodes = (wanted as f64 * s.config.quadtree_oversampling).round() as usize;
            distribute(
                corners,
                region,
                nodes,
                &mut lane.scratch,
                &mut lane.selected,
            );
        }
        OrbDistribution::Radius | OrbDistribution::Strongest => {
            lane.selected.clear();
            lane.selected.extend(0..corners.len() as u32);
        }
    }
    // The response is computed for a bounded number of candidates: the strongest by FAST
    // score (OpenCV's ORB keeps 2N by FAST score before ranking by Harris).
    let pre = (wanted as f64 * s.config.candidates).ceil() as usize;
    if lane.selected.len() > pre {
        lane.selected.select_nth_unstable_by(pre, by_score);
        lane.selected.truncate(pre);
        lane.selected.sort_unstable();
    }
    lane.responses.clear();
    match s.config.score_type {
        OrbScore::Harris => lane.responses.extend(lane.selected.iter().map(|&i| {
            let c = corners[i as usize];
            harris_response(level, c.x as isize, c.y as isize)
        })),
        OrbScore::Fast => lane.responses.extend(
            lane.selected
                .iter()
                .map(|&i| corners[i as usize].score as f32),
        ),
    }
    // Strongest first (ties by position, deterministic). Corners of the initial threshold
    // come before the low-threshold fallback's: those only fill what the strong ones leave
    // (their cells follow a fixed grid, so they are the least repeatable).
    lane.order.clear();
    lane.order.extend(0..lane.selected.len() as u32);
    let r = &lane.responses;
    let sel = &lane.selected;
    let strong = |k: u32| corners[sel[k as usize] as usize].score >= s.config.ini_th_fast;
    let rank = |&a: &u32, &b: &u32| {
        strong(b)
            .cmp(&strong(a))
            .then(r[b as usize].total_cmp(&r[a as usize]))
            .then(a.cmp(&b))
    };
    match s.config.distribution {
        OrbDistribution::Quadtree | OrbDistribution::Strongest => {
            // The `wanted` best, in any order (sorted by index below): a partition is enough.
            if lane.order.len() > wanted {
                lane.order.select_nth_unstable_by(wanted, rank);
                lane.order.truncate(wanted);
            }
        }
        OrbDistribution::Radius => {
            lane.order.sort_unstable_by(rank);
            lane.pts.clear();
            lane.pts.extend(
                lane.selected
                    .iter()
                    .map(|&i| (corners[i as usize].x as f32, corners[i as usize].y as f32)),
            );
            spread_by_radius(
                &lane.pts,
                &lane.order,
                region,
                wanted,
                &mut lane.spread,
                &mut lane.kept,
            );
            std::mem::swap(&mut lane.order, &mut lane.kept);
        }
    }
    lane.order.sort_unstable();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_pixel_read_around_a_keypoint_lies_in_the_filled_border() {
        // The rotated BRIEF pattern's reach (rounded outwards) plus the 7x7 blur's 3 pixels.
        let reach = super::super::brief::pattern()
            .iter()
            .flat_map(|q| [(q[0], q[1]), (q[2], q[3])])
            .map(|(x, y)| ((x as f64).hypot(y as f64)).ceil() as usize)
            .max()
            .unwrap_or(0);
        assert!(reach < MIN_BORDER + FILLED, "pattern reach {reach}");
        const { assert!(FILLED >= 3 && FILLED <= PAD) };
        // Harris (4 + 1 px) and the orientation patch (radius 15) stay in the interior.
        const { assert!(MIN_BORDER > 15 && MIN_BORDER > super::super::harris::HARRIS_BLOCK / 2 + 1) };
    }

    #[test]
    fn per_level_counts_follow_orbslam() {
        let v = features_per_level(1000, 1.2, 8);
        assert_eq!(v.iter().sum::<usize>(), 1000);
        assert_eq!(v[0], 217);
        assert!(v.windows(2).take(6).all(|w| w[0] > w[1]));
    }

    #[test]
    fn two_lanes_give_exactly_the_one_thread_output() {
        let seq = crate::synthetic::SyntheticSequence::new(Default::default());
        let mut f = crate::camera::Frame::new(640, 480);
        seq.render_frame(30, &mut f);
        let one = OrbConfig {
            threads: 1,
            ..OrbConfig::default()
        };
        let two = OrbConfig {
            threads: 2,
            ..OrbConfig::default()
        };
        let (mut a, mut b) = (Features::default(), Features::default());
        OrbExtractor::new(640, 480, &one).extract(&f.gray, None, &mut a);
        let mut ex2 = OrbExtractor::new(640, 480, &two);
        for _ in 0..3 {
            ex2.extract(&f.gray, None, &mut b);
            assert_eq!(a.keypoints.len(), 1000);
            assert_eq!(a.keypoints, b.keypoints);
            assert_eq!(a.descriptors, b.descriptors);
        }
    }
}
