//! The built-in scene: a textured room with a desk and objects at several depths, made of
//! rectangles so ray casting stays simple and exact.

use nalgebra::{Rotation3, Vector3};

use super::texture::{Pattern, Rng, Texture};

/// A textured rectangle `origin + a * eu + b * ev`, a, b in [0, 1], eu ⟂ ev.
pub struct Quad {
    origin: Vector3<f64>,
    eu: Vector3<f64>,
    ev: Vector3<f64>,
    /// Unit normal facing the viewer side that is lit.
    normal: Vector3<f64>,
    inv_u2: f64,
    inv_v2: f64,
    texture: usize,
    /// Lambertian shading factor, precomputed from the fixed light.
    shade: f32,
}

/// A group of quads behind one bounding box.
struct Object {
    min: Vector3<f64>,
    max: Vector3<f64>,
    quads: Vec<Quad>,
}

/// A ray hit: distance along the (unit) ray and the surface colour.
pub struct Hit {
    pub t: f64,
    pub rgb: [f32; 3],
    /// Which quad was hit (edges between quads are where anti-aliasing is needed).
    pub id: u32,
}

/// How the room's surfaces are textured.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Surfaces {
    /// Random shapes on every surface (the default room).
    #[default]
    Shapes,
    /// The walls faint and sparse (a painted room), the rest as `Shapes`.
    WeakWalls,
    /// Every surface a repetitive [`Pattern`], cycling through them.
    Repetitive,
}

/// An object moving back and forth between two offsets (smoothly, cosine-eased).
struct Mover {
    object: Object,
    a: Vector3<f64>,
    b: Vector3<f64>,
    /// Frames per back-and-forth, and the phase at frame 0 (in periods).
    period: f64,
    phase: f64,
}

impl Mover {
    fn offset(&self, time: f64) -> Vector3<f64> {
        let s = 0.5 - 0.5 * (std::f64::consts::TAU * (time / self.period + self.phase)).cos();
        self.a + (self.b - self.a) * s
    }
}

/// The scene: objects and their textures.
pub struct Scene {
    objects: Vec<Object>,
    movers: Vec<Mover>,
    textures: Vec<Texture>,
    /// `Some(n)`: new surfaces get repetitive patterns, the n-th of [`Pattern::ALL`] next.
    patterns: Option<usize>,
}

const LIGHT: [f64; 3] = [0.35, 0.25, 0.9];

impl Scene {
    fn new() -> Self {
        Scene {
            objects: Vec::new(),
            movers: Vec::new(),
            textures: Vec::new(),
            patterns: None,
        }
    }

    /// Adds a textured rectangle to `quads`, its texture sized by `texels_per_m`.
    #[allow(clippy::too_many_arguments)]
    fn quad(
        &mut self,
        quads: &mut Vec<Quad>,
        origin: Vector3<f64>,
        eu: Vector3<f64>,
        ev: Vector3<f64>,
        rng: &mut Rng,
        texels_per_m: f64,
        density: f64,
        contrast: f64,
    ) {
        let tw = ((eu.norm() * texels_per_m).ceil() as usize).clamp(16, 2048);
        let th = ((ev.norm() * texels_per_m).ceil() as usize).clamp(16, 2048);
        let seed = rng.next_u64();
        let texture = match self.patterns.as_mut() {
            Some(n) => {
                *n += 1;
                Texture::pattern(tw, th, seed, Pattern::ALL[(*n - 1) % Pattern::ALL.len()])
            }
            None => Texture::generate(tw, th, seed, density, contrast),
        };
        self.textures.push(texture);
        let normal = eu.cross(&ev).normalize();
        let l = Vector3::from(LIGHT).normalize();
        let shade = (0.55 + 0.45 * normal.dot(&l).max(0.0)) as f32;
        quads.push(Quad {
            origin,
            eu,
            ev,
            normal,
            inv_u2: 1.0 / eu.norm_squared(),
            inv_v2: 1.0 / ev.norm_squared(),
            texture: self.textures.len() - 1,
            shade,
        });
    }

    fn push(&mut self, quads: Vec<Quad>) {
        let object = Self::bounded(quads);
        self.objects.push(object);
    }

    /// The quads behind their bounding box.
    fn bounded(quads: Vec<Quad>) -> Object {
        let mut min = Vector3::repeat(f64::INFINITY);
        let mut max = Vector3::repeat(f64::NEG_INFINITY);
        for q in &quads {
            for c in [
                q.origin,
                q.origin + q.eu,
                q.origin + q.ev,
                q.origin + q.eu + q.ev,
            ] {
                min = min.inf(&c);
                max = max.sup(&c);
            }
        }
        let pad = Vector3::repeat(1e-6);
        Object {
            min: min - pad,
            max: max + pad,
            quads,
        }
    }

    /// A box standing on z = `z0`, centred at (cx, cy), rotated by `yaw` about z; outward faces
    /// (the bottom is omitted: it is never seen).
    #[allow(clippy::too_many_arguments)]
    fn add_box(
        &mut self,
        rng: &mut Rng,
        c: [f64; 3],
        size: [f64; 3],
        yaw: f64,
        tpm: f64,
        density: f64,
        contrast: f64,
    ) {
        let r = Rotation3::from_axis_angle(&Vector3::z_axis(), yaw);
        let (ex, ey, ez) = (
            r * Vector3::new(size[0], 0.0, 0.0),
            r * Vector3::new(0.0, size[1], 0.0),
            Vector3::new(0.0, 0.0, size[2]),
        );
        let o = Vector3::new(c[0], c[1], c[2]) - ex / 2.0 - ey / 2.0;
        let mut q = Vec::new();
        // Faces with outward normals (eu x ev points out).
        self.quad(&mut q, o + ez, ex, ey, rng, tpm, density, contrast); // top
        self.quad(&mut q, o, ez, ex, rng, tpm, density, contrast); // -y side
        self.quad(&mut q, o + ey, ex, ez, rng, tpm, density, contrast); // +y side
        self.quad(&mut q, o, ey, ez, rng, tpm, density, contrast); // -x side
        self.quad(&mut q, o + ex, ez, ey, rng, tpm, density, contrast); // +x side
        self.push(q);
    }

    /// A textured box of `size` standing on the origin that moves between offsets `a` and
    /// `b` (see [`Mover`]).
    fn add_moving_box(
        &mut self,
        rng: &mut Rng,
        size: [f64; 3],
        (a, b): (Vector3<f64>, Vector3<f64>),
        period: f64,
        phase: f64,
    ) {
        self.add_box(rng, [0.0, 0.0, 0.0], size, 0.0, 260.0, 1.5, 0.8);
        if let Some(object) = self.objects.pop() {
            self.movers.push(Mover {
                object,
                a,
                b,
                period,
                phase,
            });
        }
    }

    /// Three boxes moving through the room (`Scenario::MovingObjects`): one across the desk
    /// top, one along the floor behind it, one up and down in front of a wall.
    pub fn add_movers(&mut self, seed: u64) {
        let mut rng = Rng::new(seed ^ 0x4d4f_5645);
        let v = Vector3::new;
        self.add_moving_box(
            &mut rng,
            [0.22, 0.22, 0.22],
            (v(-0.55, -0.05, 0.75), v(0.55, -0.05, 0.75)),
            90.0,
            0.0,
        );
        self.add_moving_box(
            &mut rng,
            [0.35, 0.35, 0.6],
            (v(-2.4, -2.0, 0.0), v(-2.4, 2.0, 0.0)),
            150.0,
            0.25,
        );
        self.add_moving_box(
            &mut rng,
            [0.3, 0.3, 0.3],
            (v(0.3, 2.6, 0.3), v(0.3, 2.6, 1.8)),
            100.0,
            0.5,
        );
    }

    /// The built-in desk scene (z up, metres): a 7 x 7 x 3 m room, a desk at the centre with
    /// boxes and standing boards on it, cabinets and posters further away.
    pub fn desk(seed: u64) -> Scene {
        Scene::room(seed, Surfaces::Shapes)
    }

    /// The desk scene with its surfaces textured as `surfaces` says (weak walls: a faint,
    /// sparse texture, so a camera looking outward sees few features).
    pub fn room(seed: u64, surfaces: Surfaces) -> Scene {
        let weak_walls = surfaces == Surfaces::WeakWalls;
        let (wall_density, wall_contrast) = if weak_walls { (0.35, 0.12) } else { (1.5, 0.8) };
        let mut s = Scene::new();
        if surfaces == Surfaces::Repetitive {
            s.patterns = Some(0);
        }
        let mut rng = Rng::new(seed);
        let (hx, hy, hz) = (3.5, 3.5, 3.0);
        // Room: floor (weakly textured), walls with posters' worth of texture, ceiling.
        let mut room = Vec::new();
        let v = |x: f64, y: f64, z: f64| Vector3::new(x, y, z);
        s.quad(
            &mut room,
            v(-hx, -hy, 0.0),
            v(0.0, 2.0 * hy, 0.0),
            v(2.0 * hx, 0.0, 0.0),
            &mut rng,
            120.0,
            0.8,
            0.35,
        );
        s.quad(
            &mut room,
            v(-hx, -hy, hz),
            v(2.0 * hx, 0.0, 0.0),
            v(0.0, 2.0 * hy, 0.0),
            &mut rng,
            60.0,
            0.5,
            0.3,
        );
        s.quad(
            &mut room,
            v(-hx, -hy, 0.0),
            v(2.0 * hx, 0.0, 0.0),
            v(0.0, 0.0, hz),
            &mut rng,
            150.0,
            wall_density,
            wall_contrast,
        );
        s.quad(
            &mut room,
            v(hx, hy, 0.0),
            v(-2.0 * hx, 0.0, 0.0),
            v(0.0, 0.0, hz),
            &mut rng,
            150.0,
            wall_density,
            wall_contrast,
        );
        s.quad(
            &mut room,
            v(-hx, hy, 0.0),
            v(0.0, -2.0 * hy, 0.0),
            v(0.0, 0.0, hz),
            &mut rng,
            150.0,
            wall_density,
            wall_contrast,
        );
        s.quad(
            &mut room,
            v(hx, -hy, 0.0),
            v(0.0, 2.0 * hy, 0.0),
            v(0.0, 0.0, hz),
            &mut rng,
            150.0,
            wall_density,
            wall_contrast,
        );
        s.push(room);
        // Desk: a block 1.6 x 1.0 x 0.75.
        s.add_box(
            &mut rng,
            [0.0, 0.0, 0.0],
            [1.6, 1.0, 0.75],
            0.0,
            260.0,
            1.6,
            0.85,
        );
        // Objects on the desk.
        let top = 0.75;
        let items: [([f64; 2], [f64; 3], f64); 7] = [
            ([-0.5, -0.25], [0.30, 0.20, 0.12], 0.3),
            ([0.45, 0.20], [0.22, 0.22, 0.30], -0.5),
            ([-0.15, 0.28], [0.40, 0.08, 0.25], 0.1),
            ([0.15, -0.22], [0.16, 0.12, 0.18], 1.0),
            ([0.62, -0.33], [0.18, 0.25, 0.08], 0.0),
            ([-0.62, 0.30], [0.12, 0.12, 0.40], 0.7),
            ([0.0, 0.0], [0.25, 0.30, 0.05], -0.2),
        ];
        for (xy, size, yaw) in items {
            s.add_box(&mut rng, [xy[0], xy[1], top], size, yaw, 320.0, 1.8, 0.9);
        }
        // Cabinets and boards around the room at several depths.
        s.add_box(
            &mut rng,
            [2.2, 1.8, 0.0],
            [0.8, 0.5, 1.2],
            0.4,
            200.0,
            1.5,
            0.85,
        );
        s.add_box(
            &mut rng,
            [-2.3, -1.5, 0.0],
            [0.6, 0.9, 0.9],
            -0.3,
            200.0,
            1.5,
            0.85,
        );
        s.add_box(
            &mut rng,
            [-1.9, 2.2, 0.0],
            [1.0, 0.4, 1.6],
            0.1,
            200.0,
            1.5,
            0.85,
        );
        s.add_box(
            &mut rng,
            [1.8, -2.3, 0.0],
            [0.5, 0.5, 0.7],
            0.0,
            200.0,
            1.5,
            0.85,
        );
        s
    }

    /// Nearest hit of the ray `o + t d` (`d` unit), moving objects where they are at frame 0.
    pub fn cast(&self, o: &Vector3<f64>, d: &Vector3<f64>) -> Option<Hit> {
        self.cast_at(o, d, 0.0)
    }

    /// Nearest hit of the ray `o + t d` (`d` unit), moving objects where they are at
    /// (fractional) frame `time`.
    pub fn cast_at(&self, o: &Vector3<f64>, d: &Vector3<f64>, time: f64) -> Option<Hit> {
        let inv = Vector3::new(1.0 / d.x, 1.0 / d.y, 1.0 / d.z);
        let mut best = Nearest {
            t: f64::INFINITY,
            hit: None,
            id: 0,
        };
        for obj in &self.objects {
            best.test(obj, o, d, &inv);
        }
        for m in &self.movers {
            // The ray in the moving object's frame (it only translates).
            best.test(&m.object, &(o - m.offset(time)), d, &inv);
        }
        let (q, a, b, id) = best.hit?;
        let mut rgb = self.textures[q.texture].sample(a, b);
        for c in &mut rgb {
            *c *= q.shade;
        }
        Some(Hit { t: best.t, rgb, id })
    }
}

/// The nearest quad hit so far, and the running quad id.
struct Nearest<'a> {
    t: f64,
    hit: Option<(&'a Quad, f64, f64, u32)>,
    id: u32,
}

impl<'a> Nearest<'a> {
    /// Tests the ray against `obj`'s quads (behind a slab test of its box).
    fn test(&mut self, obj: &'a Object, o: &Vector3<f64>, d: &Vector3<f64>, inv: &Vector3<f64>) {
        let t1 = (obj.min - o).component_mul(inv);
        let t2 = (obj.max - o).component_mul(inv);
        let tmin = t1.inf(&t2).max();
        let tmax = t1.sup(&t2).min();
        if tmax < tmin.max(0.0) || tmin > self.t {
            self.id += obj.quads.len() as u32;
            return;
        }
        for q in &obj.quads {
            self.id += 1;
            let den = d.dot(&q.normal);
            if den.abs() < 1e-12 {
                continue;
            }
            let t = (q.origin - o).dot(&q.normal) / den;
            if t <= 1e-6 || t >= self.t {
                continue;
            }
            let local = o + d * t - q.origin;
            let a = local.dot(&q.eu) * q.inv_u2;
            let b = local.dot(&q.ev) * q.inv_v2;
            if (0.0..=1.0).contains(&a) && (0.0..=1.0).contains(&b) {
                self.t = t;
                self.hit = Some((q, a, b, self.id));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rays_hit_floor_and_desk_at_the_right_distance() {
        let s = Scene::desk(1);
        // Straight down from 2 m above the desk centre: desk top + the thin object on it
        // (0.75 + 0.05 high) at 1.2 m.
        let h = s
            .cast(&Vector3::new(0.0, 0.0, 2.0), &Vector3::new(0.0, 0.0, -1.0))
            .unwrap();
        assert!((h.t - 1.2).abs() < 1e-9, "{}", h.t);
        // Straight down in a free corner of the floor.
        let h = s
            .cast(&Vector3::new(1.2, 1.0, 1.0), &Vector3::new(0.0, 0.0, -1.0))
            .unwrap();
        assert!((h.t - 1.0).abs() < 1e-9, "{}", h.t);
        // Every ray from inside the room hits something.
        for k in 0..50 {
            let a = k as f64 * 0.37;
            let d = Vector3::new(a.cos(), a.sin(), 0.3 * (a * 1.3).sin()).normalize();
            assert!(s.cast(&Vector3::new(0.0, -1.5, 1.3), &d).is_some());
        }
    }
}
