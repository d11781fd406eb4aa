//! Epipolar search of one reference pixel in one neighbour keyframe (paper section III-B):
//! the segment between the prior's inverse-depth bounds (eq. 1), the three pixel conditions,
//! the similarity error (eq. 2-3), sub-pixel refinement (eq. 4-6), its uncertainty (eq. 7) and
//! the general inverse-depth propagation (eq. 8-9).

use nalgebra::{Matrix3, Vector3};

use super::gradients::{
    fast_atan2, quantise_orientation, GradientImage, PixelGradient, ORIENTATION_STEPS,
};
use super::scan::{scan, Probe, Walk};
use crate::geometry::Se3;

pub use crate::geometry::Intrinsics;

/// Per-pixel thresholds of the search, derived once from the config.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SearchParams {
    /// lambda_G: minimum gradient modulus of a candidate (and of a reference pixel).
    pub lambda_g: f32,
    /// cos(lambda_L): the gradient must be within lambda_L of the epipolar line (either way).
    pub cos_lambda_l: f32,
    /// cos(lambda_theta): the gradient orientation must agree with the reference's, rotated by
    /// the in-plane rotation between the keyframes, within lambda_theta.
    pub cos_lambda_theta: f32,
    /// 1 / sigma_I^2.
    pub inv_sigma_i2: f32,
    /// 1 / theta (theta = sigma_G^2 / sigma_I^2).
    pub inv_theta: f32,
    /// sigma_I^2, for eq. 7.
    pub sigma_i2: f32,
    /// lambda_L and lambda_theta in orientation-code steps: an integer difference d passes
    /// when d < these (the ceiling of the angle in steps).
    pub lambda_l_steps: u8,
    pub lambda_theta_steps: u8,
    /// Largest similarity error e(u0) accepted as a match (chi-square, 2 dof).
    pub max_error: f32,
}

impl SearchParams {
    pub fn from_config(c: &crate::config::SemiDenseConfig) -> Self {
        SearchParams {
            lambda_g: c.lambda_g as f32,
            cos_lambda_l: c.lambda_l_deg.to_radians().cos() as f32,
            cos_lambda_theta: c.lambda_theta_deg.to_radians().cos() as f32,
            inv_sigma_i2: (1.0 / (c.sigma_i * c.sigma_i)) as f32,
            inv_theta: (1.0 / c.theta) as f32,
            sigma_i2: (c.sigma_i * c.sigma_i) as f32,
            lambda_l_steps: angle_steps(c.lambda_l_deg),
            lambda_theta_steps: angle_steps(c.lambda_theta_deg),
            max_error: c.max_similarity_error as f32,
        }
    }

    /// The grey-level thresholds (lambda_G, sigma_I) for an image of `contrast` times the
    /// reference contrast (theta, a ratio of variances, is unchanged).
    pub fn for_contrast(mut self, contrast: f32) -> Self {
        if contrast == 1.0 {
            return self;
        }
        self.lambda_g *= contrast;
        self.sigma_i2 *= contrast * contrast;
        self.inv_sigma_i2 = 1.0 / self.sigma_i2;
        self
    }
}

fn angle_steps(deg: f64) -> u8 {
    (deg / 360.0 * ORIENTATION_STEPS as f64)
        .ceil()
        .clamp(0.0, 255.0) as u8
}

/// Pixels added along the line on each side of a search window (so the best sample of a
/// window at the edge of the consensus still has both neighbours for the sub-pixel step).
pub const WINDOW_PAD_PX: f64 = 2.0;

/// Geometry of reference keyframe i seen from neighbour j, precomputed per pair.
#[derive(Clone, Copy, Debug)]
pub struct StereoPair {
    /// K R_ji K^-1: a reference pixel at inverse depth rho maps to `kr x + rho kt` in j.
    kr: Matrix3<f64>,
    /// K t_ji.
    kt: Vector3<f64>,
    /// In-plane rotation from i to j in orientation steps, from the ORB matches.
    rot: u8,
    /// 1 / (K t_ji).z (infinite when the translation has no depth component).
    inv_kt_z: f64,
    /// Intensity of j over i (exposure, see `photometric`): the reference pixel's intensity
    /// and gradient modulus are compared with j's at this scale.
    gain: f32,
}

/// One inverse-depth hypothesis N(rho, sigma^2).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Hypothesis {
    pub rho: f32,
    pub sigma: f32,
}

impl StereoPair {
    /// `t_ji` maps points from i's camera frame to j's; `delta_theta` (radians) is the median
    /// ORB angle change from i to j.
    pub fn new(k: &Intrinsics, t_ji: &Se3, delta_theta: f64) -> Self {
        let (kr, kt) = k.pixel_transform(t_ji);
        StereoPair {
            kr,
            kt,
            rot: quantise_orientation(delta_theta as f32),
            inv_kt_z: 1.0 / kt.z,
            gain: 1.0,
        }
    }

    /// The pair with j's intensities `gain` times i's (a finite positive value; else 1).
    pub fn with_gain(mut self, gain: f32) -> Self {
        self.gain = if gain.is_finite() && gain > 0.0 {
            gain
        } else {
            1.0
        };
        self
    }

    /// Where reference pixel (x, y) at inverse depth `rho` lands in j (None behind j).
    #[inline]
    pub fn project(&self, x: f64, y: f64, rho: f64) -> Option<(f32, f32)> {
        let mut out = [(0.0, 0.0)];
        self.project_offsets(x, y, rho, &[(0, 0)], &mut out)
            .then_some(out[0])
    }

    /// [`project`](Self::project) of the pixels (x + dx, y + dy) for each offset, all at
    /// inverse depth `rho`: the homogeneous point is linear in the pixel, so each offset
    /// costs two column additions and a division. False if one lands behind j.
    #[inline]
    pub fn project_offsets<const N: usize>(
        &self,
        x: f64,
        y: f64,
        rho: f64,
        offsets: &[(isize, isize); N],
        out: &mut [(f32, f32); N],
    ) -> bool {
        let h0 = self.kr * Vector3::new(x, y, 1.0) + self.kt * rho;
        let (cx, cy) = (self.kr.column(0), self.kr.column(1));
        for (o, &(dx, dy)) in out.iter_mut().zip(offsets) {
            let h = h0 + cx * dx as f64 + cy * dy as f64;
            if h.z <= 1e-9 {
                return false;
            }
            let inv = 1.0 / h.z;
            *o = ((h.x * inv) as f32, (h.y * inv) as f32);
        }
        true
    }

    /// Searches reference pixel (x, y) with values `p` along its epipolar segment in `target`
    /// for inverse depths in [rho_min, rho_max]. `None` when the segment leaves the image,
    /// no candidate fulfils the pixel conditions, or the best match is poor or ill-posed.
    #[inline]
    #[allow(clippy::too_many_arguments)]
    pub fn search(
        &self,
        params: &SearchParams,
        x: f64,
        y: f64,
        p: &PixelGradient,
        rho_range: (f64, f64),
        target: &GradientImage,
        samples: &mut u64,
    ) -> Option<Hypothesis> {
        self.search_within(params, x, y, p, rho_range, None, target, samples)
    }

    /// [`search`](Self::search) visiting only the samples whose inverse depth lies in
    /// `window` (padded by `WINDOW_PAD_PX` along the line): the same lattice of samples as
    /// the full search, a subset of them. The segment, its parallax check and the sub-pixel
    /// step are those of the full prior range.
    #[inline]
    #[allow(clippy::too_many_arguments)]
    pub fn search_within(
        &self,
        params: &SearchParams,
        x: f64,
        y: f64,
        p: &PixelGradient,
        rho_range: (f64, f64),
        window: Option<(f64, f64)>,
        target: &GradientImage,
        samples: &mut u64,
    ) -> Option<Hypothesis> {
        let a = self.kr * Vector3::new(x, y, 1.0);
        let b = self.kt;
        let (mut lo, mut hi) = (rho_range.0.max(0.0), rho_range.1);
        // Keep the depth in j positive over the whole interval: a.z + rho b.z > 0.
        const MIN_Z: f64 = 1e-6;
        if b.z.abs() < 1e-12 {
            if a.z <= MIN_Z {
                return None;
            }
        } else {
            let rho0 = (MIN_Z - a.z) * self.inv_kt_z;
            if b.z > 0.0 {
                lo = lo.max(rho0);
            } else {
                hi = hi.min(rho0);
            }
        }
        if hi <= lo {
            return None;
        }
        let proj = |rho: f64| {
            let h = a + b * rho;
            let inv_z = 1.0 / h.z;
            (h.x * inv_z, h.y * inv_z)
        };
        let (p0, p1) = (proj(lo), proj(hi));
        // The segment p0 + t e, t in [0, 1]; no normalisation (a square root and a division
        // on every search's critical path): it is walked along its major axis.
        let (ex, ey) = (p1.0 - p0.0, p1.1 - p0.1);
        let e2 = ex * ex + ey * ey;
        if e2 < 1.0 || !e2.is_finite() {
            // No parallax over the prior: the match would not constrain the depth.
            return None;
        }
        let (t_lo, t_hi) = clip_segment(
            p0,
            (ex, ey),
            1.0,
            (2.0, (target.width - 3) as f64),
            (2.0, (target.height - 3) as f64),
        )?;
        let (t_lo, t_hi) = match window {
            None => (t_lo, t_hi),
            Some((w_lo, w_hi)) => {
                // The projection is monotonic along the segment (depth stays positive).
                let t_of = |rho: f64| {
                    let q = proj(rho.clamp(lo, hi));
                    ((q.0 - p0.0) * ex + (q.1 - p0.1) * ey) / e2
                };
                let (ta, tb) = (t_of(w_lo), t_of(w_hi));
                let (ta, tb) = if ta <= tb { (ta, tb) } else { (tb, ta) };
                let pad = WINDOW_PAD_PX / e2.sqrt();
                let (a_, b_) = ((ta - pad).max(t_lo), (tb + pad).min(t_hi));
                if b_ < a_ {
                    return None;
                }
                (a_, b_)
            }
        };
        // Reference gradient orientation rotated into j, and the line direction, in steps.
        let a_ref = p.orientation.wrapping_add(self.rot) & 127;
        let a_line = quantise_orientation(fast_atan2(ey as f32, ex as f32));
        // Step one pixel along the major axis (the paper's parametrisation by u_j, or by v_j
        // for steep lines), starting on a whole pixel: every sample lies on a pixel column
        // (row), interpolated linearly along the minor axis only.
        let horizontal = ex.abs() >= ey.abs();
        let w = target.width;
        // Steep lines walk the transposed words, so consecutive samples are adjacent words.
        let (pm, pn, dm, dn, stride_n, words) = if horizontal {
            (p0.0, p0.1, ex, ey, w, &target.packed[..])
        } else {
            (p0.1, p0.0, ey, ex, target.height, &target.packed_t[..])
        };
        let sgn = dm.signum();
        let (ma, mb) = (pm + dm * t_lo, pm + dm * t_hi);
        let m0 = if sgn > 0.0 { ma.ceil() } else { ma.floor() };
        let span = (mb - m0) * sgn;
        if span < 0.0 {
            return None;
        }
        let n = span.floor() as usize + 1;
        let slope = dn / dm.abs(); // minor change per step
        let minor0 = pn + slope * sgn * (m0 - pm);
        const ONE: f64 = 65536.0;
        let walk = Walk {
            major0: m0 as i32,
            major_step: sgn as i32,
            minor0: (minor0 * ONE) as i32,
            minor_step: (slope * ONE) as i32,
            stride_n,
            n,
        };
        let probe = Probe {
            intensity: p.intensity * self.gain,
            modulus: p.modulus * self.gain,
            a_ref,
            a_line,
        };
        *samples += n as u64;
        let best = scan(&walk, &probe, params, words);
        if best.e > params.max_error {
            return None;
        }
        let (k, ri, rg, g, q) = (best.k, best.ri, best.rg, best.g, best.q);
        // The sub-pixel step (eq. 6) from the derivatives along the line (eq. 5).
        let denom = g * g + q * q * params.inv_theta;
        if denom < 1e-6 {
            return None;
        }
        let delta = (g * ri + q * rg * params.inv_theta) / denom;
        if delta.abs() > 1.0 {
            return None;
        }
        // Eq. 7 in steps, i.e. in the major coordinate (one step moves it by one pixel).
        let sigma_m = (2.0 * params.sigma_i2 / denom).sqrt() as f64;
        let m_star = m0 + sgn * (k as f64 + delta as f64);
        // Eq. 8 in the major coordinate (u_j for shallow lines, v_j for steep ones).
        let rho_at = |m: f64| {
            if horizontal {
                (a.x - m * a.z) / (m * b.z - b.x)
            } else {
                (a.y - m * a.z) / (m * b.z - b.y)
            }
        };
        let rho = rho_at(m_star);
        if !(rho > 0.0 && rho.is_finite()) {
            return None;
        }
        // Eq. 9.
        let sigma = (rho_at(m_star + sigma_m) - rho)
            .abs()
            .max((rho_at(m_star - sigma_m) - rho).abs());
        if !(sigma > 0.0 && sigma.is_finite()) {
            return None;
        }
        Some(Hypothesis {
            rho: rho as f32,
            sigma: sigma as f32,
        })
    }
}

/// Clips the segment `p0 + s d`, s in [0, len], to the box (Liang-Barsky); `None` if outside.
fn clip_segment(
    p0: (f64, f64),
    d: (f64, f64),
    len: f64,
    xr: (f64, f64),
    yr: (f64, f64),
) -> Option<(f64, f64)> {
    let (mut lo, mut hi) = (0.0f64, len);
    for (p, dd, (mn, mx)) in [(p0.0, d.0, xr), (p0.1, d.1, yr)] {
        if dd.abs() < 1e-12 {
            if p < mn || p > mx {
                return None;
            }
            continue;
        }
        let inv = 1.0 / dd;
        let (t1, t2) = ((mn - p) * inv, (mx - p) * inv);
        let (a, b) = if t1 < t2 { (t1, t2) } else { (t2, t1) };
        lo = lo.max(a);
        hi = hi.min(b);
    }
    (hi >= lo).then_some((lo, hi))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clipping_keeps_the_inside_part() {
        let r = clip_segment((-10.0, 5.0), (1.0, 0.0), 100.0, (0.0, 50.0), (0.0, 10.0));
        assert_eq!(r, Some((10.0, 60.0)));
        assert_eq!(
            clip_segment((-10.0, 20.0), (1.0, 0.0), 100.0, (0.0, 50.0), (0.0, 10.0)),
            None
        );
    }
}
