//! Image warps for tests and measurements: a projective warp with bilinear sampling.

use nalgebra::{Matrix3, Vector3};

/// Writes `dst(x) = src(H^-1 x)` for a `w` x `h` grey image (bilinear; 0 outside `src`).
/// `h_dst_src` maps source pixels to destination pixels. Returns false when H is singular.
pub fn warp_perspective(
    src: &[u8],
    w: usize,
    h: usize,
    h_dst_src: &Matrix3<f64>,
    dst: &mut [u8],
) -> bool {
    let Some(inv) = h_dst_src.try_inverse() else {
        return false;
    };
    for y in 0..h {
        for x in 0..w {
            let p = inv * Vector3::new(x as f64, y as f64, 1.0);
            let (sx, sy) = (p.x / p.z, p.y / p.z);
            dst[y * w + x] = if p.z > 0.0
                && sx >= 0.0
                && sy >= 0.0
                && sx <= (w - 1) as f64
                && sy <= (h - 1) as f64
            {
                let (x0, y0) = (sx.floor() as usize, sy.floor() as usize);
                let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
                let (fx, fy) = (sx - x0 as f64, sy - y0 as f64);
                let g = |xx: usize, yy: usize| src[yy * w + xx] as f64;
                let v = (1.0 - fy) * ((1.0 - fx) * g(x0, y0) + fx * g(x1, y0))
                    + fy * ((1.0 - fx) * g(x0, y1) + fx * g(x1, y1));
                v.round().clamp(0.0, 255.0) as u8
            } else {
                0
            };
        }
    }
    true
}

/// The homography rotating an image by `deg` degrees (counter-clockwise on screen, i.e. towards
/// negative y) about `(cx, cy)`.
pub fn rotation_about(cx: f64, cy: f64, deg: f64) -> Matrix3<f64> {
    let (s, c) = deg.to_radians().sin_cos();
    let t1 = Matrix3::new(1.0, 0.0, -cx, 0.0, 1.0, -cy, 0.0, 0.0, 1.0);
    let r = Matrix3::new(c, s, 0.0, -s, c, 0.0, 0.0, 0.0, 1.0);
    let t2 = Matrix3::new(1.0, 0.0, cx, 0.0, 1.0, cy, 0.0, 0.0, 1.0);
    t2 * r * t1
}

/// Applies a homography to a point.
pub fn apply_homography(h: &Matrix3<f64>, x: f64, y: f64) -> Option<(f64, f64)> {
    let p = h * Vector3::new(x, y, 1.0);
    (p.z.abs() > 1e-12).then(|| (p.x / p.z, p.y / p.z))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identity_warp_copies_and_90_degree_rotation_permutes() {
        let (w, h) = (9usize, 9usize);
        let src: Vec<u8> = (0..w * h).map(|i| i as u8).collect();
        let mut dst = vec![0; w * h];
        assert!(warp_perspective(&src, w, h, &Matrix3::identity(), &mut dst));
        assert_eq!(src, dst);
        let r = rotation_about(4.0, 4.0, 90.0);
        warp_perspective(&src, w, h, &r, &mut dst);
        // Source (8, 4) (right middle) goes to (4, 0) (top middle) under a 90-degree turn.
        let (x, y) = apply_homography(&r, 8.0, 4.0).unwrap();
        assert!((x - 4.0).abs() < 1e-9 && y.abs() < 1e-9);
        assert_eq!(dst[4], src[4 * w + 8]);
    }
}
