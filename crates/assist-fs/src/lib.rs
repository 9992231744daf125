//! Output folders that never lose what a user had.
//!
//! Every folder assist writes (a scene `NAME.assist/`, a rendered or synthesised dataset, a
//! demo) goes through this crate:
//!
//! - [`lock`]: an exclusive lock on `PARENT/.NAME.lock` (the OS's advisory file lock, so a
//!   killed holder releases it) for as long as a command reads, changes and writes `NAME`.
//!   A second process gets [`FsError::Busy`] naming the holder's pid and command. Locks are
//!   re-entrant within one process (a command that holds a scene's lock may save it).
//! - [`check_replaceable`]: an existing non-empty folder is replaced only with `force`, and
//!   only when it carries assist's [`MARKER`] (or is a scene assist wrote); anything else is
//!   [`FsError::NotOurs`] and is left alone.
//! - [`Staging`]: the new content is written into `PARENT/.NAME.tmp-PID`, then swapped into
//!   place (the old folder moved aside, the new one renamed in, the old one removed), so a
//!   reader or a kill sees either the old folder or the new one, never a mix. Temporaries a
//!   killed writer left behind are removed by the next writer of the same name (which holds
//!   the lock, so no live process can still own them).
//! - [`check_space`]: free space before long work.

use std::collections::BTreeMap;
use std::fs::{File, OpenOptions};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// The file that marks a folder as written by assist.
pub const MARKER: &str = ".assist-output";

#[derive(Debug, thiserror::Error)]
pub enum FsError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(
        "{path}: line {line}, byte {offset}: not UTF-8 text (byte 0x{byte:02x}); save the file as UTF-8"
    )]
    NotUtf8 {
        path: PathBuf,
        line: usize,
        offset: usize,
        byte: u8,
    },
    #[error("{path} already exists (pass --force to replace it)")]
    Exists { path: PathBuf },
    #[error(
        "{path} exists and was not written by assist (no {MARKER} marker in it); --force replaces only folders assist wrote: move it away or choose another output"
    )]
    NotOurs { path: PathBuf },
    #[error(
        "{path} holds {found}, not {expected}: --force replaces only an earlier output of the same kind; choose another output"
    )]
    OtherKind {
        path: PathBuf,
        found: Kind,
        expected: Kind,
    },
    #[error(
        "{path} is, or holds, this command's input {input}: --force never replaces what a command reads; choose another output"
    )]
    IsInput { path: PathBuf, input: PathBuf },
    #[error(
        "{path} holds files assist did not write there ({files}); --force would delete them: move them away or choose another output"
    )]
    Foreign { path: PathBuf, files: String },
    #[error("{path} is a file; expected a folder (or a name that does not exist yet)")]
    NotAFolder { path: PathBuf },
    #[error("{path}: expected a folder name (not a root or '..')")]
    NoName { path: PathBuf },
    #[error(
        "{path} is in use by another assist process ({holder}); wait for it to finish, or choose another output"
    )]
    Busy { path: PathBuf, holder: String },
    #[error("{path}: not enough free space: about {need} MB needed, {available} MB available")]
    NoSpace {
        path: PathBuf,
        need: u64,
        available: u64,
    },
}

pub type Result<T> = std::result::Result<T, FsError>;

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> FsError + '_ {
    move |source| FsError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// The parent folder (`.` for a bare name) and the file name of `target`.
fn split(target: &Path) -> Result<(PathBuf, String)> {
    let name = target
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .filter(|n| n != "..");
    let name = match name {
        Some(n) => n,
        // `.` or `dir/.`: use the folder's own name.
        None => {
            let canon = std::fs::canonicalize(target).map_err(io(target))?;
            return match (canon.parent(), canon.file_name()) {
                (Some(p), Some(n)) => Ok((p.to_path_buf(), n.to_string_lossy().into_owned())),
                _ => Err(FsError::NoName {
                    path: target.to_path_buf(),
                }),
            };
        }
    };
    let parent = target
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
        .to_path_buf();
    Ok((parent, name))
}

/// Whether `dir` carries assist's marker, or is a scene directory assist wrote before the
/// marker existed (its `scene.json` says `"format": "assist-scene"`).
pub fn has_marker(dir: &Path) -> bool {
    if dir.join(MARKER).is_file() || dir.join(".assist-demo").is_file() {
        return true;
    }
    let mut head = String::new();
    File::open(dir.join("scene.json"))
        .and_then(|f| f.take(4096).read_to_string(&mut head))
        .is_ok()
        && head.contains("\"assist-scene\"")
}

/// Refuses to replace what the user had: `target` may be missing or an empty folder; a
/// non-empty folder only with `force` and only when it [`has_marker`]; never a file.
pub fn check_replaceable(target: &Path, force: bool) -> Result<()> {
    let meta = match std::fs::symlink_metadata(target) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(io(target)(e)),
        Ok(m) => m,
    };
    if !meta.is_dir() {
        return Err(FsError::NotAFolder {
            path: target.to_path_buf(),
        });
    }
    let empty = std::fs::read_dir(target)
        .map_err(io(target))?
        .next()
        .is_none();
    if empty {
        return Ok(());
    }
    if !force {
        return Err(FsError::Exists {
            path: target.to_path_buf(),
        });
    }
    if !has_marker(target) {
        return Err(FsError::NotOurs {
            path: target.to_path_buf(),
        });
    }
    Ok(())
}

/// What an output folder of assist holds, read from the file that defines it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// A scene (`scene.json`): `train`, `edit`, `embed`, `scene light`.
    Scene,
    /// A dataset (`transforms.json` and the like): `render`, `synth`, a capture.
    Dataset,
    /// Meshes and models (`export.json`): `export`.
    Export,
    /// Generated samples (`generate.json`): `generate`.
    Generated,
    /// The demo's folder.
    Demo,
}

impl std::fmt::Display for Kind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Kind::Scene => "a scene",
            Kind::Dataset => "a dataset",
            Kind::Export => "an export",
            Kind::Generated => "generated samples",
            Kind::Demo => "the demo",
        })
    }
}

impl Kind {
    /// The kind of `dir`, from the files that define each kind; `None` for anything else.
    pub fn of(dir: &Path) -> Option<Kind> {
        let has = |f: &str| std::fs::symlink_metadata(dir.join(f)).is_ok();
        if has(".assist-demo") {
            Some(Kind::Demo)
        } else if has("scene.json") {
            Some(Kind::Scene)
        } else if has("generate.json") {
            Some(Kind::Generated)
        } else if has("export.json") {
            Some(Kind::Export)
        } else if [
            "transforms.json",
            "transforms_train.json",
            "poses_bounds.npy",
            "sparse",
        ]
        .iter()
        .any(|f| has(f))
        {
            Some(Kind::Dataset)
        } else {
            None
        }
    }
}

/// [`check_replaceable`], and an existing output must be of the `kind` the command writes:
/// `--force` never turns a scene into a render, or a dataset into a scene.
pub fn check_replaceable_as(target: &Path, force: bool, kind: Kind) -> Result<()> {
    check_replaceable(target, force)?;
    check_kind(target, kind)
}

/// An existing `target` must be of `kind` (or of none assist knows): for commands that
/// continue their own earlier output, checked before any work.
pub fn check_kind(target: &Path, kind: Kind) -> Result<()> {
    if let Some(found) = Kind::of(target).filter(|k| *k != kind) {
        return Err(FsError::OtherKind {
            path: target.to_path_buf(),
            found,
            expected: kind,
        });
    }
    Ok(())
}

/// Refuses an output that is one of the command's `inputs` or holds one (replacing it
/// would delete what the command reads).
pub fn check_not_input(target: &Path, inputs: &[&Path]) -> Result<()> {
    let Ok(out) = std::fs::canonicalize(target) else {
        return Ok(());
    };
    for input in inputs {
        if let Ok(i) = std::fs::canonicalize(input)
            && i.starts_with(&out)
        {
            return Err(FsError::IsInput {
                path: target.to_path_buf(),
                input: input.to_path_buf(),
            });
        }
    }
    Ok(())
}

/// Refuses to replace `target` when it holds entries other than `ours` (the names the
/// command writes at its top level; the marker, locks and temporaries count as ours).
pub fn check_only_ours(target: &Path, ours: &[&str]) -> Result<()> {
    let Ok(entries) = std::fs::read_dir(target) else {
        return Ok(());
    };
    let mut foreign: Vec<String> = entries
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n != MARKER && !n.starts_with(".index.json.tmp") && !ours.contains(&n.as_str()))
        .collect();
    if foreign.is_empty() {
        return Ok(());
    }
    foreign.sort();
    Err(FsError::Foreign {
        path: target.to_path_buf(),
        files: foreign.join(", "),
    })
}

struct Held {
    /// Open for as long as the lock is held: closing it releases the lock.
    _file: File,
    count: usize,
}

static HELD: Mutex<BTreeMap<PathBuf, Held>> = Mutex::new(BTreeMap::new());

fn held() -> std::sync::MutexGuard<'static, BTreeMap<PathBuf, Held>> {
    HELD.lock().unwrap_or_else(|e| e.into_inner())
}

/// An exclusive claim on an output name; released when dropped (or when the process ends,
/// however it ends). The lock file is removed on release (on Unix), so none is left
/// beside the user's folders after a command.
#[derive(Debug)]
pub struct OutputLock {
    key: PathBuf,
}

impl OutputLock {
    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.key
    }
}

impl Drop for OutputLock {
    fn drop(&mut self) {
        let mut map = held();
        if let Some(h) = map.get_mut(&self.key) {
            h.count -= 1;
            if h.count == 0 {
                // Removed while still locked, then closed (which releases the lock). A
                // process that opened the old file meanwhile finds, once it has the lock,
                // that the path no longer names its file, and starts over (see `lock`).
                #[cfg(unix)]
                let _ = std::fs::remove_file(&self.key);
                map.remove(&self.key);
            }
        }
    }
}

/// The lock file of `target`: `PARENT/.NAME.lock`, with the parent made absolute so that
/// two spellings of one folder share a lock.
pub fn lock_path(target: &Path) -> Result<PathBuf> {
    let (parent, name) = split(target)?;
    std::fs::create_dir_all(&parent).map_err(io(&parent))?;
    let parent = std::fs::canonicalize(&parent).map_err(io(&parent))?;
    Ok(parent.join(format!(".{name}.lock")))
}

/// Whether `path` still names the open `file`.
#[cfg(unix)]
fn still_at(file: &File, path: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (file.metadata(), std::fs::metadata(path)) {
        (Ok(a), Ok(b)) => a.ino() == b.ino() && a.dev() == b.dev(),
        _ => false,
    }
}

#[cfg(not(unix))]
fn still_at(_: &File, _: &Path) -> bool {
    true
}

/// Claims `target` for this process (`what` describes the holder in a rival's error).
/// Fails at once with [`FsError::Busy`] when another process holds it; creating the lock
/// file also proves the parent folder writable before any work starts.
pub fn lock(target: &Path, what: &str) -> Result<OutputLock> {
    let key = lock_path(target)?;
    let mut map = held();
    if let Some(h) = map.get_mut(&key) {
        h.count += 1;
        return Ok(OutputLock { key });
    }
    let mut attempts = 0;
    let mut file = loop {
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&key)
            .map_err(io(&key))?;
        match file.try_lock() {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => {
                let mut holder = String::new();
                let _ = file.read_to_string(&mut holder);
                let holder = holder.trim();
                return Err(FsError::Busy {
                    path: target.to_path_buf(),
                    holder: if holder.is_empty() {
                        "holder unknown".into()
                    } else {
                        holder.to_string()
                    },
                });
            }
            Err(std::fs::TryLockError::Error(e)) => return Err(io(&key)(e)),
        }
        // The previous holder removes the file as it lets go: a lock on a file no longer
        // at the path claims nothing.
        attempts += 1;
        if still_at(&file, &key) || attempts > 100 {
            break file;
        }
    };
    let note = format!("pid {}: {what}", std::process::id());
    let _ = file
        .set_len(0)
        .and_then(|_| file.write_all(note.as_bytes()));
    map.insert(
        key.clone(),
        Held {
            _file: file,
            count: 1,
        },
    );
    Ok(OutputLock { key })
}

/// Removes what killed writers of `NAME` left in `parent` (`.NAME.tmp-*`, `.NAME.old-*`).
/// Only call while holding `NAME`'s lock: then no live process owns them.
fn clean_stale(parent: &Path, name: &str) -> usize {
    let (tmp, old) = (format!(".{name}.tmp-"), format!(".{name}.old-"));
    let Ok(entries) = std::fs::read_dir(parent) else {
        return 0;
    };
    let mut removed = 0;
    for e in entries.flatten() {
        let n = e.file_name().to_string_lossy().into_owned();
        if n.starts_with(&tmp) || n.starts_with(&old) {
            let p = e.path();
            let gone = if p.is_dir() {
                std::fs::remove_dir_all(&p)
            } else {
                std::fs::remove_file(&p)
            };
            if gone.is_ok() {
                removed += 1;
            }
        }
    }
    removed
}

/// A folder being written beside its target, swapped into place by [`Staging::commit`];
/// removed if dropped uncommitted.
#[derive(Debug)]
pub struct Staging {
    target: PathBuf,
    tmp: PathBuf,
    old: PathBuf,
    what: String,
    committed: bool,
    _lock: OutputLock,
}

impl Staging {
    /// Claims `target` ([`lock`]), removes stale temporaries of it and creates an empty
    /// staging folder. Does not check whether `target` may be replaced: see
    /// [`check_replaceable`].
    pub fn begin(target: &Path, what: &str) -> Result<Staging> {
        let lock = lock(target, what)?;
        let (parent, name) = split(target)?;
        clean_stale(&parent, &name);
        let pid = std::process::id();
        let tmp = parent.join(format!(".{name}.tmp-{pid}"));
        let old = parent.join(format!(".{name}.old-{pid}"));
        std::fs::create_dir_all(&tmp).map_err(io(&tmp))?;
        Ok(Staging {
            target: target.to_path_buf(),
            tmp,
            old,
            what: what.to_string(),
            committed: false,
            _lock: lock,
        })
    }

    /// Where to write the new content.
    pub fn dir(&self) -> &Path {
        &self.tmp
    }

    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Marks the new folder as assist's and swaps it into place: the old folder is moved
    /// aside first and removed last, so a failure leaves the old one where it was.
    pub fn commit(mut self) -> Result<()> {
        let marker = self.tmp.join(MARKER);
        std::fs::write(&marker, format!("written by assist {}\n", self.what))
            .map_err(io(&marker))?;
        let had_old = std::fs::symlink_metadata(&self.target).is_ok();
        if had_old {
            std::fs::rename(&self.target, &self.old).map_err(io(&self.target))?;
        }
        if let Err(e) = std::fs::rename(&self.tmp, &self.target) {
            if had_old {
                let _ = std::fs::rename(&self.old, &self.target);
            }
            return Err(io(&self.target)(e));
        }
        self.committed = true;
        if had_old {
            let _ = std::fs::remove_dir_all(&self.old);
        }
        Ok(())
    }
}

impl Drop for Staging {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_dir_all(&self.tmp);
        }
    }
}

/// Reads a UTF-8 text file; text that is not UTF-8 is [`FsError::NotUtf8`], naming the
/// line and byte offset of the first bad byte.
pub fn read_text(path: &Path) -> Result<String> {
    let bytes = std::fs::read(path).map_err(io(path))?;
    String::from_utf8(bytes).map_err(|e| {
        let offset = e.utf8_error().valid_up_to();
        let bytes = e.as_bytes();
        FsError::NotUtf8 {
            path: path.to_path_buf(),
            line: 1 + bytes[..offset].iter().filter(|&&b| b == b'\n').count(),
            offset,
            byte: bytes[offset],
        }
    })
}

/// The nearest existing ancestor of `p` (for free-space queries on folders not yet made).
fn existing_ancestor(p: &Path) -> PathBuf {
    let mut cur = if p.as_os_str().is_empty() {
        PathBuf::from(".")
    } else {
        p.to_path_buf()
    };
    while !cur.exists() {
        match cur.parent() {
            Some(q) if !q.as_os_str().is_empty() => cur = q.to_path_buf(),
            _ => return PathBuf::from("."),
        }
    }
    cur
}

/// Bytes available to this user on the file system that would hold `target`.
pub fn available_space(target: &Path) -> Result<u64> {
    let at = existing_ancestor(target);
    fs4::available_space(&at).map_err(io(&at))
}

/// Fails with [`FsError::NoSpace`] unless `need` bytes fit where `target` will be written.
pub fn check_space(target: &Path, need: u64) -> Result<()> {
    let available = available_space(target)?;
    if available < need {
        return Err(FsError::NoSpace {
            path: target.to_path_buf(),
            need: need.div_ceil(1 << 20),
            available: available >> 20,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmpdir(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("assist-fs-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn force_replaces_only_assists_own_folders() {
        let d = tmpdir("force");
        let mine = d.join("mine");
        let s = Staging::begin(&mine, "test").unwrap();
        std::fs::write(s.dir().join("a.txt"), "1").unwrap();
        s.commit().unwrap();
        assert!(has_marker(&mine));
        assert!(matches!(
            check_replaceable(&mine, false),
            Err(FsError::Exists { .. })
        ));
        check_replaceable(&mine, true).unwrap();

        let theirs = d.join("theirs");
        std::fs::create_dir_all(&theirs).unwrap();
        check_replaceable(&theirs, false).unwrap(); // empty
        std::fs::write(theirs.join("precious.txt"), "keep").unwrap();
        let e = check_replaceable(&theirs, true).unwrap_err();
        assert!(matches!(e, FsError::NotOurs { .. }), "{e}");
        assert!(e.to_string().contains("theirs"), "{e}");
        std::fs::write(d.join("file"), "x").unwrap();
        assert!(matches!(
            check_replaceable(&d.join("file"), true),
            Err(FsError::NotAFolder { .. })
        ));
        check_replaceable(&d.join("missing"), false).unwrap();
        // A scene written before the marker existed counts as assist's.
        let old = d.join("old.assist");
        std::fs::create_dir_all(&old).unwrap();
        std::fs::write(old.join("scene.json"), r#"{"format": "assist-scene"}"#).unwrap();
        check_replaceable(&old, true).unwrap();
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_commit_swaps_the_whole_folder_and_a_drop_leaves_nothing() {
        let d = tmpdir("swap");
        let t = d.join("out");
        let s = Staging::begin(&t, "test").unwrap();
        std::fs::write(s.dir().join("stale.txt"), "old").unwrap();
        s.commit().unwrap();
        let s = Staging::begin(&t, "test").unwrap();
        std::fs::write(s.dir().join("new.txt"), "new").unwrap();
        s.commit().unwrap();
        assert!(
            !t.join("stale.txt").exists(),
            "no file of the old folder survives"
        );
        assert!(t.join("new.txt").exists());
        let s = Staging::begin(&t, "test").unwrap();
        std::fs::write(s.dir().join("half.txt"), "x").unwrap();
        drop(s);
        assert!(t.join("new.txt").exists() && !t.join("half.txt").exists());
        let names: Vec<String> = std::fs::read_dir(&d)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert!(
            names
                .iter()
                .all(|n| !n.contains(".tmp-") && !n.contains(".old-")),
            "{names:?}"
        );
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn the_next_writer_removes_what_a_killed_writer_left() {
        let d = tmpdir("stale");
        std::fs::create_dir_all(d.join(".out.tmp-999999/fields")).unwrap();
        std::fs::create_dir_all(d.join(".out.old-999998")).unwrap();
        std::fs::create_dir_all(d.join(".other.tmp-999999")).unwrap();
        let s = Staging::begin(&d.join("out"), "test").unwrap();
        assert!(!d.join(".out.tmp-999999").exists());
        assert!(!d.join(".out.old-999998").exists());
        assert!(
            d.join(".other.tmp-999999").exists(),
            "another name's are left alone"
        );
        s.commit().unwrap();
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn locks_are_reentrant_within_a_process_and_name_the_holder() {
        let d = tmpdir("lock");
        let t = d.join("scene.assist");
        let a = lock(&t, "edit").unwrap();
        let b = lock(&d.join(".").join("scene.assist"), "save").unwrap();
        assert_eq!(a.path(), b.path());
        // Another open file description conflicts, as another process would.
        let f = OpenOptions::new()
            .read(true)
            .write(true)
            .open(a.path())
            .unwrap();
        assert!(matches!(
            f.try_lock(),
            Err(std::fs::TryLockError::WouldBlock)
        ));
        let holder = std::fs::read_to_string(a.path()).unwrap();
        assert!(holder.contains(&std::process::id().to_string()) && holder.contains("edit"));
        drop(a);
        assert!(matches!(
            f.try_lock(),
            Err(std::fs::TryLockError::WouldBlock)
        ));
        drop(b);
        f.try_lock().unwrap();
        #[cfg(unix)]
        assert!(
            !d.join(".scene.assist.lock").exists(),
            "released locks leave no file"
        );
        // A lock on the removed file claims nothing: a new claim succeeds.
        let c = lock(&t, "again").unwrap();
        drop(c);
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn text_that_is_not_utf8_names_its_line_and_byte() {
        let d = tmpdir("utf8");
        let p = d.join("a.json");
        std::fs::write(&p, b"{\n  \"a\": \"\xff\"}").unwrap();
        let e = read_text(&p).unwrap_err().to_string();
        assert!(e.contains("line 2, byte 10") && e.contains("0xff"), "{e}");
        std::fs::write(&p, "{\"ü\": 1}").unwrap();
        assert_eq!(read_text(&p).unwrap(), "{\"ü\": 1}");
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn space_checks_name_the_target() {
        let d = tmpdir("space");
        check_space(&d.join("new/out"), 1).unwrap();
        let e = check_space(&d.join("out"), u64::MAX).unwrap_err();
        assert!(
            matches!(e, FsError::NoSpace { .. }) && e.to_string().contains("out"),
            "{e}"
        );
        std::fs::remove_dir_all(&d).unwrap();
    }
}
