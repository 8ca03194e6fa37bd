//! Deterministic CAD-like scene generation for tests and benchmarks.
//!
//! A scene is a grid of "machine cells", each holding what CAD assemblies are made of: large
//! thin shells (housings), pipes with flanges and bolt circles, perforated plates, and many
//! small parts (bolts, nuts, brackets) beside them. Like real CAD exports, parts are
//! tessellated separately and never welded to each other, flanges touch pipes without sharing
//! vertices (T-junctions, cracks), some parts are duplicated in place (coincident geometry)
//! and some fins share an edge three ways (non-manifold).
//!
//! The output depends only on the requested triangle count: a small integer hash drives every
//! choice, never a clock or a thread.

use std::f32::consts::TAU;

/// A generated scene: triangle soup with a part id per triangle.
#[derive(Debug, Default, Clone, PartialEq)]
pub struct GeneratedScene {
    /// Vertex positions.
    pub positions: Vec<[f32; 3]>,
    /// Triangles.
    pub triangles: Vec<[u32; 3]>,
    /// Part id of each triangle.
    pub triangle_parts: Vec<u32>,
    /// Number of parts.
    pub part_count: u32,
}

/// A small deterministic hash (SplitMix64 finaliser) for reproducible "random" choices.
fn hash(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// A number in `[0, 1)` from a seed.
fn unit(seed: u64) -> f32 {
    (hash(seed) >> 40) as f32 / (1u64 << 24) as f32
}

impl GeneratedScene {
    fn begin_part(&mut self) -> u32 {
        self.part_count += 1;
        self.part_count - 1
    }

    fn vertex(&mut self, p: [f32; 3]) -> u32 {
        self.positions.push(p);
        self.positions.len() as u32 - 1
    }

    fn triangle(&mut self, part: u32, t: [u32; 3]) {
        self.triangles.push(t);
        self.triangle_parts.push(part);
    }

    /// A grid of `(rows+1) × (cols+1)` vertices from `point(u, v)`, triangulated; `wrap_u`
    /// closes the surface in u (a tube).
    fn grid(
        &mut self,
        part: u32,
        rows: u32,
        cols: u32,
        wrap_u: bool,
        point: impl Fn(f32, f32) -> [f32; 3],
    ) {
        let base = self.positions.len() as u32;
        let ring = if wrap_u { rows } else { rows + 1 };
        for j in 0..=cols {
            for i in 0..ring {
                self.vertex(point(i as f32 / rows as f32, j as f32 / cols as f32));
            }
        }
        for j in 0..cols {
            for i in 0..rows {
                let i1 = if wrap_u { (i + 1) % rows } else { i + 1 };
                let a = base + j * ring + i;
                let b = base + j * ring + i1;
                let c = base + (j + 1) * ring + i;
                let d = base + (j + 1) * ring + i1;
                self.triangle(part, [a, b, d]);
                self.triangle(part, [a, d, c]);
            }
        }
    }

    /// A pipe along x from `origin`, radius `r`, length `length`, with flanges at both ends.
    fn pipe(&mut self, origin: [f32; 3], r: f32, length: f32, detail: u32) {
        let part = self.begin_part();
        let segments = detail.max(8);
        self.grid(part, segments, detail.max(2), true, |u, v| {
            let a = u * TAU;
            [
                origin[0] + v * length,
                origin[1] + r * a.cos(),
                origin[2] + r * a.sin(),
            ]
        });
        for end in [0.0, length] {
            // The flange is an annulus touching the pipe without sharing vertices: a crack.
            let flange = self.begin_part();
            self.grid(flange, segments, 2, true, |u, v| {
                let a = u * TAU;
                let rr = r * (1.0 + v);
                [
                    origin[0] + end,
                    origin[1] + rr * a.cos(),
                    origin[2] + rr * a.sin(),
                ]
            });
            for k in 0..6 {
                let a = k as f32 * TAU / 6.0;
                let centre = [
                    origin[0] + end,
                    origin[1] + 1.6 * r * a.cos(),
                    origin[2] + 1.6 * r * a.sin(),
                ];
                self.bolt(centre, 0.12 * r, detail / 4);
            }
        }
    }

    /// A small bolt: hexagonal head and shank, a closed little part.
    fn bolt(&mut self, centre: [f32; 3], r: f32, detail: u32) {
        let part = self.begin_part();
        let sides = 6 + 2 * (detail / 2).min(5);
        self.grid(part, sides, 3, true, |u, v| {
            let a = u * TAU;
            let rr = if v < 0.5 { r } else { 0.6 * r };
            [
                centre[0] - r + 4.0 * r * v,
                centre[1] + rr * a.cos(),
                centre[2] + rr * a.sin(),
            ]
        });
    }

    /// A perforated plate in the z = `z` plane: a grid of quads with holes left out.
    fn perforated_plate(&mut self, corner: [f32; 3], size: f32, cells: u32, seed: u64) {
        let part = self.begin_part();
        let base = self.positions.len() as u32;
        let n = cells + 1;
        for j in 0..n {
            for i in 0..n {
                let s = size / cells as f32;
                self.vertex([
                    corner[0] + i as f32 * s,
                    corner[1] + j as f32 * s,
                    corner[2],
                ]);
            }
        }
        for j in 0..cells {
            for i in 0..cells {
                if i % 4 == 2 && j % 4 == 2 && unit(seed ^ u64::from(i * 7919 + j)) < 0.8 {
                    continue; // A hole.
                }
                let a = base + j * n + i;
                self.triangle(part, [a, a + 1, a + n + 1]);
                self.triangle(part, [a, a + n + 1, a + n]);
            }
        }
    }

    /// A large thin box shell (a housing): two coincident-free sheets close together.
    fn housing(&mut self, corner: [f32; 3], size: [f32; 3], detail: u32) {
        let part = self.begin_part();
        for (offset, flipped) in [(0.0f32, false), (0.02 * size[2], true)] {
            // The inner sheet runs v the other way, so its triangles face the other side.
            self.grid(part, detail, detail, false, |u, v| {
                let v = if flipped { 1.0 - v } else { v };
                [
                    corner[0] + u * size[0],
                    corner[1] + v * size[1],
                    corner[2] + offset,
                ]
            });
        }
        // Three fins sharing one edge: non-manifold.
        let fins = self.begin_part();
        let e0 = self.vertex([corner[0], corner[1], corner[2] + size[2]]);
        let e1 = self.vertex([corner[0] + size[0], corner[1], corner[2] + size[2]]);
        for k in 0..3 {
            let a = k as f32 * 0.7;
            let tip = self.vertex([
                corner[0] + 0.5 * size[0],
                corner[1] + 0.2 * size[1] * a.cos(),
                corner[2] + size[2] + 0.2 * size[1] * a.sin(),
            ]);
            self.triangle(fins, [e0, e1, tip]);
        }
    }

    /// Duplicates the last `count` triangles of a part in place (coincident geometry).
    fn duplicate_last(&mut self, count: usize) {
        let start = self.triangles.len().saturating_sub(count);
        let part = self.begin_part();
        for t in start..self.triangles.len() {
            let tri = self.triangles[t];
            let copy = tri.map(|v| self.positions[v as usize]);
            let new = copy.map(|p| self.vertex(p));
            self.triangle(part, new);
        }
    }
}

/// The machine cells of a scene of about `target_triangles` triangles, one at a time: each
/// is a scene of its own (its triangles use only its own vertices, numbered from 0; its
/// parts are numbered from 0), so a writer holds one cell, never the whole scene. [`generate`]
/// is their concatenation.
pub struct Cells {
    cells_per_side: u64,
    detail: u32,
    index: u64,
    triangles: u64,
    target: u64,
}

/// The cells of the scene [`generate`] makes for `target_triangles`.
pub fn cells(target_triangles: u64) -> Cells {
    // One machine cell has a fixed mix of parts; the cell count and the detail per cell scale
    // together so that both the part count and the tessellation grow with the target.
    let cells_per_side = ((target_triangles as f64 / 40_000.0).cbrt().ceil() as u32).max(1);
    let cells = u64::from(cells_per_side).pow(3);
    let per_cell = (target_triangles / cells).max(200);
    // Triangle yield of one cell at detail d is about 47 d² (measured from the shapes below).
    let detail = ((per_cell as f64 / 47.0).sqrt().round() as u32).max(4);
    Cells {
        cells_per_side: u64::from(cells_per_side),
        detail,
        index: 0,
        triangles: 0,
        target: target_triangles,
    }
}

impl Iterator for Cells {
    type Item = GeneratedScene;

    fn next(&mut self) -> Option<GeneratedScene> {
        if self.triangles >= self.target {
            return None;
        }
        let (c, side, detail) = (self.index, self.cells_per_side, self.detail);
        let mut scene = GeneratedScene::default();
        let (x, y, z) = (c % side, (c / side) % side, c / side.pow(2));
        let origin = [x as f32 * 12.0, y as f32 * 12.0, z as f32 * 12.0];
        let jitter = unit(c) * 2.0;
        scene.housing(origin, [10.0, 10.0, 6.0], detail * 2);
        scene.pipe(
            [origin[0] + 1.0, origin[1] + 3.0 + jitter, origin[2] + 2.0],
            0.6,
            8.0,
            detail,
        );
        scene.perforated_plate(
            [origin[0] + 1.0, origin[1] + 1.0, origin[2] + 5.0],
            6.0,
            detail * 2,
            c,
        );
        for k in 0..8 {
            let a = k as f32 / 8.0 * TAU;
            scene.bolt(
                [
                    origin[0] + 5.0 + 2.0 * a.cos(),
                    origin[1] + 7.0 + 2.0 * a.sin(),
                    origin[2] + 1.0,
                ],
                0.1,
                detail / 4,
            );
        }
        scene.duplicate_last(40);
        self.index += 1;
        self.triangles += scene.triangles.len() as u64;
        Some(scene)
    }
}

impl GeneratedScene {
    /// Appends `cell`, renumbering its vertices and parts after this scene's.
    fn append(&mut self, cell: &GeneratedScene) {
        let (vertex_base, part_base) = (self.positions.len() as u32, self.part_count);
        self.positions.extend_from_slice(&cell.positions);
        self.triangles
            .extend(cell.triangles.iter().map(|t| t.map(|v| v + vertex_base)));
        self.triangle_parts
            .extend(cell.triangle_parts.iter().map(|p| p + part_base));
        self.part_count += cell.part_count;
    }
}

/// Generates a CAD-like scene of about `target_triangles` triangles (within a few percent).
pub fn generate(target_triangles: u64) -> GeneratedScene {
    let mut scene = GeneratedScene::default();
    for cell in cells(target_triangles) {
        scene.append(&cell);
    }
    scene
}

/// Writes a scene as binary little-endian PLY with a per-face `part` property.
pub fn write_ply(scene: &GeneratedScene, out: &mut impl std::io::Write) -> std::io::Result<()> {
    let counts = [scene.positions.len(), scene.triangles.len()].map(|n| n as u64);
    write_ply_header(out, scene.part_count, counts[0], counts[1])?;
    let mut buffer = Vec::with_capacity(1 << 20);
    put_positions(&mut buffer, out, &scene.positions)?;
    put_faces(&mut buffer, out, scene, 0, 0)?;
    out.write_all(&buffer)
}

/// Writes the scene [`generate`] makes for `target_triangles` as [`write_ply`] writes it,
/// byte for byte, one cell at a time: memory stays at one cell whatever the size. The cells
/// are generated three times (counts for the header, positions, faces).
pub fn write_ply_streamed(
    target_triangles: u64,
    out: &mut impl std::io::Write,
) -> std::io::Result<Totals> {
    let totals = totals(target_triangles);
    write_ply_header(out, totals.parts, totals.vertices, totals.triangles)?;
    let mut buffer = Vec::with_capacity(1 << 20);
    for cell in cells(target_triangles) {
        put_positions(&mut buffer, out, &cell.positions)?;
    }
    let (mut vertex_base, mut part_base) = (0u32, 0u32);
    for cell in cells(target_triangles) {
        put_faces(&mut buffer, out, &cell, vertex_base, part_base)?;
        vertex_base += cell.positions.len() as u32;
        part_base += cell.part_count;
    }
    out.write_all(&buffer)?;
    Ok(totals)
}

/// Writes the scene [`generate`] makes for `target_triangles` as Wavefront OBJ, one cell at a
/// time (memory stays at one cell): per cell its `v` lines, then its faces, each part under
/// `o part_N`. Positions are written in the shortest form that reads back to the same
/// `f32`, so the OBJ and PLY files hold the same scene.
pub fn write_obj(target_triangles: u64, out: &mut impl std::io::Write) -> std::io::Result<Totals> {
    writeln!(
        out,
        "# vds-gen CAD-like scene, about {target_triangles} triangles"
    )?;
    let mut totals = Totals::default();
    let mut text = String::with_capacity(1 << 20);
    let mut order = Vec::new();
    for cell in cells(target_triangles) {
        use std::fmt::Write;
        for p in &cell.positions {
            let _ = writeln!(text, "v {} {} {}", p[0], p[1], p[2]);
            flush_text(&mut text, out)?;
        }
        // A part's faces together, so that each part is one `o` group.
        order.clear();
        order.extend(0..cell.triangles.len());
        order.sort_by_key(|&t| cell.triangle_parts[t]);
        let mut part = None;
        for &t in &order {
            if part != Some(cell.triangle_parts[t]) {
                part = Some(cell.triangle_parts[t]);
                let _ = writeln!(text, "o part_{}", totals.parts + cell.triangle_parts[t]);
            }
            let [a, b, c] = cell.triangles[t].map(|v| totals.vertices + u64::from(v) + 1);
            let _ = writeln!(text, "f {a} {b} {c}");
            flush_text(&mut text, out)?;
        }
        totals.add(&cell);
    }
    out.write_all(text.as_bytes())?;
    Ok(totals)
}

/// Writes the scene [`generate`] makes for `target_triangles` as binary STL, one cell at a
/// time (memory stays at one cell): each triangle its unit normal (zero for one without
/// area) and its three corners; STL has neither shared vertices nor parts, so the reader's
/// weld joins the corners again and the scene is one part. Fails for more than 2³² − 1
/// triangles, which an STL's count cannot hold.
pub fn write_stl(target_triangles: u64, out: &mut impl std::io::Write) -> std::io::Result<Totals> {
    let totals = totals(target_triangles);
    let count = u32::try_from(totals.triangles).map_err(|_| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "an STL file holds at most 2^32 - 1 triangles",
        )
    })?;
    let mut header = [b' '; 80];
    let title = b"vds-gen CAD-like scene";
    header[..title.len()].copy_from_slice(title);
    out.write_all(&header)?;
    out.write_all(&count.to_le_bytes())?;
    let mut buffer = Vec::with_capacity(1 << 20);
    for cell in cells(target_triangles) {
        for t in &cell.triangles {
            let [a, b, c] = t.map(|v| cell.positions[v as usize]);
            let normal = unit_normal(a, b, c);
            for value in normal.iter().chain(&a).chain(&b).chain(&c) {
                buffer.extend_from_slice(&value.to_le_bytes());
            }
            buffer.extend_from_slice(&[0, 0]);
            flush_full(&mut buffer, out)?;
        }
    }
    out.write_all(&buffer)?;
    Ok(totals)
}

/// The unit normal of triangle `a b c` (counter-clockwise), zero when it has no area.
fn unit_normal(a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> [f32; 3] {
    let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
    let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
    let n = [
        u[1] * v[2] - u[2] * v[1],
        u[2] * v[0] - u[0] * v[2],
        u[0] * v[1] - u[1] * v[0],
    ];
    let length = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    if length > 0.0 {
        n.map(|x| x / length)
    } else {
        [0.0; 3]
    }
}

/// How large a generated scene is.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Totals {
    /// Vertices.
    pub vertices: u64,
    /// Triangles.
    pub triangles: u64,
    /// Parts.
    pub parts: u32,
}

impl Totals {
    fn add(&mut self, cell: &GeneratedScene) {
        self.vertices += cell.positions.len() as u64;
        self.triangles += cell.triangles.len() as u64;
        self.parts += cell.part_count;
    }
}

/// The size of the scene [`generate`] makes for `target_triangles`, counted cell by cell.
pub fn totals(target_triangles: u64) -> Totals {
    let mut totals = Totals::default();
    for cell in cells(target_triangles) {
        totals.add(&cell);
    }
    totals
}

/// Writes `text` out and empties it once it holds more than 1 MiB.
fn flush_text(text: &mut String, out: &mut impl std::io::Write) -> std::io::Result<()> {
    if text.len() > 1 << 20 {
        out.write_all(text.as_bytes())?;
        text.clear();
    }
    Ok(())
}

/// Writes `buffer` out and empties it once it holds more than 1 MiB.
fn flush_full(buffer: &mut Vec<u8>, out: &mut impl std::io::Write) -> std::io::Result<()> {
    if buffer.len() > 1 << 20 {
        out.write_all(buffer)?;
        buffer.clear();
    }
    Ok(())
}

fn write_ply_header(
    out: &mut impl std::io::Write,
    parts: u32,
    vertices: u64,
    triangles: u64,
) -> std::io::Result<()> {
    write!(
        out,
        "ply\nformat binary_little_endian 1.0\ncomment vds-gen CAD-like scene, {parts} parts\n\
         element vertex {vertices}\nproperty float x\nproperty float y\nproperty float z\n\
         element face {triangles}\nproperty list uchar uint vertex_indices\nproperty uint part\nend_header\n",
    )
}

fn put_positions(
    buffer: &mut Vec<u8>,
    out: &mut impl std::io::Write,
    positions: &[[f32; 3]],
) -> std::io::Result<()> {
    for p in positions {
        for c in p {
            buffer.extend_from_slice(&c.to_le_bytes());
        }
        flush_full(buffer, out)?;
    }
    Ok(())
}

fn put_faces(
    buffer: &mut Vec<u8>,
    out: &mut impl std::io::Write,
    scene: &GeneratedScene,
    vertex_base: u32,
    part_base: u32,
) -> std::io::Result<()> {
    for (t, part) in scene.triangles.iter().zip(&scene.triangle_parts) {
        buffer.push(3);
        for v in t {
            buffer.extend_from_slice(&(v + vertex_base).to_le_bytes());
        }
        buffer.extend_from_slice(&(part + part_base).to_le_bytes());
        flush_full(buffer, out)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn output_is_deterministic_and_near_the_target() {
        let a = generate(50_000);
        let b = generate(50_000);
        assert_eq!(a, b);
        let n = a.triangles.len() as f64;
        assert!((50_000.0..=60_000.0).contains(&n), "{n} triangles");
        assert!(a.part_count > 20, "CAD-like scenes have many parts");
    }

    #[test]
    fn streamed_ply_is_the_whole_scene_written_at_once() {
        for target in [1_000, 50_000] {
            let scene = generate(target);
            let mut whole = Vec::new();
            write_ply(&scene, &mut whole).unwrap();
            let mut streamed = Vec::new();
            let totals = write_ply_streamed(target, &mut streamed).unwrap();
            assert_eq!(streamed, whole);
            assert_eq!(totals.triangles, scene.triangles.len() as u64);
            assert_eq!(totals.parts, scene.part_count);
        }
    }

    #[test]
    fn stl_holds_every_triangle_s_corners_in_order() {
        let scene = generate(5_000);
        let mut stl = Vec::new();
        let totals = write_stl(5_000, &mut stl).unwrap();
        let count = scene.triangles.len();
        assert_eq!(totals.triangles, count as u64);
        assert_eq!(stl.len(), 84 + 50 * count);
        assert_eq!(
            u32::from_le_bytes(stl[80..84].try_into().unwrap()) as usize,
            count
        );
        let f32_at = |at: usize| f32::from_le_bytes(stl[at..at + 4].try_into().unwrap());
        for (t, corners) in scene.triangles.iter().enumerate() {
            let record = 84 + 50 * t;
            for (k, &v) in corners.iter().enumerate() {
                let p = [0, 1, 2].map(|i| f32_at(record + 12 + 12 * k + 4 * i));
                assert_eq!(p, scene.positions[v as usize], "triangle {t}, corner {k}");
            }
            let normal = [0, 1, 2].map(|i| f32_at(record + 4 * i));
            let length = normal.iter().map(|x| x * x).sum::<f32>();
            assert!(length == 0.0 || (length - 1.0).abs() < 1e-5, "{normal:?}");
        }
    }
}
