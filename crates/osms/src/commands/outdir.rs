//! Directories osms writes for people (reports, dataset exports): written beside the target
//! and swapped in once complete, so an interrupted write leaves the previous one whole, and
//! only ever replacing a directory that is empty or that osms wrote (it holds a marker), so
//! `--out ~/results` can never remove someone's files.

use std::path::{Path, PathBuf};

use anyhow::{Context as _, Result, bail};

/// A kind of directory osms writes, named by its marker file.
#[derive(Debug, Clone, Copy)]
pub struct Marker {
    /// The marker's file name inside the directory.
    pub file: &'static str,
    /// What the directory is, for messages ("report directory").
    pub what: &'static str,
}

/// Whether `dir` may be replaced: it is empty or holds `marker`.
pub fn replaceable(dir: &Path, marker: Marker) -> Result<bool> {
    if !dir.is_dir() {
        return Ok(false);
    }
    let mut entries =
        std::fs::read_dir(dir).with_context(|| format!("cannot read {}", dir.display()))?;
    Ok(entries.next().is_none() || dir.join(marker.file).is_file())
}

/// Fails unless `dir` is new, empty or one osms wrote, before any work starts.
pub fn check(dir: &Path, marker: Marker) -> Result<()> {
    if dir.exists() && !replaceable(dir, marker)? {
        bail!(
            "{} exists and is not a {} osms wrote (no {} in it)\nhint: pass an empty or new directory to --out",
            dir.display(),
            marker.what,
            marker.file
        );
    }
    Ok(())
}

/// Writes `dir` through `fill`, which fills a fresh sibling directory (holding only the hidden
/// marker) and returns the paths it wrote (relative to it), then swaps it in. Returns the written paths under `dir`.
pub fn replace(
    dir: &Path,
    marker: Marker,
    fill: impl FnOnce(&Path) -> Result<Vec<PathBuf>>,
) -> Result<Vec<PathBuf>> {
    check(dir, marker)?;
    let parent = match dir.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    std::fs::create_dir_all(parent)
        .with_context(|| format!("cannot create {}", parent.display()))?;
    let name = dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .with_context(|| format!("{} names no directory", dir.display()))?;
    let partial = parent.join(format!(".{name}.partial"));
    let old = parent.join(format!(".{name}.old"));
    // A make killed between the two renames below leaves the previous directory only as
    // `.old`: put it back first.
    if !dir.exists() && old.join(marker.file).is_file() {
        std::fs::rename(&old, dir)
            .with_context(|| format!("cannot restore {} from {}", dir.display(), old.display()))?;
    }
    for leftover in [&partial, &old] {
        if leftover.exists() {
            if !replaceable(leftover, marker)? {
                bail!(
                    "{} is in the way and is not a {} osms wrote\nhint: move it away, osms writes beside --out through it",
                    leftover.display(),
                    marker.what
                );
            }
            std::fs::remove_dir_all(leftover)
                .with_context(|| format!("cannot remove {}", leftover.display()))?;
        }
    }
    std::fs::create_dir_all(&partial)
        .with_context(|| format!("cannot create {}", partial.display()))?;
    // The marker first: a leftover of an interrupted write is then osms's to remove.
    let marker_path = partial.join(marker.file);
    std::fs::write(
        &marker_path,
        format!("written by osms; osms may replace this {}\n", marker.what),
    )
    .with_context(|| format!("cannot write {}", marker_path.display()))?;
    let written = match fill(&partial) {
        Ok(w) => w,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&partial);
            return Err(e);
        }
    };
    if dir.exists()
        && let Err(e) = std::fs::rename(dir, &old)
    {
        let _ = std::fs::remove_dir_all(&partial);
        return Err(e).with_context(|| format!("cannot move {} aside", dir.display()));
    }
    if let Err(e) = std::fs::rename(&partial, dir) {
        // Put the previous directory back before failing.
        let _ = std::fs::rename(&old, dir);
        let _ = std::fs::remove_dir_all(&partial);
        return Err(e).with_context(|| format!("cannot write {}", dir.display()));
    }
    if old.exists() {
        std::fs::remove_dir_all(&old)
            .with_context(|| format!("cannot remove {}", old.display()))?;
    }
    Ok(written.into_iter().map(|p| dir.join(p)).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    const M: Marker = Marker {
        file: ".osms-test",
        what: "test directory",
    };

    #[test]
    fn only_empty_or_osms_written_directories_are_replaced() {
        let root = tempfile::tempdir().expect("dir");
        let dir = root.path().join("out");
        std::fs::create_dir(&dir).expect("mkdir");
        assert!(replaceable(&dir, M).expect("empty"));
        std::fs::write(dir.join("notes.txt"), "mine").expect("write");
        assert!(!replaceable(&dir, M).expect("someone's files"));
        let err = replace(&dir, M, |_| Ok(Vec::new())).expect_err("refused");
        assert!(
            err.to_string().contains("not a test directory osms wrote"),
            "{err}"
        );
        assert!(dir.join("notes.txt").is_file());
        std::fs::write(dir.join(M.file), "").expect("marker");
        assert!(replaceable(&dir, M).expect("osms wrote it"));
        assert!(!replaceable(&dir.join(M.file), M).expect("a file"));
    }

    #[test]
    fn a_failed_fill_leaves_the_previous_directory_whole() {
        let root = tempfile::tempdir().expect("dir");
        let dir = root.path().join("out");
        let first = replace(&dir, M, |p| {
            std::fs::write(p.join("a.txt"), "one")?;
            Ok(vec!["a.txt".into()])
        })
        .expect("first");
        assert_eq!(first, vec![dir.join("a.txt")]);
        let err = replace(&dir, M, |p| {
            std::fs::write(p.join("a.txt"), "two")?;
            bail!("interrupted")
        })
        .expect_err("fails");
        assert_eq!(err.to_string(), "interrupted");
        assert_eq!(
            std::fs::read_to_string(dir.join("a.txt")).expect("read"),
            "one"
        );
        let entries: Vec<_> = std::fs::read_dir(root.path())
            .expect("ls")
            .map(|e| e.expect("entry").file_name())
            .collect();
        assert_eq!(entries, vec![std::ffi::OsString::from("out")]);
    }

    #[test]
    fn leftovers_are_removed_only_when_osms_wrote_them_and_an_old_copy_is_restored() {
        let root = tempfile::tempdir().expect("dir");
        let dir = root.path().join("out");
        let theirs = root.path().join(".out.partial");
        std::fs::create_dir(&theirs).expect("mkdir");
        std::fs::write(theirs.join("keep.txt"), "mine").expect("write");
        let err = replace(&dir, M, |_| Ok(Vec::new())).expect_err("in the way");
        assert!(err.to_string().contains("is in the way"), "{err}");
        assert!(theirs.join("keep.txt").is_file());
        std::fs::remove_dir_all(&theirs).expect("rm");

        // A write killed between moving the old directory aside and swapping the new one in.
        let old = root.path().join(".out.old");
        std::fs::create_dir(&old).expect("mkdir");
        std::fs::write(old.join(M.file), "").expect("marker");
        std::fs::write(old.join("a.txt"), "one").expect("write");
        let err = replace(&dir, M, |_| bail!("interrupted")).expect_err("fails");
        assert_eq!(err.to_string(), "interrupted");
        assert_eq!(
            std::fs::read_to_string(dir.join("a.txt")).expect("restored"),
            "one"
        );
    }
}
