//! Rotation-consistency check: matches between two images must agree on the in-plane rotation.
//! A histogram of angle differences (30 bins); only matches in the three most populated bins are
//! kept (bins under 10% of the top bin are dropped too, as ORB-SLAM).

/// Histogram over matches; buffers reused between calls.
pub struct RotationHistogram {
    bins: Vec<Vec<u32>>,
}

pub const HISTO_LENGTH: usize = 30;

impl Default for RotationHistogram {
    fn default() -> Self {
        Self::with_capacity(64)
    }
}

impl RotationHistogram {
    pub fn with_capacity(per_bin: usize) -> Self {
        RotationHistogram {
            bins: (0..HISTO_LENGTH)
                .map(|_| Vec::with_capacity(per_bin))
                .collect(),
        }
    }

    pub fn clear(&mut self) {
        for b in &mut self.bins {
            b.clear();
        }
    }

    /// Adds match `id` whose keypoint angles (degrees) differ by `a1 - a2`.
    pub fn add(&mut self, a1: f32, a2: f32, id: u32) {
        let mut rot = a1 - a2;
        if rot < 0.0 {
            rot += 360.0;
        }
        let bin = ((rot * HISTO_LENGTH as f32 / 360.0).round() as usize) % HISTO_LENGTH;
        self.bins[bin].push(id);
    }

    /// Calls `reject` for every match outside the three dominant bins.
    pub fn for_each_rejected(&self, mut reject: impl FnMut(u32)) {
        let mut top = [(0usize, usize::MAX); 3];
        for (i, b) in self.bins.iter().enumerate() {
            let n = b.len();
            if n > top[0].0 {
                top = [(n, i), top[0], top[1]];
            } else if n > top[1].0 {
                top = [top[0], (n, i), top[1]];
            } else if n > top[2].0 {
                top[2] = (n, i);
            }
        }
        let max = top[0].0;
        let keep = |i: usize| {
            top.iter()
                .any(|&(n, b)| b == i && (n as f32) >= 0.1 * max as f32)
        };
        for (i, b) in self.bins.iter().enumerate() {
            if !keep(i) {
                b.iter().for_each(|&id| reject(id));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_dominant_rotation_and_rejects_strays() {
        let mut h = RotationHistogram::default();
        for i in 0..50 {
            h.add(100.0 + (i % 3) as f32, 70.0, i); // ~30 deg
        }
        h.add(10.0, 200.0, 900); // stray
        let mut rejected = Vec::new();
        h.for_each_rejected(|id| rejected.push(id));
        assert_eq!(rejected, vec![900]);
    }
}
