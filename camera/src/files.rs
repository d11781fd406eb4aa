//! Image-list replays: the file-backed mock of a camera (TUM RGB-D, EuRoC, plain folders).

use std::path::{Path, PathBuf};

use crate::decode::ImageDecoderBuf;
use crate::list::{self, ListEntry};
use crate::{Frame, FrameSource, FrameStatus, SourceError, SourceInfo};

/// Which layout a folder uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ListKind {
    Tum,
    Euroc,
    Folder,
}

/// Replays a list of image files in timestamp order.
pub struct ImageListSource {
    info: SourceInfo,
    base: PathBuf,
    entries: Vec<ListEntry>,
    next: usize,
    decoder: ImageDecoderBuf,
    kind: ListKind,
}

/// Orders names with their digit runs compared as numbers (`frame2` < `frame10`); equal
/// numbers with different zero padding fall back to the plain order.
pub fn natural_cmp(a: &str, b: &str) -> std::cmp::Ordering {
    use std::cmp::Ordering;
    let (mut x, mut y) = (a.as_bytes(), b.as_bytes());
    loop {
        match (x.first(), y.first()) {
            (None, None) => return a.cmp(b),
            (None, Some(_)) => return Ordering::Less,
            (Some(_), None) => return Ordering::Greater,
            (Some(c), Some(d)) if c.is_ascii_digit() && d.is_ascii_digit() => {
                let run = |s: &[u8]| s.iter().take_while(|c| c.is_ascii_digit()).count();
                let (n, m) = (run(x), run(y));
                let strip = |s: &[u8]| {
                    let z = s.iter().take_while(|&&c| c == b'0').count();
                    s[z.min(s.len().saturating_sub(1))..].to_vec()
                };
                let (p, q) = (strip(&x[..n]), strip(&y[..m]));
                let o = p.len().cmp(&q.len()).then_with(|| p.cmp(&q));
                if o != Ordering::Equal {
                    return o;
                }
                (x, y) = (&x[n..], &y[m..]);
            }
            (Some(c), Some(d)) => {
                if c != d {
                    return c.cmp(d);
                }
                (x, y) = (&x[1..], &y[1..]);
            }
        }
    }
}

fn read_text(path: &Path) -> Result<String, SourceError> {
    crate::capped::read_text_capped(path, crate::capped::LIST_CAP)
        .map_err(|e| SourceError::io(path, e))
}

fn is_image(p: &Path) -> bool {
    matches!(
        p.extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase())
            .as_deref(),
        Some("png" | "jpg" | "jpeg")
    )
}

impl ImageListSource {
    /// Opens a folder, recognising its layout: `rgb.txt` (TUM), `mav0/` or `cam0/data.csv`
    /// (EuRoC), or images with a `times.txt`/`timestamps.txt` (plain folder).
    pub fn open(path: &Path) -> Result<Self, SourceError> {
        if !path.is_dir() {
            return Err(SourceError::Invalid {
                path: path.to_path_buf(),
                message: "not a folder (expected a TUM, EuRoC or image folder)".into(),
            });
        }
        if path.join("rgb.txt").is_file() {
            Self::open_tum(path)
        } else if euroc_cam_dir(path).is_some() {
            Self::open_euroc(path)
        } else {
            Self::open_folder(path, None)
        }
    }

    /// TUM RGB-D layout: `rgb.txt` listing images relative to the folder.
    pub fn open_tum(dir: &Path) -> Result<Self, SourceError> {
        let list_path = dir.join("rgb.txt");
        let entries = list::parse_tum(&read_text(&list_path)?, &list_path)?;
        Self::from_entries(dir, &list_path, entries, ListKind::Tum)
    }

    /// EuRoC layout: `dir` is the dataset root, its `mav0`, or `mav0/cam0`.
    pub fn open_euroc(dir: &Path) -> Result<Self, SourceError> {
        let cam = euroc_cam_dir(dir).ok_or_else(|| SourceError::Invalid {
            path: dir.to_path_buf(),
            message: "no EuRoC cam0/data.csv found (looked in ., mav0/, cam0/, mav0/cam0/)".into(),
        })?;
        let list_path = cam.join("data.csv");
        let entries = list::parse_euroc(&read_text(&list_path)?, &list_path)?;
        Self::from_entries(&cam, &list_path, entries, ListKind::Euroc)
    }

    /// A plain folder of PNG/JPEG images with a timestamps file (`times.txt` or
    /// `timestamps.txt` inside it unless given).
    pub fn open_folder(dir: &Path, timestamps: Option<&Path>) -> Result<Self, SourceError> {
        let rd = std::fs::read_dir(dir).map_err(|e| SourceError::io(dir, e))?;
        let mut images: Vec<PathBuf> = rd
            .filter_map(|e| e.ok())
            .map(|e| PathBuf::from(e.file_name()))
            .filter(|p| is_image(p))
            .collect();
        // Numbers in names compare as numbers: `2.jpg` before `10.jpg` (a plain sort pairs
        // `10.jpg` with the third timestamp).
        images.sort_by(|a, b| natural_cmp(&a.to_string_lossy(), &b.to_string_lossy()));
        if images.is_empty() {
            return Err(SourceError::Invalid {
                path: dir.to_path_buf(),
                message: "folder holds no PNG/JPEG images and no rgb.txt or EuRoC data.csv".into(),
            });
        }
        let ts_path = match timestamps {
            Some(p) => p.to_path_buf(),
            None => ["times.txt", "timestamps.txt"]
                .iter()
                .map(|n| dir.join(n))
                .find(|p| p.is_file())
                .ok_or_else(|| SourceError::Invalid {
                    path: dir.to_path_buf(),
                    message: format!(
                        "{} images but no times.txt/timestamps.txt giving their timestamps",
                        images.len()
                    ),
                })?,
        };
        let entries = list::parse_timestamps(&read_text(&ts_path)?, &ts_path, &images)?;
        Self::from_entries(dir, &ts_path, entries, ListKind::Folder)
    }

    fn from_entries(
        base: &Path,
        list_path: &Path,
        entries: Vec<ListEntry>,
        kind: ListKind,
    ) -> Result<Self, SourceError> {
        for e in &entries {
            let f = base.join(&e.file);
            if !f.is_file() {
                let what = if f.exists() {
                    "which is not a file"
                } else {
                    "which does not exist"
                };
                return Err(SourceError::List {
                    path: list_path.to_path_buf(),
                    line: e.line,
                    message: format!("names {} {what}", f.display()),
                });
            }
        }
        // Size and colour from the first decodable image.
        let mut decoder = ImageDecoderBuf::new();
        let mut probe = Frame::new(0, 0);
        let mut first_err = None;
        let mut ok = false;
        for e in entries.iter().take(5) {
            match decoder.read_file(&base.join(&e.file), None, &mut probe) {
                Ok(()) => {
                    ok = true;
                    break;
                }
                Err(err) => {
                    first_err.get_or_insert(err);
                }
            }
        }
        if !ok {
            return Err(first_err.unwrap_or_else(|| SourceError::Invalid {
                path: list_path.to_path_buf(),
                message: "no readable image".into(),
            }));
        }
        let fps = estimate_fps(&entries);
        Ok(ImageListSource {
            info: SourceInfo {
                name: base.display().to_string(),
                width: probe.width,
                height: probe.height,
                fps,
                has_color: probe.has_color,
                len: Some(entries.len()),
            },
            base: base.to_path_buf(),
            entries,
            next: 0,
            decoder,
            kind,
        })
    }

    pub fn kind(&self) -> ListKind {
        self.kind
    }

    /// The folder the list's paths are relative to (for EuRoC, `mav0/cam0`).
    pub fn base(&self) -> &Path {
        &self.base
    }

    /// Timestamps of all frames, in order.
    pub fn timestamps(&self) -> impl Iterator<Item = f64> + '_ {
        self.entries.iter().map(|e| e.timestamp)
    }

    /// Restricts the replay to frames `[start, start+count)`.
    pub fn limit(&mut self, start: usize, count: Option<usize>) {
        let start = start.min(self.entries.len());
        self.entries.drain(..start);
        if let Some(c) = count {
            self.entries.truncate(c);
        }
        self.info.len = Some(self.entries.len());
    }
}

/// Finds the folder holding EuRoC's `data.csv` for cam0 below `dir`.
pub fn euroc_cam_dir(dir: &Path) -> Option<PathBuf> {
    ["", "cam0", "mav0/cam0"]
        .iter()
        .map(|s| {
            if s.is_empty() {
                dir.to_path_buf()
            } else {
                dir.join(s)
            }
        })
        .find(|d| d.join("data.csv").is_file() && d.join("data").is_dir())
}

/// Median frame rate of a list (robust to a few missing frames).
fn estimate_fps(entries: &[ListEntry]) -> f64 {
    let t: Vec<f64> = entries.iter().map(|e| e.timestamp).collect();
    median_rate(&t)
}

/// Median rate of increasing timestamps (30 when there are fewer than two).
pub(crate) fn median_rate(timestamps: &[f64]) -> f64 {
    let mut d: Vec<f64> = timestamps.windows(2).map(|w| w[1] - w[0]).collect();
    if d.is_empty() {
        return 30.0;
    }
    d.sort_by(|a, b| a.total_cmp(b));
    let m = d[d.len() / 2];
    if m > 0.0 {
        1.0 / m
    } else {
        30.0
    }
}

impl FrameSource for ImageListSource {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn next_frame(&mut self, out: &mut Frame) -> Result<FrameStatus, SourceError> {
        let Some(e) = self.entries.get(self.next) else {
            return Ok(FrameStatus::End);
        };
        let index = self.next as u64;
        self.next += 1;
        let path = self.base.join(&e.file);
        let size = Some((self.info.width, self.info.height));
        match self.decoder.read_file(&path, size, out) {
            Ok(()) => {
                out.timestamp = e.timestamp;
                out.index = index;
                Ok(FrameStatus::Ready)
            }
            Err(err) if err.is_frame_local() => Ok(FrameStatus::Skipped {
                index,
                reason: err.to_string(),
            }),
            Err(err) => Err(err),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn image_names_sort_with_numbers_as_numbers() {
        let mut v = vec![
            "10.jpg",
            "2.jpg",
            "0.jpg",
            "1.jpg",
            "frame_11.png",
            "frame_9.png",
            "002.jpg",
        ];
        v.sort_by(|a, b| natural_cmp(a, b));
        assert_eq!(
            v,
            [
                "0.jpg",
                "1.jpg",
                "002.jpg",
                "2.jpg",
                "10.jpg",
                "frame_9.png",
                "frame_11.png"
            ]
        );
        // Zero-padded names (the usual case) keep their plain order.
        let mut w = vec!["000010.png", "000002.png", "000100.png"];
        w.sort_by(|a, b| natural_cmp(a, b));
        assert_eq!(w, ["000002.png", "000010.png", "000100.png"]);
    }
    use std::io::Write;

    fn write_png(path: &Path, w: u32, h: u32, v: u8) {
        image::GrayImage::from_pixel(w, h, image::Luma([v]))
            .save(path)
            .unwrap();
    }

    fn tum_dir(n: usize) -> tempfile::TempDir {
        let d = tempfile::tempdir().unwrap();
        std::fs::create_dir(d.path().join("rgb")).unwrap();
        let mut list = std::fs::File::create(d.path().join("rgb.txt")).unwrap();
        writeln!(list, "# timestamp filename").unwrap();
        for i in 0..n {
            let name = format!("rgb/{i}.png");
            write_png(&d.path().join(&name), 6, 4, i as u8);
            writeln!(list, "{} {name}", 10.0 + i as f64 / 30.0).unwrap();
        }
        d
    }

    #[test]
    fn replays_tum_folder_in_order() {
        let d = tum_dir(3);
        let mut s = ImageListSource::open(d.path()).unwrap();
        assert_eq!(s.kind(), ListKind::Tum);
        assert_eq!((s.info().width, s.info().height), (6, 4));
        assert!((s.info().fps - 30.0).abs() < 1e-6);
        let mut f = Frame::new(6, 4);
        for i in 0..3 {
            assert_eq!(s.next_frame(&mut f).unwrap(), FrameStatus::Ready);
            assert_eq!(f.index, i);
            assert_eq!(f.gray[0], i as u8);
        }
        assert_eq!(s.next_frame(&mut f).unwrap(), FrameStatus::End);
    }

    #[test]
    fn corrupt_frame_is_skipped_not_fatal() {
        let d = tum_dir(3);
        std::fs::write(d.path().join("rgb/1.png"), b"garbage").unwrap();
        let mut s = ImageListSource::open(d.path()).unwrap();
        let mut f = Frame::new(6, 4);
        assert_eq!(s.next_frame(&mut f).unwrap(), FrameStatus::Ready);
        match s.next_frame(&mut f).unwrap() {
            FrameStatus::Skipped { index, reason } => {
                assert_eq!(index, 1);
                assert!(reason.contains("1.png"), "{reason}");
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(s.next_frame(&mut f).unwrap(), FrameStatus::Ready);
        assert_eq!(f.index, 2);
    }

    #[test]
    fn wrong_size_frame_is_skipped() {
        let d = tum_dir(2);
        write_png(&d.path().join("rgb/1.png"), 7, 4, 0);
        let mut s = ImageListSource::open(d.path()).unwrap();
        let mut f = Frame::new(6, 4);
        s.next_frame(&mut f).unwrap();
        assert!(matches!(
            s.next_frame(&mut f).unwrap(),
            FrameStatus::Skipped { .. }
        ));
    }

    #[test]
    fn missing_file_names_list_line() {
        let d = tum_dir(2);
        std::fs::remove_file(d.path().join("rgb/1.png")).unwrap();
        let e = ImageListSource::open(d.path()).err().unwrap().to_string();
        assert!(
            e.contains("rgb.txt:3") && e.contains("does not exist"),
            "{e}"
        );
    }

    #[test]
    fn missing_list_and_empty_folder_are_clear_errors() {
        let d = tempfile::tempdir().unwrap();
        let e = ImageListSource::open(d.path()).err().unwrap().to_string();
        assert!(e.contains("no PNG/JPEG"), "{e}");
        let e = ImageListSource::open_tum(d.path())
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("rgb.txt"), "{e}");
        let e = ImageListSource::open(&d.path().join("nope"))
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("not a folder"), "{e}");
    }

    #[test]
    fn plain_folder_with_timestamps() {
        let d = tempfile::tempdir().unwrap();
        write_png(&d.path().join("b.png"), 5, 5, 2);
        write_png(&d.path().join("a.png"), 5, 5, 1);
        std::fs::write(d.path().join("times.txt"), "0.0\n0.05\n").unwrap();
        let mut s = ImageListSource::open(d.path()).unwrap();
        assert_eq!(s.kind(), ListKind::Folder);
        assert!((s.info().fps - 20.0).abs() < 1e-6);
        let mut f = Frame::new(5, 5);
        s.next_frame(&mut f).unwrap();
        assert_eq!(f.gray[0], 1);
        std::fs::remove_file(d.path().join("times.txt")).unwrap();
        let e = ImageListSource::open(d.path()).err().unwrap().to_string();
        assert!(e.contains("times.txt"), "{e}");
    }

    #[test]
    fn limit_restricts_range() {
        let d = tum_dir(5);
        let mut s = ImageListSource::open(d.path()).unwrap();
        s.limit(1, Some(2));
        assert_eq!(s.info().len, Some(2));
        let mut f = Frame::new(6, 4);
        s.next_frame(&mut f).unwrap();
        assert_eq!(f.gray[0], 1);
    }
}
