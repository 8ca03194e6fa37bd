//! Reading an input file into memory, transparently gunzipping `*.gz`, and telling the mesh
//! format from the file name.

use std::io::Read;
use std::path::Path;

use crate::error::ImportError;

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

/// An input file's bytes: memory-mapped, or decompressed into memory.
pub enum Bytes {
    /// A plain file, mapped.
    Mapped(memmap2::Mmap),
    /// A gzipped file, decompressed (or an empty file, which cannot be mapped).
    Owned(Vec<u8>),
}

impl std::ops::Deref for Bytes {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        match self {
            Bytes::Mapped(map) => map,
            Bytes::Owned(bytes) => bytes,
        }
    }
}

/// Reads a whole file, gunzipping it when `gz` is set.
///
/// Plain files are memory-mapped rather than read: for a multi-gigabyte mesh that skips
/// copying every byte into freshly zeroed pages, which was half of a 10 M-triangle import
/// on the dev machine.
pub fn read_bytes(path: &Path, gz: bool) -> Result<Bytes, ImportError> {
    let io_error = |cause| ImportError::Io {
        path: path.to_path_buf(),
        cause,
    };
    let file = std::fs::File::open(path).map_err(io_error)?;
    if gz {
        let mut out = Vec::new();
        flate2::read::MultiGzDecoder::new(std::io::BufReader::new(file))
            .read_to_end(&mut out)
            .map_err(io_error)?;
        return Ok(Bytes::Owned(out));
    }
    if file.metadata().map_err(io_error)?.len() == 0 {
        return Ok(Bytes::Owned(Vec::new()));
    }
    map(&file).map(Bytes::Mapped).map_err(io_error)
}

#[allow(unsafe_code)]
fn map(file: &std::fs::File) -> std::io::Result<memmap2::Mmap> {
    // SAFETY: `Mmap::map` is unsafe because the mapped bytes change if another process writes
    // or truncates the file while it is mapped. Soundness here rests on two facts: the
    // readers only ever see the bytes as `&[u8]` and treat every byte as untrusted (each
    // value is validated where it is read, so changed bytes can only change which error or
    // mesh results, never cause an out-of-bounds access); and a truncation while mapped would
    // raise SIGBUS, which terminates the process rather than reading invalid memory. This is
    // the same contract ripgrep accepts for searching mapped files.
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
