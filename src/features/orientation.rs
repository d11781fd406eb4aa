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

/// Angle in degrees [0, 360) of the vector from the keypoint to the patch's intensity centroid.
#[inline]
pub fn ic_angle(img: &PaddedImage, x: isize, y: isize, umax: &[isize; 16]) -> f32 {
    let mut m01: i64 = 0;
    let mut m10: i64 = 0;
    let c = img.idx(x, y) as isize;
    let st = img.stride as isize;
    let d = &img.data;
    // Centre row.
    for u in -HALF_PATCH..=HALF_PATCH {
        m10 += u as i64 * d[(c + u) as usize] as i64;
    }
    for v in 1..=HALF_PATCH {
        let mut vsum: i64 = 0;
        let w = umax[v as usize];
        for u in -w..=w {
            let below = d[(c + v * st + u) as usize] as i64;
            let above = d[(c - v * st + u) as usize] as i64;
            vsum += below - above;
            m10 += u as i64 * (below + above);
        }
        m01 += v as i64 * vsum;
    }
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
        let u = circle_umax();
        let a = ic_angle(&img, 32, 32, &u);
        assert!(!(1.0..=359.0).contains(&a), "{a}");
        let down: Vec<u8> = (0..64 * 64).map(|i| (i / 64 * 3) as u8).collect();
        img.copy_from(&down);
        assert!((ic_angle(&img, 32, 32, &u) - 90.0).abs() < 1.0);
    }

    #[test]
    fn umax_is_a_circle() {
        let u = circle_umax();
        assert_eq!(u[0], 15);
        assert_eq!(u[15], 0);
        assert!(u.windows(2).all(|w| w[0] >= w[1]));
    }
}
