//! Zhang's closed-form initialisation (Z. Zhang, "A flexible new technique for camera
//! calibration", PAMI 2000): one homography per view, intrinsics from the image of the
//! absolute conic, extrinsics from each homography, and radial distortion k1, k2 by linear
//! least squares.

use nalgebra::{DMatrix, Matrix3, Rotation3, Vector2, Vector3};

use crate::geometry::Se3;

/// Normalised-DLT homography mapping board points (X, Y) to pixels.
pub fn homography(board: &[Vector2<f64>], image: &[Vector2<f64>]) -> Option<Matrix3<f64>> {
    if board.len() < 4 || board.len() != image.len() {
        return None;
    }
    let (tb, ti) = (normaliser(board), normaliser(image));
    let n = board.len();
    let mut a = DMatrix::<f64>::zeros(2 * n, 9);
    for k in 0..n {
        let p = tb * Vector3::new(board[k].x, board[k].y, 1.0);
        let q = ti * Vector3::new(image[k].x, image[k].y, 1.0);
        let (x, y, u, v) = (p.x / p.z, p.y / p.z, q.x / q.z, q.y / q.z);
        let r = [x, y, 1.0, 0.0, 0.0, 0.0, -u * x, -u * y, -u];
        let s = [0.0, 0.0, 0.0, x, y, 1.0, -v * x, -v * y, -v];
        for c in 0..9 {
            a[(2 * k, c)] = r[c];
            a[(2 * k + 1, c)] = s[c];
        }
    }
    let h = smallest_right_singular_vector(&a)?;
    let hn = Matrix3::from_row_slice(h.as_slice());
    let h = ti.try_inverse()? * hn * tb;
    let scale = h[(2, 2)];
    (scale.abs() > 1e-12).then(|| h / scale)
}

/// Hartley normalisation: centroid to the origin, mean distance sqrt(2).
fn normaliser(pts: &[Vector2<f64>]) -> Matrix3<f64> {
    let c = pts.iter().fold(Vector2::zeros(), |a, p| a + p) / pts.len() as f64;
    let d = pts.iter().map(|p| (p - c).norm()).sum::<f64>() / pts.len() as f64;
    let s = if d > 1e-12 {
        std::f64::consts::SQRT_2 / d
    } else {
        1.0
    };
    Matrix3::new(s, 0.0, -s * c.x, 0.0, s, -s * c.y, 0.0, 0.0, 1.0)
}

fn smallest_right_singular_vector(a: &DMatrix<f64>) -> Option<nalgebra::DVector<f64>> {
    // Eigenvector of A^T A with the smallest eigenvalue (A is tall; the normal matrix is small).
    let ata = a.transpose() * a;
    let eig = nalgebra::SymmetricEigen::new(ata);
    let (i, _) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .min_by(|x, y| x.1.total_cmp(y.1))?;
    Some(eig.eigenvectors.column(i).into_owned())
}

/// Intrinsics (fx, fy, cx, cy) from at least three homographies, zero skew.
pub fn intrinsics(hs: &[Matrix3<f64>]) -> Option<(f64, f64, f64, f64)> {
    if hs.len() < 3 {
        return None;
    }
    let v = |h: &Matrix3<f64>, i: usize, j: usize| {
        let (hi, hj) = (h.column(i), h.column(j));
        [
            hi[0] * hj[0],
            hi[0] * hj[1] + hi[1] * hj[0],
            hi[1] * hj[1],
            hi[2] * hj[0] + hi[0] * hj[2],
            hi[2] * hj[1] + hi[1] * hj[2],
            hi[2] * hj[2],
        ]
    };
    // Zero skew is one more equation: B12 = 0.
    let mut a = DMatrix::<f64>::zeros(2 * hs.len() + 1, 6);
    for (k, h) in hs.iter().enumerate() {
        let (v12, v11, v22) = (v(h, 0, 1), v(h, 0, 0), v(h, 1, 1));
        for c in 0..6 {
            a[(2 * k, c)] = v12[c];
            a[(2 * k + 1, c)] = v11[c] - v22[c];
        }
    }
    a[(2 * hs.len(), 1)] = 1.0;
    let mut b = smallest_right_singular_vector(&a)?;
    if b[0] < 0.0 {
        b = -b;
    }
    let (b11, b12, b22, b13, b23, b33) = (b[0], b[1], b[2], b[3], b[4], b[5]);
    let den = b11 * b22 - b12 * b12;
    if den.abs() < 1e-300 || b11 <= 0.0 {
        return None;
    }
    let v0 = (b12 * b13 - b11 * b23) / den;
    let lambda = b33 - (b13 * b13 + v0 * (b12 * b13 - b11 * b23)) / b11;
    let alpha2 = lambda / b11;
    let beta2 = lambda * b11 / den;
    if alpha2 <= 0.0 || beta2 <= 0.0 {
        return None;
    }
    let (alpha, beta) = (alpha2.sqrt(), beta2.sqrt());
    let u0 = -b13 * alpha2 / lambda;
    let r = (alpha, beta, u0, v0);
    (r.0.is_finite() && r.1.is_finite() && r.2.is_finite() && r.3.is_finite()).then_some(r)
}

/// Camera-from-board pose from a homography and K, with the board in front of the camera.
pub fn pose(h: &Matrix3<f64>, k: &Matrix3<f64>) -> Option<Se3> {
    let kinv = k.try_inverse()?;
    let (h1, h2, h3) = (kinv * h.column(0), kinv * h.column(1), kinv * h.column(2));
    let mut lambda = 1.0 / h1.norm();
    if (lambda * h3).z < 0.0 {
        lambda = -lambda;
    }
    let r1 = h1 * lambda;
    let r2 = h2 * lambda;
    let r3 = r1.cross(&r2);
    let t = h3 * lambda;
    // Nearest rotation (SVD).
    let m = Matrix3::from_columns(&[r1, r2, r3]);
    let svd = m.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut r = u * vt;
    if r.determinant() < 0.0 {
        r = -r;
    }
    let rot = Rotation3::from_matrix_unchecked(r);
    Some(Se3::from_parts(
        nalgebra::Translation3::from(t),
        nalgebra::UnitQuaternion::from_rotation_matrix(&rot),
    ))
}

/// Radial k1, k2 by linear least squares given intrinsics and poses (Zhang, section 3.3).
pub fn radial_distortion(
    views: &[(Se3, Vec<Vector2<f64>>)],
    board: &[Vector3<f64>],
    (fx, fy, cx, cy): (f64, f64, f64, f64),
) -> (f64, f64) {
    let mut ata = nalgebra::Matrix2::zeros();
    let mut atb = Vector2::zeros();
    for (pose, obs) in views {
        for (p, o) in board.iter().zip(obs) {
            let c = pose * nalgebra::Point3::from(*p);
            if c.z <= 0.0 {
                continue;
            }
            let (x, y) = (c.x / c.z, c.y / c.z);
            let r2 = x * x + y * y;
            let (u, v) = (fx * x + cx, fy * y + cy);
            for (row, res) in [
                (Vector2::new((u - cx) * r2, (u - cx) * r2 * r2), o.x - u),
                (Vector2::new((v - cy) * r2, (v - cy) * r2 * r2), o.y - v),
            ] {
                ata += row * row.transpose();
                atb += row * res;
            }
        }
    }
    match ata.try_inverse() {
        Some(inv) => {
            let k = inv * atb;
            (k.x, k.y)
        }
        None => (0.0, 0.0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, UnitQuaternion};

    #[test]
    fn recovers_intrinsics_and_poses_from_exact_homographies() {
        let k = Matrix3::new(520.0, 0.0, 322.0, 0.0, 515.0, 241.0, 0.0, 0.0, 1.0);
        let board: Vec<Vector2<f64>> = (0..6)
            .flat_map(|j| (0..9).map(move |i| Vector2::new(i as f64 * 0.03, j as f64 * 0.03)))
            .collect();
        let poses = [
            (0.2, -0.1, 0.05, 0.6),
            (-0.3, 0.2, -0.1, 0.7),
            (0.1, 0.35, 0.2, 0.5),
            (-0.2, -0.3, 0.0, 0.8),
        ];
        let mut hs = Vec::new();
        let mut truth = Vec::new();
        for (ax, ay, az, d) in poses {
            let pose = Se3::from_parts(
                nalgebra::Translation3::new(-0.12, -0.075, d),
                UnitQuaternion::from_euler_angles(ax, ay, az),
            );
            let img: Vec<Vector2<f64>> = board
                .iter()
                .map(|b| {
                    let c = pose * Point3::new(b.x, b.y, 0.0);
                    let p = k * c.coords;
                    Vector2::new(p.x / p.z, p.y / p.z)
                })
                .collect();
            hs.push(homography(&board, &img).unwrap());
            truth.push(pose);
        }
        let (fx, fy, cx, cy) = intrinsics(&hs).unwrap();
        assert!(
            (fx - 520.0).abs() < 1e-4 && (fy - 515.0).abs() < 1e-4,
            "{fx} {fy}"
        );
        assert!(
            (cx - 322.0).abs() < 1e-4 && (cy - 241.0).abs() < 1e-4,
            "{cx} {cy}"
        );
        for (h, t) in hs.iter().zip(&truth) {
            let p = pose(h, &k).unwrap();
            assert!((p.translation.vector - t.translation.vector).norm() < 1e-6);
            assert!(p.rotation.angle_to(&t.rotation) < 1e-6);
        }
    }
}
