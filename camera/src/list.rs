//! Parsers of image lists: TUM `rgb.txt`, EuRoC `data.csv`, and a plain timestamps file.
//!
//! Pure functions over text, so every rule is unit tested and fuzzable; errors carry the
//! list's path and the 1-based line.

use std::path::{Path, PathBuf};

use crate::SourceError;

/// One image of a replay list.
#[derive(Clone, Debug, PartialEq)]
pub struct ListEntry {
    pub timestamp: f64,
    /// Path relative to the list's base folder.
    pub file: PathBuf,
    /// 1-based line in the list file.
    pub line: usize,
}

fn list_err(path: &Path, line: usize, message: impl Into<String>) -> SourceError {
    SourceError::List {
        path: path.to_path_buf(),
        line,
        message: message.into(),
    }
}

fn parse_timestamp(tok: &str, path: &Path, line: usize) -> Result<f64, SourceError> {
    let t: f64 = tok
        .parse()
        .map_err(|_| list_err(path, line, format!("timestamp {tok:?} is not a number")))?;
    if !t.is_finite() {
        return Err(list_err(
            path,
            line,
            format!("timestamp {tok:?} is not finite"),
        ));
    }
    Ok(t)
}

/// Checks that timestamps strictly increase; a replay with time going backwards would break
/// the motion model and real-time pacing.
fn check_monotonic(entries: &[ListEntry], path: &Path) -> Result<(), SourceError> {
    for w in entries.windows(2) {
        if w[1].timestamp <= w[0].timestamp {
            return Err(list_err(
                path,
                w[1].line,
                format!(
                    "timestamp {} does not increase (previous {} at line {})",
                    w[1].timestamp, w[0].timestamp, w[0].line
                ),
            ));
        }
    }
    if entries.is_empty() {
        // A fault of the whole file, not of a line.
        return Err(SourceError::Invalid {
            path: path.to_path_buf(),
            message: "the list names no images (only comments or blank lines)".into(),
        });
    }
    Ok(())
}

/// TUM RGB-D `rgb.txt`: `timestamp filename` per line, `#` comments.
pub fn parse_tum(text: &str, path: &Path) -> Result<Vec<ListEntry>, SourceError> {
    let mut out = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let l = raw.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let mut toks = l.split_whitespace();
        let (Some(ts), Some(file)) = (toks.next(), toks.next()) else {
            return Err(list_err(path, line, "expected `timestamp filename`"));
        };
        if toks.next().is_some() {
            return Err(list_err(
                path,
                line,
                "expected two fields: `timestamp filename`",
            ));
        }
        out.push(ListEntry {
            timestamp: parse_timestamp(ts, path, line)?,
            file: PathBuf::from(file),
            line,
        });
    }
    check_monotonic(&out, path)?;
    Ok(out)
}

/// EuRoC `mav0/camN/data.csv`: `timestamp_ns,filename`, header comment `#...`; images are in
/// `data/`. Timestamps are converted to seconds.
pub fn parse_euroc(text: &str, path: &Path) -> Result<Vec<ListEntry>, SourceError> {
    let mut out = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let l = raw.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let Some((ts, file)) = l.split_once(',') else {
            return Err(list_err(path, line, "expected `timestamp_ns,filename`"));
        };
        let ts = ts.trim();
        let ns: u64 = ts.parse().map_err(|_| {
            list_err(
                path,
                line,
                format!("timestamp {ts:?} is not an integer of nanoseconds"),
            )
        })?;
        let file = file.trim();
        if file.is_empty() || file.contains(',') {
            return Err(list_err(path, line, "expected `timestamp_ns,filename`"));
        }
        // Split to keep full precision: ns up to 2^63 do not fit an f64 mantissa exactly.
        let secs = (ns / 1_000_000_000) as f64 + (ns % 1_000_000_000) as f64 * 1e-9;
        out.push(ListEntry {
            timestamp: secs,
            file: Path::new("data").join(file),
            line,
        });
    }
    check_monotonic(&out, path)?;
    Ok(out)
}

/// A plain timestamps file for an image folder: each line `timestamp [filename]`. When no line
/// names a file, the folder's images (sorted by name, given in `images`) are paired in order
/// and their count must match.
pub fn parse_timestamps(
    text: &str,
    path: &Path,
    images: &[PathBuf],
) -> Result<Vec<ListEntry>, SourceError> {
    let mut out = Vec::new();
    let mut named = None;
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let l = raw.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let mut toks = l
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|t| !t.is_empty());
        let Some(ts) = toks.next() else { continue };
        let file = toks.next();
        if toks.next().is_some() {
            return Err(list_err(path, line, "expected `timestamp [filename]`"));
        }
        match (named, file.is_some()) {
            (None, has) => named = Some(has),
            (Some(a), b) if a != b => {
                return Err(list_err(
                    path,
                    line,
                    "either every line names a file or none does",
                ))
            }
            _ => {}
        }
        let timestamp = parse_timestamp(ts, path, line)?;
        let file = match file {
            Some(f) => PathBuf::from(f),
            None => match images.get(out.len()) {
                Some(p) => p.clone(),
                None => {
                    return Err(list_err(
                        path,
                        line,
                        format!(
                            "more timestamps than the {} images of the folder",
                            images.len()
                        ),
                    ))
                }
            },
        };
        out.push(ListEntry {
            timestamp,
            file,
            line,
        });
    }
    if named == Some(false) && out.len() != images.len() {
        return Err(list_err(
            path,
            0,
            format!(
                "{} timestamps for {} images in the folder",
                out.len(),
                images.len()
            ),
        ));
    }
    check_monotonic(&out, path)?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p() -> &'static Path {
        Path::new("rgb.txt")
    }

    #[test]
    fn tum_parses_comments_and_entries() {
        let t = "# color images\n# timestamp filename\n1.0 rgb/a.png\n\n1.5 rgb/b.png\n";
        let e = parse_tum(t, p()).unwrap();
        assert_eq!(e.len(), 2);
        assert_eq!(e[1].timestamp, 1.5);
        assert_eq!(e[1].file, PathBuf::from("rgb/b.png"));
        assert_eq!(e[1].line, 5);
    }

    #[test]
    fn tum_rejects_bad_numbers_with_line() {
        let err = parse_tum("1.0 a.png\nabc b.png\n", p())
            .unwrap_err()
            .to_string();
        assert!(err.contains("rgb.txt:2"), "{err}");
        assert!(err.contains("not a number"), "{err}");
        let err = parse_tum("1.0 a.png\nNaN b.png\n", p())
            .unwrap_err()
            .to_string();
        assert!(err.contains("rgb.txt:2"), "{err}");
    }

    #[test]
    fn tum_rejects_backwards_and_repeated_time() {
        let err = parse_tum("2.0 a.png\n1.0 b.png\n", p())
            .unwrap_err()
            .to_string();
        assert!(
            err.contains(":2:") && err.contains("does not increase"),
            "{err}"
        );
        assert!(parse_tum("2.0 a.png\n2.0 b.png\n", p()).is_err());
    }

    #[test]
    fn tum_rejects_empty_and_malformed() {
        let err = parse_tum("# only comments\n", p()).unwrap_err().to_string();
        assert!(err.contains("no images"), "{err}");
        // A fault of the whole file: no line number (there is no line 0).
        assert!(!err.contains(":0:"), "{err}");
        assert!(parse_tum("1.0\n", p()).is_err());
        assert!(parse_tum("1.0 a b\n", p()).is_err());
    }

    #[test]
    fn euroc_converts_nanoseconds() {
        let t = "#timestamp [ns],filename\n1403715273262142976,1403715273262142976.png\n1403715273312143104,x.png\n";
        let e = parse_euroc(t, Path::new("data.csv")).unwrap();
        assert_eq!(e.len(), 2);
        assert!((e[0].timestamp - 1403715273.262143).abs() < 1e-6);
        assert!((e[1].timestamp - e[0].timestamp - 0.05).abs() < 1e-6);
        assert_eq!(e[1].file, PathBuf::from("data/x.png"));
        let err = parse_euroc("12.5,x.png\n", Path::new("data.csv")).unwrap_err();
        assert!(err.to_string().contains("data.csv:1"));
    }

    #[test]
    fn timestamps_pair_with_sorted_images() {
        let imgs = vec![PathBuf::from("a.png"), PathBuf::from("b.png")];
        let e = parse_timestamps("0.1\n0.2\n", Path::new("t.txt"), &imgs).unwrap();
        assert_eq!(e[1].file, PathBuf::from("b.png"));
        assert!(parse_timestamps("0.1\n", Path::new("t.txt"), &imgs).is_err());
        assert!(parse_timestamps("0.1\n0.2\n0.3\n", Path::new("t.txt"), &imgs).is_err());
        let named = parse_timestamps("0.1 b.png\n0.2 a.png\n", Path::new("t.txt"), &imgs).unwrap();
        assert_eq!(named[0].file, PathBuf::from("b.png"));
        assert!(parse_timestamps("0.1 b.png\n0.2\n", Path::new("t.txt"), &imgs).is_err());
    }
}
