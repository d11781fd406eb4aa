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
    fn iteration_count_formula() {
        assert_eq!(iterations_needed(0.99, 1.0, 4, 300), 1);
        assert_eq!(iterations_needed(0.99, 0.5, 4, 300), 72);
        assert_eq!(iterations_needed(0.99, 0.01, 4, 300), 300);
    }
}
