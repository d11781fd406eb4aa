//! The camera path: one smooth orbit around the desk that ends where it started.

use std::f64::consts::TAU;

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};

use crate::geometry::WorldFromCamera;

/// An orbit parameterised by frame index; every term is periodic so the last frame meets the
/// first (a loop to close).
#[derive(Clone, Debug)]
pub struct OrbitPath {
    frames: usize,
}

impl OrbitPath {
    pub fn desk(frames: usize) -> Self {
        OrbitPath {
            frames: frames.max(2),
        }
    }

    /// `T_wc` of frame `i` (camera x right, y down, z forward; world z up).
    pub fn pose(&self, i: usize) -> WorldFromCamera {
        self.pose_at(i as f64)
    }

    /// `T_wc` at a fractional frame index (motion blur samples between frames).
    pub fn pose_at(&self, i: f64) -> WorldFromCamera {
        // The orbit closes after `frames` frames: frame `frames` would equal frame 0.
        let phi = TAU * i / self.frames as f64;
        // Ease in so the first frames move slowly forward (a gentle start for initialisation).
        let radius = 1.35 + 0.15 * (3.0 * phi).sin();
        let pos = Vector3::new(
            radius * phi.cos(),
            radius * phi.sin(),
            1.35 + 0.12 * (2.0 * phi).sin(),
        );
        let target = Vector3::new(
            0.12 * (2.0 * phi).cos(),
            0.10 * phi.sin(),
            0.80 + 0.05 * (3.0 * phi).cos(),
        );
        let f = (target - pos).normalize();
        let up = Vector3::z();
        let right = f.cross(&up).normalize();
        let down = f.cross(&right);
        let r = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[right, down, f]));
        let roll = Rotation3::from_axis_angle(&Vector3::z_axis(), 0.06 * (2.0 * phi).sin());
        let q = UnitQuaternion::from_rotation_matrix(&(r * roll));
        WorldFromCamera::from_parts(pos, q)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn path_is_smooth_and_closes() {
        let p = OrbitPath::desk(300);
        let end = OrbitPath::desk(300).pose(300);
        assert!((end.position() - p.pose(0).position()).norm() < 1e-9);
        for i in 0..300 {
            let (a, b) = (p.pose(i), p.pose(i + 1));
            let step = (b.position() - a.position()).norm();
            assert!(step < 0.05 && step > 0.005, "frame {i}: step {step}");
            assert!(a.0.rotation.angle_to(&b.0.rotation) < 0.05);
        }
    }

    #[test]
    fn camera_looks_at_the_desk() {
        let p = OrbitPath::desk(300);
        for i in (0..300).step_by(25) {
            let t_cw = p.pose(i).inverse();
            let c = t_cw.transform(&Vector3::new(0.0, 0.0, 0.8));
            assert!(
                c.z > 0.5 && (c.x / c.z).abs() < 0.2 && (c.y / c.z).abs() < 0.2,
                "{i}: {c:?}"
            );
        }
    }
}
