//! Procedural colour textures: value noise plus many sharp-edged shapes, so surfaces carry
//! corners for ORB and gradients for semi-dense mapping, without repeating (a repeated
//! texture would fake loop closures).

/// Deterministic 64-bit mixer (SplitMix64).
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A small deterministic generator for scene construction.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(mix64(seed))
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        mix64(self.0)
    }
    /// Uniform in [0, 1).
    pub fn f(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.f()
    }
}

/// An RGB texture sampled bilinearly with clamping at the borders.
pub struct Texture {
    pub width: usize,
    pub height: usize,
    /// Linear RGB in [0, 255] as f32, row-major.
    pub texels: Vec<[f32; 3]>,
}

impl Texture {
    /// Bilinear sample at texture coordinates (s, t) in [0, 1].
    #[inline]
    pub fn sample(&self, s: f64, t: f64) -> [f32; 3] {
        let x = (s * self.width as f64 - 0.5).clamp(0.0, (self.width - 1) as f64);
        let y = (t * self.height as f64 - 0.5).clamp(0.0, (self.height - 1) as f64);
        let (x0, y0) = (x as usize, y as usize);
        let (x1, y1) = ((x0 + 1).min(self.width - 1), (y0 + 1).min(self.height - 1));
        let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let p = |xx: usize, yy: usize| self.texels[yy * self.width + xx];
        let (a, b, c, d) = (p(x0, y0), p(x1, y0), p(x0, y1), p(x1, y1));
        let mut o = [0.0; 3];
        for k in 0..3 {
            let top = a[k] + (b[k] - a[k]) * fx;
            let bot = c[k] + (d[k] - c[k]) * fx;
            o[k] = top + (bot - top) * fy;
        }
        o
    }

    /// A procedural texture of `width` x `height` texels.
    ///
    /// `density` is shapes per 1000 texels²; `contrast` in [0, 1] scales the shapes' colour
    /// difference from the base (low for a weakly textured floor).
    pub fn generate(
        width: usize,
        height: usize,
        seed: u64,
        density: f64,
        contrast: f64,
    ) -> Texture {
        let mut rng = Rng::new(seed);
        let base = [
            rng.range(70.0, 190.0),
            rng.range(70.0, 190.0),
            rng.range(70.0, 190.0),
        ];
        let mut texels = vec![[0f32; 3]; width * height];
        // Two octaves of value noise for low-frequency shading variation.
        let noise_seed = rng.next_u64();
        for y in 0..height {
            for x in 0..width {
                let n = 0.6 * value_noise(x as f64 / 37.0, y as f64 / 37.0, noise_seed)
                    + 0.4 * value_noise(x as f64 / 9.0, y as f64 / 9.0, noise_seed ^ 0xABCD);
                let v = (n - 0.5) * 50.0;
                texels[y * width + x] = [
                    (base[0] + v) as f32,
                    (base[1] + v) as f32,
                    (base[2] + v) as f32,
                ];
            }
        }
        let shapes = ((width * height) as f64 / 1000.0 * density) as usize;
        for _ in 0..shapes {
            let col = [
                lerp(base[0], rng.range(0.0, 255.0), contrast),
                lerp(base[1], rng.range(0.0, 255.0), contrast),
                lerp(base[2], rng.range(0.0, 255.0), contrast),
            ];
            let (cx, cy) = (rng.range(0.0, width as f64), rng.range(0.0, height as f64));
            let size = 3.0 + 40.0 * rng.f().powi(2);
            match rng.next_u64() % 4 {
                0 | 1 => {
                    let (hw, hh) = (size * rng.range(0.3, 1.0), size * rng.range(0.3, 1.0));
                    let ang = rng.range(0.0, std::f64::consts::PI);
                    fill(&mut texels, width, height, cx, cy, size, col, |dx, dy| {
                        let (c, s) = (ang.cos(), ang.sin());
                        let (u, v) = (c * dx + s * dy, -s * dx + c * dy);
                        u.abs() <= hw && v.abs() <= hh
                    });
                }
                2 => {
                    let r = size * 0.6;
                    fill(&mut texels, width, height, cx, cy, size, col, |dx, dy| {
                        dx * dx + dy * dy <= r * r
                    });
                }
                _ => {
                    // Triangle.
                    let a = [rng.range(-size, size), rng.range(-size, size)];
                    let b = [rng.range(-size, size), rng.range(-size, size)];
                    let c = [rng.range(-size, size), rng.range(-size, size)];
                    fill(&mut texels, width, height, cx, cy, size, col, |dx, dy| {
                        let e = |p: [f64; 2], q: [f64; 2]| {
                            (q[0] - p[0]) * (dy - p[1]) - (q[1] - p[1]) * (dx - p[0])
                        };
                        let (d1, d2, d3) = (e(a, b), e(b, c), e(c, a));
                        (d1 >= 0.0 && d2 >= 0.0 && d3 >= 0.0)
                            || (d1 <= 0.0 && d2 <= 0.0 && d3 <= 0.0)
                    });
                }
            }
        }
        for t in &mut texels {
            for c in t.iter_mut() {
                *c = c.clamp(0.0, 255.0);
            }
        }
        Texture {
            width,
            height,
            texels,
        }
    }
}

/// Repetitive surface patterns (`Scenario::Repetitive`): what makes epipolar matching
/// ambiguous.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pattern {
    /// Fine value noise (a few texels per feature) on a mid grey.
    Noise,
    /// Parallel stripes, period 10 texels, at a random angle.
    Stripes,
    /// Square tiles of 24 texels with dark grout, each a slightly different shade.
    Tiles,
    /// Rows of random 5 x 7 glyphs (printed text seen from afar).
    Text,
}

impl Pattern {
    pub const ALL: [Pattern; 4] = [
        Pattern::Noise,
        Pattern::Stripes,
        Pattern::Tiles,
        Pattern::Text,
    ];
}

impl Texture {
    /// A `width` x `height` texture of `pattern`.
    pub fn pattern(width: usize, height: usize, seed: u64, pattern: Pattern) -> Texture {
        let mut rng = Rng::new(seed);
        let base = [
            rng.range(90.0, 170.0),
            rng.range(90.0, 170.0),
            rng.range(90.0, 170.0),
        ];
        let angle = rng.range(0.0, std::f64::consts::PI);
        let (ca, sa) = (angle.cos(), angle.sin());
        let glyphs: Vec<u64> = (0..16).map(|_| rng.next_u64()).collect();
        let tile_shade: Vec<f64> = (0..64).map(|_| rng.range(-25.0, 25.0)).collect();
        let noise_seed = rng.next_u64();
        let mut texels = vec![[0f32; 3]; width * height];
        for y in 0..height {
            for x in 0..width {
                let v = match pattern {
                    Pattern::Noise => {
                        let n = 0.7 * value_noise(x as f64 / 2.5, y as f64 / 2.5, noise_seed)
                            + 0.3 * value_noise(x as f64 / 6.0, y as f64 / 6.0, noise_seed ^ 7);
                        (n - 0.5) * 160.0
                    }
                    Pattern::Stripes => {
                        let t = (ca * x as f64 + sa * y as f64) / 10.0;
                        if t.rem_euclid(1.0) < 0.5 {
                            45.0
                        } else {
                            -45.0
                        }
                    }
                    Pattern::Tiles => {
                        let (tx, ty) = (x % 24, y % 24);
                        if tx < 2 || ty < 2 {
                            -70.0
                        } else {
                            tile_shade[(x / 24 * 7 + y / 24 * 3) % tile_shade.len()]
                        }
                    }
                    Pattern::Text => {
                        // Cells of 7 x 10 texels: a 5 x 7 glyph and spacing, lines of 12 px.
                        let (cx, cy) = (x / 7, y / 12);
                        let (gx, gy) = (x % 7, y % 12);
                        let glyph = glyphs[(mix64((cx as u64) << 20 ^ cy as u64) % 16) as usize];
                        let on = gx < 5 && gy < 7 && (glyph >> (gy * 5 + gx)) & 1 == 1;
                        if on {
                            -80.0
                        } else {
                            30.0
                        }
                    }
                };
                texels[y * width + x] = [
                    (base[0] + v).clamp(0.0, 255.0) as f32,
                    (base[1] + v).clamp(0.0, 255.0) as f32,
                    (base[2] + v).clamp(0.0, 255.0) as f32,
                ];
            }
        }
        Texture {
            width,
            height,
            texels,
        }
    }
}

fn lerp(a: f64, b: f64, t: f64) -> f64 {
    a + (b - a) * t
}

#[allow(clippy::too_many_arguments)]
fn fill(
    texels: &mut [[f32; 3]],
    w: usize,
    h: usize,
    cx: f64,
    cy: f64,
    r: f64,
    col: [f64; 3],
    inside: impl Fn(f64, f64) -> bool,
) {
    let x0 = (cx - r).floor().max(0.0) as usize;
    let x1 = ((cx + r).ceil() as usize).min(w);
    let y0 = (cy - r).floor().max(0.0) as usize;
    let y1 = ((cy + r).ceil() as usize).min(h);
    for y in y0..y1 {
        for x in x0..x1 {
            if inside(x as f64 + 0.5 - cx, y as f64 + 0.5 - cy) {
                texels[y * w + x] = [col[0] as f32, col[1] as f32, col[2] as f32];
            }
        }
    }
}

/// Smooth value noise in [0, 1] on an integer lattice.
fn value_noise(x: f64, y: f64, seed: u64) -> f64 {
    let (xi, yi) = (x.floor() as i64, y.floor() as i64);
    let (fx, fy) = (x - xi as f64, y - yi as f64);
    let h = |i: i64, j: i64| {
        (mix64(seed ^ (i as u64).wrapping_mul(0x1656_67B1) ^ (j as u64).wrapping_mul(0x27D4_EB2F))
            >> 11) as f64
            / (1u64 << 53) as f64
    };
    let s = |t: f64| t * t * (3.0 - 2.0 * t);
    let (sx, sy) = (s(fx), s(fy));
    let top = lerp(h(xi, yi), h(xi + 1, yi), sx);
    let bot = lerp(h(xi, yi + 1), h(xi + 1, yi + 1), sx);
    lerp(top, bot, sy)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn generation_is_deterministic_and_textured() {
        let a = Texture::generate(64, 64, 7, 2.0, 0.8);
        let b = Texture::generate(64, 64, 7, 2.0, 0.8);
        assert_eq!(a.texels, b.texels);
        let c = Texture::generate(64, 64, 8, 2.0, 0.8);
        assert_ne!(a.texels, c.texels);
        let mean = a.texels.iter().map(|t| t[0] as f64).sum::<f64>() / 4096.0;
        let var = a
            .texels
            .iter()
            .map(|t| (t[0] as f64 - mean).powi(2))
            .sum::<f64>()
            / 4096.0;
        assert!(var > 100.0, "texture too flat: var {var}");
    }

    #[test]
    fn bilinear_sample_interpolates() {
        let t = Texture {
            width: 2,
            height: 1,
            texels: vec![[0.0; 3], [100.0; 3]],
        };
        assert_eq!(t.sample(0.5, 0.5)[0], 50.0);
        assert_eq!(t.sample(0.0, 0.5)[0], 0.0);
    }
}
