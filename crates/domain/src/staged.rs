//! Output directories built beside their target and published by rename: a reader never sees a
//! half-written one, a failure leaves the previous contents intact, and publishing over an
//! earlier output replaces that output's own files without deleting anything else.
//!
//! [`Staged::create`] makes the hidden directory `.<name>.partial` beside the target `name`; the
//! caller writes into [`Staged::path`] and ends with [`Staged::publish`], naming the entries that
//! the target's previous publication owns (a scene's arrays, a run's manifest). Publishing
//!
//! 1. moves every entry of the old target that the previous publication does not own (a file the
//!    user put there) into the staging directory; if the new output writes an entry of the same
//!    name, publishing is refused before anything moves;
//! 2. renames the old target to `.<name>.old`, then the staging directory to `name`;
//! 3. removes `.<name>.old`, which now holds only the previous publication's own entries.
//!
//! A failure during 1 or 2 moves everything back. Dropping an unpublished [`Staged`] removes its
//! staging directory. A staging directory left by a process that was killed is removed by the
//! next [`Staged::create`] (reported by [`Staged::replaced_leftover`]); one whose writer is still
//! running (Linux: its pid is alive) is refused.

use crate::{Error, Result};
use std::collections::BTreeSet;
use std::ffi::{OsStr, OsString};
use std::fs;
use std::path::{Path, PathBuf};

/// The file inside a staging directory that names the process writing it.
const WRITER_FILE: &str = ".prism-writer";

/// A directory being written beside its target (see the module docs).
#[derive(Debug)]
pub struct Staged {
    target: PathBuf,
    staging: PathBuf,
    parent: PathBuf,
    name: OsString,
    replaced_leftover: bool,
    published: bool,
}

impl Staged {
    /// Start writing `target`: creates its parent if needed and an empty staging directory.
    pub fn create(target: &Path) -> Result<Self> {
        let name = target
            .file_name()
            .filter(|n| *n != OsStr::new(".") && *n != OsStr::new(".."))
            .ok_or_else(|| {
                Error::invalid(
                    "output",
                    format!("`{}` does not name a directory", target.display()),
                )
            })?
            .to_os_string();
        let parent = match target.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        fs::create_dir_all(&parent).map_err(|e| Error::io(&parent, e))?;
        if target.exists() && !target.is_dir() {
            return Err(Error::invalid(
                "output",
                format!("`{}` exists and is not a directory", target.display()),
            ));
        }
        let staging = parent.join(hidden(&name, "partial"));
        let mut replaced_leftover = false;
        if staging.exists() {
            if let Some(pid) = live_writer(&staging) {
                return Err(Error::invalid(
                    "output",
                    format!(
                        "another prism process (pid {pid}) is writing `{}` (in {})",
                        target.display(),
                        staging.display()
                    ),
                ));
            }
            fs::remove_dir_all(&staging).map_err(|e| Error::io(&staging, e))?;
            replaced_leftover = true;
        }
        fs::create_dir(&staging).map_err(|e| Error::io(&staging, e))?;
        let writer = staging.join(WRITER_FILE);
        fs::write(&writer, std::process::id().to_string()).map_err(|e| Error::io(&writer, e))?;
        Ok(Staged {
            target: target.to_path_buf(),
            staging,
            parent,
            name,
            replaced_leftover,
            published: false,
        })
    }

    /// Where the output is being written.
    pub fn path(&self) -> &Path {
        &self.staging
    }

    /// The directory the output is published to.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Whether [`Staged::create`] removed the staging directory of an interrupted earlier writer.
    pub fn replaced_leftover(&self) -> bool {
        self.replaced_leftover
    }

    /// Publish the output (see the module docs). `owned` gives, for the existing target, the
    /// names of its entries that the previous publication wrote (they are replaced; every other
    /// entry is kept).
    pub fn publish(self, owned: impl Fn(&Path) -> Result<BTreeSet<OsString>>) -> Result<()> {
        self.publish_with(owned, |_| Ok(()))
    }

    /// [`Staged::publish`] with a hook called at `"kept"` (foreign entries moved in) and
    /// `"swapped"` (old target moved aside): tests inject failures there.
    pub fn publish_with(
        mut self,
        owned: impl Fn(&Path) -> Result<BTreeSet<OsString>>,
        hook: impl Fn(&str) -> Result<()>,
    ) -> Result<()> {
        let writer = self.staging.join(WRITER_FILE);
        fs::remove_file(&writer).map_err(|e| Error::io(&writer, e))?;
        if !self.target.exists() {
            fs::rename(&self.staging, &self.target).map_err(|e| Error::io(&self.target, e))?;
            self.published = true;
            sync_dir(&self.parent);
            return Ok(());
        }
        let owned = owned(&self.target)?;
        let foreign: Vec<OsString> = entries(&self.target)?
            .into_iter()
            .filter(|n| !owned.contains(n))
            .collect();
        if let Some(clash) = foreign.iter().find(|n| self.staging.join(n).exists()) {
            return Err(Error::invalid(
                "output",
                format!(
                    "`{}` holds `{}`, which this output would overwrite but which an earlier \
                     output did not write; move it away first",
                    self.target.display(),
                    clash.to_string_lossy()
                ),
            ));
        }
        // A leftover of an earlier publication is cleared before anything moves, so that a
        // leftover that cannot be removed stops publishing with every file where it was.
        let old = self.parent.join(hidden(&self.name, "old"));
        if old.exists() {
            fs::remove_dir_all(&old).map_err(|e| Error::io(&old, e))?;
        }
        let mut moved = Vec::new();
        let result = (|| {
            for n in &foreign {
                fs::rename(self.target.join(n), self.staging.join(n))
                    .map_err(|e| Error::io(self.target.join(n), e))?;
                moved.push(n.clone());
            }
            hook("kept")
        })();
        let put_back = |moved: &[OsString]| {
            for n in moved {
                let _ = fs::rename(self.staging.join(n), self.target.join(n));
            }
        };
        if let Err(e) = result {
            put_back(&moved);
            return Err(e);
        }
        if let Err(e) = fs::rename(&self.target, &old).map_err(|e| Error::io(&self.target, e)) {
            put_back(&moved);
            return Err(e);
        }
        let swapped = hook("swapped").and_then(|()| {
            fs::rename(&self.staging, &self.target).map_err(|e| Error::io(&self.target, e))
        });
        if let Err(e) = swapped {
            if let Err(r) = fs::rename(&old, &self.target) {
                // The user's files stay in the staging directory, which is then kept.
                self.published = true;
                return Err(Error::io(
                    &old,
                    std::io::Error::other(format!(
                        "{r}, after {e}: the previous output is in `{}`, the files kept from it \
                         in `{}`",
                        old.display(),
                        self.staging.display()
                    )),
                ));
            }
            put_back(&moved);
            return Err(e);
        }
        self.published = true;
        sync_dir(&self.parent);
        fs::remove_dir_all(&old).map_err(|e| Error::io(&old, e))
    }
}

impl Drop for Staged {
    fn drop(&mut self) {
        if !self.published {
            let _ = fs::remove_dir_all(&self.staging);
        }
    }
}

/// `.<name>.<what>`.
fn hidden(name: &OsStr, what: &str) -> OsString {
    let mut s = OsString::from(".");
    s.push(name);
    s.push(".");
    s.push(what);
    s
}

/// The names of a directory's entries.
pub fn entries(dir: &Path) -> Result<Vec<OsString>> {
    let mut names = Vec::new();
    for e in fs::read_dir(dir).map_err(|e| Error::io(dir, e))? {
        names.push(e.map_err(|e| Error::io(dir, e))?.file_name());
    }
    names.sort();
    Ok(names)
}

/// The pid recorded in a staging directory, if that process is alive and is not this one. Only
/// Linux can tell (through `/proc`); elsewhere a leftover is taken to be stale.
fn live_writer(staging: &Path) -> Option<u32> {
    let pid: u32 = fs::read_to_string(staging.join(WRITER_FILE))
        .ok()?
        .trim()
        .parse()
        .ok()?;
    let alive = Path::new("/proc").join(pid.to_string()).exists();
    (alive && pid != std::process::id()).then_some(pid)
}

/// Replace the file `path` with `bytes` atomically: written to the hidden sibling
/// `.<name>.partial`, flushed, then renamed over `path`. A reader sees the old file or the new
/// one, never a part; a failure leaves the old file as it was.
pub fn replace_file(path: &Path, bytes: &[u8]) -> Result<()> {
    let name = path
        .file_name()
        .ok_or_else(|| Error::invalid("path", format!("{} names no file", path.display())))?;
    let staged = path.with_file_name(format!(".{}.partial", name.to_string_lossy()));
    let write = || -> std::io::Result<()> {
        let mut f = fs::File::create(&staged)?;
        std::io::Write::write_all(&mut f, bytes)?;
        f.sync_all()
    };
    if let Err(e) = write().and_then(|()| fs::rename(&staged, path)) {
        let _ = fs::remove_file(&staged);
        return Err(Error::io(path, e));
    }
    if let Some(dir) = path.parent() {
        sync_dir(dir);
    }
    Ok(())
}

/// Refuse an output `path` that exists (a file, a directory or a link, even a dangling one):
/// what a command without `--force` must not replace.
pub fn refuse_existing(path: &Path) -> Result<()> {
    if fs::symlink_metadata(path).is_ok() {
        return Err(Error::invalid(
            "output",
            format!("`{}` exists; pass --force to replace it", path.display()),
        ));
    }
    Ok(())
}

/// Write the new file `path` atomically ([`replace_file`]); an existing file is refused unless
/// `force` (the command's `--force`), so a command never silently replaces a file it was not
/// asked to.
pub fn publish_file(path: &Path, bytes: &[u8], force: bool) -> Result<()> {
    if !force {
        refuse_existing(path)?;
    }
    if path.is_dir() {
        return Err(Error::invalid(
            "output",
            format!("`{}` is a directory", path.display()),
        ));
    }
    replace_file(path, bytes)
}

/// Flush a directory's entries (best effort: not every platform can open a directory).
pub fn sync_dir(dir: &Path) {
    if let Ok(d) = fs::File::open(dir) {
        let _ = d.sync_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_replaced_file_holds_the_new_bytes_and_no_staging_is_left() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("metrics.json");
        fs::write(&path, "old").unwrap();
        replace_file(&path, b"new").unwrap();
        assert_eq!(fs::read_to_string(&path).unwrap(), "new");
        assert_eq!(names(dir.path()), vec!["metrics.json"]);
        // A target that cannot be written keeps nothing behind.
        let missing = dir.path().join("no-such-dir").join("f");
        assert!(replace_file(&missing, b"x").is_err());
        assert_eq!(names(dir.path()), vec!["metrics.json"]);
    }

    fn names(dir: &Path) -> Vec<String> {
        entries(dir)
            .unwrap()
            .into_iter()
            .map(|n| n.to_string_lossy().into_owned())
            .collect()
    }

    fn owned(list: &'static [&'static str]) -> impl Fn(&Path) -> Result<BTreeSet<OsString>> {
        move |_| Ok(list.iter().map(OsString::from).collect())
    }

    #[test]
    fn publishing_replaces_owned_entries_and_keeps_the_users() {
        let tmp = tempfile::tempdir().unwrap();
        let target = tmp.path().join("out");
        let s = Staged::create(&target).unwrap();
        fs::write(s.path().join("a.npy"), "1").unwrap();
        fs::write(s.path().join("stale.npy"), "1").unwrap();
        s.publish(owned(&[])).unwrap();
        assert_eq!(names(&target), ["a.npy", "stale.npy"]);
        fs::write(target.join("notes.txt"), "mine").unwrap();

        let s = Staged::create(&target).unwrap();
        fs::write(s.path().join("a.npy"), "2").unwrap();
        s.publish(owned(&["a.npy", "stale.npy"])).unwrap();
        assert_eq!(names(&target), ["a.npy", "notes.txt"]);
        assert_eq!(fs::read_to_string(target.join("a.npy")).unwrap(), "2");
        assert_eq!(
            fs::read_to_string(target.join("notes.txt")).unwrap(),
            "mine"
        );
        assert_eq!(
            names(tmp.path()),
            ["out"],
            "no staging or old directory left"
        );
    }

    #[test]
    fn a_failure_or_a_clash_leaves_the_old_output_intact() {
        let tmp = tempfile::tempdir().unwrap();
        let target = tmp.path().join("out");
        fs::create_dir(&target).unwrap();
        fs::write(target.join("a.npy"), "old").unwrap();
        fs::write(target.join("notes.txt"), "mine").unwrap();
        for stage in ["kept", "swapped"] {
            let s = Staged::create(&target).unwrap();
            fs::write(s.path().join("a.npy"), "new").unwrap();
            let e = s
                .publish_with(owned(&["a.npy"]), |at| {
                    if at == stage {
                        Err(Error::invalid("test", format!("injected at {at}")))
                    } else {
                        Ok(())
                    }
                })
                .unwrap_err();
            assert!(e.to_string().contains(stage), "{e}");
            assert_eq!(names(&target), ["a.npy", "notes.txt"], "{stage}");
            assert_eq!(fs::read_to_string(target.join("a.npy")).unwrap(), "old");
            assert_eq!(names(tmp.path()), ["out"], "{stage}: leftovers");
        }
        // `notes.txt` was not written by the earlier output: the new one may not overwrite it.
        let s = Staged::create(&target).unwrap();
        fs::write(s.path().join("notes.txt"), "generated").unwrap();
        let e = s.publish(owned(&["a.npy"])).unwrap_err().to_string();
        assert!(e.contains("notes.txt"), "{e}");
        assert_eq!(
            fs::read_to_string(target.join("notes.txt")).unwrap(),
            "mine"
        );
        // Dropping an unpublished output removes it.
        let s = Staged::create(&target).unwrap();
        fs::write(s.path().join("x"), "").unwrap();
        drop(s);
        assert_eq!(names(tmp.path()), ["out"]);
    }

    #[test]
    fn a_killed_writers_leftover_is_replaced_and_a_live_one_refused() {
        let tmp = tempfile::tempdir().unwrap();
        let target = tmp.path().join("out");
        let leftover = tmp.path().join(".out.partial");
        fs::create_dir(&leftover).unwrap();
        // A pid far above Linux's pid_max is never alive.
        fs::write(leftover.join(WRITER_FILE), "4294967295").unwrap();
        fs::write(leftover.join("half.npy"), "").unwrap();
        let s = Staged::create(&target).unwrap();
        assert!(s.replaced_leftover());
        assert!(names(s.path()).iter().all(|n| n != "half.npy"));
        drop(s);
        if Path::new("/proc/1").exists() {
            fs::create_dir(&leftover).unwrap();
            fs::write(leftover.join(WRITER_FILE), "1").unwrap();
            let e = Staged::create(&target).unwrap_err().to_string();
            assert!(e.contains("pid 1"), "{e}");
        }
    }
}
