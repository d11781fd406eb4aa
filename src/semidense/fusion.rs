//! Inverse-depth hypothesis fusion (paper section III-C): the largest set of mutually
//! compatible hypotheses (chi-square test at 95%, eq. 10), fused by inverse variance (eq. 11)
//! when it has at least lambda_N members.

use super::epipolar::Hypothesis;

/// chi-square, 2 dof, 95% (eq. 10).
pub const CHI2_2DOF_95: f32 = 5.99;
/// chi-square, 1 dof, 95% (eq. 13).
pub const CHI2_1DOF_95: f32 = 3.84;

/// Eq. 10 on (rho, sigma^2) pairs.
#[inline]
pub fn compatible(rho_a: f32, s2_a: f32, rho_b: f32, s2_b: f32) -> bool {
    let d = rho_a - rho_b;
    d * d * (1.0 / s2_a + 1.0 / s2_b) < CHI2_2DOF_95
}

/// Fuses the hypotheses: for each one, the set compatible with it; the largest set (ties: the
/// one with the smallest fused variance) is fused with eq. 11 if it has at least `lambda_n`
/// members. Returns (rho, sigma^2).
pub fn fuse(h: &[Hypothesis], lambda_n: usize) -> Option<(f32, f32)> {
    if h.len() < lambda_n {
        return None;
    }
    // Inverse variances once (eq. 10 and 11 both use them).
    let mut info = [0.0f32; super::MAX_NEIGHBOURS];
    for (i, x) in h.iter().enumerate().take(info.len()) {
        info[i] = 1.0 / (x.sigma * x.sigma);
    }
    let h = &h[..h.len().min(info.len())];
    let mut best: Option<(usize, f32, f32)> = None; // (count, information, weighted sum)
    for (a, ha) in h.iter().enumerate() {
        let (mut n, mut inf, mut sum) = (0usize, 0.0f32, 0.0f32);
        for (b, hb) in h.iter().enumerate() {
            let d = ha.rho - hb.rho;
            if d * d * (info[a] + info[b]) < CHI2_2DOF_95 {
                n += 1;
                inf += info[b];
                sum += hb.rho * info[b];
            }
        }
        let better = match best {
            None => true,
            Some((bn, binf, _)) => n > bn || (n == bn && inf > binf),
        };
        if better {
            best = Some((n, inf, sum));
        }
    }
    let (n, inf, sum) = best?;
    (n >= lambda_n && inf > 0.0).then(|| (sum / inf, 1.0 / inf))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn h(rho: f32, sigma: f32) -> Hypothesis {
        Hypothesis { rho, sigma }
    }

    #[test]
    fn fuses_the_compatible_majority_and_rejects_planted_outliers() {
        let hs = [
            h(1.0, 0.02),
            h(1.01, 0.02),
            h(0.99, 0.03),
            h(1.6, 0.02),
            h(0.3, 0.05),
        ];
        let (rho, s2) = fuse(&hs, 3).unwrap();
        assert!((rho - 1.0).abs() < 0.01, "{rho}");
        // Three measurements: the variance is below the smallest single one.
        assert!(s2 < 0.02 * 0.02);
    }

    #[test]
    fn too_few_compatible_hypotheses_give_nothing() {
        let hs = [h(1.0, 0.01), h(1.5, 0.01), h(2.0, 0.01), h(1.01, 0.01)];
        assert_eq!(fuse(&hs, 3), None);
        assert_eq!(fuse(&hs[..2], 3), None);
    }
}
