//! The triangle soup that format readers fill: positions, triangles, a part id per
//! triangle, and per part its name, colour and parent, before any welding. Polygons are
//! fan-triangulated here, in one place; colours are averaged per part here
//! ([`ColorSum`]).

use crate::error::{FormatError, Location, Problem};

/// Triangles as read from one or more files, not yet welded.
///
/// Readers append parts with [`MeshSoup::begin_part`], vertices with
/// [`MeshSoup::push_vertex`] and faces with [`MeshSoup::push_polygon`]; every index is
/// absolute (counted from the soup's first vertex).
///
/// A soup made by [`crate::spill_files`] *spills*: the readers that stream (PLY, binary STL,
/// OBJ) hand what they have read to files every [`SPILL_ROWS`] rows (OBJ: every megabyte of
/// text), and every reader does at the end of its file, so `positions`, `triangles` and `triangle_parts` then hold only what
/// was read since the last spill ([`MeshSoup::vertex_count`] counts all).
#[derive(Debug, Default, Clone, PartialEq)]
pub struct MeshSoup {
    /// Vertex positions (since the last spill).
    pub positions: Vec<[f32; 3]>,
    /// Triangles as three absolute vertex indices (since the last spill).
    pub triangles: Vec<[u32; 3]>,
    /// The part each triangle belongs to (index into `part_names`).
    pub triangle_parts: Vec<u32>,
    /// One name per part (an OBJ object/group, a glTF node, a file).
    pub part_names: Vec<String>,
    /// One entry per part name: its parent and colour.
    pub parts: Vec<crate::PartInfo>,
    /// Faces with fewer than three corners that readers skipped.
    pub short_faces_dropped: u64,
    /// What was read without being needed for the geometry and could not be (a material
    /// library, a texture): each costs colours, not the import.
    pub warnings: Vec<String>,
    /// Where a spilling soup's vertices and triangles went, and how many.
    pub(crate) spill: SpillSlot,
}

/// Rows a streaming reader reads between spills: 3–4 MB of vertices or triangles.
pub const SPILL_ROWS: usize = 1 << 18;

/// A soup's spill, if it has one. A clone of a soup keeps what it holds in memory and spills
/// nowhere; soups compare by what they hold in memory.
#[derive(Debug, Default)]
pub(crate) struct SpillSlot(pub(crate) Option<Box<crate::spill::FileSpill>>);

impl Clone for SpillSlot {
    fn clone(&self) -> Self {
        SpillSlot(None)
    }
}

impl PartialEq for SpillSlot {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl MeshSoup {
    /// Starts a new part at the top of the assembly, without a colour, and returns its id.
    pub fn begin_part(&mut self, name: impl Into<String>) -> u32 {
        self.begin_child_part(name, None)
    }

    /// Starts a new part under `parent` (an earlier part), without a colour, and returns
    /// its id.
    pub fn begin_child_part(&mut self, name: impl Into<String>, parent: Option<u32>) -> u32 {
        debug_assert!(parent.is_none_or(|p| (p as usize) < self.part_names.len()));
        self.part_names.push(name.into());
        self.parts.push(crate::PartInfo {
            parent,
            color: None,
        });
        (self.part_names.len() - 1) as u32
    }

    /// Appends a vertex after checking it is finite and within [`crate::MAX_COORDINATE`],
    /// and returns its index.
    pub fn push_vertex(
        &mut self,
        p: [f32; 3],
        location: impl FnOnce() -> Location,
    ) -> Result<u32, FormatError> {
        if let Err(problem) = check_position(p) {
            return Err(FormatError::new(location(), problem));
        }
        let index = u32::try_from(self.vertex_count()).map_err(|_| {
            FormatError::new(
                location(),
                Problem::Unsupported("more than 2^32 vertices".into()),
            )
        })?;
        self.positions.push(p);
        Ok(index)
    }

    /// Appends a polygon with absolute vertex indices, fan-triangulated. Faces with fewer
    /// than three corners are counted in `short_faces_dropped`. Indices must already be
    /// checked against the vertex count.
    pub fn push_polygon(&mut self, part: u32, corners: &[u32]) {
        if corners.len() < 3 {
            self.short_faces_dropped += 1;
            return;
        }
        for pair in corners[1..].windows(2) {
            self.triangles.push([corners[0], pair[0], pair[1]]);
            self.triangle_parts.push(part);
        }
    }

    /// Vertices pushed so far, spilled or not.
    pub fn vertex_count(&self) -> usize {
        self.spilled().0 + self.positions.len()
    }

    /// Triangles pushed so far, spilled or not.
    pub fn triangle_count(&self) -> usize {
        self.spilled().1 + self.triangles.len()
    }

    /// Vertices and triangles already spilled.
    fn spilled(&self) -> (usize, usize) {
        self.spill.0.as_ref().map_or((0, 0), |s| s.spilled())
    }

    /// Whether this soup spills (streaming readers then read in pieces).
    pub(crate) fn spills(&self) -> bool {
        self.spill.0.is_some()
    }

    /// Rows a streaming reader reads between spills: [`SPILL_ROWS`], or fewer in tests.
    pub(crate) fn spill_rows(&self) -> usize {
        self.spill.0.as_ref().map_or(SPILL_ROWS, |s| s.rows)
    }

    /// Reserves room for `vertices` more vertices and `triangles` more triangles: all of
    /// them, or at most [`SPILL_ROWS`] in a soup that spills.
    pub(crate) fn reserve(&mut self, vertices: usize, triangles: usize) {
        let rows = self.spill_rows();
        let cap = |n: usize| if self.spills() { n.min(rows) } else { n };
        let (vertices, triangles) = (cap(vertices), cap(triangles));
        self.positions.reserve(vertices);
        self.triangles.reserve(triangles);
        self.triangle_parts.reserve(triangles);
    }

    /// Hands what the soup holds in memory to its spill, if it has one (else does nothing).
    /// A write error is kept by the spill and reported when the file has been read.
    pub(crate) fn spill_now(&mut self) {
        if let Some(spill) = self.spill.0.as_mut() {
            spill.take(
                &mut self.positions,
                &mut self.triangles,
                &mut self.triangle_parts,
            );
        }
    }

    /// [`MeshSoup::spill_now`] after a reader's fast path: when it `found` the rows it just
    /// decoded (now the soup's positions or triangles) in a mapped input, a spilling soup
    /// keeps them as rows to read again from the map ([`crate::mapped`]) rather than
    /// writing them.
    pub(crate) fn spill_found(&mut self, found: Option<crate::mapped::FoundRows>) {
        if let (Some(spill), Some(found)) = (self.spill.0.as_mut(), found) {
            // Taken only when the rows make everything the soup holds.
            let held = (self.positions.len(), self.triangles.len());
            if spill.take_mapped(found, held) {
                self.positions.clear();
                self.triangles.clear();
                self.triangle_parts.clear();
            }
        }
        self.spill_now();
    }

    /// Says that the reader will not look at `bytes` (a prefix of its input) again: a
    /// spilling soup's input map may drop those pages from memory.
    pub(crate) fn done_with_input(&mut self, bytes: &[u8]) {
        if let Some(spill) = self.spill.0.as_mut() {
            spill.done_with_input(bytes);
        }
    }

    /// Appends another soup (another input file) as further parts of this scene.
    ///
    /// # Panics
    /// If the two hold more than 2^32 vertices together (vertex indices are `u32`); the
    /// importer refuses such inputs with an error before it appends.
    pub fn append(&mut self, other: MeshSoup) {
        assert!(
            indices_fit(self.positions.len(), other.positions.len()),
            "more than 2^32 vertices in one soup"
        );
        let vertex_base = self.positions.len() as u32;
        let part_base = self.part_names.len() as u32;
        self.positions.extend(other.positions);
        self.triangles
            .extend(other.triangles.iter().map(|t| t.map(|v| v + vertex_base)));
        self.triangle_parts
            .extend(other.triangle_parts.iter().map(|p| p + part_base));
        self.part_names.extend(other.part_names);
        self.parts
            .extend(other.parts.into_iter().map(|p| crate::PartInfo {
                parent: p.parent.map(|q| q + part_base),
                color: p.color,
            }));
        self.short_faces_dropped += other.short_faces_dropped;
        self.warnings.extend(other.warnings);
    }
}

/// Whether soups of `a` and `b` vertices can be joined with `u32` vertex indices.
pub(crate) fn indices_fit(a: usize, b: usize) -> bool {
    (a as u64).saturating_add(b as u64) <= 1 << 32
}

/// Checks that a position is finite and within [`crate::MAX_COORDINATE`]: what every reader
/// requires of every vertex.
pub(crate) fn check_position(p: [f32; 3]) -> Result<(), Problem> {
    if !p.iter().all(|c| c.is_finite()) {
        return Err(Problem::NonFiniteCoordinate);
    }
    match p
        .iter()
        .find(|c| f64::from(c.abs()) > crate::MAX_COORDINATE)
    {
        Some(&c) => Err(Problem::CoordinateOutOfRange {
            value: f64::from(c),
            limit: crate::MAX_COORDINATE,
        }),
        None => Ok(()),
    }
}

/// Checks a file-relative vertex index against the number of vertices read so far.
pub(crate) fn check_index(
    index: i64,
    vertex_count: usize,
    location: impl FnOnce() -> Location,
) -> Result<u32, FormatError> {
    if index >= 0 && (index as u64) < vertex_count as u64 {
        Ok(index as u32)
    } else {
        Err(FormatError::new(
            location(),
            Problem::IndexOutOfRange {
                index,
                vertex_count: vertex_count as u64,
            },
        ))
    }
}

/// A running sum of RGBA samples (each component in `0..=1`), for a part's average colour.
/// Samples are added in file order and summed in `f64`, so the average is deterministic.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct ColorSum {
    sum: [f64; 4],
    count: u64,
}

impl ColorSum {
    /// Adds one sample; components are clamped to `0..=1`, and a sample with a NaN is
    /// skipped.
    pub(crate) fn add(&mut self, rgba: [f64; 4]) {
        self.add_weighted(rgba, 1);
    }

    /// Adds a sample that stands for `weight` samples (a primitive's colour for each of its
    /// triangles).
    pub(crate) fn add_weighted(&mut self, rgba: [f64; 4], weight: u64) {
        if rgba.iter().any(|c| c.is_nan()) || weight == 0 {
            return;
        }
        for (s, c) in self.sum.iter_mut().zip(rgba) {
            *s += c.clamp(0.0, 1.0) * weight as f64;
        }
        self.count += weight;
    }

    /// The average, if any sample was added.
    pub(crate) fn mean(&self) -> Option<[f32; 4]> {
        (self.count > 0).then(|| {
            self.sum
                .map(|s| ((s / self.count as f64) as f32).clamp(0.0, 1.0))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::indices_fit;

    #[test]
    fn soups_join_up_to_two_to_the_32_vertices() {
        assert!(indices_fit(0, 1 << 32));
        assert!(indices_fit((1 << 32) - 5, 5));
        assert!(!indices_fit((1 << 32) - 5, 6));
        assert!(!indices_fit(usize::MAX, usize::MAX));
    }
}
