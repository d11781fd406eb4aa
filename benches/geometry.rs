//! Geometry solver costs: one two-view initialisation attempt (1000 matches, 200 RANSAC
//! iterations, H and F in parallel) and one PnP-RANSAC call (300 correspondences, 30% outliers).

#[path = "../tests/common/problems.rs"]
mod problems;

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::{Matrix3, Point3, Translation3, UnitQuaternion, Vector2, Vector3};
use problems::Rng;
use sdslam::geometry::pnp::{pnp_ransac, PnpRansacConfig};
use sdslam::geometry::two_view::{initialize, TwoViewConfig};
use sdslam::geometry::Se3;

fn geometry(c: &mut Criterion) {
    let k = Matrix3::new(520.0, 0.0, 320.0, 0.0, 520.0, 240.0, 0.0, 0.0, 1.0);
    let proj =
        |p: &Vector3<f64>| Vector2::new(520.0 * p.x / p.z + 320.0, 520.0 * p.y / p.z + 240.0);
    let mut rng = Rng(1);
    let t_21 = Se3::from_parts(
        Translation3::new(0.4, 0.05, 0.02),
        UnitQuaternion::from_euler_angles(0.02, -0.08, 0.01),
    );
    let (mut x1, mut x2) = (Vec::new(), Vec::new());
    while x1.len() < 1000 {
        let u = Vector2::new(640.0 * rng.f(), 480.0 * rng.f());
        let p =
            Vector3::new((u.x - 320.0) / 520.0, (u.y - 240.0) / 520.0, 1.0) * (1.5 + 3.5 * rng.f());
        let q = t_21 * Point3::from(p);
        let u2 = proj(&q.coords);
        if q.z < 0.5 || u2.x < 0.0 || u2.y < 0.0 || u2.x >= 640.0 || u2.y >= 480.0 {
            continue;
        }
        x1.push(u);
        x2.push(if rng.f() < 0.2 {
            Vector2::new(640.0 * rng.f(), 480.0 * rng.f())
        } else {
            u2 + Vector2::new(rng.f() - 0.5, rng.f() - 0.5)
        });
    }
    let cfg = TwoViewConfig::default();
    c.bench_function("two_view_initialize_1000_matches_200_iterations", |b| {
        b.iter(|| initialize(&x1, &x2, &k, &cfg))
    });

    let t_cw = Se3::from_parts(
        Translation3::new(0.1, -0.2, 0.5),
        UnitQuaternion::from_euler_angles(0.1, 0.3, -0.2),
    );
    let t_wc = t_cw.inverse();
    let (mut pw, mut px) = (Vec::new(), Vec::new());
    while pw.len() < 300 {
        let u = Vector2::new(640.0 * rng.f(), 480.0 * rng.f());
        let pc =
            Vector3::new((u.x - 320.0) / 520.0, (u.y - 240.0) / 520.0, 1.0) * (2.0 + 6.0 * rng.f());
        pw.push((t_wc * Point3::from(pc)).coords);
        px.push(if rng.f() < 0.3 {
            Vector2::new(640.0 * rng.f(), 480.0 * rng.f())
        } else {
            u + Vector2::new(rng.f() - 0.5, rng.f() - 0.5)
        });
    }
    let s2 = vec![1.0; pw.len()];
    let pcfg = PnpRansacConfig::default();
    c.bench_function("pnp_ransac_300_points_30pct_outliers", |b| {
        b.iter(|| pnp_ransac(&pw, &px, &s2, &k, &pcfg))
    });
}

criterion_group!(benches, geometry);
criterion_main!(benches);
