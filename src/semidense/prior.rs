//! Regional narrowing of the inverse-depth prior (not in the paper, `[semidense]
//! prior_cell_px`): the paper searches every pixel over one keyframe-wide interval [rho_0 -
//! 2 sigma, rho_0 + 2 sigma] from all its ORB map points (section III-A). On deep scenes that
//! interval spans ~100 pixels of epipolar line per neighbour. Here each cell of a grid gets the
//! inverse depths of the map points in it and its 8 neighbouring cells, widened by a relative
//! margin and intersected with the paper's interval, so the search only narrows; cells with
//! too few points keep the paper's interval.

/// Inverse-depth search ranges per grid cell, rebuilt per keyframe into reserved buffers.
#[derive(Clone, Debug)]
pub struct RegionalPrior {
    /// Cell side in pixels; 0 = off (every pixel uses the keyframe-wide interval).
    cell: usize,
    cols: usize,
    rows: usize,
    /// Per cell: smallest and largest inverse depth of its points, and their count.
    lo: Vec<f32>,
    hi: Vec<f32>,
    count: Vec<u32>,
    /// Per cell: the search range after `finish`, and whether it is narrower than `global`
    /// (enough points around it).
    ranges: Vec<(f64, f64)>,
    narrowed: Vec<bool>,
    global: (f64, f64),
}

impl RegionalPrior {
    /// Reserves the grid for `width` x `height` images with cells of `cell` pixels.
    pub fn new(width: usize, height: usize, cell: usize) -> Self {
        let (cols, rows) = if cell == 0 {
            (0, 0)
        } else {
            (width.div_ceil(cell), height.div_ceil(cell))
        };
        let n = cols * rows;
        RegionalPrior {
            cell,
            cols,
            rows,
            lo: vec![f32::INFINITY; n],
            hi: vec![0.0; n],
            count: vec![0; n],
            ranges: vec![(0.0, 0.0); n],
            narrowed: vec![false; n],
            global: (0.0, 0.0),
        }
    }

    pub fn enabled(&self) -> bool {
        self.cell > 0
    }

    /// Starts a keyframe.
    pub fn clear(&mut self) {
        self.lo.fill(f32::INFINITY);
        self.hi.fill(0.0);
        self.count.fill(0);
    }

    /// A map point seen at pixel (u, v) with inverse depth `rho`.
    pub fn add(&mut self, u: f32, v: f32, rho: f32) {
        if !(self.enabled() && u >= 0.0 && v >= 0.0 && rho > 0.0 && rho.is_finite()) {
            return;
        }
        let (cx, cy) = (u as usize / self.cell, v as usize / self.cell);
        if cx >= self.cols || cy >= self.rows {
            return;
        }
        let i = cy * self.cols + cx;
        self.lo[i] = self.lo[i].min(rho);
        self.hi[i] = self.hi[i].max(rho);
        self.count[i] += 1;
    }

    /// Turns the points into per-cell ranges: the 3 x 3 cells around each cell need at least
    /// `min_points` points; their [min, max] inverse depth is widened to [min (1 - margin),
    /// max (1 + margin)] and intersected with `global` (the paper's interval).
    pub fn finish(&mut self, global: (f64, f64), min_points: usize, margin: f64) {
        self.global = global;
        for cy in 0..self.rows {
            for cx in 0..self.cols {
                let (mut lo, mut hi, mut n) = (f32::INFINITY, 0.0f32, 0u32);
                for y in cy.saturating_sub(1)..(cy + 2).min(self.rows) {
                    for x in cx.saturating_sub(1)..(cx + 2).min(self.cols) {
                        let i = y * self.cols + x;
                        lo = lo.min(self.lo[i]);
                        hi = hi.max(self.hi[i]);
                        n += self.count[i];
                    }
                }
                let mut r = global;
                let mut narrowed = false;
                if n as usize >= min_points.max(1) {
                    let a = (lo as f64 * (1.0 - margin)).max(global.0);
                    let b = (hi as f64 * (1.0 + margin)).min(global.1);
                    if b > a {
                        r = (a, b);
                        narrowed = true;
                    }
                }
                self.ranges[cy * self.cols + cx] = r;
                self.narrowed[cy * self.cols + cx] = narrowed;
            }
        }
    }

    /// The search range of pixel (x, y).
    #[inline]
    pub fn range(&self, x: usize, y: usize) -> (f64, f64) {
        if !self.enabled() {
            return self.global;
        }
        let (cx, cy) = (
            (x / self.cell).min(self.cols - 1),
            (y / self.cell).min(self.rows - 1),
        );
        self.ranges[cy * self.cols + cx]
    }

    /// The search range of pixel (x, y) when its cell had enough points around it.
    #[inline]
    pub fn narrowed_range(&self, x: usize, y: usize) -> Option<(f64, f64)> {
        if !self.enabled() {
            return None;
        }
        let (cx, cy) = (
            (x / self.cell).min(self.cols - 1),
            (y / self.cell).min(self.rows - 1),
        );
        let i = cy * self.cols + cx;
        self.narrowed[i].then_some(self.ranges[i])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_narrow_within_the_global_interval_and_fall_back_without_points() {
        let mut p = RegionalPrior::new(100, 60, 20);
        p.clear();
        // A near plane on the left (rho ~ 1), a far one on the right (rho ~ 0.25).
        for k in 0..10 {
            p.add(5.0 + k as f32, 10.0, 1.0 + 0.01 * k as f32);
            p.add(85.0 + k as f32 * 0.5, 10.0, 0.25);
        }
        p.finish((0.1, 2.0), 5, 0.2);
        let (a, b) = p.range(10, 10);
        assert!(
            (a - 0.8).abs() < 1e-6 && (b - 1.09 * 1.2).abs() < 1e-5,
            "{a} {b}"
        );
        let (a, b) = p.range(90, 10);
        assert!((a - 0.2).abs() < 1e-6 && (b - 0.3).abs() < 1e-6, "{a} {b}");
        assert_eq!(p.narrowed_range(90, 10), Some(p.range(90, 10)));
        // The middle cell (x 40-59) has no points around it: the global interval.
        assert_eq!(p.range(50, 50), (0.1, 2.0));
        assert_eq!(p.narrowed_range(50, 50), None);
        // Never wider than the global interval.
        p.finish((0.9, 1.0), 5, 0.2);
        assert_eq!(p.range(10, 10), (0.9, 1.0));
        // Off: always the global interval.
        let mut off = RegionalPrior::new(100, 60, 0);
        off.add(5.0, 5.0, 1.0);
        off.finish((0.1, 2.0), 1, 0.2);
        assert_eq!(off.range(5, 5), (0.1, 2.0));
        assert_eq!(off.narrowed_range(5, 5), None);
    }
}
