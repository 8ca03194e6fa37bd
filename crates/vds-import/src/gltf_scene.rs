//! glTF 2.0 (`.gltf` with external or embedded buffers, and `.glb`) through the `gltf` crate:
//! walks the default scene's node hierarchy, applies world transforms, and reads every
//! triangle primitive (strips and fans converted). Each mesh-carrying node becomes a part.
//!
//! The `gltf` crate parses and validates the JSON; accessor data is read here, after checking
//! every byte range with checked arithmetic, because the crate's own accessor iterators
//! assume well-formed ranges (a zero count or an overflowing stride would panic there).

use std::path::Path;

use base64::Engine as _;
use glam::{DMat4, DVec3};
use gltf::accessor::{DataType, Dimensions};
use gltf::mesh::Mode;

use crate::error::{FormatError, Location, Problem};
use crate::soup::{MeshSoup, check_index};

/// glTF node trees deeper than this are rejected: real scenes nest a few dozen levels, and the
/// limit bounds recursion on hostile files.
const MAX_NODE_DEPTH: usize = 1024;

/// Reads a glTF or GLB file's bytes into `soup`. `path` locates external buffers.
pub fn read_gltf(data: &[u8], path: &Path, soup: &mut MeshSoup) -> Result<(), FormatError> {
    // gltf-json 1.4's validation indexes `accessors` with a POSITION index before checking it
    // (mesh.rs, `primitive_validate_hook`), so a hostile file can panic it. Until that is
    // fixed upstream, a panic there is turned into the error it should have been.
    let parsed = std::panic::catch_unwind(|| gltf::Gltf::from_slice(data)).map_err(|_| {
        FormatError::syntax(
            Location::File,
            "invalid glTF: a primitive refers to an accessor that does not exist",
        )
    })?;
    let gltf =
        parsed.map_err(|e| FormatError::syntax(Location::File, format!("invalid glTF: {e}")))?;
    let buffers = load_buffers(&gltf, path)?;
    let document = &gltf.document;
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
    let mut on_path = vec![false; document.nodes().len()];
    for root in roots {
        walk(&root, DMat4::IDENTITY, 0, &mut on_path, &buffers, soup)?;
    }
    Ok(())
}

fn load_buffers(gltf: &gltf::Gltf, path: &Path) -> Result<Vec<Vec<u8>>, FormatError> {
    let mut out = Vec::new();
    for buffer in gltf.document.buffers() {
        let at = || Location::Element {
            kind: "buffer".into(),
            index: buffer.index() as u64,
        };
        let bytes = match buffer.source() {
            gltf::buffer::Source::Bin => gltf
                .blob
                .clone()
                .ok_or_else(|| FormatError::syntax(at(), "GLB has no binary chunk"))?,
            gltf::buffer::Source::Uri(uri) => {
                if let Some(rest) = uri.strip_prefix("data:") {
                    let (_, payload) = rest
                        .split_once(";base64,")
                        .ok_or_else(|| FormatError::syntax(at(), "data URI is not base64"))?;
                    base64::engine::general_purpose::STANDARD
                        .decode(payload)
                        .map_err(|e| FormatError::syntax(at(), format!("bad base64: {e}")))?
                } else {
                    let file = path
                        .parent()
                        .unwrap_or(Path::new("."))
                        .join(uri.replace("%20", " "));
                    std::fs::read(&file).map_err(|e| {
                        FormatError::syntax(at(), format!("cannot read {}: {e}", file.display()))
                    })?
                }
            }
        };
        if bytes.len() < buffer.length() {
            return Err(FormatError::new(
                at(),
                Problem::Truncated {
                    needed: buffer.length() as u64,
                    available: bytes.len() as u64,
                },
            ));
        }
        out.push(bytes);
    }
    Ok(out)
}

fn walk(
    node: &gltf::Node,
    parent: DMat4,
    depth: usize,
    on_path: &mut [bool],
    buffers: &[Vec<u8>],
    soup: &mut MeshSoup,
) -> Result<(), FormatError> {
    let at = || Location::Element {
        kind: "node".into(),
        index: node.index() as u64,
    };
    if depth > MAX_NODE_DEPTH || on_path[node.index()] {
        return Err(FormatError::syntax(
            at(),
            "node hierarchy has a cycle or is too deep",
        ));
    }
    on_path[node.index()] = true;
    let local = node.transform().matrix().map(|c| c.map(f64::from));
    let world = parent * DMat4::from_cols_array_2d(&local);
    if let Some(mesh) = node.mesh() {
        let name = node
            .name()
            .or(mesh.name())
            .map_or_else(|| format!("node {}", node.index()), str::to_string);
        let part = soup.begin_part(name);
        for primitive in mesh.primitives() {
            read_primitive(&mesh, &primitive, &world, buffers, part, soup)?;
        }
    }
    for child in node.children() {
        walk(&child, world, depth + 1, on_path, buffers, soup)?;
    }
    on_path[node.index()] = false;
    Ok(())
}

/// The bytes of an accessor's elements: `(data, stride)`, with every range checked.
fn accessor_bytes<'b>(
    accessor: &gltf::Accessor,
    element_size: usize,
    buffers: &'b [Vec<u8>],
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
        .ok_or_else(|| FormatError::syntax(at(), "buffer view names a missing buffer"))?;
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
    buffers: &[Vec<u8>],
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
    let base = soup.positions.len() as u32;
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
