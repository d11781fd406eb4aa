//! Which vector width the kernels may use. The 128-bit kernels are written once on `wide`'s
//! vectors, which compile to SSE on x86-64 (the x86-64-v2 baseline the crate is built for)
//! and to NEON on aarch64: what an ARM robot runs is the code built and tested here. Wider
//! hand-written kernels (AVX2, AVX-512) check the CPU at run time and are kept where they are
//! measurably faster, each tested equal to its 128-bit twin. The width can be capped for the
//! whole process, so the "128-bit profile" is measured on this machine with the same binary
//! (`--simd 128`, or `SDSLAM_SIMD=128` for the benches).

use std::sync::atomic::{AtomicU8, Ordering};

/// The widest vectors the kernels may use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Width {
    /// The compiled baseline only (SSE up to 4.2 on x86-64-v2; NEON on aarch64).
    W128 = 1,
    /// AVX and AVX2 when the CPU has them.
    W256 = 2,
    /// AVX-512 too (the default: whatever the CPU has).
    W512 = 3,
}

static CAP: AtomicU8 = AtomicU8::new(Width::W512 as u8);

/// Caps the width for the whole process (kernels check at each call).
pub fn set_max_width(w: Width) {
    CAP.store(w as u8, Ordering::Relaxed);
}

/// The current cap.
pub fn max_width() -> Width {
    match CAP.load(Ordering::Relaxed) {
        1 => Width::W128,
        2 => Width::W256,
        _ => Width::W512,
    }
}

/// `128`, `256`, `512` or `auto` (= 512: what the CPU has).
pub fn parse_width(s: &str) -> Result<Width, String> {
    match s.trim() {
        "128" => Ok(Width::W128),
        "256" => Ok(Width::W256),
        "512" | "auto" => Ok(Width::W512),
        other => Err(format!("`{other}`: expected 128, 256, 512 or auto")),
    }
}

/// Applies `SDSLAM_SIMD` (128, 256, 512, auto) when it is set: how the benches and the
/// command line take the 128-bit profile.
pub fn cap_from_env() -> Result<(), String> {
    match std::env::var("SDSLAM_SIMD") {
        Ok(s) => {
            set_max_width(parse_width(&s).map_err(|e| format!("SDSLAM_SIMD={e}"))?);
            Ok(())
        }
        Err(_) => Ok(()),
    }
}

/// AVX2 kernels allowed and supported.
#[cfg(target_arch = "x86_64")]
#[inline]
pub fn avx2() -> bool {
    max_width() >= Width::W256 && std::arch::is_x86_feature_detected!("avx2")
}

/// 256-bit AVX float kernels allowed and supported.
#[cfg(target_arch = "x86_64")]
#[inline]
pub fn avx() -> bool {
    max_width() >= Width::W256 && std::arch::is_x86_feature_detected!("avx")
}

/// AVX-512F kernels allowed and supported.
#[cfg(target_arch = "x86_64")]
#[inline]
pub fn avx512f() -> bool {
    max_width() >= Width::W512 && std::arch::is_x86_feature_detected!("avx512f")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn widths_parse_and_order() {
        assert_eq!(parse_width("128"), Ok(Width::W128));
        assert_eq!(parse_width("auto"), Ok(Width::W512));
        assert!(parse_width("64").is_err());
        assert!(Width::W128 < Width::W256 && Width::W256 < Width::W512);
    }
}
