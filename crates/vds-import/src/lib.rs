//! Mesh import for vds: reads OBJ, glTF 2.0 / GLB, PLY and STL files (optionally gzipped)
//! into one [`Scene`]: welded positions, triangles, and a part id per triangle.
//!
//! The vertex tree is global (Luebke's point: small parts merge across objects), so every
//! input, and every object inside an input, lands in one scene; parts are kept only as a
//! per-triangle id and a name, for colouring and picking.
//!
//! Every malformed input yields an [`ImportError`] naming the file and the line, byte or
//! element at fault; no reader panics or allocates from a count it has not checked against
//! the file size.

#![deny(missing_docs)]

mod error;
mod gltf_scene;
mod obj;
mod ply;
mod soup;
mod source;
mod stl;
mod weld;

use std::path::Path;

pub use error::{FormatError, ImportError, Location, Problem};
pub use soup::MeshSoup;
pub use source::{Format, format_of};
pub use weld::{Weld, weld};

/// An indexed triangle scene: what the vertex-tree builder consumes.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Scene {
    /// Welded vertex positions; every one is used by at least one triangle.
    pub positions: Vec<[f32; 3]>,
    /// Triangles with three distinct corners.
    pub triangles: Vec<[u32; 3]>,
    /// The part of each triangle (index into `part_names`).
    pub triangle_parts: Vec<u32>,
    /// Part names, in input order.
    pub part_names: Vec<String>,
    /// What import and welding did.
    pub stats: ImportStats,
}

/// Counts of what import and welding changed.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ImportStats {
    /// Vertices as read, before welding.
    pub input_vertices: u64,
    /// Triangles as read (after triangulating polygons).
    pub input_triangles: u64,
    /// Vertices joined into another by welding.
    pub welded_vertices: u64,
    /// Triangles dropped because two corners were the same vertex (after welding).
    pub degenerate_triangles_dropped: u64,
    /// Faces with fewer than three corners, dropped by the readers.
    pub short_faces_dropped: u64,
    /// Vertices that no triangle uses, dropped.
    pub unreferenced_vertices_dropped: u64,
}

/// Options for [`load_files`].
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ImportOptions {
    /// How vertices are welded.
    pub weld: Weld,
}

/// Reads one mesh file into a soup, choosing the reader by extension (`.gz` looked through).
pub fn read_file(path: &Path, soup: &mut MeshSoup) -> Result<(), ImportError> {
    let (format, gz) = format_of(path).ok_or_else(|| ImportError::UnknownFormat {
        path: path.to_path_buf(),
    })?;
    let bytes = source::read_bytes(path, gz)?;
    let name = source::part_name_of(path);
    let mut file_soup = MeshSoup::default();
    let result = match format {
        Format::Obj => obj::read_obj(&bytes, &name, &mut file_soup),
        Format::Gltf => gltf_scene::read_gltf(&bytes, path, &mut file_soup),
        Format::Ply => ply::read_ply(&bytes, &name, &mut file_soup),
        Format::Stl => stl::read_stl(&bytes, &name, &mut file_soup),
    };
    result.map_err(|e| e.in_file(path))?;
    if soup.positions.is_empty() && soup.part_names.is_empty() {
        *soup = file_soup; // The common single-file case: no copy.
    } else {
        soup.append(file_soup);
    }
    Ok(())
}

/// Reads mesh bytes of a known format (for tests and embedders that hold files in memory).
/// `name` names the part of single-part formats; glTF external buffers are not available.
pub fn read_bytes(
    bytes: &[u8],
    format: Format,
    name: &str,
    soup: &mut MeshSoup,
) -> Result<(), FormatError> {
    match format {
        Format::Obj => obj::read_obj(bytes, name, soup),
        Format::Gltf => gltf_scene::read_gltf(bytes, Path::new(name), soup),
        Format::Ply => ply::read_ply(bytes, name, soup),
        Format::Stl => stl::read_stl(bytes, name, soup),
    }
}

/// Reads several files into one welded scene (an assembly exported as many files).
pub fn load_files<P: AsRef<Path>>(
    paths: &[P],
    options: &ImportOptions,
) -> Result<Scene, ImportError> {
    let mut soup = MeshSoup::default();
    for path in paths {
        read_file(path.as_ref(), &mut soup)?;
    }
    Ok(weld(soup, options.weld))
}

/// Reads one file into a welded scene.
pub fn load_file(path: impl AsRef<Path>, options: &ImportOptions) -> Result<Scene, ImportError> {
    load_files(&[path], options)
}
