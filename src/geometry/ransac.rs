//! Deterministic randomness for RANSAC: a seeded generator and minimal-set sampling, so solver
//! results are reproducible run to run.

/// PCG-style 64-bit generator (SplitMix64 output); tiny, fast, seedable.
#[derive(Clone, Debug)]
pub struct SeededRng(u64);

impl SeededRng {
    pub fn new(seed: u64) -> Self {
        SeededRng(seed ^ 0x853C_49E6_748F_EA9B)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform integer in `0..n` (n > 0), Lemire's multiply-shift.
    pub fn below(&mut self, n: usize) -> usize {
        ((self.next_u64() as u128 * n as u128) >> 64) as usize
    }

    /// Fills `out` with `out.len()` distinct indices from `0..n` (requires `out.len() <= n`).
    pub fn sample_distinct(&mut self, n: usize, out: &mut [usize]) {
        debug_assert!(out.len() <= n);
        for i in 0..out.len() {
            loop {
                let c = self.below(n);
                if !out[..i].contains(&c) {
                    out[i] = c;
                    break;
                }
            }
        }
    }
}

/// RANSAC iterations needed to draw an all-inlier minimal set of size `k` with probability
/// `p`, given an inlier ratio `w`; capped at `max`.
pub fn iterations_needed(p: f64, w: f64, k: usize, max: usize) -> usize {
    let wk = w.clamp(0.0, 1.0).powi(k as i32);
    if wk <= 0.0 {
        return max;
    }
    if wk >= 1.0 {
        return 1;
    }
    let n = ((1.0 - p).ln() / (1.0 - wk).ln()).ceil();
    if n.is_finite() {
        (n as usize).clamp(1, max)
    } else {
        max
    }
}

/// Stopping rule of [`adaptive_ransac`].
#[derive(Clone, Copy, Debug)]
pub struct RansacStop {
    /// Probability of drawing at least one all-inlier minimal set.
    pub probability: f64,
    pub max_iterations: usize,
}

/// Adaptive RANSAC over `n` data with minimal sets of `K` distinct indices: `hypothesize`
/// builds a model from a set (or rejects it), `classify` marks inliers and counts them. The
/// iteration count shrinks as the best inlier ratio grows. Returns the best model, its inlier
/// mask and count (`None` if no set gave a model).
pub fn adaptive_ransac<M, const K: usize>(
    n: usize,
    rng: &mut SeededRng,
    stop: RansacStop,
    mut hypothesize: impl FnMut(&[usize; K]) -> Option<M>,
    mut classify: impl FnMut(&M, &mut [bool]) -> usize,
) -> Option<(M, Vec<bool>, usize)> {
    if n < K {
        return None;
    }
    let mut set = [0usize; K];
    let mut cur = vec![false; n];
    let mut best: Option<(M, Vec<bool>, usize)> = None;
    let mut needed = stop.max_iterations;
    let mut it = 0;
    while it < needed.min(stop.max_iterations) {
        it += 1;
        rng.sample_distinct(n, &mut set);
        let Some(model) = hypothesize(&set) else {
            continue;
        };
        let c = classify(&model, &mut cur);
        if best.as_ref().is_none_or(|b| c > b.2) {
            needed = iterations_needed(
                stop.probability,
                c as f64 / n as f64,
                K,
                stop.max_iterations,
            );
            match &mut best {
                Some(b) => {
                    b.0 = model;
                    b.1.copy_from_slice(&cur);
                    b.2 = c;
                }
                None => best = Some((model, cur.clone(), c)),
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_are_distinct_in_range_and_reproducible() {
        let mut a = SeededRng::new(7);
        let mut b = SeededRng::new(7);
        let (mut s1, mut s2) = ([0usize; 8], [0usize; 8]);
        for _ in 0..100 {
            a.sample_distinct(20, &mut s1);
            b.sample_distinct(20, &mut s2);
            assert_eq!(s1, s2);
            assert!(s1.iter().all(|&i| i < 20));
            let mut u = s1.to_vec();
            u.sort();
            u.dedup();
            assert_eq!(u.len(), 8);
        }
    }

    #[test]
    fn adaptive_ransac_finds_a_line_among_outliers() {
        // y = 2x + 1 on 60 points, 40 random outliers; minimal set of 2.
        let mut r = SeededRng::new(9);
        let pts: Vec<(f64, f64)> = (0..100)
            .map(|i| {
                let x = i as f64;
                if i % 5 < 2 {
                    (x, (r.next_u64() % 1000) as f64)
                } else {
                    (x, 2.0 * x + 1.0)
                }
            })
            .collect();
        let mut rng = SeededRng::new(1);
        let stop = RansacStop {
            probability: 0.99,
            max_iterations: 500,
        };
        let (m, inl, c) = adaptive_ransac::<(f64, f64), 2>(
            pts.len(),
            &mut rng,
            stop,
            |s| {
                let (a, b) = (pts[s[0]], pts[s[1]]);
                let slope = (b.1 - a.1) / (b.0 - a.0);
                slope.is_finite().then_some((slope, a.1 - slope * a.0))
            },
            |&(k, d), out| {
                let mut n = 0;
                for (o, p) in out.iter_mut().zip(&pts) {
                    *o = (p.1 - (k * p.0 + d)).abs() < 1e-6;
                    n += *o as usize;
                }
                n
            },
        )
        .unwrap();
        assert!((m.0 - 2.0).abs() < 1e-9 && (m.1 - 1.0).abs() < 1e-9);
        assert!(c >= 60 && inl.iter().filter(|b| **b).count() == c);
    }

    #[test]
    fn iteration_count_formula() {
        assert_eq!(iterations_needed(0.99, 1.0, 4, 300), 1);
        assert_eq!(iterations_needed(0.99, 0.5, 4, 300), 72);
        assert_eq!(iterations_needed(0.99, 0.01, 4, 300), 300);
    }
}
