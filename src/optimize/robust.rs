//! Robust kernels.

/// Huber weight for a squared (information-weighted) error `e2` with threshold `delta2`
/// (ORB-SLAM: delta² = 5.991 for 2-DoF reprojection errors): 1 inside, sqrt(delta2 / e2) outside.
#[inline]
pub fn huber_weight(e2: f64, delta2: f64) -> f64 {
    if e2 <= delta2 {
        1.0
    } else {
        (delta2 / e2).sqrt()
    }
}

/// Huber cost of a squared error: `e2` inside, `2 delta |e| - delta²` outside.
#[inline]
pub fn huber_cost(e2: f64, delta2: f64) -> f64 {
    if e2 <= delta2 {
        e2
    } else {
        2.0 * (delta2 * e2).sqrt() - delta2
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn huber_is_continuous_and_linear_outside() {
        assert_eq!(huber_cost(4.0, 5.991), 4.0);
        let d2 = 5.991;
        assert!((huber_cost(d2, d2) - d2).abs() < 1e-12);
        assert!((huber_cost(4.0 * d2, d2) - 3.0 * d2).abs() < 1e-9);
        assert_eq!(huber_weight(1.0, d2), 1.0);
        assert!((huber_weight(4.0 * d2, d2) - 0.5).abs() < 1e-12);
    }
}
