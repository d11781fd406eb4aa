//! Keypoint orientation by the intensity centroid of a circular patch (Rosin 1999, as ORB).

use crate::image::PaddedImage;

/// Patch radius (31 x 31 patch).
pub const HALF_PATCH: isize = 15;

/// Half-width of each row of the circular patch: `umax[v]` for |v| <= 15.
pub fn circle_umax() -> [isize; 16] {
    let mut u = [0isize; 16];
    let r2 = (HALF_PATCH * HALF_PATCH) as f64 + 0.5;
    for (v, o) in u.iter_mut().enumerate() {
        *o = (r2 - (v * v) as f64).sqrt().floor() as isize;
    }
    u
}

/// Per-pixel moment weights of the circular patch, 31 rows of 32 (the last column zero):
/// `x` weights are `u`, `y` weights `v`, both 0 outside the circle. Fixed-width rows let the
/// moment sums run as wide multiply-adds.
pub struct MomentWeights {
    wx: [[i16; 32]; 31],
    wy: [[i16; 32]; 31],
}

impl MomentWeights {
    pub fn new(umax: &[isize; 16]) -> Self {
        let mut wx = [[0i16; 32]; 31];
        let mut wy = [[0i16; 32]; 31];
        for v in -HALF_PATCH..=HALF_PATCH {
            let w = umax[v.unsigned_abs()];
            for u in -w..=w {
                let (r, c) = ((v + HALF_PATCH) as usize, (u + HALF_PATCH) as usize);
                wx[r][c] = u as i16;
                wy[r][c] = v as i16;
            }
        }
        MomentWeights { wx, wy }
    }
}

/// Angle in degrees [0, 360) of the vector from the keypoint to the patch's intensity centroid.
#[inline(always)]
pub fn ic_angle(img: &PaddedImage, x: isize, y: isize, weights: &MomentWeights) -> f32 {
    let st = img.stride;
    let first = img.idx(x - HALF_PATCH, y - HALF_PATCH);
    let mut m10 = [0i32; 32];
    let mut m01 = [0i32; 32];
    for r in 0..31 {
        let row = &img.data[first + r * st..first + r * st + 32];
        for (i, &p) in row.iter().enumerate() {
            m10[i] += weights.wx[r][i] as i32 * p as i32;
            m01[i] += weights.wy[r][i] as i32 * p as i32;
        }
    }
    let (m10, m01): (i32, i32) = (m10.iter().sum(), m01.iter().sum());
    let a = (m01 as f32).atan2(m10 as f32).to_degrees();
    if a < 0.0 {
        a + 360.0
    } else {
        a
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gradient_direction_sets_the_angle() {
        // Brightness increasing to the right: centroid to the right (0 deg); downward: 90 deg.
        let mut img = PaddedImage::new(64, 64, 24);
        let right: Vec<u8> = (0..64 * 64).map(|i| (i % 64 * 3) as u8).collect();
        img.copy_from(&right);
        let u = MomentWeights::new(&circle_umax());
        let a = ic_angle(&img, 32, 32, &u);
        assert!(!(1.0..=359.0).contains(&a), "{a}");
        let down: Vec<u8> = (0..64 * 64).map(|i| (i / 64 * 3) as u8).collect();
        img.copy_from(&down);
        assert!((ic_angle(&img, 32, 32, &u) - 90.0).abs() < 1.0);
    }

    #[test]
    fn moments_match_the_circular_patch_sum() {
        let mut img = PaddedImage::new(64, 64, 24);
        let mut s = 7u64;
        let data: Vec<u8> = (0..64 * 64)
            .map(|_| {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1);
                (s >> 56) as u8
            })
            .collect();
        img.copy_from(&data);
        let umax = circle_umax();
        let (mut m10, mut m01) = (0i64, 0i64);
        for v in -HALF_PATCH..=HALF_PATCH {
            let w = umax[v.unsigned_abs()];
            for u in -w..=w {
                let p = img.at(30 + u, 31 + v) as i64;
                m10 += u as i64 * p;
                m01 += v as i64 * p;
            }
        }
        let mut expect = (m01 as f32).atan2(m10 as f32).to_degrees();
        if expect < 0.0 {
            expect += 360.0;
        }
        let got = ic_angle(&img, 30, 31, &MomentWeights::new(&umax));
        assert!((got - expect).abs() < 1e-4, "{got} vs {expect}");
    }

    #[test]
    fn umax_is_a_circle() {
        let u = circle_umax();
        assert_eq!(u[0], 15);
        assert_eq!(u[15], 0);
        assert!(u.windows(2).all(|w| w[0] >= w[1]));
    }
}
