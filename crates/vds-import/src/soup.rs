//! The triangle soup that format readers fill: positions, triangles, and a part id per
//! triangle, before any welding. Polygons are fan-triangulated here, in one place.

use crate::error::{FormatError, Location, Problem};

/// Triangles as read from one or more files, not yet welded.
///
/// Readers append parts with [`MeshSoup::begin_part`], vertices with
/// [`MeshSoup::push_vertex`] and faces with [`MeshSoup::push_polygon`]; every index is
/// absolute (into `positions`).
#[derive(Debug, Default, Clone, PartialEq)]
pub struct MeshSoup {
    /// Vertex positions.
    pub positions: Vec<[f32; 3]>,
    /// Triangles as three indices into `positions`.
    pub triangles: Vec<[u32; 3]>,
    /// The part each triangle belongs to (index into `part_names`).
    pub triangle_parts: Vec<u32>,
    /// One name per part (an OBJ object/group, a glTF node, a file).
    pub part_names: Vec<String>,
    /// Faces with fewer than three corners that readers skipped.
    pub short_faces_dropped: u64,
}

impl MeshSoup {
    /// Starts a new part and returns its id.
    pub fn begin_part(&mut self, name: impl Into<String>) -> u32 {
        self.part_names.push(name.into());
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
        let index = u32::try_from(self.positions.len()).map_err(|_| {
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

    /// Appends another soup (another input file) as further parts of this scene.
    pub fn append(&mut self, other: MeshSoup) {
        let vertex_base = self.positions.len() as u32;
        let part_base = self.part_names.len() as u32;
        self.positions.extend(other.positions);
        self.triangles
            .extend(other.triangles.iter().map(|t| t.map(|v| v + vertex_base)));
        self.triangle_parts
            .extend(other.triangle_parts.iter().map(|p| p + part_base));
        self.part_names.extend(other.part_names);
        self.short_faces_dropped += other.short_faces_dropped;
    }
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
