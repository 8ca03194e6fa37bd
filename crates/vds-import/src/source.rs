//! Reading an input file (mapped; a gzipped one decompressed, within a limit, into a
//! temporary file that is mapped), streaming a gzipped OBJ file through its reader, and
//! telling the mesh format from the file name.

use std::io::Read;
use std::path::Path;

use crate::error::{ImportError, Location, Problem};

/// The mesh formats this crate reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// Wavefront OBJ.
    Obj,
    /// glTF 2.0, JSON (`.gltf`) or binary (`.glb`).
    Gltf,
    /// Stanford PLY, ASCII or binary.
    Ply,
    /// STL, ASCII or binary.
    Stl,
}

/// The format named by a path's extension (a trailing `.gz` is looked through), and whether
/// the file is gzip-compressed.
pub fn format_of(path: &Path) -> Option<(Format, bool)> {
    let name = path.file_name()?.to_str()?.to_ascii_lowercase();
    let (name, gz) = match name.strip_suffix(".gz") {
        Some(inner) => (inner.to_string(), true),
        None => (name, false),
    };
    let ext = name.rsplit_once('.')?.1;
    let format = match ext {
        "obj" => Format::Obj,
        "gltf" | "glb" => Format::Gltf,
        "ply" => Format::Ply,
        "stl" => Format::Stl,
        _ => return None,
    };
    Some((format, gz))
}

/// An input file's bytes: memory-mapped, or (empty) in memory.
pub enum Bytes {
    /// A plain file, or a gzipped file's decompressed temporary copy, mapped; for a plain
    /// file, what it was when it was mapped, which a spilling import checks before it reads
    /// rows of the map again ([`crate::mapped`]). (A decompressed copy has no name: nothing
    /// else can change it.)
    Mapped(memmap2::Mmap, Option<FileIdentity>),
    /// An empty file, which cannot be mapped.
    Owned(Vec<u8>),
}

/// What tells a file apart from itself changed or replaced: its device and inode, length and
/// times of last change.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FileIdentity {
    device: u64,
    inode: u64,
    length: u64,
    modified: (i64, i64),
    changed: (i64, i64),
}

impl FileIdentity {
    /// The identity in `metadata`.
    pub fn of(metadata: &std::fs::Metadata) -> FileIdentity {
        use std::os::unix::fs::MetadataExt;
        FileIdentity {
            device: metadata.dev(),
            inode: metadata.ino(),
            length: metadata.len(),
            modified: (metadata.mtime(), metadata.mtime_nsec()),
            changed: (metadata.ctime(), metadata.ctime_nsec()),
        }
    }
}

impl std::ops::Deref for Bytes {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        match self {
            Bytes::Mapped(map, _) => map,
            Bytes::Owned(bytes) => bytes,
        }
    }
}

impl std::fmt::Debug for Bytes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let kind = match self {
            Bytes::Mapped(..) => "mapped",
            Bytes::Owned(_) => "owned",
        };
        write!(f, "Bytes({kind}, {} bytes)", self.len())
    }
}

impl Bytes {
    /// Lets the pages that hold `part` (bytes of this file the reader is done with) go from
    /// this process's resident memory: a reader that streams through a large mapped file then
    /// holds only the pages it is reading, not every page it has read. Does nothing for bytes
    /// in memory or outside the map.
    #[allow(unsafe_code)]
    pub(crate) fn release(&self, part: &[u8]) {
        let Bytes::Mapped(map, _) = self else {
            return;
        };
        let base = map.as_ptr() as usize;
        let start = part.as_ptr() as usize;
        if part.is_empty() || start < base || start + part.len() > base + map.len() {
            return;
        }
        // SAFETY: `unchecked_advise_range` is unsafe because some advice changes what memory
        // reads (`MADV_DONTNEED` on private or anonymous memory zeroes it). This map is a
        // read-only shared map of a file (`Mmap::map`): `MADV_DONTNEED` only drops its page
        // table entries, and the next read of those bytes faults the same file pages in again
        // from the page cache or the disk. Every `&[u8]` borrowed from the map therefore keeps
        // reading the file's bytes; the only way they could change is the file being written,
        // the contract `map` already accepts. The range is inside the map (checked above); a
        // failure only leaves the pages resident.
        let _ = unsafe {
            map.unchecked_advise_range(memmap2::UncheckedAdvice::DontNeed, start - base, part.len())
        };
    }
}

/// Opens `path` for reading after making sure it is a regular file, itself or through
/// symbolic links.
///
/// A FIFO would block the open (or the read) forever and a device like `/dev/zero` never
/// ends, so neither is ever read. The file is opened with `O_NONBLOCK` and checked with
/// `fstat` on the open descriptor rather than `stat` on the name, so a FIFO swapped in
/// between cannot block the open; on a regular file the flag changes nothing.
pub fn open_regular_file(path: &Path) -> Result<std::fs::File, ImportError> {
    let io_error = |cause| ImportError::Io {
        path: path.to_path_buf(),
        cause,
    };
    // `stat` first, so that a device is never opened at all (opening some has side
    // effects, a tape rewinding); `fstat` after, for what may have been swapped in.
    let kind = std::fs::metadata(path).map_err(io_error)?.file_type();
    if !kind.is_file() {
        return Err(ImportError::NotAFile {
            path: path.to_path_buf(),
            kind: describe(kind),
        });
    }
    let mut options = std::fs::OpenOptions::new();
    options.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.custom_flags(libc::O_NONBLOCK);
    }
    let file = options.open(path).map_err(io_error)?;
    let kind = file.metadata().map_err(io_error)?.file_type();
    if kind.is_file() {
        return Ok(file);
    }
    Err(ImportError::NotAFile {
        path: path.to_path_buf(),
        kind: describe(kind),
    })
}

/// What a non-regular file is, for the error message.
fn describe(kind: std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if kind.is_fifo() {
            return "a FIFO";
        }
        if kind.is_char_device() {
            return "a character device";
        }
        if kind.is_block_device() {
            return "a block device";
        }
        if kind.is_socket() {
            return "a socket";
        }
    }
    if kind.is_dir() {
        "a directory"
    } else {
        "not a regular file"
    }
}

/// Reads a whole file, gunzipping it when `gz` is set; decompressed data larger than
/// `max_decompressed_bytes` is refused, after reading at most one byte more than that.
///
/// Plain files are memory-mapped rather than read: for a multi-gigabyte mesh that skips
/// copying every byte into freshly zeroed pages, which was half of a 10 M-triangle import
/// on the dev machine. A gzipped file is decompressed into an unnamed temporary file (in
/// `temp_folder`, else the system's temporary folder, `TMPDIR`) and that is mapped: the
/// decompressed bytes live in the page cache, which the kernel can drop and reread, not in
/// the process's own memory. (A gzipped OBJ file does not come here: it is streamed through
/// its reader.)
pub fn read_bytes(
    path: &Path,
    gz: bool,
    max_decompressed_bytes: u64,
    temp_folder: Option<&Path>,
) -> Result<Bytes, ImportError> {
    let io_error = |cause| ImportError::Io {
        path: path.to_path_buf(),
        cause,
    };
    let file = open_regular_file(path)?;
    if gz {
        let folder = temp_folder.map_or_else(std::env::temp_dir, Path::to_path_buf);
        let mut decompressed = tempfile::tempfile_in(&folder).map_err(|cause| ImportError::Io {
            path: folder,
            cause,
        })?;
        let mut out = std::io::BufWriter::with_capacity(1 << 20, &mut decompressed);
        let written =
            std::io::copy(&mut gunzip(file, max_decompressed_bytes), &mut out).map_err(io_error)?;
        std::io::Write::flush(&mut out).map_err(io_error)?;
        drop(out);
        if written > max_decompressed_bytes {
            return Err(over_the_limit(path, written, max_decompressed_bytes));
        }
        if written == 0 {
            return Ok(Bytes::Owned(Vec::new()));
        }
        return map(&decompressed)
            .map(|m| Bytes::Mapped(m, None))
            .map_err(io_error);
    }
    let metadata = file.metadata().map_err(io_error)?;
    if metadata.len() == 0 {
        return Ok(Bytes::Owned(Vec::new()));
    }
    let identity = FileIdentity::of(&metadata);
    map(&file)
        .map(|m| Bytes::Mapped(m, Some(identity)))
        .map_err(io_error)
}

/// Reads a gzipped OBJ file into `soup` as a stream: the decompressed text is never held
/// whole. Decompressed text longer than `options.max_decompressed_bytes` is refused as
/// [`read_bytes`] refuses it (reading stops one byte past the limit), so that the limit
/// bounds the time a gzip bomb can take.
pub(crate) fn read_obj_gz(
    path: &Path,
    name: &str,
    materials: &crate::obj::MaterialFiles,
    options: &crate::ImportOptions,
    soup: &mut crate::MeshSoup,
) -> Result<(), ImportError> {
    let file = open_regular_file(path)?;
    let limit = options.max_decompressed_bytes;
    let mut stream = gunzip(file, limit);
    let result = crate::obj::read_obj_stream(&mut stream, name, Some(materials), soup);
    let read = limit.saturating_add(1) - stream.limit();
    if read > limit {
        return Err(over_the_limit(path, read, limit));
    }
    result.map_err(|e| match e {
        crate::obj::StreamError::Read(cause) => ImportError::Io {
            path: path.to_path_buf(),
            cause,
        },
        crate::obj::StreamError::Format(e) => e.in_file(path),
    })
}

/// `file` gunzipped, ending one byte past `limit` (so that going past it can be seen).
fn gunzip(
    file: std::fs::File,
    limit: u64,
) -> std::io::Take<flate2::read::MultiGzDecoder<std::io::BufReader<std::fs::File>>> {
    flate2::read::MultiGzDecoder::new(std::io::BufReader::new(file)).take(limit.saturating_add(1))
}

/// The error for a gzipped input that decompresses past `limit` (`amount` is how far it got).
fn over_the_limit(path: &Path, amount: u64, limit: u64) -> ImportError {
    ImportError::Malformed {
        path: path.to_path_buf(),
        location: Location::File,
        problem: Problem::LimitExceeded {
            what: "decompressed size is at least".into(),
            amount,
            limit,
            option: "--max-decompressed-bytes",
        },
    }
}

#[allow(unsafe_code)]
fn map(file: &std::fs::File) -> std::io::Result<memmap2::Mmap> {
    // SAFETY: `Mmap::map` is unsafe because the mapped bytes change if another process writes
    // or truncates the file while it is mapped. Soundness here rests on two facts: the
    // readers only ever see the bytes as `&[u8]` and treat every byte as untrusted (each
    // value is validated where it is read, so changed bytes can only change which error or
    // mesh results, never cause an out-of-bounds access); and a truncation while mapped would
    // raise SIGBUS, which terminates the process rather than reading invalid memory. This is
    // the same contract ripgrep accepts for searching mapped files. (A gzipped input's
    // temporary copy has no name, so no other process can open it to change it.)
    unsafe { memmap2::Mmap::map(file) }
}

/// The file stem without `.gz` and the mesh extension, used to name single-part files.
pub fn part_name_of(path: &Path) -> String {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let name = name.strip_suffix(".gz").unwrap_or(&name);
    match name.rsplit_once('.') {
        Some((stem, _)) if !stem.is_empty() => stem.to_string(),
        _ => name.to_string(),
    }
}
