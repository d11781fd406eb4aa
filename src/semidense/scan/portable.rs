//! The portable scan, for every CPU without AVX2 (the 128-bit profile here; NEON on an ARM
//! robot), written once on `wide`'s 128-bit vectors: SSE on x86-64, NEON on aarch64, plain
//! arrays elsewhere. Four samples per step, in the layout of the AVX2 scan: lane l reads the
//! word at memory position `pos + l` along the major axis, so a shallow step is two
//! contiguous loads and a blend instead of four scalar loads.

use bytemuck::cast;
use wide::{f32x4, i32x4};

use super::{circular_test, finish, ranking_constants, Best, Probe, Walk, NONE};
use crate::semidense::epipolar::SearchParams;

/// Lanes: the width of SSE and NEON vectors of f32.
const LANES: usize = 4;

/// Each lane keeps its own first minimum; the winner is the lowest sample index among the
/// lanes' minima of the lowest error: the same as the scalar scan, bit for bit.
pub(in crate::semidense) fn scan_lanes(
    walk: &Walk,
    probe: &Probe,
    params: &SearchParams,
    t: &[u32],
) -> Best {
    let forward = walk.major_step > 0;
    // Sample index of each lane in the first step.
    let k_first = i32x4::new(if forward { [0, 1, 2, 3] } else { [3, 2, 1, 0] });
    let (k3, b3) = circular_test(probe.a_ref, params.lambda_theta_steps, 128);
    let (k2, b2) = circular_test(probe.a_line, params.lambda_l_steps, 64);
    let (k3, b3) = (i32x4::splat(k3), i32x4::splat(b3));
    let (k2, b2) = (i32x4::splat(k2), i32x4::splat(b2));
    let (pg_fixed, k_g) = ranking_constants(probe, params);
    let (pi, pg, k_g) = (
        f32x4::splat(probe.intensity),
        f32x4::splat(pg_fixed),
        f32x4::splat(k_g),
    );
    // Four samples of a line that moves less than a row over three steps lie on at most
    // two rows.
    let shallow = 3 * walk.minor_step.unsigned_abs() < 65536;
    let stride = walk.stride_n as isize;
    let mut best_e = f32x4::splat(f32::INFINITY);
    let mut best_k = i32x4::splat(0);
    let mut kv = k_first;
    // Rounded minor coordinate of each lane (16.16 fixed point, + 0.5 for rounding).
    let mut minor = i32x4::splat(walk.minor0 + 32768) + k_first * i32x4::splat(walk.minor_step);
    let minor_step = i32x4::splat(LANES as i32 * walk.minor_step);
    // Memory position of lane 0, and its rounded minor coordinate.
    let back = if forward { 0 } else { LANES - 1 };
    let mut pos = walk.major0 as isize - back as isize;
    let pos_step: isize = if forward { 4 } else { -4 };
    let mut minor_lane0 = walk.minor0 + 32768 + walk.minor_step * back as i32;
    // The other row a shallow step may touch, relative to lane 0's.
    let next_row = (walk.minor_step.signum() * if forward { 1 } else { -1 }) as isize * stride;
    let n = i32x4::splat(walk.n as i32);
    let mut k0 = 0;
    while k0 < walk.n {
        let row = minor >> 16u32;
        let live = n.simd_gt(kv);
        // Reads that would leave `t` give zeros (only lanes past the end of the walk can).
        let near = if shallow {
            let r0 = minor_lane0 >> 16;
            let p = pos + r0 as isize * stride;
            row.simd_eq(i32x4::splat(r0))
                .select(load4(t, p), load4(t, p + next_row))
        } else {
            let r = row.to_array();
            i32x4::new(std::array::from_fn(|l| {
                let i = pos + l as isize + r[l] as isize * stride;
                usize::try_from(i)
                    .ok()
                    .and_then(|i| t.get(i))
                    .map_or(0, |&v| v as i32)
            }))
        };
        // Conditions 1-3 (see `passes`).
        let o = (near & 0xff) >> 1u32;
        let c3 = b3.simd_gt((o - k3) & 127);
        let c2 = b2.simd_gt((o - k2) & 63);
        let strong = (near & 1).simd_eq(i32x4::splat(1));
        let ok = c3 & c2 & strong & live;
        // `ranking_error`, four lanes at a time.
        let ri = pi - ((near >> 8u32) & 0xff).round_float();
        let rg = pg - ((near >> 16u32) & 0xffff).round_float();
        let e = ri * ri + rg * rg * k_g;
        // Per lane, keep the first minimum (strictly smaller replaces).
        let better = cast::<f32x4, i32x4>(e.simd_lt(best_e)) & ok;
        best_e = cast::<i32x4, f32x4>(better).select(e, best_e);
        best_k = better.select(kv, best_k);
        kv += i32x4::splat(LANES as i32);
        minor += minor_step;
        pos += pos_step;
        minor_lane0 += LANES as i32 * walk.minor_step;
        k0 += LANES;
    }
    finish(reduce(best_e, best_k), walk, probe, params, t)
}

/// The four words at `p..p + 4` of `t`, zeros where they fall outside it.
#[inline]
fn load4(t: &[u32], p: isize) -> i32x4 {
    let words = usize::try_from(p)
        .ok()
        .and_then(|p| t.get(p..p + LANES))
        .and_then(|s| <[u32; LANES]>::try_from(s).ok())
        .unwrap_or([0; LANES]);
    cast(words)
}

/// The smallest error over the lanes, then the smallest sample index among the lanes
/// holding it.
#[inline]
fn reduce(e: f32x4, k: i32x4) -> Best {
    let (e, k) = (e.to_array(), k.to_array());
    let mut best = NONE;
    for l in 0..LANES {
        if e[l] < best.e || (e[l] == best.e && (k[l] as usize) < best.k) {
            best.e = e[l];
            best.k = k[l] as usize;
        }
    }
    best
}
