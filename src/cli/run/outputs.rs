//! The output folder of `sdslam run`: checked before any work, cleared of an earlier run's
//! outputs, and written one file at a time so that one failing output (a full disk, a file
//! size limit, a folder where a file should be) is reported and the others are still written.

use std::path::{Path, PathBuf};

use sdslam::{Error, Result};

/// Every file `sdslam run` writes into its output folder (plus `depth/*.png`).
pub const RUN_OUTPUTS: [&str; 9] = [
    "groundtruth.txt",
    "trajectory.txt",
    "keyframes.txt",
    "report.json",
    "semidense.ply",
    "semidense_online.ply",
    "trajectory.png",
    "cloud.png",
    "timing.png",
];

/// `trajectory_map<id>.txt` or `keyframes_map<id>.txt`: poses of a map other than the primary.
fn is_map_output(name: &str) -> bool {
    ["trajectory_map", "keyframes_map"].iter().any(|prefix| {
        name.strip_prefix(prefix)
            .and_then(|r| r.strip_suffix(".txt"))
            .is_some_and(|id| !id.is_empty() && id.bytes().all(|b| b.is_ascii_digit()))
    })
}

/// The output folder and the writes that failed so far.
pub struct Outputs {
    dir: PathBuf,
    failures: Vec<String>,
}

impl Outputs {
    /// Creates `dir` and checks, before any frame is processed, that every output can be
    /// written: the folder is writable and not the source folder, no output name is taken by
    /// a folder, `depth` is a folder if it exists, and `save_map`'s folder exists and is
    /// writable. Then removes the outputs of an earlier run in `dir` (a reused folder must
    /// not mix a new trajectory with an old report or another sequence's ground truth).
    pub fn prepare(dir: &Path, source: Option<&str>, save_map: Option<&Path>) -> Result<Self> {
        if dir.exists() && !dir.is_dir() {
            return Err(Error::Invalid(format!(
                "--out {}: is a file, not a folder (choose another output folder)",
                dir.display()
            )));
        }
        if let Some(src) = source.map(Path::new).filter(|p| p.is_dir()) {
            if same_folder(src, dir) {
                return Err(Error::Invalid(format!(
                    "--out {}: is the source folder; its groundtruth.txt would be overwritten (choose another output folder)",
                    dir.display()
                )));
            }
        }
        sdslam::io::prepare_output_dir(dir)?;
        for name in RUN_OUTPUTS {
            let p = dir.join(name);
            if p.is_dir() {
                return Err(Error::Invalid(format!(
                    "{}: is a folder, but sdslam writes its {name} output there (remove it or choose another --out)",
                    p.display()
                )));
            }
        }
        let depth = dir.join("depth");
        if depth.exists() && !depth.is_dir() {
            return Err(Error::Invalid(format!(
                "{}: is a file, but depth maps are written into a folder of that name (remove it or choose another --out)",
                depth.display()
            )));
        }
        if let Some(map) = save_map {
            check_writable_file(map, "--save-map")?;
        }
        for name in RUN_OUTPUTS {
            remove_if_present(&dir.join(name))?;
        }
        // Other atlas maps' poses of an earlier run (`trajectory_map<id>.txt`, `keyframes_map<id>.txt`).
        if let Ok(entries) = std::fs::read_dir(dir) {
            for e in entries.flatten() {
                let name = e.file_name();
                let name = name.to_string_lossy();
                if is_map_output(&name) {
                    remove_if_present(&e.path())?;
                }
            }
        }
        if let Ok(entries) = std::fs::read_dir(&depth) {
            for e in entries.flatten() {
                let p = e.path();
                if p.extension().is_some_and(|x| x == "png") {
                    remove_if_present(&p)?;
                }
            }
        }
        Ok(Outputs {
            dir: dir.to_path_buf(),
            failures: Vec::new(),
        })
    }

    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Writes output `name` (a file in the folder) with `write`; a failure is reported at
    /// once and remembered, and does not stop the other outputs.
    pub fn write(&mut self, name: &str, write: impl FnOnce(&Path) -> Result<()>) -> bool {
        let path = self.path(name);
        self.write_at(name, &path, write)
    }

    /// As [`write`](Self::write), for an output outside the folder (`--save-map FILE`).
    /// `SDSLAM_FAULT=write:NAME` makes the write of output NAME fail (tests of this path).
    pub fn write_at(
        &mut self,
        name: &str,
        path: &Path,
        write: impl FnOnce(&Path) -> Result<()>,
    ) -> bool {
        let result = if sdslam::runtime::faults::injected(&format!("write:{name}")) {
            Err(Error::io(
                path,
                std::io::Error::other("injected write failure (SDSLAM_FAULT)"),
            ))
        } else {
            write(path)
        };
        match result {
            Ok(()) => true,
            Err(e) => {
                note!("error: {name} not written: {e}");
                self.failures.push(format!("{name}: {e}"));
                false
            }
        }
    }

    /// The writes that failed, one line each.
    pub fn failures(&self) -> &[String] {
        &self.failures
    }
}

fn same_folder(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    }
}

fn remove_if_present(p: &Path) -> Result<()> {
    match std::fs::remove_file(p) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(Error::Invalid(format!(
            "{}: an earlier run's output could not be removed: {e}",
            p.display()
        ))),
    }
}

/// `path` can be created: not a folder, its folder exists and accepts a new file.
pub fn check_writable_file(path: &Path, option: &str) -> Result<()> {
    if path.is_dir() {
        return Err(Error::Invalid(format!(
            "{option} {}: is a folder; give a file name",
            path.display()
        )));
    }
    let parent = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    if !parent.is_dir() {
        return Err(Error::Invalid(format!(
            "{option} {}: folder {} does not exist",
            path.display(),
            parent.display()
        )));
    }
    let probe = parent.join(format!(".sdslam-write-test{}", std::process::id()));
    std::fs::write(&probe, b"").map_err(|e| {
        Error::Invalid(format!(
            "{option} {}: folder {} is not writable: {e}",
            path.display(),
            parent.display()
        ))
    })?;
    let _ = std::fs::remove_file(probe);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("sdslam-outputs-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    #[test]
    fn an_earlier_runs_outputs_are_removed_and_other_files_kept() {
        let d = scratch("stale");
        std::fs::create_dir_all(d.join("depth")).unwrap();
        std::fs::write(d.join("groundtruth.txt"), "old").unwrap();
        std::fs::write(d.join("depth/1.000000.png"), "old").unwrap();
        std::fs::write(d.join("notes.txt"), "mine").unwrap();
        Outputs::prepare(&d, None, None).unwrap();
        assert!(!d.join("groundtruth.txt").exists());
        assert!(!d.join("depth/1.000000.png").exists());
        assert!(d.join("notes.txt").exists());
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn unwritable_layouts_are_refused_before_the_run() {
        let d = scratch("layout");
        std::fs::create_dir_all(d.join("trajectory.txt")).unwrap();
        let e = Outputs::prepare(&d, None, None).err().unwrap().to_string();
        assert!(
            e.contains("trajectory.txt") && e.contains("is a folder"),
            "{e}"
        );
        std::fs::remove_dir_all(d.join("trajectory.txt")).unwrap();
        std::fs::write(d.join("depth"), "").unwrap();
        let e = Outputs::prepare(&d, None, None).err().unwrap().to_string();
        assert!(e.contains("depth") && e.contains("is a file"), "{e}");
        std::fs::remove_file(d.join("depth")).unwrap();
        let map = d.join("missing/map.bin");
        let e = Outputs::prepare(&d, None, Some(&map))
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains("--save-map") && e.contains("does not exist"),
            "{e}"
        );
        let src = d.to_string_lossy().to_string();
        let e = Outputs::prepare(&d, Some(&src), None)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("source folder"), "{e}");
        let file = d.join("afile");
        std::fs::write(&file, "").unwrap();
        let e = Outputs::prepare(&file, None, None)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("is a file, not a folder"), "{e}");
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn a_failed_write_is_remembered_and_the_next_one_still_happens() {
        let d = scratch("failing");
        let mut o = Outputs::prepare(&d, None, None).unwrap();
        let bad = o.write("a.txt", |p| {
            Err(Error::io(p, std::io::Error::other("disk full")))
        });
        let good = o.write("b.txt", |p| sdslam::io::write_atomic(p, b"x"));
        assert!(!bad && good);
        assert_eq!(o.failures().len(), 1);
        assert!(o.failures()[0].contains("disk full"));
        assert!(d.join("b.txt").exists());
        let _ = std::fs::remove_dir_all(&d);
    }
}
