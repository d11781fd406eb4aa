//! A grey image with a replicated border, so window operations near the edge (FAST circle,
//! orientation patch, rotated BRIEF pattern) need no bounds checks.

/// Row-major 8-bit image of `width` x `height` inside a border of `pad` pixels on every side.
#[derive(Clone, Debug)]
pub struct PaddedImage {
    pub width: usize,
    pub height: usize,
    pub pad: usize,
    /// `width + 2 * pad`.
    pub stride: usize,
    pub data: Vec<u8>,
}

impl PaddedImage {
    /// Allocates a zeroed image.
    pub fn new(width: usize, height: usize, pad: usize) -> Self {
        let stride = width + 2 * pad;
        PaddedImage {
            width,
            height,
            pad,
            stride,
            data: vec![0; stride * (height + 2 * pad)],
        }
    }

    /// Index of interior pixel (x, y); x and y may be negative down to `-pad`.
    #[inline(always)]
    pub fn idx(&self, x: isize, y: isize) -> usize {
        ((y + self.pad as isize) as usize) * self.stride + (x + self.pad as isize) as usize
    }

    #[inline(always)]
    pub fn at(&self, x: isize, y: isize) -> u8 {
        self.data[self.idx(x, y)]
    }

    /// Interior row `y` (length `width`).
    #[inline]
    pub fn row(&self, y: usize) -> &[u8] {
        let s = (y + self.pad) * self.stride + self.pad;
        &self.data[s..s + self.width]
    }

    #[inline]
    pub fn row_mut(&mut self, y: usize) -> &mut [u8] {
        let s = (y + self.pad) * self.stride + self.pad;
        &mut self.data[s..s + self.width]
    }

    /// Copies a tightly packed `width` x `height` image into the interior and fills the border.
    pub fn copy_from(&mut self, src: &[u8]) {
        self.copy_interior_from(src);
        self.fill_border();
    }

    /// Copies a tightly packed `width` x `height` image into the interior only.
    pub fn copy_interior_from(&mut self, src: &[u8]) {
        let w = self.width;
        for y in 0..self.height {
            let s = &src[y * w..(y + 1) * w];
            self.row_mut(y).copy_from_slice(s);
        }
    }

    /// Fills the border by reflection about the edge pixel (OpenCV's BORDER_REFLECT_101), so
    /// gradients at the edge stay continuous.
    pub fn fill_border(&mut self) {
        self.fill_border_width(self.pad);
    }

    /// Fills the `k` pixels of border nearest the interior (at most the pad), by reflection;
    /// the rest of the border keeps what it held. For readers that reach only `k` pixels out.
    pub fn fill_border_width(&mut self, k: usize) {
        let (w, h, st) = (self.width, self.height, self.stride);
        let (p, pk) = (self.pad, k.min(self.pad));
        if w < 2 || h < 2 {
            return;
        }
        let reflect = |i: isize, n: usize| -> usize {
            let n = n as isize;
            let mut i = i;
            // Reflect repeatedly for pads larger than the image.
            loop {
                if i < 0 {
                    i = -i;
                } else if i >= n {
                    i = 2 * (n - 1) - i;
                } else {
                    return i as usize;
                }
            }
        };
        if w > pk {
            // Common case: each side is the mirror image of the first `pk` interior pixels.
            for y in 0..h {
                let row = &mut self.data[(y + p) * st..(y + p + 1) * st];
                let (left, rest) = row.split_at_mut(p);
                for (k, v) in left[p - pk..].iter_mut().rev().enumerate() {
                    *v = rest[k + 1];
                }
                let (inner, right) = rest.split_at_mut(w);
                for (k, v) in right[..pk].iter_mut().enumerate() {
                    *v = inner[w - 2 - k];
                }
            }
        } else {
            self.fill_side_borders_small(reflect, pk);
        }
        for k in 1..=pk {
            let top = reflect(-(k as isize), h) + p;
            let bot = reflect((h - 1 + k) as isize, h) + p;
            self.data
                .copy_within(top * st..(top + 1) * st, (p - k) * st);
            self.data
                .copy_within(bot * st..(bot + 1) * st, (p + h - 1 + k) * st);
        }
    }

    /// Side borders when the pad is wider than the image (repeated reflection).
    fn fill_side_borders_small(&mut self, reflect: impl Fn(isize, usize) -> usize, pk: usize) {
        let (w, h, p, st) = (self.width, self.height, self.pad, self.stride);
        for y in 0..h {
            let row = (y + p) * st;
            for k in 1..=pk {
                let l = reflect(-(k as isize), w);
                let r = reflect((w - 1 + k) as isize, w);
                self.data[row + p - k] = self.data[row + p + l];
                self.data[row + p + w - 1 + k] = self.data[row + p + r];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn border_reflects_without_repeating_the_edge() {
        let mut im = PaddedImage::new(4, 3, 2);
        im.copy_from(&[1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12]);
        assert_eq!(im.at(-1, 0), 2);
        assert_eq!(im.at(-2, 0), 3);
        assert_eq!(im.at(4, 0), 3);
        assert_eq!(im.at(0, -1), 5);
        assert_eq!(im.at(-1, -1), 6);
        assert_eq!(im.at(3, 3), 8);
    }

    #[test]
    fn wide_and_narrow_pads_agree_with_reflection() {
        let data: Vec<u8> = (0..12u8 * 7).collect();
        let mut wide = PaddedImage::new(12, 7, 5);
        wide.copy_from(&data);
        let mut narrow = PaddedImage::new(12, 7, 14);
        narrow.copy_from(&data);
        for y in -5..12isize {
            for x in -5..17isize {
                assert_eq!(wide.at(x, y), narrow.at(x, y), "({x}, {y})");
            }
        }
        assert_eq!(wide.at(-5, 0), 5);
        assert_eq!(wide.at(16, 0), 6);
    }
}
