//! TUM trajectory files: `timestamp tx ty tz qx qy qz qw` of `T_wc` per line.

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

use crate::error::{Error, Result};
use crate::eval::TimedPose;
use crate::geometry::WorldFromCamera;

/// Largest position coordinate accepted (a million km: beyond any map, still far from where
/// squared distances overflow).
const MAX_COORDINATE_M: f64 = 1e9;

/// Parses TUM trajectory text; `path` names it in errors. Poses are returned sorted by time.
pub fn parse_tum_trajectory(text: &str, path: &Path) -> Result<Vec<TimedPose>> {
    let err = |line: usize, message: String| Error::Parse {
        path: path.to_path_buf(),
        line,
        message,
    };
    let mut out = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let l = raw.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let toks: Vec<&str> = l
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|t| !t.is_empty())
            .collect();
        if toks.len() != 8 {
            return Err(err(
                line,
                format!(
                    "expected 8 fields `timestamp tx ty tz qx qy qz qw`, found {}",
                    toks.len()
                ),
            ));
        }
        let mut v = [0f64; 8];
        for (k, t) in toks.iter().enumerate() {
            v[k] = t
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| {
                    err(
                        line,
                        format!("field {} ({t:?}) is not a finite number", k + 1),
                    )
                })?;
        }
        if let Some(k) = (1..4).find(|&k| v[k].abs() > MAX_COORDINATE_M) {
            return Err(err(
                line,
                format!(
                    "field {} ({}) is beyond {MAX_COORDINATE_M:e} m: not a position",
                    k + 1,
                    toks[k]
                ),
            ));
        }
        let q = Quaternion::new(v[7], v[4], v[5], v[6]);
        let n = q.norm();
        if (n - 1.0).abs() > 1e-2 {
            return Err(err(line, format!("quaternion norm {n:.4} is not 1")));
        }
        out.push(TimedPose {
            timestamp: v[0],
            t_wc: WorldFromCamera::from_parts(
                Vector3::new(v[1], v[2], v[3]),
                UnitQuaternion::from_quaternion(q),
            ),
        });
    }
    out.sort_by(|a, b| a.timestamp.total_cmp(&b.timestamp));
    Ok(out)
}

pub fn read_tum_trajectory(path: &Path) -> Result<Vec<TimedPose>> {
    let text = sdslam_camera::capped::read_text_capped(path, sdslam_camera::capped::LIST_CAP)
        .map_err(|e| Error::io(path, e))?;
    parse_tum_trajectory(&text, path)
}

/// TUM text for `poses` (6 decimals on time, 7 on position and rotation).
pub fn tum_trajectory_text(poses: &[TimedPose]) -> String {
    let mut s = String::with_capacity(poses.len() * 80);
    for p in poses {
        let t = p.t_wc.position();
        let q = p.t_wc.0.rotation.quaternion();
        let _ = writeln!(
            s,
            "{:.6} {:.7} {:.7} {:.7} {:.7} {:.7} {:.7} {:.7}",
            p.timestamp, t.x, t.y, t.z, q.i, q.j, q.k, q.w
        );
    }
    s
}

pub fn write_tum_trajectory(path: &Path, poses: &[TimedPose]) -> Result<()> {
    super::write_atomic(path, tum_trajectory_text(poses).as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip() {
        let poses = vec![TimedPose {
            timestamp: 1700000000.033333,
            t_wc: WorldFromCamera::from_parts(
                Vector3::new(1.0, -2.0, 0.5),
                UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3),
            ),
        }];
        let back = parse_tum_trajectory(&tum_trajectory_text(&poses), Path::new("t")).unwrap();
        assert!((back[0].timestamp - poses[0].timestamp).abs() < 1e-6);
        assert!((back[0].t_wc.position() - poses[0].t_wc.position()).norm() < 1e-6);
        assert!(back[0].t_wc.0.rotation.angle_to(&poses[0].t_wc.0.rotation) < 1e-6);
    }

    #[test]
    fn bad_lines_are_named() {
        let e = parse_tum_trajectory("# h\n1 0 0 0 0 0 0 1\n2 0 0 0 0 0 1\n", Path::new("gt.txt"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("gt.txt:3") && e.contains("8 fields"), "{e}");
        let e = parse_tum_trajectory("1 0 0 x 0 0 0 1\n", Path::new("gt.txt"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("gt.txt:1") && e.contains("field 4"), "{e}");
        let e = parse_tum_trajectory("1 0 0 0 0 0 0 3\n", Path::new("gt.txt"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("quaternion"), "{e}");
    }
}
