//! Writing an output file safely, for every writer of the workspace (`.vdt` files, `vds-cut`'s
//! meshes): the one atomic-write path.
//!
//! - The bytes go to a temporary file `.NAME.PID.partial` beside the target, which is renamed
//!   over the target only once complete and synced, so an interrupted or failed write never
//!   leaves a half-written file under the target's name.
//! - A path that names something other than a regular file (a device such as `/dev/null`, a
//!   directory, a FIFO, a socket), directly or through a symbolic link, is refused: renaming
//!   over it would replace it (as root, `-o /dev/null` would replace `/dev/null`). A symbolic
//!   link to a regular file is written through: the file it points to is replaced, the link
//!   stays.
//! - Partials left by killed writers of the same target are removed before each write. A
//!   partial is *stale* when nobody holds the advisory lock (`flock`) its writer takes for as
//!   long as it writes, and the process its name records is not another live process (checked
//!   in `/proc` where there is one). The lock is what makes this sound: it is released by the
//!   kernel when its holder dies however it dies, it works across PID namespaces (containers
//!   sharing a volume) and it is not fooled by PID reuse (a container's build often has the
//!   same PID every run). The PID check only keeps the partials of writers that take no lock
//!   (older builds of these tools, filesystems without locks).
//!
//! What this must not do: decide whether an output may replace an *input*; that is the
//! command line's business ([`same_file`] is the test it uses).

use std::ffi::OsStr;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// An output file could not be written.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// The path names something that is not a regular file, which writing would replace.
    #[error("{path}: is {kind}, not a regular file; refusing to replace it")]
    NotRegularFile {
        /// The output path as given.
        path: PathBuf,
        /// What it is: "a character device", "a directory", "a symbolic link to nothing", ...
        kind: &'static str,
    },
    /// The operating system refused.
    #[error("{path}: {cause}")]
    Io {
        /// The output path as given.
        path: PathBuf,
        /// Why.
        cause: std::io::Error,
    },
}

/// How many times a write starts over when its temporary file was removed under it (by a
/// concurrent cleaner that took it for stale in the instant between creating and locking it).
const CREATE_ATTEMPTS: u32 = 4;

/// The file `path` should be written to: `path` itself when nothing is there or a regular
/// file is, the file a symbolic link points to when that is a regular file.
///
/// # Errors
/// [`OutputError::NotRegularFile`] when `path`, or what it links to, exists and is not a
/// regular file, or is a symbolic link to nothing; [`OutputError::Io`] when it cannot be
/// examined.
pub fn resolve_output(path: &Path) -> Result<PathBuf, OutputError> {
    let io = |cause| OutputError::Io {
        path: path.to_path_buf(),
        cause,
    };
    let refuse = |kind| OutputError::NotRegularFile {
        path: path.to_path_buf(),
        kind,
    };
    let link = match std::fs::symlink_metadata(path) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(path.to_path_buf()),
        Err(e) => return Err(io(e)),
    };
    if !link.file_type().is_symlink() {
        return match kind_of(&link.file_type(), false) {
            None => Ok(path.to_path_buf()),
            Some(kind) => Err(refuse(kind)),
        };
    }
    let target = match std::fs::metadata(path) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(refuse("a symbolic link to nothing"));
        }
        Err(e) => return Err(io(e)),
    };
    match kind_of(&target.file_type(), true) {
        None => std::fs::canonicalize(path).map_err(io),
        Some(kind) => Err(refuse(kind)),
    }
}

/// What a file type is, in words (`linked`: as the target of a symbolic link), when it is not
/// a regular file.
fn kind_of(file_type: &std::fs::FileType, linked: bool) -> Option<&'static str> {
    let (plain, through_link) = if file_type.is_file() {
        return None;
    } else if file_type.is_dir() {
        ("a directory", "a symbolic link to a directory")
    } else {
        special_kind(file_type)
    };
    Some(if linked { through_link } else { plain })
}

#[cfg(unix)]
fn special_kind(file_type: &std::fs::FileType) -> (&'static str, &'static str) {
    use std::os::unix::fs::FileTypeExt;
    if file_type.is_char_device() {
        (
            "a character device",
            "a symbolic link to a character device",
        )
    } else if file_type.is_block_device() {
        ("a block device", "a symbolic link to a block device")
    } else if file_type.is_fifo() {
        ("a FIFO", "a symbolic link to a FIFO")
    } else if file_type.is_socket() {
        ("a socket", "a symbolic link to a socket")
    } else {
        (
            "something other than a file",
            "a symbolic link to something other than a file",
        )
    }
}

#[cfg(not(unix))]
fn special_kind(_: &std::fs::FileType) -> (&'static str, &'static str) {
    (
        "something other than a file",
        "a symbolic link to something other than a file",
    )
}

/// Whether `a` and `b` name the same file: the same device and inode once symbolic links are
/// followed (so `x.glb`, `./x.glb`, `/abs/x.glb`, a link to it and a hard link all compare
/// equal). `false` when either does not exist.
///
/// # Errors
/// When either exists but cannot be examined.
pub fn same_file(a: &Path, b: &Path) -> std::io::Result<bool> {
    let metadata = |p: &Path| match std::fs::metadata(p) {
        Ok(m) => Ok(Some(m)),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(e),
    };
    let (Some(ma), Some(mb)) = (metadata(a)?, metadata(b)?) else {
        return Ok(false);
    };
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        Ok((ma.dev(), ma.ino()) == (mb.dev(), mb.ino()))
    }
    #[cfg(not(unix))]
    {
        let _ = (ma, mb);
        Ok(std::fs::canonicalize(a)? == std::fs::canonicalize(b)?)
    }
}

/// The temporary file a write of `target` by this process uses.
fn partial_path(target: &Path) -> PathBuf {
    let name = target.file_name().unwrap_or(OsStr::new("output"));
    let mut partial = std::ffi::OsString::from(".");
    partial.push(name);
    partial.push(format!(".{}.partial", std::process::id()));
    target.with_file_name(partial)
}

/// The directory `path` lies in (`.` for a bare file name).
fn directory_of(path: &Path) -> &Path {
    match path.parent() {
        Some(parent) if !parent.as_os_str().is_empty() => parent,
        _ => Path::new("."),
    }
}

/// The PID a partial of `target` named `name` records, if `name` is one: `.NAME.PID.partial`.
fn partial_pid(target_name: &OsStr, name: &OsStr) -> Option<u32> {
    let (target_name, name) = (target_name.to_str()?, name.to_str()?);
    let pid = name
        .strip_prefix('.')?
        .strip_prefix(target_name)?
        .strip_prefix('.')?
        .strip_suffix(".partial")?;
    if pid.is_empty() || !pid.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    pid.parse().ok()
}

/// Whether process `pid` is alive and not this one; `None` where that cannot be told (no
/// `/proc`).
fn other_process_alive(pid: u32) -> Option<bool> {
    if !Path::new("/proc/self").exists() {
        return None;
    }
    Some(pid != std::process::id() && Path::new("/proc").join(pid.to_string()).exists())
}

/// How an attempt to take a partial's lock went.
enum Lock {
    /// Taken: nobody else holds it.
    Taken,
    /// Someone holds it: the partial is being written.
    Held,
    /// Locks do not work here.
    Unsupported,
}

#[cfg(unix)]
fn try_lock(file: &File) -> Lock {
    use rustix::fs::{FlockOperation, flock};
    match flock(file, FlockOperation::NonBlockingLockExclusive) {
        Ok(()) => Lock::Taken,
        Err(e) if e == rustix::io::Errno::WOULDBLOCK => Lock::Held,
        Err(_) => Lock::Unsupported,
    }
}

#[cfg(not(unix))]
fn try_lock(_: &File) -> Lock {
    Lock::Unsupported
}

/// Opens `path` for reading with `O_NONBLOCK` (no effect on a regular file).
fn open_nonblocking(path: &Path) -> std::io::Result<File> {
    let mut options = File::options();
    options.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.custom_flags(rustix::fs::OFlags::NONBLOCK.bits() as i32);
    }
    options.open(path)
}

/// Takes the lock a writer holds while it writes, waiting for a cleaner that holds it for an
/// instant: a second at most, since anyone who can read the directory can open the partial
/// and hold a lock on it. Without the lock the write goes on: a cleaner still keeps a partial
/// whose writer's PID is alive. Where locks do not work the write goes on without one.
#[cfg(unix)]
fn lock_for_writing(file: &File) {
    use rustix::fs::{FlockOperation, flock};
    for _ in 0..200 {
        match flock(file, FlockOperation::NonBlockingLockExclusive) {
            Err(e) if e == rustix::io::Errno::WOULDBLOCK => {
                std::thread::sleep(std::time::Duration::from_millis(5));
            }
            _ => return,
        }
    }
}

#[cfg(not(unix))]
fn lock_for_writing(_: &File) {}

/// Whether the open `file` is still what `path` names (a cleaner may have removed it between
/// its creation and its lock).
fn still_named(file: &File, path: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        match (file.metadata(), std::fs::symlink_metadata(path)) {
            (Ok(a), Ok(b)) => (a.dev(), a.ino()) == (b.dev(), b.ino()),
            _ => false,
        }
    }
    #[cfg(not(unix))]
    {
        let _ = file;
        path.exists()
    }
}

/// Removes the stale partials of `target` (see the module documentation for what makes one
/// stale) and returns how many it removed. Partials of other targets, and anything that is
/// not a regular file, are left alone.
///
/// # Errors
/// When the directory cannot be listed; partials that cannot be removed are skipped.
pub fn remove_stale_partials(target: &Path) -> std::io::Result<usize> {
    let Some(target_name) = target.file_name() else {
        return Ok(0);
    };
    let mut removed = 0;
    for entry in std::fs::read_dir(directory_of(target))? {
        let Ok(entry) = entry else { continue };
        let name = entry.file_name();
        let Some(pid) = partial_pid(target_name, &name) else {
            continue;
        };
        if !entry.file_type().is_ok_and(|t| t.is_file()) {
            continue;
        }
        let path = entry.path();
        // Non-blocking, so that a FIFO swapped in after the type check cannot block it.
        let Ok(file) = open_nonblocking(&path) else {
            continue;
        };
        if !file.metadata().is_ok_and(|m| m.is_file()) {
            continue;
        }
        let stale = match try_lock(&file) {
            Lock::Held => false,
            // No writer holds it. Only a live other process (a writer that takes no lock, or
            // one between creating and locking) keeps it; one with this process's PID is a
            // dead predecessor's, since this process's writers lock theirs.
            Lock::Taken => other_process_alive(pid) != Some(true),
            // Without locks only the PID can tell; this process's own might be another
            // thread's.
            Lock::Unsupported => {
                other_process_alive(pid) == Some(false) && pid != std::process::id()
            }
        };
        // Removed while the lock is held, and only if it is still the file examined.
        if stale && still_named(&file, &path) && std::fs::remove_file(&path).is_ok() {
            removed += 1;
        }
    }
    Ok(removed)
}

/// Writes `path` atomically with what `write` puts into the writer it is given:
/// [`AtomicFile::create`], `write`, [`AtomicFile::commit`].
///
/// # Errors
/// [`OutputError::NotRegularFile`] when `path` names something that is not a regular file
/// (see [`resolve_output`]); [`OutputError::Io`] when a step fails, `write` included.
pub fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> Result<(), OutputError> {
    let mut file = AtomicFile::create(path)?;
    write(&mut file).map_err(|cause| OutputError::Io {
        path: path.to_path_buf(),
        cause,
    })?;
    file.commit()
}

/// A file being written atomically: a temporary file beside the target (`.NAME.PID.partial`,
/// locked while written), synced and renamed over the target by [`AtomicFile::commit`].
/// Stale partials of the same target are removed when it is created. Dropped without a
/// commit (an error, a panic), it removes its temporary file and leaves the target as it was.
/// Several may be open at once for different targets.
pub struct AtomicFile {
    out: Option<BufWriter<File>>,
    temporary: PathBuf,
    target: PathBuf,
    path: PathBuf,
}

impl AtomicFile {
    /// Starts writing `path`.
    ///
    /// # Errors
    /// [`OutputError::NotRegularFile`] when `path` names something that is not a regular
    /// file (see [`resolve_output`]); [`OutputError::Io`] when the temporary file cannot be
    /// made.
    pub fn create(path: &Path) -> Result<AtomicFile, OutputError> {
        let io = |cause| OutputError::Io {
            path: path.to_path_buf(),
            cause,
        };
        let target = resolve_output(path)?;
        // Best effort: a directory that cannot be listed fails the create below with its
        // reason.
        let _ = remove_stale_partials(&target);
        let temporary = partial_path(&target);
        let mut attempt = 0;
        let file = loop {
            attempt += 1;
            // `create_new` refuses an existing name, a symbolic link included, so nothing
            // planted at the temporary name is written through.
            let file = match File::options()
                .write(true)
                .create_new(true)
                .open(&temporary)
            {
                Ok(file) => file,
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                    return Err(io(std::io::Error::new(
                        e.kind(),
                        format!(
                            "{} exists and is locked: another write of this file is under way",
                            temporary.display()
                        ),
                    )));
                }
                Err(e) => return Err(io(e)),
            };
            lock_for_writing(&file);
            if still_named(&file, &temporary) {
                break file;
            }
            if attempt == CREATE_ATTEMPTS {
                return Err(io(std::io::Error::other(format!(
                    "{} kept being removed while it was created",
                    temporary.display()
                ))));
            }
        };
        Ok(AtomicFile {
            out: Some(BufWriter::new(file)),
            temporary,
            target,
            path: path.to_path_buf(),
        })
    }

    /// Syncs the file and renames it over the target.
    ///
    /// # Errors
    /// [`OutputError::Io`] when a step fails; the target is then as it was.
    pub fn commit(self) -> Result<(), OutputError> {
        self.finish(true)
    }

    /// Renames the file over the target without syncing it or its directory: for a file a
    /// crash of the machine makes worthless anyway (a build's own intermediate files in its
    /// own temporary folder), where the sync would only wait for the disk. A crash can leave
    /// the target empty or partly written, never a process's half-written file under the
    /// target's name while the machine runs.
    ///
    /// # Errors
    /// [`OutputError::Io`] when a step fails; the target is then as it was.
    pub fn commit_unsynced(self) -> Result<(), OutputError> {
        self.finish(false)
    }

    fn finish(mut self, sync: bool) -> Result<(), OutputError> {
        let out = self.out.take().expect("a file is committed once");
        // On failure the temporary file is removed while still open, so its lock keeps any
        // other writer of the same target from taking the name in between.
        let fail = |cause, file: File| {
            let _ = std::fs::remove_file(&self.temporary);
            drop(file);
            Err(OutputError::Io {
                path: self.path.clone(),
                cause,
            })
        };
        let file = match out.into_inner() {
            Ok(file) => file,
            Err(error) => {
                let (cause, out) = error.into_parts();
                return fail(cause, out.into_parts().0);
            }
        };
        if sync && let Err(cause) = file.sync_all() {
            return fail(cause, file);
        }
        // Renamed while the lock is held, so no cleaner takes it for stale before.
        if let Err(cause) = std::fs::rename(&self.temporary, &self.target) {
            return fail(cause, file);
        }
        drop(file);
        // The rename is durable once the directory is synced; failing to sync it (some
        // filesystems refuse) loses nothing written so far.
        if sync && let Ok(directory) = File::open(directory_of(&self.target)) {
            let _ = directory.sync_all();
        }
        Ok(())
    }
}

impl Write for AtomicFile {
    fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        self.out.as_mut().expect("not committed").write(bytes)
    }

    fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        self.out.as_mut().expect("not committed").write_all(bytes)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.out.as_mut().expect("not committed").flush()
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if let Some(out) = self.out.take() {
            // Unwritten bytes are dropped, not flushed; the file is removed while still open
            // and locked (see `commit`).
            let (file, _) = out.into_parts();
            let _ = std::fs::remove_file(&self.temporary);
            drop(file);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_dir(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("vds-output-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn names(dir: &Path) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }

    /// A PID no process has: above Linux's largest `pid_max` (2^22).
    const DEAD_PID: u32 = 99_999_999;

    #[test]
    fn write_replaces_a_regular_file_whole_and_leaves_no_partial() {
        let dir = temp_dir("replace");
        let target = dir.join("out.bin");
        std::fs::write(&target, b"an older, longer file").unwrap();
        write_atomically(&target, |w| w.write_all(b"new")).unwrap();
        assert_eq!(std::fs::read(&target).unwrap(), b"new");
        assert_eq!(names(&dir), ["out.bin"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn failed_write_keeps_the_old_file_and_removes_its_partial() {
        let dir = temp_dir("failed");
        let target = dir.join("out.bin");
        std::fs::write(&target, b"old").unwrap();
        let error = write_atomically(&target, |w| {
            w.write_all(b"half")?;
            Err(std::io::Error::other("the encoder gave up"))
        })
        .unwrap_err();
        assert!(error.to_string().contains("out.bin"), "{error}");
        assert_eq!(std::fs::read(&target).unwrap(), b"old");
        assert_eq!(names(&dir), ["out.bin"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn rejects_a_directory_as_output() {
        let dir = temp_dir("directory");
        let target = dir.join("sub");
        std::fs::create_dir(&target).unwrap();
        let error = write_atomically(&target, |w| w.write_all(b"x")).unwrap_err();
        assert!(
            matches!(
                error,
                OutputError::NotRegularFile {
                    kind: "a directory",
                    ..
                }
            ),
            "{error}"
        );
        assert!(target.is_dir());
        assert_eq!(names(&dir), ["sub"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[cfg(unix)]
    #[test]
    fn rejects_a_device_and_a_symlink_to_a_device_as_output() {
        let dir = temp_dir("device");
        let error = resolve_output(Path::new("/dev/null")).unwrap_err();
        assert!(
            matches!(
                error,
                OutputError::NotRegularFile {
                    kind: "a character device",
                    ..
                }
            ),
            "{error}"
        );
        assert!(error.to_string().contains("/dev/null"), "{error}");
        let link = dir.join("null.vdt");
        std::os::unix::fs::symlink("/dev/null", &link).unwrap();
        let error = write_atomically(&link, |w| w.write_all(b"x")).unwrap_err();
        assert!(
            matches!(
                error,
                OutputError::NotRegularFile {
                    kind: "a symbolic link to a character device",
                    ..
                }
            ),
            "{error}"
        );
        assert!(error.to_string().contains("null.vdt"), "{error}");
        assert!(std::fs::symlink_metadata(&link).unwrap().is_symlink());
        assert_eq!(names(&dir), ["null.vdt"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[cfg(unix)]
    #[test]
    fn rejects_a_dangling_symlink_as_output() {
        let dir = temp_dir("dangling");
        let link = dir.join("out.vdt");
        std::os::unix::fs::symlink(dir.join("nowhere"), &link).unwrap();
        let error = write_atomically(&link, |w| w.write_all(b"x")).unwrap_err();
        assert!(
            matches!(error, OutputError::NotRegularFile { .. }),
            "{error}"
        );
        assert_eq!(names(&dir), ["out.vdt"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[cfg(unix)]
    #[test]
    fn writes_through_a_symlink_to_a_regular_file() {
        let dir = temp_dir("through");
        let real = dir.join("real.vdt");
        std::fs::write(&real, b"old").unwrap();
        let link = dir.join("link.vdt");
        std::os::unix::fs::symlink(&real, &link).unwrap();
        write_atomically(&link, |w| w.write_all(b"new")).unwrap();
        assert!(std::fs::symlink_metadata(&link).unwrap().is_symlink());
        assert_eq!(std::fs::read(&real).unwrap(), b"new");
        assert_eq!(names(&dir), ["link.vdt", "real.vdt"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[cfg(unix)]
    #[test]
    fn same_file_compares_identity_not_spelling() {
        let dir = temp_dir("identity");
        let a = dir.join("a.obj");
        std::fs::write(&a, b"x").unwrap();
        let dotted = dir.join(".").join("a.obj");
        let hard = dir.join("hard.obj");
        std::fs::hard_link(&a, &hard).unwrap();
        let soft = dir.join("soft.obj");
        std::os::unix::fs::symlink(&a, &soft).unwrap();
        let other = dir.join("b.obj");
        std::fs::write(&other, b"x").unwrap();
        for same in [&a, &dotted, &hard, &soft] {
            assert!(same_file(&a, same).unwrap(), "{}", same.display());
        }
        assert!(!same_file(&a, &other).unwrap());
        assert!(!same_file(&a, &dir.join("missing.obj")).unwrap());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn removes_stale_partials_of_the_same_target_only() {
        let dir = temp_dir("stale");
        let target = dir.join("x.vdt");
        let stale = [
            format!(".x.vdt.{DEAD_PID}.partial"),
            // A dead predecessor that had this process's PID (containers reuse PIDs).
            format!(".x.vdt.{}.partial", std::process::id()),
        ];
        let kept = [
            format!(".y.vdt.{DEAD_PID}.partial"),
            format!(".x.vdt.{DEAD_PID}.7.partial"),
            ".x.vdt.partial".to_string(),
            "x.vdt.1.partial".to_string(),
        ];
        for name in stale.iter().chain(&kept) {
            std::fs::write(dir.join(name), b"half a file").unwrap();
        }
        write_atomically(&target, |w| w.write_all(b"whole")).unwrap();
        let mut expected: Vec<String> = kept.to_vec();
        expected.push("x.vdt".into());
        expected.sort();
        assert_eq!(names(&dir), expected);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[cfg(unix)]
    #[test]
    fn keeps_a_partial_that_is_being_written() {
        let dir = temp_dir("in-use");
        let target = dir.join("x.vdt");
        let busy = dir.join(format!(".x.vdt.{DEAD_PID}.partial"));
        std::fs::write(&busy, b"half a file").unwrap();
        // A writer (here this test) holds the lock: whatever its PID says, it is alive.
        let holder = File::open(&busy).unwrap();
        assert!(matches!(try_lock(&holder), Lock::Taken));
        assert_eq!(remove_stale_partials(&target).unwrap(), 0);
        assert!(busy.exists());
        drop(holder);
        assert_eq!(remove_stale_partials(&target).unwrap(), 1);
        assert!(!busy.exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn keeps_an_unlocked_partial_of_a_live_process() {
        let dir = temp_dir("live");
        let target = dir.join("x.vdt");
        // PID 1 is always alive where there is a /proc; a writer without locks (an older
        // build) may be writing this one.
        let live = dir.join(".x.vdt.1.partial");
        std::fs::write(&live, b"half a file").unwrap();
        let removed = remove_stale_partials(&target).unwrap();
        if Path::new("/proc/1").exists() {
            assert_eq!(removed, 0);
            assert!(live.exists());
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn partial_names_parse_only_for_their_target() {
        let t = OsStr::new("a.vdt");
        assert_eq!(partial_pid(t, OsStr::new(".a.vdt.42.partial")), Some(42));
        assert_eq!(partial_pid(t, OsStr::new(".a.vdt..partial")), None);
        assert_eq!(partial_pid(t, OsStr::new(".a.vdt.4x.partial")), None);
        assert_eq!(partial_pid(t, OsStr::new(".a.vdt.5.42.partial")), None);
        assert_eq!(partial_pid(t, OsStr::new(".b.vdt.42.partial")), None);
        assert_eq!(
            partial_pid(t, OsStr::new(".a.vdt.99999999999999.partial")),
            None
        );
    }
    #[test]
    fn an_atomic_file_dropped_without_commit_leaves_nothing() {
        let dir = temp_dir("atomic-drop");
        let target = dir.join("x.bin");
        std::fs::write(&target, b"before").unwrap();
        {
            let mut file = AtomicFile::create(&target).unwrap();
            file.write_all(b"half of it").unwrap();
        }
        assert_eq!(std::fs::read(&target).unwrap(), b"before");
        assert_eq!(names(&dir), vec!["x.bin".to_string()]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn atomic_files_of_two_targets_are_written_side_by_side() {
        let dir = temp_dir("atomic-two");
        let (a, b) = (dir.join("a.bin"), dir.join("b.bin"));
        let mut first = AtomicFile::create(&a).unwrap();
        let mut second = AtomicFile::create(&b).unwrap();
        first.write_all(b"one").unwrap();
        second.write_all(b"two").unwrap();
        // A second writer of the same target is refused while the first is open.
        assert!(AtomicFile::create(&a).is_err());
        second.commit().unwrap();
        first.commit().unwrap();
        assert_eq!(std::fs::read(&a).unwrap(), b"one");
        assert_eq!(std::fs::read(&b).unwrap(), b"two");
        assert_eq!(names(&dir), vec!["a.bin".to_string(), "b.bin".to_string()]);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
