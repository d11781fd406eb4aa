//! A preallocated frame buffer: 8-bit grey for the SLAM core, RGB kept for colouring clouds.

/// One timestamped image. Buffers are sized once by [`Frame::new`] and reused.
#[derive(Clone, Debug)]
pub struct Frame {
    /// Seconds, in the clock of the source (dataset timestamps or monotonic device time).
    pub timestamp: f64,
    /// Index of the frame in its source (0-based, counts skipped frames too).
    pub index: u64,
    pub width: u32,
    pub height: u32,
    /// Row-major grey image, `width * height` bytes.
    pub gray: Vec<u8>,
    /// Row-major RGB image, `width * height * 3` bytes; meaningful only when `has_color`.
    pub rgb: Vec<u8>,
    pub has_color: bool,
    /// When the frame became available to the consumer (for latency accounting).
    pub arrival: Option<std::time::Instant>,
}

impl Frame {
    /// Allocates buffers for a `width` x `height` frame (grey and colour).
    pub fn new(width: u32, height: u32) -> Self {
        let n = width as usize * height as usize;
        Frame {
            timestamp: 0.0,
            index: 0,
            width,
            height,
            gray: vec![0; n],
            rgb: vec![0; n * 3],
            has_color: false,
            arrival: None,
        }
    }

    /// Number of pixels.
    pub fn len(&self) -> usize {
        self.width as usize * self.height as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Grey value at (x, y); no bounds check beyond the slice's.
    #[inline]
    pub fn gray_at(&self, x: u32, y: u32) -> u8 {
        self.gray[y as usize * self.width as usize + x as usize]
    }

    /// Resizes the buffers when a source changes size; a no-op in steady state.
    pub fn ensure_size(&mut self, width: u32, height: u32) {
        if self.width != width || self.height != height {
            *self = Frame::new(width, height);
        }
    }
}

/// ITU-R BT.601 luma in integer arithmetic, the conversion used for every colour input.
#[inline]
pub fn luma(r: u8, g: u8, b: u8) -> u8 {
    ((77 * r as u32 + 150 * g as u32 + 29 * b as u32 + 128) >> 8) as u8
}

/// Fills `frame.gray` from `frame.rgb`.
pub fn gray_from_rgb(frame: &mut Frame) {
    let (gray, rgb) = (&mut frame.gray, &frame.rgb);
    for (g, px) in gray.iter_mut().zip(rgb.chunks_exact(3)) {
        *g = luma(px[0], px[1], px[2]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn luma_of_pure_colours_and_grey() {
        assert_eq!(luma(255, 255, 255), 255);
        assert_eq!(luma(0, 0, 0), 0);
        assert_eq!(luma(100, 100, 100), 100);
        assert!(luma(0, 255, 0) > luma(255, 0, 0));
        assert!(luma(255, 0, 0) > luma(0, 0, 255));
    }

    #[test]
    fn ensure_size_keeps_buffers_when_same() {
        let mut f = Frame::new(4, 3);
        let p = f.gray.as_ptr();
        f.ensure_size(4, 3);
        assert_eq!(p, f.gray.as_ptr());
        f.ensure_size(5, 3);
        assert_eq!(f.gray.len(), 15);
        assert_eq!(f.rgb.len(), 45);
    }
}
