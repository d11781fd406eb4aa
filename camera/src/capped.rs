//! Bounded reads: every input file is read with a size limit fitting what it can hold, so a
//! padded, corrupt or endless input (`/dev/zero`, a 3 GB "PNG") is refused with a message
//! instead of exhausting memory.

use std::io::Read;
use std::path::Path;

/// Text inputs of a person's making: calibrations, configurations.
pub const SETTINGS_CAP: u64 = 16 << 20;
/// Lists and trajectories (80 bytes a line: ten million lines).
pub const LIST_CAP: u64 = 1 << 30;
/// Vocabularies (ORB-SLAM's text `ORBvoc.txt` is 145 MB), saved maps, point clouds.
pub const BULK_CAP: u64 = 1 << 30;

/// Reads `path` whole, refusing (`InvalidData`) a file longer than `cap` bytes after reading
/// at most `cap + 1` of them.
pub fn read_capped(path: &Path, cap: u64) -> std::io::Result<Vec<u8>> {
    let f = std::fs::File::open(path)?;
    let hint = f.metadata().map(|m| m.len()).unwrap_or(0).min(cap);
    let mut bytes = Vec::with_capacity(hint as usize);
    f.take(cap + 1).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > cap {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "larger than {} MB, more than such a file can hold",
                cap >> 20
            ),
        ));
    }
    Ok(bytes)
}

/// The first `n` bytes of `path` (fewer if it is shorter): to recognise a format before
/// reading a large file whole.
pub fn read_head(path: &Path, n: usize) -> std::io::Result<Vec<u8>> {
    let mut head = Vec::with_capacity(n);
    std::fs::File::open(path)?
        .take(n as u64)
        .read_to_end(&mut head)?;
    Ok(head)
}

/// [`read_capped`] for UTF-8 text (a UTF-8 byte-order mark is dropped).
pub fn read_text_capped(path: &Path, cap: u64) -> std::io::Result<String> {
    let bytes = read_capped(path, cap)?;
    let mut text = String::from_utf8(bytes).map_err(|e| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "not UTF-8 text (invalid byte at offset {})",
                e.utf8_error().valid_up_to()
            ),
        )
    })?;
    if text.starts_with('\u{feff}') {
        text.drain(..3);
    }
    Ok(text)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_endless_file_is_refused_after_the_cap() {
        let e = read_capped(Path::new("/dev/zero"), 1 << 20).unwrap_err();
        assert_eq!(e.kind(), std::io::ErrorKind::InvalidData);
        assert!(e.to_string().contains("larger than 1 MB"), "{e}");
    }

    #[test]
    fn a_byte_order_mark_is_dropped_and_short_files_are_read_whole() {
        let p = std::env::temp_dir().join(format!("sdslam-capped-{}", std::process::id()));
        std::fs::write(&p, "\u{feff}%YAML:1.0\n").unwrap();
        assert_eq!(read_text_capped(&p, 100).unwrap(), "%YAML:1.0\n");
        assert!(read_capped(&p, 5).is_err());
        let _ = std::fs::remove_file(&p);
    }
}
