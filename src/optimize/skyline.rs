//! Symmetric positive-definite solver for the reduced camera system and the pose graph: dense
//! Cholesky (packed lower triangle) for small systems, and for large ones reverse Cuthill-McKee
//! ordering of the block graph followed by an in-place skyline (profile) Cholesky. Keyframe
//! graphs are chains with local covisibility (loop edges stay near the band after RCM), so the
//! profile stays narrow.
//! Buffers are reused between solves of the same size.

/// Up to this many blocks the system is factorised densely.
pub const DENSE_MAX_BLOCKS: usize = 16;

/// Dot product with four independent accumulators, so the reduction vectorises (a single
/// floating-point accumulator forces sequential adds).
#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [0.0f64; 4];
    let chunks = n / 4;
    for k in 0..chunks {
        for l in 0..4 {
            acc[l] += a[4 * k + l] * b[4 * k + l];
        }
    }
    let mut s = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for k in chunks * 4..n {
        s += a[k] * b[k];
    }
    s
}

/// The unordered block pair (i, j) as one integer key.
#[inline]
fn pair_key(i: usize, j: usize) -> u64 {
    ((i.min(j) as u64) << 32) | i.max(j) as u64
}

/// A multiply-xorshift hash of a `u64` key: BA looks a slot up for every observation pair of
/// every point, and SipHash (std's default, built against hostile keys) took 9% of a run's
/// CPU on posters. The keys are block indices, so no denial-of-service concern applies.
#[derive(Default)]
struct PairHasher(u64);

impl std::hash::Hasher for PairHasher {
    fn finish(&self) -> u64 {
        let x = self.0.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        x ^ (x >> 29)
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0.rotate_left(8) ^ b as u64).wrapping_mul(0x100_0000_01B3);
        }
    }
    fn write_u64(&mut self, v: u64) {
        self.0 = v;
    }
}

/// A symmetric matrix of `n` blocks of size `b` with a fixed block structure: set the structure
/// once (`set_structure`), then per solve clear, accumulate into slots, and solve.
pub struct BlockSystem {
    b: usize,
    n: usize,
    /// Stored blocks (i <= j), diagonal blocks first (slot i is block (i, i)).
    pairs: Vec<(u32, u32)>,
    slot_of: std::collections::HashMap<u64, u32, std::hash::BuildHasherDefault<PairHasher>>,
    /// `b*b` row-major values per slot.
    vals: Vec<f64>,
    pub rhs: Vec<f64>,
    perm: Vec<usize>,
    inv_perm: Vec<usize>,
    first: Vec<usize>,
    start: Vec<usize>,
    values: Vec<f64>,
    y: Vec<f64>,
}

impl BlockSystem {
    pub fn new(block: usize) -> Self {
        BlockSystem {
            b: block,
            n: 0,
            pairs: Vec::new(),
            slot_of: Default::default(),
            vals: Vec::new(),
            rhs: Vec::new(),
            perm: Vec::new(),
            inv_perm: Vec::new(),
            first: Vec::new(),
            start: Vec::new(),
            values: Vec::new(),
            y: Vec::new(),
        }
    }

    pub fn dim(&self) -> usize {
        self.n * self.b
    }

    /// Declares `n` blocks and the off-diagonal blocks `(i, j)` that may be non-zero; computes
    /// the ordering and the skyline profile.
    pub fn set_structure(
        &mut self,
        n: usize,
        off_diagonal: impl IntoIterator<Item = (usize, usize)>,
    ) {
        let b = self.b;
        self.n = n;
        self.pairs.clear();
        self.slot_of.clear();
        for i in 0..n {
            self.slot_of.insert(pair_key(i, i), i as u32);
            self.pairs.push((i as u32, i as u32));
        }
        let mut adj: Vec<Vec<u32>> = vec![Vec::new(); n];
        for (i, j) in off_diagonal {
            if i == j {
                continue;
            }
            let key = (i.min(j) as u32, i.max(j) as u32);
            if let std::collections::hash_map::Entry::Vacant(e) = self.slot_of.entry(pair_key(i, j))
            {
                e.insert(self.pairs.len() as u32);
                self.pairs.push(key);
                adj[i].push(j as u32);
                adj[j].push(i as u32);
            }
        }
        self.vals.clear();
        self.vals.resize(self.pairs.len() * b * b, 0.0);
        self.rhs.clear();
        self.rhs.resize(n * b, 0.0);
        // Reverse Cuthill-McKee from minimum-degree starts, per connected component.
        self.perm.clear();
        let mut seen = vec![false; n];
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by_key(|&i| adj[i].len());
        let mut queue = std::collections::VecDeque::new();
        for &s0 in &order {
            if seen[s0] {
                continue;
            }
            seen[s0] = true;
            queue.push_back(s0);
            while let Some(v) = queue.pop_front() {
                self.perm.push(v);
                let mut nb: Vec<usize> = adj[v]
                    .iter()
                    .map(|&u| u as usize)
                    .filter(|&u| !seen[u])
                    .collect();
                nb.sort_by_key(|&u| adj[u].len());
                for u in nb {
                    seen[u] = true;
                    queue.push_back(u);
                }
            }
        }
        self.perm.reverse();
        self.inv_perm.resize(n, 0);
        for (new, &old) in self.perm.iter().enumerate() {
            self.inv_perm[old] = new;
        }
        // Profile: first non-zero column of each scalar row (permuted order). Small systems
        // (local BA windows) take the full profile: a dense packed Cholesky, no ordering gain to
        // be had; large ones keep the RCM skyline.
        let dim = n * b;
        self.first.clear();
        self.first.resize(dim, usize::MAX);
        if n <= DENSE_MAX_BLOCKS {
            self.first.fill(0);
        }
        for (i, nb) in adj.iter().enumerate() {
            let pi = self.inv_perm[i];
            let lo = nb
                .iter()
                .map(|&j| self.inv_perm[j as usize])
                .fold(pi, usize::min);
            for r in 0..b {
                self.first[pi * b + r] = self.first[pi * b + r].min(lo * b);
            }
        }
        self.start.clear();
        let mut total = 0;
        for r in 0..dim {
            self.start.push(total);
            total += r - self.first[r] + 1;
        }
        self.values.clear();
        self.values.resize(total, 0.0);
        self.y.resize(dim, 0.0);
    }

    /// Slot of block (i, j) (either order), if declared.
    pub fn slot(&self, i: usize, j: usize) -> Option<usize> {
        self.slot_of.get(&pair_key(i, j)).map(|&s| s as usize)
    }

    /// Zeroes every value and the right-hand side.
    pub fn clear(&mut self) {
        self.vals.fill(0.0);
        self.rhs.fill(0.0);
    }

    /// Adds `m` (b x b row-major, the block (i, j) of the full matrix) into `slot`; for i > j
    /// pass `transpose = true` so the stored upper block receives `m^T`.
    #[inline]
    pub fn add(&mut self, slot: usize, m: &[f64], transpose: bool) {
        let b = self.b;
        let v = &mut self.vals[slot * b * b..(slot + 1) * b * b];
        if transpose {
            for r in 0..b {
                for c in 0..b {
                    v[r * b + c] += m[c * b + r];
                }
            }
        } else {
            for (x, y) in v.iter_mut().zip(m) {
                *x += y;
            }
        }
    }

    /// The `b*b` row-major values of `slot`, to accumulate into directly.
    #[inline]
    pub fn block_mut(&mut self, slot: usize) -> &mut [f64] {
        let b = self.b;
        &mut self.vals[slot * b * b..(slot + 1) * b * b]
    }

    /// Marquardt damping of the diagonal: `A_kk += lambda * A_kk + eps`.
    pub fn damp(&mut self, lambda: f64, eps: f64) {
        let b = self.b;
        for i in 0..self.n {
            let v = &mut self.vals[i * b * b..(i + 1) * b * b];
            for k in 0..b {
                v[k * b + k] += lambda * v[k * b + k] + eps;
            }
        }
    }

    /// Factorises and solves `A x = rhs` into `out` (length `dim`). False when `A` is not
    /// positive definite.
    pub fn solve(&mut self, out: &mut [f64]) -> bool {
        let (n, b) = (self.n, self.b);
        let dim = n * b;
        self.values.fill(0.0);
        for (slot, &(i, j)) in self.pairs.iter().enumerate() {
            let (i, j) = (i as usize, j as usize);
            let (pi, pj) = (self.inv_perm[i], self.inv_perm[j]);
            let m = &self.vals[slot * b * b..(slot + 1) * b * b];
            for r in 0..b {
                for c in 0..b {
                    let (gr, gc) = (pi * b + r, pj * b + c);
                    if i == j && gr < gc {
                        continue;
                    }
                    let (row, col) = if gr >= gc { (gr, gc) } else { (gc, gr) };
                    self.values[self.start[row] + col - self.first[row]] = m[r * b + c];
                }
            }
        }
        // In-place Cholesky on the profile (row-oriented).
        for i in 0..dim {
            let fi = self.first[i];
            for j in fi..=i {
                let fj = self.first[j];
                let k0 = fi.max(fj);
                let (ri, rj) = (self.start[i] + k0 - fi, self.start[j] + k0 - fj);
                let len = j - k0;
                let mut s = self.values[self.start[i] + j - fi];
                let dot = dot(&self.values[ri..ri + len], &self.values[rj..rj + len]);
                s -= dot;
                if j == i {
                    if s.is_nan() || s <= 0.0 || !s.is_finite() {
                        return false;
                    }
                    self.values[self.start[i] + i - fi] = s.sqrt();
                } else {
                    let d = self.values[self.start[j] + j - fj];
                    self.values[self.start[i] + j - fi] = s / d;
                }
            }
        }
        let y = &mut self.y;
        for i in 0..n {
            let pi = self.inv_perm[i];
            y[pi * b..(pi + 1) * b].copy_from_slice(&self.rhs[i * b..(i + 1) * b]);
        }
        for i in 0..dim {
            let fi = self.first[i];
            let row = &self.values[self.start[i]..self.start[i] + i - fi];
            let s = dot(row, &y[fi..i]);
            y[i] = (y[i] - s) / self.values[self.start[i] + i - fi];
        }
        for i in (0..dim).rev() {
            let fi = self.first[i];
            y[i] /= self.values[self.start[i] + i - fi];
            let yi = y[i];
            let row = &self.values[self.start[i]..self.start[i] + i - fi];
            for (yk, l) in y[fi..i].iter_mut().zip(row) {
                *yk -= l * yi;
            }
        }
        for i in 0..n {
            let pi = self.inv_perm[i];
            out[i * b..(i + 1) * b].copy_from_slice(&y[pi * b..(pi + 1) * b]);
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_a_random_block_tridiagonal_system_with_a_loop_edge() {
        let (n, b) = (20usize, 3usize);
        let mut sys = BlockSystem::new(b);
        let mut dense = nalgebra::DMatrix::<f64>::zeros(n * b, n * b);
        let mut s = 3u64;
        let mut rnd = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        let mut edges: Vec<(usize, usize)> = (0..n - 1).map(|i| (i, i + 1)).collect();
        edges.push((n - 1, 0));
        sys.set_structure(n, edges.iter().copied());
        sys.clear();
        for (i, j) in edges {
            let m: Vec<f64> = (0..b * b).map(|_| rnd()).collect();
            let slot = sys.slot(i, j).unwrap();
            sys.add(slot, &m, i > j);
            for r in 0..b {
                for c in 0..b {
                    dense[(i * b + r, j * b + c)] += m[r * b + c];
                    dense[(j * b + c, i * b + r)] += m[r * b + c];
                }
            }
        }
        for i in 0..n {
            let mut d = vec![0.0; b * b];
            for k in 0..b {
                d[k * b + k] = 10.0;
            }
            sys.add(i, &d, false);
            for k in 0..b {
                dense[(i * b + k, i * b + k)] += 10.0;
            }
        }
        let rhs: Vec<f64> = (0..n * b).map(|_| rnd()).collect();
        sys.rhs.copy_from_slice(&rhs);
        let mut x = vec![0.0; n * b];
        assert!(sys.solve(&mut x));
        let r = &dense * nalgebra::DVector::from_column_slice(&x)
            - nalgebra::DVector::from_column_slice(&rhs);
        assert!(r.norm() < 1e-10, "{}", r.norm());
    }

    #[test]
    fn reports_indefinite_matrices() {
        let mut sys = BlockSystem::new(1);
        sys.set_structure(2, [(0, 1)]);
        sys.clear();
        sys.add(0, &[1.0], false);
        sys.add(1, &[1.0], false);
        sys.add(sys.slot(0, 1).unwrap(), &[2.0], false);
        let mut x = vec![0.0; 2];
        assert!(!sys.solve(&mut x));
    }
}
