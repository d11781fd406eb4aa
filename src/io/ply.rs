//! Binary little-endian PLY of the semi-dense cloud: `float x, y, z`, `uchar red, green, blue`,
//! `float sigma` (inverse-depth standard deviation), `double timestamp` (reference keyframe).

use std::path::Path;

use crate::error::{Error, Result};

pub use crate::geometry::CloudPoint;

const HEADER_PROPS: &str = "property float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nproperty float sigma\nproperty double timestamp\n";

/// Bytes per vertex: 3 floats, 3 bytes, 1 float, 1 double.
const VERTEX_BYTES: usize = 12 + 3 + 4 + 8;

/// Streams `points` as a PLY file into `w`.
pub fn encode_ply_into(points: &[CloudPoint], w: &mut dyn std::io::Write) -> std::io::Result<()> {
    write!(
        w,
        "ply\nformat binary_little_endian 1.0\ncomment sdslam semi-dense cloud\nelement vertex {}\n{HEADER_PROPS}end_header\n",
        points.len()
    )?;
    let mut v = [0u8; VERTEX_BYTES];
    for p in points {
        for (k, c) in p.position.iter().enumerate() {
            v[4 * k..4 * k + 4].copy_from_slice(&c.to_le_bytes());
        }
        v[12..15].copy_from_slice(&p.rgb);
        v[15..19].copy_from_slice(&p.sigma.to_le_bytes());
        v[19..27].copy_from_slice(&p.timestamp.to_le_bytes());
        w.write_all(&v)?;
    }
    Ok(())
}

/// Encodes `points` as a PLY file image.
pub fn encode_ply(points: &[CloudPoint]) -> Vec<u8> {
    let mut out = Vec::with_capacity(256 + points.len() * VERTEX_BYTES);
    // Writing into a Vec cannot fail.
    let _ = encode_ply_into(points, &mut out);
    out
}

/// Writes `points` to `path` atomically, streamed (no file image in memory).
pub fn write_ply(path: &Path, points: &[CloudPoint]) -> Result<()> {
    super::write_atomic_with(path, |w| encode_ply_into(points, w))
}

/// Reads a PLY written by [`encode_ply`] (exactly that layout); for tests and evaluation.
pub fn decode_ply(bytes: &[u8], path: &Path) -> Result<Vec<CloudPoint>> {
    let bad = |m: &str| Error::Invalid(format!("{}: {m}", path.display()));
    let end = b"end_header\n";
    let hlen = bytes
        .windows(end.len())
        .position(|w| w == end)
        .ok_or_else(|| bad("no PLY end_header"))?
        + end.len();
    let header = std::str::from_utf8(&bytes[..hlen]).map_err(|_| bad("header is not text"))?;
    if !header.starts_with("ply\nformat binary_little_endian 1.0\n")
        || !header.contains(HEADER_PROPS)
    {
        return Err(bad(
            "not an sdslam binary PLY (unexpected format or properties)",
        ));
    }
    let n: usize = header
        .lines()
        .find_map(|l| l.strip_prefix("element vertex "))
        .and_then(|s| s.trim().parse().ok())
        .ok_or_else(|| bad("missing vertex count"))?;
    let body = &bytes[hlen..];
    if body.len()
        != n.checked_mul(VERTEX_BYTES)
            .ok_or_else(|| bad("vertex count overflows"))?
    {
        return Err(bad(&format!(
            "{} bytes of vertex data for {n} vertices",
            body.len()
        )));
    }
    let f32_at = |b: &[u8], o: usize| f32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
    Ok(body
        .chunks_exact(VERTEX_BYTES)
        .map(|v| {
            let mut ts = [0u8; 8];
            ts.copy_from_slice(&v[19..27]);
            CloudPoint {
                position: [f32_at(v, 0), f32_at(v, 4), f32_at(v, 8)],
                rgb: [v[12], v[13], v[14]],
                sigma: f32_at(v, 15),
                timestamp: f64::from_le_bytes(ts),
            }
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_rejects_truncation() {
        let pts = vec![
            CloudPoint {
                position: [1.0, -2.0, 3.5],
                rgb: [1, 2, 3],
                sigma: 0.01,
                timestamp: 1700000000.5,
            },
            CloudPoint {
                position: [0.0, 0.0, 0.0],
                rgb: [255, 0, 9],
                sigma: 1.0,
                timestamp: 0.0,
            },
        ];
        let b = encode_ply(&pts);
        assert_eq!(decode_ply(&b, Path::new("c.ply")).unwrap(), pts);
        let e = decode_ply(&b[..b.len() - 3], Path::new("c.ply"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("c.ply"), "{e}");
        assert!(decode_ply(&encode_ply(&[]), Path::new("e.ply"))
            .unwrap()
            .is_empty());
    }
}
