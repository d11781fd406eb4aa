//! Hamming distance of 256-bit descriptors (popcount; hardware `popcnt` where the target has
//! it, see `.cargo/config.toml`).

use crate::features::Descriptor;

/// Strict distance threshold (ORB-SLAM's TH_LOW).
pub const TH_LOW: u32 = 50;
/// Loose distance threshold (TH_HIGH).
pub const TH_HIGH: u32 = 100;

#[inline(always)]
pub fn hamming(a: &Descriptor, b: &Descriptor) -> u32 {
    (a[0] ^ b[0]).count_ones()
        + (a[1] ^ b[1]).count_ones()
        + (a[2] ^ b[2]).count_ones()
        + (a[3] ^ b[3]).count_ones()
}

/// Nearest/second-nearest ratio test: the best match must be clearly better than the second.
#[inline]
pub fn passes_ratio(best: u32, second: u32, ratio: f32) -> bool {
    (best as f32) < ratio * second as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distance_counts_differing_bits() {
        let a = [0u64; 4];
        let b = [1u64, 3, u64::MAX, 0];
        assert_eq!(hamming(&a, &b), 1 + 2 + 64);
        assert_eq!(hamming(&b, &b), 0);
        assert!(passes_ratio(30, 60, 0.6));
        assert!(!passes_ratio(40, 60, 0.6));
    }
}
