//! Mesh import for vds: reads OBJ, glTF 2.0 / GLB, PLY and STL files (optionally gzipped)
//! into one [`Scene`]: welded positions, triangles, and a part id per triangle.
//!
//! The vertex tree is global (Luebke's point: small parts merge across objects), so every
//! input, and every object inside an input, lands in one scene; parts are kept only as a
//! per-triangle id and, per part, a name, a colour and a parent in the assembly
//! ([`PartInfo`]), for colouring, picking and the assembly tree.
//!
//! Every malformed input yields an [`ImportError`] naming the file and the line, byte or
//! element at fault; no reader panics or allocates from a count it has not checked against
//! the file size.

#![deny(missing_docs)]

mod error;
mod gltf_scene;
mod mapped;
mod obj;
mod ply;
mod soup;
mod source;
mod spill;
mod stl;
mod texture;
mod uri;
mod weld;

use std::path::Path;

pub use error::{FormatError, ImportError, Location, Problem};
pub use soup::{MeshSoup, SPILL_ROWS};
pub use source::{Format, format_of, open_regular_file};
pub use spill::{SoupFiles, SpilledScene};
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
    /// Per part name, its parent and colour; empty in scenes made by hand, which means every
    /// part at the top and none coloured.
    pub parts: Vec<PartInfo>,
    /// What import and welding did.
    pub stats: ImportStats,
    /// What could not be read but cost only colours (a missing material library or
    /// texture), each naming its file.
    pub warnings: Vec<String>,
}

/// What an input says about a part besides its name.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PartInfo {
    /// The part it belongs to in the assembly (always an earlier part): a glTF node's
    /// nearest ancestor that is a part. OBJ, STL and PLY parts are flat (none).
    pub parent: Option<u32>,
    /// RGBA in `0..=1`: glTF `baseColorFactor` (triangle-weighted over the node's
    /// primitives; textures are not read), OBJ `Kd` and `d` of the group's materials, PLY
    /// per-face or per-vertex colours, binary STL VisCAM/SolidView colour words, each
    /// averaged over the part's triangles. None when the input gives no colour.
    pub color: Option<[f32; 4]>,
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

/// The largest coordinate magnitude accepted, after any transform: 2⁶⁰ ≈ 1.15·10¹⁸.
///
/// Near `f32::MAX` (3.4·10³⁸) the builder's squared distances and the `.vdt` grid's step
/// overflow. At 2⁶⁰ every squared coordinate difference ((2·2⁶⁰)²·3 < 2¹²⁴) is still finite
/// in `f32`, and the build, the file's verification and the runtime's pixel bound are tested
/// at this size (the runtime's `threshold_holds_for_models_at_the_largest_accepted_
/// coordinates`). No real model comes near it: the Earth in micrometres is 1.3·10¹³.
pub const MAX_COORDINATE: f64 = (1u64 << 60) as f64;

/// Options for [`load_files`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImportOptions {
    /// How vertices are welded.
    pub weld: Weld,
    /// The most triangles all inputs together may hold. glTF instance trees are counted
    /// before they are expanded, and refused when they would expand to more triangles than
    /// this, more than three vertices per allowed triangle, or more node instances than this
    /// or 2²⁶, whichever is larger.
    pub max_triangles: u64,
    /// The most bytes a `.gz` input may decompress to (streamed for OBJ, into a mapped
    /// temporary file otherwise), and what a glTF's external buffer files hold together.
    pub max_decompressed_bytes: u64,
    /// Whether glTF URIs and OBJ `mtllib` paths may name files outside the model's folder (absolute paths, `..`
    /// leaving the folder, symbolic links out of it). Off by default: a model handed to a
    /// batch job must not make it read other files. Schemes other than `data:` and file
    /// paths are refused either way: nothing is fetched from a network.
    pub allow_external_uris: bool,
}

impl ImportOptions {
    /// The default [`ImportOptions::max_triangles`]: 2²⁸ ≈ 268 M, about what the in-memory
    /// build fits in 24 GiB (it peaks near 100 bytes per triangle).
    pub const DEFAULT_MAX_TRIANGLES: u64 = 1 << 28;
    /// The default [`ImportOptions::max_decompressed_bytes`]: 4 GiB.
    pub const DEFAULT_MAX_DECOMPRESSED_BYTES: u64 = 4 << 30;
}

impl Default for ImportOptions {
    fn default() -> Self {
        Self {
            weld: Weld::default(),
            max_triangles: Self::DEFAULT_MAX_TRIANGLES,
            max_decompressed_bytes: Self::DEFAULT_MAX_DECOMPRESSED_BYTES,
            allow_external_uris: false,
        }
    }
}

/// Reads one mesh file into a soup, choosing the reader by extension (`.gz` looked through).
///
/// The file must be a regular file (links are followed); a file without any triangle is an
/// error, and so is one that takes the soup past `options.max_triangles`.
pub fn read_file(
    path: &Path,
    options: &ImportOptions,
    soup: &mut MeshSoup,
) -> Result<(), ImportError> {
    let mut file_soup = MeshSoup::default();
    let budget = options
        .max_triangles
        .saturating_sub(soup.triangles.len() as u64);
    read_into(path, options, budget, &mut file_soup)?;
    check_file(path, options, budget, soup.positions.len(), &mut file_soup)?;
    if soup.positions.is_empty() && soup.part_names.is_empty() {
        *soup = file_soup; // The common single-file case: no copy.
    } else {
        soup.append(file_soup);
    }
    Ok(())
}

/// Reads the file at `path` into `file_soup`, a fresh soup (which may spill), with at most
/// `budget` triangles for glTF instance trees.
fn read_into(
    path: &Path,
    options: &ImportOptions,
    budget: u64,
    file_soup: &mut MeshSoup,
) -> Result<(), ImportError> {
    let (format, gz) = format_of(path).ok_or_else(|| ImportError::UnknownFormat {
        path: path.to_path_buf(),
    })?;
    let name = source::part_name_of(path);
    let folder = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let materials = obj::MaterialFiles {
        folder,
        allow_external: options.allow_external_uris,
    };
    if format == Format::Obj && gz {
        // Streamed: the decompressed text is never in memory whole.
        return source::read_obj_gz(path, &name, &materials, options, file_soup);
    }
    // A build that spills decompresses gzipped inputs beside its spill files, not in
    // `TMPDIR`, which may be memory.
    let temp_folder = file_soup.spill.0.as_ref().map(|s| s.folder());
    let bytes = std::sync::Arc::new(source::read_bytes(
        path,
        gz,
        options.max_decompressed_bytes,
        temp_folder,
    )?);
    if let Some(spill) = file_soup.spill.0.as_mut() {
        spill.input = Some((bytes.clone(), path.to_path_buf()));
    }
    let result = match format {
        Format::Obj => obj::read_obj(&bytes, &name, Some(&materials), file_soup),
        Format::Gltf => {
            let gltf_options = gltf_scene::GltfOptions {
                folder: Some(folder),
                allow_external_uris: options.allow_external_uris,
                max_triangles: budget,
                max_buffer_bytes: options.max_decompressed_bytes,
            };
            gltf_scene::read_gltf(&bytes, &gltf_options, file_soup)
        }
        Format::Ply => ply::read_ply(&bytes, &name, file_soup),
        Format::Stl => stl::read_stl(&bytes, &name, file_soup),
    };
    if let Some(spill) = file_soup.spill.0.as_mut() {
        spill.input = None;
    }
    result.map_err(|e| e.in_file(path))
}

/// Checks one file's soup (triangles, the limit, `vertices_before` more vertices) and names
/// the file in its warnings.
fn check_file(
    path: &Path,
    options: &ImportOptions,
    budget: u64,
    vertices_before: usize,
    file_soup: &mut MeshSoup,
) -> Result<(), ImportError> {
    for warning in &mut file_soup.warnings {
        *warning = format!("{}: {warning}", path.display());
    }
    let triangles = file_soup.triangle_count() as u64;
    if triangles == 0 {
        return Err(ImportError::NoTriangles {
            path: path.to_path_buf(),
        });
    }
    if triangles > budget {
        return Err(FormatError::new(
            Location::File,
            Problem::LimitExceeded {
                what: "the inputs so far hold".into(),
                amount: options.max_triangles - budget + triangles,
                limit: options.max_triangles,
                option: "--max-triangles",
            },
        )
        .in_file(path));
    }
    // Vertex indices are `u32`: the inputs together may not hold more vertices than that.
    if !soup::indices_fit(vertices_before, file_soup.vertex_count()) {
        return Err(FormatError::new(
            Location::File,
            Problem::Unsupported("more than 2^32 vertices in the inputs together".into()),
        )
        .in_file(path));
    }
    Ok(())
}

/// Reads mesh bytes of a known format (for tests and embedders that hold files in memory).
/// `name` names the part of single-part formats; glTF external buffers are not available
/// (a URI other than `data:` is an error), OBJ material libraries are not read and instance trees are limited by
/// [`ImportOptions::DEFAULT_MAX_TRIANGLES`].
pub fn read_bytes(
    bytes: &[u8],
    format: Format,
    name: &str,
    soup: &mut MeshSoup,
) -> Result<(), FormatError> {
    match format {
        Format::Obj => obj::read_obj(bytes, name, None, soup),
        Format::Gltf => {
            // No folder to read from: every URI other than `data:` is refused.
            let options = gltf_scene::GltfOptions {
                folder: None,
                allow_external_uris: false,
                max_triangles: ImportOptions::DEFAULT_MAX_TRIANGLES,
                max_buffer_bytes: 0,
            };
            gltf_scene::read_gltf(bytes, &options, soup)
        }
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
        read_file(path.as_ref(), options, &mut soup)?;
    }
    let scene = weld(soup, options.weld);
    if scene.triangles.is_empty() {
        return Err(ImportError::NoUsableTriangles {
            paths: paths.iter().map(|p| p.as_ref().to_path_buf()).collect(),
        });
    }
    Ok(scene)
}

/// Reads several files into a welded scene whose triangles stay on disk, in unnamed temporary
/// files in `folder`: the same scene [`load_files`] makes with [`Weld::Exact`], read with
/// memory that does not grow with the model's triangles. PLY, STL and OBJ files are
/// streamed (their soup spills every [`SPILL_ROWS`] rows or megabyte of OBJ text, and their
/// mapped pages are let go as they are read; the OBJ reader keeps a table of its `v` lines);
/// a glTF file's soup is held while that file is read (its buffers are in memory anyway).
/// What stays in memory is about 12 bytes per welded vertex and 4 per input vertex
/// ([`SpilledScene`]), and a PLY file's vertex colours (16 bytes per vertex) while it is read.
/// `options.weld` is not read: the weld is exact.
pub fn spill_files<P: AsRef<Path>>(
    paths: &[P],
    options: &ImportOptions,
    folder: &Path,
) -> Result<SpilledScene, ImportError> {
    spill_files_in_pieces(paths, options, folder, SPILL_ROWS)
}

/// [`spill_files`], with streaming readers spilling every `rows` rows.
pub(crate) fn spill_files_in_pieces<P: AsRef<Path>>(
    paths: &[P],
    options: &ImportOptions,
    folder: &Path,
    rows: usize,
) -> Result<SpilledScene, ImportError> {
    let mut files = SoupFiles::create(folder)?;
    for path in paths {
        let path = path.as_ref();
        let budget = options.max_triangles.saturating_sub(files.triangle_count());
        let vertices_before = files.vertex_count();
        let mut file_soup = MeshSoup::default();
        file_soup.spill.0 = Some(Box::new(files.for_file(rows)));
        let read = read_into(path, options, budget, &mut file_soup).and_then(|()| {
            check_file(
                path,
                options,
                budget,
                vertices_before as usize,
                &mut file_soup,
            )
        });
        file_soup.spill_now();
        let spill = file_soup.spill.0.take().expect("the soup's spill");
        read?;
        files = spill.finish(file_soup).map_err(|cause| ImportError::Io {
            path: folder.to_path_buf(),
            cause,
        })?;
    }
    let scene = files.weld()?;
    if scene.triangle_count == 0 {
        return Err(ImportError::NoUsableTriangles {
            paths: paths.iter().map(|p| p.as_ref().to_path_buf()).collect(),
        });
    }
    Ok(scene)
}

/// Reads one file into a welded scene.
pub fn load_file(path: impl AsRef<Path>, options: &ImportOptions) -> Result<Scene, ImportError> {
    load_files(&[path], options)
}
