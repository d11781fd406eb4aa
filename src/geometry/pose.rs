//! Poses named by the frames they map between, so `T_cw` and `T_wc` cannot be confused.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// A rigid transform `p_a = T_ab * p_b`.
pub type Se3 = Isometry3<f64>;

/// `T_cw`: maps world points into the camera frame (what projection needs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraFromWorld(pub Se3);

/// `T_wc`: the camera's pose in the world (what trajectories report).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WorldFromCamera(pub Se3);

impl CameraFromWorld {
    pub fn identity() -> Self {
        CameraFromWorld(Se3::identity())
    }
    pub fn inverse(&self) -> WorldFromCamera {
        WorldFromCamera(self.0.inverse())
    }
    /// World point -> camera frame.
    #[inline]
    pub fn transform(&self, p_w: &Vector3<f64>) -> Vector3<f64> {
        self.0.rotation * p_w + self.0.translation.vector
    }
    /// Camera centre in world coordinates.
    pub fn center(&self) -> Vector3<f64> {
        self.inverse().0.translation.vector
    }
}

impl WorldFromCamera {
    pub fn identity() -> Self {
        WorldFromCamera(Se3::identity())
    }
    pub fn from_parts(t: Vector3<f64>, q: UnitQuaternion<f64>) -> Self {
        WorldFromCamera(Se3::from_parts(Translation3::from(t), q))
    }
    pub fn inverse(&self) -> CameraFromWorld {
        CameraFromWorld(self.0.inverse())
    }
    /// Camera point -> world frame.
    #[inline]
    pub fn transform(&self, p_c: &Vector3<f64>) -> Vector3<f64> {
        self.0.rotation * p_c + self.0.translation.vector
    }
    pub fn position(&self) -> Vector3<f64> {
        self.0.translation.vector
    }
}

/// A similarity `p_a = s R p_b + t` (trajectory alignment, loop correction).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sim3 {
    pub scale: f64,
    pub rotation: UnitQuaternion<f64>,
    pub translation: Vector3<f64>,
}

impl Sim3 {
    pub fn identity() -> Self {
        Sim3 {
            scale: 1.0,
            rotation: UnitQuaternion::identity(),
            translation: Vector3::zeros(),
        }
    }
    #[inline]
    pub fn transform(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.scale * (self.rotation * p) + self.translation
    }
    pub fn inverse(&self) -> Sim3 {
        let ri = self.rotation.inverse();
        Sim3 {
            scale: 1.0 / self.scale,
            rotation: ri,
            translation: -(ri * self.translation) / self.scale,
        }
    }
    /// Maps a camera pose: the camera centre moves by the similarity, orientation rotates.
    pub fn apply_to_pose(&self, t_wc: &WorldFromCamera) -> WorldFromCamera {
        WorldFromCamera::from_parts(
            self.transform(&t_wc.position()),
            self.rotation * t_wc.0.rotation,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_round_trips_and_centres_agree() {
        let t_wc = WorldFromCamera::from_parts(
            Vector3::new(1.0, 2.0, 3.0),
            UnitQuaternion::from_euler_angles(0.1, -0.4, 0.7),
        );
        let t_cw = t_wc.inverse();
        assert!((t_cw.center() - t_wc.position()).norm() < 1e-12);
        let p = Vector3::new(0.3, -0.2, 5.0);
        assert!((t_wc.transform(&t_cw.transform(&p)) - p).norm() < 1e-12);
    }

    #[test]
    fn sim3_inverse() {
        let s = Sim3 {
            scale: 2.5,
            rotation: UnitQuaternion::from_euler_angles(0.3, 0.2, -0.1),
            translation: Vector3::new(1.0, -1.0, 0.5),
        };
        let p = Vector3::new(0.1, 0.2, 0.3);
        assert!((s.inverse().transform(&s.transform(&p)) - p).norm() < 1e-12);
    }
}
