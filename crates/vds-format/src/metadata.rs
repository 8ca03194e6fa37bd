//! The variable-size metadata section, encoded with `rkyv` and validated (bytecheck) when
//! read. Nothing here depends on the clock or the machine, so identical inputs and options
//! give identical bytes.

/// One input file the tree was built from.
#[derive(Debug, Clone, PartialEq, Default, rkyv::Archive, rkyv::Serialize, rkyv::Deserialize)]
pub struct InputInfo {
    /// The file's name, without its directories (so that the same input gives the same bytes
    /// however it was spelt and wherever the build ran; [`InputInfo::content_hash`] says which
    /// file it was).
    pub name: String,
    /// Its size in bytes.
    pub bytes: u64,
    /// XXH3-64 of its contents.
    pub content_hash: u64,
}

/// The options the tree was built with.
#[derive(Debug, Clone, PartialEq, Default, rkyv::Archive, rkyv::Serialize, rkyv::Deserialize)]
pub struct BuildInfo {
    /// Relative weld tolerance, if any (exact welding otherwise).
    pub weld: Option<f32>,
    /// zstd level of the pages.
    pub zstd_level: i32,
    /// Target raw bytes per page.
    pub page_bytes: u32,
}

/// Everything about a tree that is not a fixed-size record.
#[derive(Debug, Clone, PartialEq, Default, rkyv::Archive, rkyv::Serialize, rkyv::Deserialize)]
pub struct Metadata {
    /// The writing tool and its version, e.g. `vds-build 0.1.0`.
    pub tool: String,
    /// Build options.
    pub build: BuildInfo,
    /// Input files, in order.
    pub inputs: Vec<InputInfo>,
    /// Part names; triangles refer to them by index.
    pub part_names: Vec<String>,
    /// Lower corner of the bounding box of all vertices.
    pub bounds_min: [f32; 3],
    /// Upper corner.
    pub bounds_max: [f32; 3],
    /// Vertices as read, before welding.
    pub input_vertices: u64,
    /// Triangles as read, before dropping degenerate ones.
    pub input_triangles: u64,
    /// Number of nodes with k children, k = 0..=8.
    pub degree_histogram: [u64; 9],
}
