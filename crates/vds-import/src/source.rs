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

/// Reads a whole file, gunzipping it when `gz` is set.
pub fn read_bytes(path: &Path, gz: bool) -> Result<Vec<u8>, ImportError> {
    let io_error = |cause| ImportError::Io {
        path: path.to_path_buf(),
        cause,
    };
    let raw = std::fs::read(path).map_err(io_error)?;
    if !gz {
        return Ok(raw);
    }
    let mut out = Vec::new();
    flate2::read::MultiGzDecoder::new(&raw[..])
        .read_to_end(&mut out)
        .map_err(io_error)?;
    Ok(out)
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
