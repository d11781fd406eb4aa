//! Stage timers with preallocated sample storage, summarised as percentiles.

use serde::Serialize;

/// Timing percentiles of one stage, in milliseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Percentiles {
    pub p50: f64,
    pub p90: f64,
    pub p99: f64,
    pub max: f64,
    pub count: usize,
}

/// Records durations of one stage. Samples go into storage reserved up front; past capacity,
/// the oldest half is thinned (every other sample dropped) so recording never reallocates
/// beyond the reserve and memory stays bounded on endless live runs.
#[derive(Clone, Debug)]
pub struct StageTimer {
    samples_ms: Vec<f32>,
    total: usize,
    max_ms: f64,
}

impl StageTimer {
    pub fn with_capacity(n: usize) -> Self {
        StageTimer {
            samples_ms: Vec::with_capacity(n.max(2)),
            total: 0,
            max_ms: 0.0,
        }
    }

    pub fn record(&mut self, d: std::time::Duration) {
        self.record_ms(d.as_secs_f64() * 1e3);
    }

    pub fn record_ms(&mut self, ms: f64) {
        if self.samples_ms.len() == self.samples_ms.capacity() {
            let mut k = 0;
            for i in (0..self.samples_ms.len()).step_by(2) {
                self.samples_ms[k] = self.samples_ms[i];
                k += 1;
            }
            self.samples_ms.truncate(k);
        }
        self.samples_ms.push(ms as f32);
        self.total += 1;
        self.max_ms = self.max_ms.max(ms);
    }

    /// Samples kept before thinning starts.
    pub fn capacity(&self) -> usize {
        self.samples_ms.capacity()
    }

    /// Adds another timer's samples (another worker's), its count and its max. Percentiles
    /// weigh the kept samples: exact while neither timer has thinned.
    pub fn absorb(&mut self, other: &StageTimer) {
        for &ms in &other.samples_ms {
            self.record_ms(ms as f64);
        }
        // `record_ms` counted the kept samples; the other timer may have thinned more.
        self.total += other.total - other.samples_ms.len();
        self.max_ms = self.max_ms.max(other.max_ms);
    }

    pub fn count(&self) -> usize {
        self.total
    }

    /// The kept samples (every one until the capacity is reached, then evenly thinned).
    pub fn samples_ms(&self) -> &[f32] {
        &self.samples_ms
    }

    /// Nearest-rank percentiles over the kept samples; max over all.
    pub fn percentiles(&self) -> Percentiles {
        if self.samples_ms.is_empty() {
            return Percentiles::default();
        }
        let mut s = self.samples_ms.clone();
        s.sort_by(|a, b| a.total_cmp(b));
        let at = |p: f64| {
            let rank = ((p / 100.0) * s.len() as f64).ceil() as usize;
            s[rank.clamp(1, s.len()) - 1] as f64
        };
        Percentiles {
            p50: at(50.0),
            p90: at(90.0),
            p99: at(99.0),
            max: self.max_ms,
            count: self.total,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_of_uniform_samples() {
        let mut t = StageTimer::with_capacity(1000);
        for i in 1..=100 {
            t.record_ms(i as f64);
        }
        let p = t.percentiles();
        assert_eq!(
            (p.p50, p.p90, p.p99, p.max, p.count),
            (50.0, 90.0, 99.0, 100.0, 100)
        );
    }

    #[test]
    fn absorbing_another_timer_counts_its_samples_and_max() {
        let (mut a, mut b) = (
            StageTimer::with_capacity(100),
            StageTimer::with_capacity(50),
        );
        for i in 1..=50 {
            a.record_ms(i as f64);
        }
        for i in 51..=100 {
            b.record_ms(i as f64);
        }
        a.absorb(&b);
        let p = a.percentiles();
        assert_eq!((p.count, p.max), (100, 100.0));
        assert_eq!(p.p50, 50.0);
    }

    #[test]
    fn storage_is_bounded() {
        let mut t = StageTimer::with_capacity(64);
        let cap = t.samples_ms.capacity();
        for i in 0..10_000 {
            t.record_ms(i as f64);
        }
        assert_eq!(t.samples_ms.capacity(), cap);
        assert_eq!(t.count(), 10_000);
        assert_eq!(t.percentiles().max, 9999.0);
    }
}
