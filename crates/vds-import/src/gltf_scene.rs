//! glTF 2.0 (`.gltf` with external or embedded buffers, and `.glb`) through the `gltf` crate:
//! walks the default scene's node hierarchy, applies world transforms, and reads every
//! triangle primitive (strips and fans converted). Each instance of a node whose mesh has
//! triangles becomes a part, and so does each instance of a node above one (a grouping node
//! such as `Engine` or `Block`), so the parts keep the assembly's tree: a part's parent is
//! the part of its nearest ancestor node. Names are the node's own (the path
//! `Engine/Block/Bolt_12` is the chain of parents). A part's colour is its primitives'
//! material `baseColorFactor` (times the mean of its base-colour texture, when it has one:
//! [`crate::texture`]), weighted by their triangles; a primitive without a material adds no
//! colour. A texture that cannot be read is a warning, and its material's factor stands
//! alone.
//!
//! Buffer URIs resolve inside the model's folder (see [`crate::uri`]), external buffers are
//! read only up to their `byteLength`, and the instance tree is counted before it is
//! expanded, so a small file cannot make the reader grow without bound.
//!
//! The `gltf` crate parses and validates the JSON; accessor data is read here, after checking
//! every byte range with checked arithmetic, because the crate's own accessor iterators
//! assume well-formed ranges (a zero count or an overflowing stride would panic there).

use std::path::{Path, PathBuf};
use std::rc::Rc;

use base64::Engine as _;
use glam::{DMat4, DVec3};
use gltf::accessor::{DataType, Dimensions};
use gltf::mesh::Mode;

use crate::error::{FormatError, Location, Problem};
use crate::soup::{MeshSoup, check_index};
use crate::uri;

/// glTF node trees deeper than this are rejected: real scenes nest a few dozen levels, and the
/// limit bounds recursion on hostile files.
const MAX_NODE_DEPTH: usize = 1024;

/// How much of its surroundings a glTF file may use.
pub struct GltfOptions<'a> {
    /// The model's folder: relative buffer URIs resolve against it (`None`: bytes from
    /// memory, every URI but `data:` is refused).
    pub folder: Option<&'a Path>,
    /// Whether URIs may leave `folder` (see [`crate::ImportOptions::allow_external_uris`]).
    pub allow_external_uris: bool,
    /// The most triangles the file's instance tree may expand to.
    pub max_triangles: u64,
    /// The most bytes the external buffer files may hold together.
    pub max_buffer_bytes: u64,
}

/// Reads a glTF or GLB file's bytes into `soup`.
pub fn read_gltf(
    data: &[u8],
    options: &GltfOptions,
    soup: &mut MeshSoup,
) -> Result<(), FormatError> {
    let invalid =
        |e: gltf::Error| FormatError::syntax(Location::File, format!("invalid glTF: {e}"));
    // gltf 1.4's GLB reader subtracts the 12-byte header from the header's length field
    // unchecked (binary.rs, `Glb::from_slice`): a smaller field would overflow.
    if let Some(length) = data
        .strip_prefix(b"glTF")
        .and_then(|rest| rest.get(4..8))
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        && length < 12
    {
        return Err(FormatError::syntax(
            Location::Byte(8),
            format!("GLB length {length} is shorter than the 12-byte header"),
        ));
    }
    let gltf::Gltf { document, blob } =
        gltf::Gltf::from_slice_without_validation(data).map_err(invalid)?;
    let json = document.into_json();
    check_position_accessors(&json)?;
    let document = gltf::Document::from_json(json).map_err(invalid)?;
    let roots: Vec<gltf::Node> = match document
        .default_scene()
        .or_else(|| document.scenes().next())
    {
        Some(scene) => scene.nodes().collect(),
        None => {
            // No scene: every node that is nobody's child is a root.
            let mut is_child = vec![false; document.nodes().len()];
            for node in document.nodes() {
                for child in node.children() {
                    is_child[child.index()] = true;
                }
            }
            document.nodes().filter(|n| !is_child[n.index()]).collect()
        }
    };
    check_expansion(&document, &roots, options.max_triangles)?;
    let buffers = load_buffers(&document, blob, options)?;
    let mut on_path = vec![false; document.nodes().len()];
    let mut ancestors = Vec::new();
    let mut textures = Textures {
        options,
        buffers: &buffers,
        means: rustc_hash::FxHashMap::default(),
        warnings: Vec::new(),
    };
    for root in roots {
        walk(
            &root,
            DMat4::IDENTITY,
            &mut ancestors,
            &mut on_path,
            &mut textures,
            soup,
        )?;
    }
    soup.warnings.extend(textures.warnings);
    Ok(())
}

/// The most bytes one texture file may hold (real base-colour textures are a few MiB).
const MAX_IMAGE_FILE_BYTES: u64 = 256 << 20;

/// Base-colour textures' means, each image decoded once, and the images that could not be.
struct Textures<'a> {
    options: &'a GltfOptions<'a>,
    buffers: &'a [Buffer],
    /// By image index: the mean linear RGBA, or none for an image that could not be read.
    means: rustc_hash::FxHashMap<usize, Option<[f64; 4]>>,
    warnings: Vec<String>,
}

impl Textures<'_> {
    /// The colour of `material`: its factor, times its base-colour texture's mean.
    fn colour(&mut self, material: &gltf::Material) -> [f64; 4] {
        let pbr = material.pbr_metallic_roughness();
        let factor = pbr.base_color_factor().map(f64::from);
        let Some(info) = pbr.base_color_texture() else {
            return factor;
        };
        let image = info.texture().source();
        let index = image.index();
        if !self.means.contains_key(&index) {
            let mean = match self
                .image_bytes(&image)
                .and_then(|b| crate::texture::average(&b))
            {
                Ok(mean) => Some(mean),
                Err(why) => {
                    let name = match image.source() {
                        gltf::image::Source::Uri { uri, .. } if !uri.starts_with("data:") => {
                            format!(" ({uri})")
                        }
                        _ => String::new(),
                    };
                    self.warnings.push(format!(
                        "image {index}{name}: {why}; its materials' colours are their \
                         baseColorFactor alone"
                    ));
                    None
                }
            };
            self.means.insert(index, mean);
        }
        match self.means[&index] {
            Some(mean) => std::array::from_fn(|k| factor[k] * mean[k]),
            None => factor,
        }
    }

    /// The encoded bytes of `image`: a buffer view, a `data:` URI or a file beside the model.
    fn image_bytes(&self, image: &gltf::Image) -> Result<Vec<u8>, String> {
        match image.source() {
            gltf::image::Source::View { view, .. } => {
                let buffer = self
                    .buffers
                    .get(view.buffer().index())
                    .ok_or("its buffer view names no buffer")?;
                let start = view.offset();
                let end = start
                    .checked_add(view.length())
                    .filter(|&end| end <= buffer.len)
                    .ok_or("its buffer view reaches past its buffer")?;
                Ok(buffer.as_slice()[start..end].to_vec())
            }
            gltf::image::Source::Uri { uri, .. } => {
                if let Some(rest) = uri.strip_prefix("data:") {
                    let (_, payload) = rest
                        .split_once(";base64,")
                        .ok_or("data URI is not base64")?;
                    return base64::engine::general_purpose::STANDARD
                        .decode(payload)
                        .map_err(|e| format!("bad base64: {e}"));
                }
                let path = uri::resolve(uri, self.options.folder, self.options.allow_external_uris)
                    .map_err(|reason| format!("refused: {reason}"))?;
                let inside = (!self.options.allow_external_uris)
                    .then_some(self.options.folder)
                    .flatten();
                let file = uri::open_buffer_file(&path, inside)?;
                if file.size > MAX_IMAGE_FILE_BYTES {
                    return Err(format!(
                        "{} bytes, more than the {MAX_IMAGE_FILE_BYTES} a texture may hold",
                        file.size
                    ));
                }
                file.read_prefix(MAX_IMAGE_FILE_BYTES)
            }
        }
    }
}

/// gltf-json 1.4's validation indexes `accessors` with a primitive's POSITION index before
/// checking it (`primitive_validate_hook` in its mesh.rs), so a hostile file would panic it.
/// This checks those indices first, so validation never sees a dangling one.
fn check_position_accessors(json: &gltf::json::Root) -> Result<(), FormatError> {
    use gltf::json::validation::Checked;
    for (mesh_index, mesh) in json.meshes.iter().enumerate() {
        for (primitive_index, primitive) in mesh.primitives.iter().enumerate() {
            let position = primitive
                .attributes
                .get(&Checked::Valid(gltf::json::mesh::Semantic::Positions));
            if position.is_some_and(|index| index.value() >= json.accessors.len()) {
                return Err(FormatError::syntax(
                    Location::Element {
                        kind: format!("mesh {mesh_index} primitive"),
                        index: primitive_index as u64,
                    },
                    "POSITION refers to an accessor that does not exist",
                ));
            }
        }
    }
    Ok(())
}

/// Node instances are limited like triangles (each costs a transform in the walk), but never
/// below 2²⁶ ≈ 67 M, which walk in about a second: a small `max_triangles` should not refuse
/// a file for its empty grouping nodes.
const MIN_INSTANCE_LIMIT: u64 = 1 << 26;

/// What a node's subtree expands to when every instance is read: triangles, vertices and
/// node instances, each saturating at `u64::MAX`.
#[derive(Clone, Copy, Default)]
struct Expansion {
    triangles: u64,
    vertices: u64,
    instances: u64,
    /// Memory the part names of the instances take (each instance of a mesh with triangles
    /// is a part, and so is each instance of a node above one): a 1 MB name instanced a
    /// million times is a terabyte of names.
    name_bytes: u64,
}

impl Expansion {
    fn add(&mut self, other: Expansion) {
        self.triangles = self.triangles.saturating_add(other.triangles);
        self.vertices = self.vertices.saturating_add(other.vertices);
        self.instances = self.instances.saturating_add(other.instances);
        self.name_bytes = self.name_bytes.saturating_add(other.name_bytes);
    }
}

/// The most bytes all part names may take together, counted with a `String`'s own 24 bytes
/// each: 256 MiB, far beyond any real assembly's names (a million parts of 200 characters).
const MAX_NAME_BYTES: u64 = 1 << 28;

/// The name of the part a node's instance becomes: the node's name, else its mesh's, else
/// `node N`.
fn part_name(node: &gltf::Node) -> String {
    let mesh = node.mesh();
    node.name()
        .or(mesh.as_ref().and_then(|m| m.name()))
        .map_or_else(|| format!("node {}", node.index()), str::to_string)
}

/// Refuses an instance tree that would expand past `max_triangles` before anything is
/// expanded: a node listed twice by each of 40 nested nodes is 2⁴⁰ instances in a few
/// hundred bytes. Each node's expansion is computed once (memoised over the node graph), so
/// this costs one visit per node and per child link; the error names the deepest node whose
/// subtree alone is over the limit, which is where the instancing multiplies.
fn check_expansion(
    document: &gltf::Document,
    roots: &[gltf::Node],
    max_triangles: u64,
) -> Result<(), FormatError> {
    let meshes: Vec<Expansion> = document.meshes().map(|m| mesh_expansion(&m)).collect();
    let mut memo: Vec<Option<Expansion>> = vec![None; document.nodes().len()];
    let mut on_path = vec![false; document.nodes().len()];
    let mut total = Expansion::default();
    for root in roots {
        total.add(node_expansion(root, 0, &meshes, &mut memo, &mut on_path)?);
    }
    // Which count is over, in the order that matters most for memory.
    let vertex_limit = max_triangles.saturating_mul(3);
    let (what, limit, count): (&str, u64, fn(&Expansion) -> u64) =
        if total.triangles > max_triangles {
            ("triangles", max_triangles, |e| e.triangles)
        } else if total.vertices > vertex_limit {
            (
                "vertices (at most 3 per allowed triangle)",
                vertex_limit,
                |e| e.vertices,
            )
        } else if total.instances > max_triangles.max(MIN_INSTANCE_LIMIT) {
            (
                "node instances",
                max_triangles.max(MIN_INSTANCE_LIMIT),
                |e| e.instances,
            )
        } else if total.name_bytes > MAX_NAME_BYTES {
            ("bytes of part names", MAX_NAME_BYTES, |e| e.name_bytes)
        } else {
            return Ok(());
        };
    // Walk down from the roots to the deepest node that is over the limit on its own.
    let mut culprit: Option<gltf::Node> = None;
    let mut candidates: Vec<gltf::Node> = roots.to_vec();
    while let Some(node) = candidates
        .iter()
        .find(|n| memo[n.index()].is_some_and(|e| count(&e) > limit))
        .cloned()
    {
        candidates = node.children().collect();
        culprit = Some(node);
    }
    let amount = culprit
        .as_ref()
        .and_then(|n| memo[n.index()])
        .map_or(count(&total), |e| count(&e));
    let (location, whose) = match &culprit {
        Some(node) => (
            Location::Element {
                kind: "node".into(),
                index: node.index() as u64,
            },
            match node.name() {
                Some(name) => format!("node '{name}' with its instances expands to {what}:"),
                None => format!("the node with its instances expands to {what}:"),
            },
        ),
        None => (
            Location::File,
            format!("the scene with its instances expands to {what}:"),
        ),
    };
    Err(FormatError::new(
        location,
        Problem::LimitExceeded {
            what: whose,
            amount,
            limit,
            // The part-name limit is fixed; the others follow --max-triangles.
            option: if limit == MAX_NAME_BYTES && what == "bytes of part names" {
                ""
            } else {
                "--max-triangles"
            },
        },
    ))
}

/// Triangles and vertices of one instance of a mesh, from its accessors' counts.
fn mesh_expansion(mesh: &gltf::Mesh) -> Expansion {
    let mut out = Expansion::default();
    for primitive in mesh.primitives() {
        let vertices = primitive
            .get(&gltf::Semantic::Positions)
            .map_or(0, |a| a.count() as u64);
        let corners = primitive.indices().map_or(vertices, |a| a.count() as u64);
        let triangles = match primitive.mode() {
            Mode::Triangles => corners / 3,
            Mode::TriangleStrip | Mode::TriangleFan => corners.saturating_sub(2),
            _ => 0,
        };
        out.add(Expansion {
            triangles,
            vertices,
            ..Expansion::default()
        });
    }
    out
}

fn node_expansion(
    node: &gltf::Node,
    depth: usize,
    meshes: &[Expansion],
    memo: &mut [Option<Expansion>],
    on_path: &mut [bool],
) -> Result<Expansion, FormatError> {
    if let Some(known) = memo[node.index()] {
        return Ok(known);
    }
    if depth > MAX_NODE_DEPTH || on_path[node.index()] {
        return Err(FormatError::syntax(
            Location::Element {
                kind: "node".into(),
                index: node.index() as u64,
            },
            "node hierarchy has a cycle or is too deep",
        ));
    }
    on_path[node.index()] = true;
    let mut out = Expansion {
        instances: 1,
        ..node
            .mesh()
            .map_or_else(Expansion::default, |m| meshes[m.index()])
    };
    for child in node.children() {
        out.add(node_expansion(&child, depth + 1, meshes, memo, on_path)?);
    }
    // A part per instance with triangles of its own, or with triangles below it.
    if out.triangles > 0 {
        out.name_bytes = out
            .name_bytes
            .saturating_add(24 + size_of::<crate::PartInfo>() as u64)
            .saturating_add(part_name(node).len() as u64);
    }

    on_path[node.index()] = false;
    memo[node.index()] = Some(out);
    Ok(out)
}

/// A buffer's bytes: its own, or a share of a file that several buffers name.
struct Buffer {
    bytes: Rc<[u8]>,
    /// How many of `bytes` are this buffer's (at most its `byteLength`).
    len: usize,
}

impl Buffer {
    fn as_slice(&self) -> &[u8] {
        &self.bytes[..self.len]
    }
}

/// Where a buffer's bytes come from, before any file is read.
enum Origin {
    Bytes(Vec<u8>),
    /// Index into the distinct files.
    File(usize),
}

/// Reads every buffer. A file is read once however many buffers name it (by any path or
/// link), up to the largest `byteLength` among them: a hundred buffers naming one large file
/// cost its size once, not a hundred times.
fn load_buffers(
    document: &gltf::Document,
    blob: Option<Vec<u8>>,
    options: &GltfOptions,
) -> Result<Vec<Buffer>, FormatError> {
    let mut blob = blob;
    let mut origins = Vec::new();
    let mut files: Vec<(uri::BufferFile, u64, PathBuf)> = Vec::new();
    for buffer in document.buffers() {
        let at = || Location::Element {
            kind: "buffer".into(),
            index: buffer.index() as u64,
        };
        let origin = match buffer.source() {
            gltf::buffer::Source::Bin => Origin::Bytes(blob.take().ok_or_else(|| {
                FormatError::syntax(
                    at(),
                    "GLB has no binary chunk (or a second buffer claims it)",
                )
            })?),
            gltf::buffer::Source::Uri(uri) => {
                if let Some(rest) = uri.strip_prefix("data:") {
                    let (_, payload) = rest
                        .split_once(";base64,")
                        .ok_or_else(|| FormatError::syntax(at(), "data URI is not base64"))?;
                    Origin::Bytes(
                        base64::engine::general_purpose::STANDARD
                            .decode(payload)
                            .map_err(|e| FormatError::syntax(at(), format!("bad base64: {e}")))?,
                    )
                } else {
                    let path = uri::resolve(uri, options.folder, options.allow_external_uris)
                        .map_err(|reason| {
                            FormatError::new(
                                at(),
                                Problem::RefusedUri {
                                    uri: uri.to_string(),
                                    reason,
                                },
                            )
                        })?;
                    let inside = (!options.allow_external_uris)
                        .then_some(options.folder)
                        .flatten();
                    let file = uri::open_buffer_file(&path, inside).map_err(|e| {
                        FormatError::syntax(at(), format!("cannot read {}: {e}", path.display()))
                    })?;
                    let need = buffer.length() as u64;
                    match files
                        .iter()
                        .position(|(f, _, _)| f.identity == file.identity)
                    {
                        Some(known) => {
                            files[known].1 = files[known].1.max(need);
                            Origin::File(known)
                        }
                        None => {
                            files.push((file, need, path));
                            Origin::File(files.len() - 1)
                        }
                    }
                }
            }
        };
        origins.push(origin);
    }
    // External buffers are read into memory: together they may hold at most what a `.gz`
    // input may decompress to (a sparse file of a terabyte costs nothing on disk).
    let external: u64 = files
        .iter()
        .map(|(file, need, _)| (*need).min(file.size))
        .fold(0, u64::saturating_add);
    if external > options.max_buffer_bytes {
        return Err(FormatError::new(
            Location::File,
            Problem::LimitExceeded {
                what: "the external buffers hold".into(),
                amount: external,
                limit: options.max_buffer_bytes,
                option: "--max-decompressed-bytes",
            },
        ));
    }
    let mut shared: Vec<Rc<[u8]>> = Vec::with_capacity(files.len());
    for (file, need, path) in files {
        let bytes = file.read_prefix(need).map_err(|e| {
            FormatError::syntax(
                Location::File,
                format!("cannot read {}: {e}", path.display()),
            )
        })?;
        shared.push(bytes.into());
    }
    let mut out = Vec::with_capacity(origins.len());
    for (buffer, origin) in document.buffers().zip(origins) {
        let bytes: Rc<[u8]> = match origin {
            Origin::Bytes(bytes) => bytes.into(),
            Origin::File(index) => Rc::clone(&shared[index]),
        };
        let len = bytes.len().min(buffer.length());
        if len < buffer.length() {
            return Err(FormatError::new(
                Location::Element {
                    kind: "buffer".into(),
                    index: buffer.index() as u64,
                },
                Problem::Truncated {
                    needed: buffer.length() as u64,
                    available: len as u64,
                },
            ));
        }
        out.push(Buffer { bytes, len });
    }
    Ok(out)
}

/// A node on the path from a root to the node being walked, and the part its instance
/// became on this path, once one has (an ancestor becomes a part only when a node below it
/// has triangles, so that grouping nodes without geometry leave no parts).
struct Ancestor<'a> {
    node: gltf::Node<'a>,
    part: Option<u32>,
}

fn walk<'a>(
    node: &gltf::Node<'a>,
    parent: DMat4,
    ancestors: &mut Vec<Ancestor<'a>>,
    on_path: &mut [bool],
    textures: &mut Textures<'_>,
    soup: &mut MeshSoup,
) -> Result<(), FormatError> {
    let buffers = textures.buffers;
    let at = || Location::Element {
        kind: "node".into(),
        index: node.index() as u64,
    };
    if ancestors.len() > MAX_NODE_DEPTH || on_path[node.index()] {
        return Err(FormatError::syntax(
            at(),
            "node hierarchy has a cycle or is too deep",
        ));
    }
    on_path[node.index()] = true;
    let local = node.transform().matrix().map(|c| c.map(f64::from));
    let world = parent * DMat4::from_cols_array_2d(&local);
    let mut own_part = None;
    if let Some(mesh) = node.mesh() {
        // The part is named only once it has triangles: a mesh of empty primitives
        // instanced many times must not leave a name per instance. Its id comes after the
        // ancestors that become parts with it.
        let pending = ancestors.iter().filter(|a| a.part.is_none()).count();
        let part = (soup.part_names.len() + pending) as u32;
        let before = soup.triangles.len();
        let mut color = crate::soup::ColorSum::default();
        for primitive in mesh.primitives() {
            let first = soup.triangles.len();
            read_primitive(&mesh, &primitive, &world, buffers, part, soup)?;
            let material = primitive.material();
            if material.index().is_some() {
                let rgba = textures.colour(&material);
                color.add_weighted(rgba, (soup.triangles.len() - first) as u64);
            }
        }
        if soup.triangles.len() > before {
            let mut above = None;
            for ancestor in ancestors.iter_mut() {
                let id = *ancestor
                    .part
                    .get_or_insert_with(|| soup.begin_child_part(part_name(&ancestor.node), above));
                above = Some(id);
            }
            let id = soup.begin_child_part(part_name(node), above);
            debug_assert_eq!(id, part);
            soup.parts[id as usize].color = color.mean();
            own_part = Some(id);
        }
    }
    ancestors.push(Ancestor {
        node: node.clone(),
        part: own_part,
    });
    for child in node.children() {
        walk(&child, world, ancestors, on_path, textures, soup)?;
    }
    ancestors.pop();
    on_path[node.index()] = false;
    Ok(())
}

/// The bytes of an accessor's elements: `(data, stride)`, with every range checked.
fn accessor_bytes<'b>(
    accessor: &gltf::Accessor,
    element_size: usize,
    buffers: &'b [Buffer],
    at: &dyn Fn() -> Location,
) -> Result<(&'b [u8], usize), FormatError> {
    if accessor.sparse().is_some() {
        return Err(FormatError::new(
            at(),
            Problem::Unsupported("sparse accessors".into()),
        ));
    }
    let view = accessor.view().ok_or_else(|| {
        FormatError::new(
            at(),
            Problem::Unsupported("accessor without buffer view".into()),
        )
    })?;
    let buffer = buffers
        .get(view.buffer().index())
        .ok_or_else(|| FormatError::syntax(at(), "buffer view names a missing buffer"))?
        .as_slice();
    let stride = view.stride().unwrap_or(element_size);
    let overflow = || FormatError::syntax(at(), "accessor byte range overflows");
    let view_end = view
        .offset()
        .checked_add(view.length())
        .ok_or_else(overflow)?;
    let view_bytes = buffer.get(view.offset()..view_end).ok_or_else(|| {
        FormatError::new(
            at(),
            Problem::Truncated {
                needed: view_end as u64,
                available: buffer.len() as u64,
            },
        )
    })?;
    let count = accessor.count();
    let end = match count {
        0 => accessor.offset(),
        _ => stride
            .checked_mul(count - 1)
            .and_then(|n| n.checked_add(element_size))
            .and_then(|n| n.checked_add(accessor.offset()))
            .ok_or_else(overflow)?,
    };
    if stride < element_size || end > view_bytes.len() {
        return Err(FormatError::syntax(
            at(),
            "accessor does not fit in its buffer view",
        ));
    }
    Ok((&view_bytes[accessor.offset()..end], stride))
}

fn read_primitive(
    mesh: &gltf::Mesh,
    primitive: &gltf::Primitive,
    world: &DMat4,
    buffers: &[Buffer],
    part: u32,
    soup: &mut MeshSoup,
) -> Result<(), FormatError> {
    let at = || Location::Element {
        kind: format!("mesh {} primitive", mesh.index()),
        index: primitive.index() as u64,
    };
    let mode = primitive.mode();
    if !matches!(
        mode,
        Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
    ) {
        return Err(FormatError::new(
            at(),
            Problem::UnsupportedPrimitiveMode(format!("{mode:?}")),
        ));
    }
    let positions = primitive
        .get(&gltf::Semantic::Positions)
        .ok_or_else(|| FormatError::syntax(at(), "primitive has no POSITION attribute"))?;
    if positions.dimensions() != Dimensions::Vec3
        || positions.data_type() != DataType::F32
        || positions.normalized()
    {
        return Err(FormatError::new(
            at(),
            Problem::Unsupported("POSITION that is not a float VEC3 (quantised meshes)".into()),
        ));
    }
    let (bytes, stride) = accessor_bytes(&positions, 12, buffers, &at)?;
    let vertex_count = positions.count();
    let base = soup.vertex_count() as u32;
    soup.positions.reserve(vertex_count);
    for i in 0..vertex_count {
        let record = &bytes[i * stride..i * stride + 12];
        let coord = |k: usize| {
            f64::from(f32::from_le_bytes(
                record[4 * k..4 * k + 4].try_into().expect("4 bytes"),
            ))
        };
        let p = world.transform_point3(DVec3::new(coord(0), coord(1), coord(2)));
        soup.push_vertex([p.x as f32, p.y as f32, p.z as f32], at)?;
    }

    let indices: Vec<u32> = match primitive.indices() {
        Some(accessor) => {
            let size = match (accessor.dimensions(), accessor.data_type()) {
                (Dimensions::Scalar, DataType::U8) => 1,
                (Dimensions::Scalar, DataType::U16) => 2,
                (Dimensions::Scalar, DataType::U32) => 4,
                _ => {
                    return Err(FormatError::syntax(
                        at(),
                        "indices must be unsigned scalars",
                    ));
                }
            };
            let (bytes, stride) = accessor_bytes(&accessor, size, buffers, &at)?;
            let mut out = Vec::with_capacity(accessor.count());
            for i in 0..accessor.count() {
                let b = &bytes[i * stride..];
                let index = match size {
                    1 => u32::from(b[0]),
                    2 => u32::from(u16::from_le_bytes([b[0], b[1]])),
                    _ => u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
                };
                out.push(base + check_index(i64::from(index), vertex_count, at)?);
            }
            out
        }
        None => (base..base + vertex_count as u32).collect(),
    };
    match mode {
        Mode::Triangles => {
            for t in indices.chunks_exact(3) {
                soup.push_polygon(part, t);
            }
        }
        Mode::TriangleStrip => {
            for (i, w) in indices.windows(3).enumerate() {
                // Every other strip triangle is flipped to keep a consistent winding.
                let t = if i % 2 == 0 {
                    [w[0], w[1], w[2]]
                } else {
                    [w[1], w[0], w[2]]
                };
                soup.push_polygon(part, &t);
            }
        }
        _ => {
            if let Some((&first, rest)) = indices.split_first() {
                for w in rest.windows(2) {
                    soup.push_polygon(part, &[first, w[0], w[1]]);
                }
            }
        }
    }
    Ok(())
}

#[cfg(all(test, unix))]
mod tests {
    use super::*;

    #[test]
    fn buffers_naming_one_file_share_its_bytes() {
        let dir = std::env::temp_dir().join(format!("vds-gltf-share-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("a.bin"), [7u8; 100]).unwrap();
        std::os::unix::fs::symlink("a.bin", dir.join("b.bin")).unwrap();
        std::fs::hard_link(dir.join("a.bin"), dir.join("c.bin")).unwrap();
        std::fs::write(dir.join("d.bin"), [7u8; 100]).unwrap();
        let json = r#"{"asset":{"version":"2.0"},"buffers":[
            {"byteLength":10,"uri":"a.bin"},{"byteLength":60,"uri":"b.bin"},
            {"byteLength":30,"uri":"c.bin"},{"byteLength":30,"uri":"d.bin"}]}"#;
        let gltf = gltf::Gltf::from_slice(json.as_bytes()).unwrap();
        let options = GltfOptions {
            folder: Some(&dir),
            allow_external_uris: false,
            max_triangles: 1,
            max_buffer_bytes: 1 << 20,
        };
        let buffers = load_buffers(&gltf.document, None, &options).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        assert!(Rc::ptr_eq(&buffers[0].bytes, &buffers[1].bytes));
        assert!(Rc::ptr_eq(&buffers[0].bytes, &buffers[2].bytes));
        assert!(!Rc::ptr_eq(&buffers[0].bytes, &buffers[3].bytes));
        // Read once, up to the largest byteLength naming the file; each sees its own length.
        assert_eq!(buffers[0].bytes.len(), 60);
        let lengths: Vec<usize> = buffers.iter().map(|b| b.as_slice().len()).collect();
        assert_eq!(lengths, [10, 60, 30, 30]);
    }
}
