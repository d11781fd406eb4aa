//! Stress scenes of the built-in renderer, each with exact ground truth: the motions and
//! images a robot's camera meets on its first day that the default orbit does not show.
//! Selected by name (`sdslam synth --scene NAME`, `sdslam run synthetic:NAME`).

use std::f64::consts::{PI, TAU};

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};

use super::path::OrbitPath;
use crate::geometry::WorldFromCamera;

/// Which scene and motion the sequence renders.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Scenario {
    /// The default: an orbit around the desk that closes a loop.
    #[default]
    Desk,
    /// Turning on the spot: the camera sweeps +-60 deg of yaw about an axis 8 cm behind it
    /// (a head or a robot turning in place), with a little pitch.
    Rotation,
    /// Looking outward while travelling a loop around the desk: the walls are weakly textured,
    /// few features per frame, most of the motion is rotation.
    OutwardLoop,
    /// Driving forward along the room, accelerating from rest (the focus of expansion is in
    /// the image centre: low parallax there).
    Forward,
    /// The orbit three times as fast, each frame the mean of three renders along its motion
    /// (motion blur).
    FastBlur,
    /// The orbit with the exposure stepping up by 60% half way (auto exposure).
    ExposureStep,
    /// The outward loop with 20 black frames a third of the way round, when the camera looks
    /// at walls it has not mapped yet.
    Blackout,
    /// The orbit in a room whose surfaces carry repetitive patterns (per surface one of
    /// fine noise, stripes, tiles, rows of glyphs): many similar pixels along an epipolar
    /// segment.
    Repetitive,
    /// The orbit with three boxes moving through the scene (across the desk, along the floor,
    /// up and down in front of a wall): points on them are not static.
    MovingObjects,
    /// The orbit in a dim room, starting from rest: a quarter of the light, and the read noise
    /// the camera's gain raises with it (3 grey levels after the gain): fewer and weaker
    /// corners, noisier ones, and little parallax at first.
    LowLight,
    /// The orbit under a camera's auto exposure hunting: the image gain drifts +-25% over
    /// three seconds and jitters +-4% from frame to frame (a USB camera adjusting to the
    /// scene), so no two keyframes share an exposure.
    AutoExposure,
}

impl Scenario {
    pub const ALL: [Scenario; 11] = [
        Scenario::Desk,
        Scenario::Rotation,
        Scenario::OutwardLoop,
        Scenario::Forward,
        Scenario::FastBlur,
        Scenario::ExposureStep,
        Scenario::Blackout,
        Scenario::Repetitive,
        Scenario::MovingObjects,
        Scenario::LowLight,
        Scenario::AutoExposure,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Scenario::Desk => "desk",
            Scenario::Rotation => "rotation",
            Scenario::OutwardLoop => "outward-loop",
            Scenario::Forward => "forward",
            Scenario::FastBlur => "fast-blur",
            Scenario::ExposureStep => "exposure-step",
            Scenario::Blackout => "blackout",
            Scenario::Repetitive => "repetitive",
            Scenario::MovingObjects => "moving-objects",
            Scenario::LowLight => "low-light",
            Scenario::AutoExposure => "auto-exposure",
        }
    }

    /// The scenario called `name`, or the list of names in the error.
    pub fn from_name(name: &str) -> Result<Scenario, String> {
        Scenario::ALL
            .into_iter()
            .find(|s| s.name() == name)
            .ok_or_else(|| {
                let names: Vec<&str> = Scenario::ALL.iter().map(|s| s.name()).collect();
                format!(
                    "unknown scene `{name}`: expected one of {}",
                    names.join(", ")
                )
            })
    }

    /// How the room's surfaces are textured.
    pub fn surfaces(self) -> super::scene::Surfaces {
        use super::scene::Surfaces;
        match self {
            Scenario::OutwardLoop | Scenario::Blackout => Surfaces::WeakWalls,
            Scenario::Repetitive => Surfaces::Repetitive,
            _ => Surfaces::Shapes,
        }
    }

    /// Whether objects move through the scene.
    pub fn moving_objects(self) -> bool {
        self == Scenario::MovingObjects
    }

    /// Renders averaged along the motion for frame blur (1 = sharp).
    pub fn blur_samples(self) -> usize {
        if self == Scenario::FastBlur {
            3
        } else {
            1
        }
    }

    /// Image gain of frame `i` of `frames`, 0 for a black frame.
    pub fn gain(self, i: usize, frames: usize) -> f32 {
        match self {
            Scenario::ExposureStep if i >= frames / 2 => 1.6,
            Scenario::Blackout if (frames / 3..frames / 3 + 20).contains(&i) => 0.0,
            Scenario::LowLight => 0.25,
            Scenario::AutoExposure => {
                // A fixed pseudo-random jitter per frame (the same sequence on every run).
                let h = (i as u32).wrapping_mul(2_654_435_761).rotate_left(13) ^ 0x9e37_79b9;
                let jitter = (h.wrapping_mul(2_246_822_519) >> 8) as f32 / (1u32 << 24) as f32;
                let drift = (std::f32::consts::TAU * i as f32 / 90.0).sin();
                1.0 + 0.25 * drift + 0.04 * (2.0 * jitter - 1.0)
            }
            _ => 1.0,
        }
    }

    /// Standard deviation of the noise added after the gain, grey levels (the sensor's read
    /// noise, which a dim scene's gain amplifies against the signal).
    pub fn noise_after_gain(self) -> f64 {
        if self == Scenario::LowLight {
            3.0
        } else {
            0.0
        }
    }
}

/// The camera path of a scenario, parameterised by (fractional) frame index.
#[derive(Clone, Debug)]
pub struct CameraPath {
    scenario: Scenario,
    frames: usize,
    orbit: OrbitPath,
}

impl CameraPath {
    pub fn new(scenario: Scenario, frames: usize) -> Self {
        let frames = frames.max(2);
        // Fast: one orbit in a third of the frames.
        let orbit_frames = if scenario == Scenario::FastBlur {
            (frames / 3).max(2)
        } else {
            frames
        };
        CameraPath {
            scenario,
            frames,
            orbit: OrbitPath::desk(orbit_frames),
        }
    }

    /// `T_wc` at frame `i` (camera x right, y down, z forward; world z up).
    pub fn pose(&self, i: f64) -> WorldFromCamera {
        let u = i / self.frames as f64;
        match self.scenario {
            Scenario::Desk
            | Scenario::ExposureStep
            | Scenario::FastBlur
            | Scenario::Repetitive
            | Scenario::AutoExposure
            | Scenario::MovingObjects => self.orbit.pose_at(i),
            // From rest: the orbit's speed reached over the first 60 frames.
            Scenario::LowLight => {
                const RAMP: f64 = 60.0;
                let eased = if i < RAMP {
                    i * i / (2.0 * RAMP)
                } else {
                    i - RAMP / 2.0
                };
                self.orbit.pose_at(eased)
            }
            Scenario::Rotation => {
                // Ease in: the first frames barely move, as a robot starting to turn.
                let ease = (u * 8.0).min(1.0);
                let yaw = ease * (PI / 3.0) * (TAU * u).sin();
                let pitch = 0.12 * (2.0 * TAU * u).sin();
                let heading = PI + yaw; // looking from +x towards the desk
                let f = Vector3::new(
                    heading.cos() * pitch.cos(),
                    heading.sin() * pitch.cos(),
                    -0.35 + pitch.sin(),
                )
                .normalize();
                let axis = Vector3::new(2.4, 0.3, 1.4);
                let pos = axis + 0.08 * Vector3::new(f.x, f.y, 0.0).normalize();
                look(pos, f, 0.0)
            }
            Scenario::OutwardLoop | Scenario::Blackout => {
                let phi = TAU * u;
                let r = 1.35;
                let pos =
                    Vector3::new(r * phi.cos(), r * phi.sin(), 1.3 + 0.05 * (2.0 * phi).sin());
                // Outward and a little ahead along the loop, slightly down.
                let out = Vector3::new(phi.cos(), phi.sin(), 0.0);
                let ahead = Vector3::new(-phi.sin(), phi.cos(), 0.0);
                let f = (out + 0.35 * ahead + Vector3::new(0.0, 0.0, -0.15)).normalize();
                look(pos, f, 0.04 * (3.0 * phi).sin())
            }
            Scenario::Forward => {
                // Smooth start from rest: position s(u) = L * (u^2 (3 - 2u)) slowed at the end.
                let s = 4.6 * u * u * (1.5 - 0.5 * u);
                let pos = Vector3::new(-3.1 + s, 1.2 + 0.03 * (TAU * u).sin(), 1.1);
                let f = Vector3::new(1.0, -0.05 * (TAU * u).cos(), -0.08).normalize();
                look(pos, f, 0.0)
            }
        }
    }
}

/// The pose at `pos` looking along `f` (world z up), rolled by `roll` radians.
fn look(pos: Vector3<f64>, f: Vector3<f64>, roll: f64) -> WorldFromCamera {
    let right = f.cross(&Vector3::z()).normalize();
    let down = f.cross(&right);
    let r = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[right, down, f]));
    let roll = Rotation3::from_axis_angle(&Vector3::z_axis(), roll);
    WorldFromCamera::from_parts(pos, UnitQuaternion::from_rotation_matrix(&(r * roll)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_unknown_names_list_the_choices() {
        for s in Scenario::ALL {
            assert_eq!(Scenario::from_name(s.name()), Ok(s));
        }
        let e = Scenario::from_name("moon").unwrap_err();
        assert!(e.contains("outward-loop") && e.contains("moon"), "{e}");
    }

    #[test]
    fn auto_exposure_hunts_and_jitters_within_a_quarter() {
        let g: Vec<f32> = (0..300)
            .map(|i| Scenario::AutoExposure.gain(i, 300))
            .collect();
        assert!(g.iter().all(|&v| (0.7..=1.3).contains(&v)), "{g:?}");
        let (lo, hi) = g
            .iter()
            .fold((2.0f32, 0.0f32), |(a, b), &v| (a.min(v), b.max(v)));
        assert!(lo < 0.8 && hi > 1.2, "{lo} {hi}");
        // Consecutive frames differ (the jitter), by at most drift plus jitter.
        let steps: Vec<f32> = g.windows(2).map(|w| (w[1] - w[0]).abs()).collect();
        assert!(steps.iter().filter(|&&d| d > 0.005).count() > 150);
        assert!(steps.iter().all(|&d| d < 0.11));
    }

    #[test]
    fn paths_are_smooth_and_stay_inside_the_room() {
        for s in Scenario::ALL {
            let p = CameraPath::new(s, 300);
            for i in 0..299 {
                let (a, b) = (p.pose(i as f64), p.pose(i as f64 + 1.0));
                let c = a.position();
                assert!(
                    c.x.abs() < 3.3 && c.y.abs() < 3.3 && c.z > 0.9 && c.z < 2.0,
                    "{s:?} {i}: {c:?}"
                );
                let step = (b.position() - c).norm();
                let turn = a.0.rotation.angle_to(&b.0.rotation);
                assert!(
                    step < 0.15 && turn < 0.1,
                    "{s:?} {i}: step {step}, turn {turn}"
                );
            }
        }
    }
}
