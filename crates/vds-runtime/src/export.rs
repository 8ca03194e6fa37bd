//! The current cut as an ordinary indexed mesh, and writing it as OBJ or PLY: what
//! `vds-cut` exports ("what the viewer would draw from here").
//!
//! Files are written through [`vds_format::write_atomically`], the workspace's one atomic
//! writer: to a temporary name beside the target, renamed into place, so a failed export never
//! leaves a half-written file; an output that is a device, a directory or anything else but a
//! regular file is refused.

use std::io::Write;
use std::path::Path;

use vds_format::OutputError;

use rustc_hash::FxHashMap;

use crate::cut::Cut;

/// An indexed triangle mesh.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions: the proxies of the boundary nodes the triangles use.
    pub positions: Vec<[f32; 3]>,
    /// Triangles, sorted by part, then by triangle index in the file.
    pub triangles: Vec<[u32; 3]>,
    /// Part id of each triangle.
    pub parts: Vec<u32>,
}

impl Mesh {
    /// The active triangles of `cut`, with vertices numbered in order of first use.
    pub fn from_cut(cut: &mut Cut) -> Mesh {
        let mut active = cut.active_triangles();
        let store = cut.store();
        active.sort_unstable_by_key(|t| (store.triangle_part(t.triangle), t.triangle));
        let mut index_of: FxHashMap<u32, u32> = FxHashMap::default();
        let mut mesh = Mesh::default();
        for t in &active {
            let corners = t.corners.map(|node| {
                *index_of.entry(node).or_insert_with(|| {
                    mesh.positions.push(cut.node(node).proxy);
                    mesh.positions.len() as u32 - 1
                })
            });
            mesh.triangles.push(corners);
            mesh.parts.push(cut.store().triangle_part(t.triangle));
        }
        mesh
    }
}

/// Output formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeshFormat {
    /// Wavefront OBJ, one object per part.
    Obj,
    /// Binary little-endian PLY with a per-face `part` property.
    Ply,
}

impl MeshFormat {
    /// The format named by `path`'s extension (`.obj` or `.ply`, any case).
    pub fn of(path: &Path) -> Option<MeshFormat> {
        let extension = path.extension()?.to_str()?.to_ascii_lowercase();
        match extension.as_str() {
            "obj" => Some(MeshFormat::Obj),
            "ply" => Some(MeshFormat::Ply),
            _ => None,
        }
    }
}

/// Writes `mesh` to `path` atomically. `part_names` name the OBJ objects (missing names are
/// numbered).
///
/// # Errors
/// [`OutputError::NotRegularFile`] when `path` names something other than a regular file,
/// [`OutputError::Io`] when writing fails (the target is then left as it was).
pub fn write_mesh(
    path: &Path,
    mesh: &Mesh,
    format: MeshFormat,
    part_names: &[String],
) -> Result<(), OutputError> {
    vds_format::write_atomically(path, |out| match format {
        MeshFormat::Obj => write_obj(out, mesh, part_names),
        MeshFormat::Ply => write_ply(out, mesh),
    })
}

fn write_obj(out: &mut dyn Write, mesh: &Mesh, part_names: &[String]) -> std::io::Result<()> {
    writeln!(out, "# vds-cut: {} triangles", mesh.triangles.len())?;
    for p in &mesh.positions {
        writeln!(out, "v {} {} {}", p[0], p[1], p[2])?;
    }
    let mut current = None;
    for (t, &part) in mesh.triangles.iter().zip(&mesh.parts) {
        if current != Some(part) {
            current = Some(part);
            match part_names.get(part as usize) {
                // OBJ names end at the line; keep them on one line.
                Some(name) if !name.is_empty() => {
                    writeln!(out, "o {}", name.replace(['\n', '\r'], " "))?
                }
                _ => writeln!(out, "o part{part}")?,
            }
        }
        writeln!(out, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1)?;
    }
    Ok(())
}

fn write_ply(out: &mut dyn Write, mesh: &Mesh) -> std::io::Result<()> {
    write!(
        out,
        "ply\nformat binary_little_endian 1.0\ncomment vds-cut\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\nelement face {}\n\
         property list uchar uint vertex_indices\nproperty uint part\nend_header\n",
        mesh.positions.len(),
        mesh.triangles.len()
    )?;
    for p in &mesh.positions {
        for c in p {
            out.write_all(&c.to_le_bytes())?;
        }
    }
    for (t, &part) in mesh.triangles.iter().zip(&mesh.parts) {
        out.write_all(&[3])?;
        for v in t {
            out.write_all(&v.to_le_bytes())?;
        }
        out.write_all(&part.to_le_bytes())?;
    }
    Ok(())
}
