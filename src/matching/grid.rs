//! Keypoints bucketed into a grid of cells (64 x 48 for 640 x 480) for radius searches in
//! constant time per cell. Built by counting sort into preallocated arrays.

use crate::features::KeyPoint;

pub struct FeatureGrid {
    cols: usize,
    rows: usize,
    inv_cell_w: f32,
    inv_cell_h: f32,
    min_x: f32,
    min_y: f32,
    /// `starts[c]..starts[c + 1]` indexes `items` for cell c.
    starts: Vec<u32>,
    items: Vec<u32>,
}

impl FeatureGrid {
    /// A grid over `[min_x, max_x) x [min_y, max_y)` (undistorted image bounds).
    pub fn new(cols: usize, rows: usize, bounds: (f32, f32, f32, f32), capacity: usize) -> Self {
        let (min_x, min_y, max_x, max_y) = bounds;
        FeatureGrid {
            cols,
            rows,
            inv_cell_w: cols as f32 / (max_x - min_x).max(1e-3),
            inv_cell_h: rows as f32 / (max_y - min_y).max(1e-3),
            min_x,
            min_y,
            // Reserved, written on the first `assign`: a map reserves 500 keyframes' grids
            // (6 MB) and most are never used.
            starts: Vec::with_capacity(cols * rows + 1),
            items: Vec::with_capacity(capacity),
        }
    }

    #[inline]
    fn cell_of(&self, x: f32, y: f32) -> Option<(usize, usize)> {
        let cx = ((x - self.min_x) * self.inv_cell_w).floor();
        let cy = ((y - self.min_y) * self.inv_cell_h).floor();
        (cx >= 0.0 && cy >= 0.0 && (cx as usize) < self.cols && (cy as usize) < self.rows)
            .then_some((cx as usize, cy as usize))
    }

    /// Buckets `keypoints` by undistorted position (points outside the bounds are left out).
    pub fn assign(&mut self, keypoints: &[KeyPoint]) {
        self.starts.clear();
        self.starts.resize(self.cols * self.rows + 1, 0);
        for k in keypoints {
            if let Some((cx, cy)) = self.cell_of(k.ux, k.uy) {
                self.starts[cy * self.cols + cx + 1] += 1;
            }
        }
        for i in 1..self.starts.len() {
            self.starts[i] += self.starts[i - 1];
        }
        let total = *self.starts.last().unwrap_or(&0) as usize;
        self.items.clear();
        self.items.resize(total, 0);
        // Fill using a moving cursor per cell (reusing the start of the next cell's range).
        let mut cursor = std::mem::take(&mut self.starts);
        for (i, k) in keypoints.iter().enumerate() {
            if let Some((cx, cy)) = self.cell_of(k.ux, k.uy) {
                let c = cy * self.cols + cx;
                self.items[cursor[c] as usize] = i as u32;
                cursor[c] += 1;
            }
        }
        // Cursors now hold each cell's end = next cell's start: shift back by one.
        for i in (1..cursor.len()).rev() {
            cursor[i] = cursor[i - 1];
        }
        cursor[0] = 0;
        self.starts = cursor;
    }

    /// Indices of keypoints within `r` (square window, as ORB-SLAM) of (x, y) whose octave is in
    /// `[min_level, max_level]`, appended to `out` (cleared first).
    #[allow(clippy::too_many_arguments)]
    pub fn in_area(
        &self,
        keypoints: &[KeyPoint],
        x: f32,
        y: f32,
        r: f32,
        min_level: u8,
        max_level: u8,
        out: &mut Vec<u32>,
    ) {
        out.clear();
        if self.starts.is_empty() {
            return; // Never assigned: no keypoints.
        }
        let c0x = (((x - r - self.min_x) * self.inv_cell_w).floor().max(0.0)) as usize;
        let c0y = (((y - r - self.min_y) * self.inv_cell_h).floor().max(0.0)) as usize;
        let c1x = ((x + r - self.min_x) * self.inv_cell_w).floor();
        let c1y = ((y + r - self.min_y) * self.inv_cell_h).floor();
        if c1x < 0.0 || c1y < 0.0 {
            return;
        }
        let (c1x, c1y) = (
            (c1x as usize).min(self.cols - 1),
            (c1y as usize).min(self.rows - 1),
        );
        for cy in c0y..=c1y {
            for cx in c0x..=c1x {
                let c = cy * self.cols + cx;
                for &i in &self.items[self.starts[c] as usize..self.starts[c + 1] as usize] {
                    let k = &keypoints[i as usize];
                    if k.octave < min_level || k.octave > max_level {
                        continue;
                    }
                    if (k.ux - x).abs() <= r && (k.uy - y).abs() <= r {
                        out.push(i);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn radius_search_equals_brute_force() {
        let mut kps = Vec::new();
        let mut s = 5u64;
        for i in 0..500 {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let x = (s >> 40) as f32 % 640.0;
            let y = (s >> 20) as f32 % 480.0;
            kps.push(KeyPoint {
                ux: x,
                uy: y,
                x,
                y,
                octave: (i % 8) as u8,
                ..Default::default()
            });
        }
        let mut g = FeatureGrid::new(64, 48, (0.0, 0.0, 640.0, 480.0), 1000);
        let mut out = vec![7];
        // Before the first assignment the grid holds nothing.
        g.in_area(&kps, 100.0, 100.0, 30.0, 0, 7, &mut out);
        assert!(out.is_empty());
        g.assign(&kps);
        for (x, y, r, lo, hi) in [
            (100.0, 100.0, 30.0, 0, 7),
            (0.0, 0.0, 50.0, 2, 3),
            (639.0, 479.0, 15.0, 0, 7),
            (320.0, 240.0, 200.0, 1, 1),
        ] {
            g.in_area(&kps, x, y, r, lo, hi, &mut out);
            let mut got = out.clone();
            got.sort();
            let expect: Vec<u32> = (0..kps.len() as u32)
                .filter(|&i| {
                    let k = &kps[i as usize];
                    (k.ux - x).abs() <= r
                        && (k.uy - y).abs() <= r
                        && k.octave >= lo
                        && k.octave <= hi
                })
                .collect();
            assert_eq!(got, expect);
        }
    }
}
