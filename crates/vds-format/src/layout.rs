//! The fixed-layout records of a `.vdt` file, read in place with `zerocopy`.
//!
//! Every multi-byte field is little-endian (`zerocopy`'s byte-order types), and every record
//! has alignment 1, so records can be viewed at any offset of a memory-mapped file without
//! copying and without alignment assumptions. Sizes are asserted at compile time; the byte
//! layout is specified in `docs/format.md`.

/// The little-endian field types the records are made of (from `zerocopy`).
pub use zerocopy::little_endian::{F32, U16, U32, U64};
use zerocopy::{FromBytes, Immutable, IntoBytes, KnownLayout, Unaligned};

/// The first eight bytes of every `.vdt` file. Like PNG's signature, the `\r\n` and `\x1a`
/// catch files mangled by text-mode transfers.
pub const VDT_MAGIC: [u8; 8] = *b"VDT\x00\r\n\x1a\n";

/// The format version this crate writes.
pub const VDT_VERSION: u32 = 6;

/// The oldest version this crate reads. Versions 1 to 3 were never released; version 4
/// files (no part records in the metadata) and version 5 files (no surface errors in the
/// pages) must be rebuilt (see `docs/format.md`, Compatibility).
pub const OLDEST_READABLE_VERSION: u32 = 6;

/// [`NodeRecord::flags`] bit: the node's cone of normals is two-sided (every normal `n`
/// has `n` or `−n` within the half-angle of the axis).
pub const FLAG_TWO_SIDED_CONE: u8 = 1;

/// `parent` of the root and `first_child` of leaves.
pub const NO_NODE: u32 = u32::MAX;

/// Where a section lies and its checksum.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, FromBytes, IntoBytes, KnownLayout, Immutable, Unaligned,
)]
#[repr(C)]
pub struct SectionRef {
    /// Byte offset from the start of the file.
    pub offset: U64,
    /// Length in bytes.
    pub length: U64,
    /// XXH3-64 of the section's bytes.
    pub checksum: U64,
}

/// The file header: the first 128 bytes.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, FromBytes, IntoBytes, KnownLayout, Immutable, Unaligned,
)]
#[repr(C)]
pub struct Header {
    /// [`VDT_MAGIC`].
    pub magic: [u8; 8],
    /// Format version; readers accept exactly the versions they know.
    pub version: U32,
    /// Size of this header in bytes (128).
    pub header_size: U32,
    /// Size of the whole file in bytes.
    pub file_size: U64,
    /// Number of tree nodes.
    pub node_count: U64,
    /// Number of triangles (subtris, all levels).
    pub triangle_count: U64,
    /// Number of original vertices (leaves).
    pub vertex_count: U64,
    /// Number of pages.
    pub page_count: U32,
    /// Depth of the deepest node.
    pub max_depth: U32,
    /// The rkyv-encoded [`crate::Metadata`].
    pub metadata: SectionRef,
    /// The page directory: `page_count` [`PageEntry`] records.
    pub directory: SectionRef,
    /// The quantisation grid's origin (see [`crate::Grid`]).
    pub grid_origin: [F32; 3],
    /// The quantisation grid's step; positive and finite.
    pub grid_step: F32,
    /// XXH3-64 of the 120 bytes before this field.
    pub header_checksum: U64,
}

/// One page of the directory.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, FromBytes, IntoBytes, KnownLayout, Immutable, Unaligned,
)]
#[repr(C)]
pub struct PageEntry {
    /// Byte offset of the page's zstd frame.
    pub offset: U64,
    /// Length of the zstd frame.
    pub compressed_length: U32,
    /// Length of the decoded page.
    pub raw_length: U32,
    /// First node id in the page; a page holds nodes `first_node .. first_node + node_count`.
    pub first_node: U32,
    /// Number of nodes.
    pub node_count: U32,
    /// First triangle index in the page (triangles are numbered in node order).
    pub first_triangle: U32,
    /// Number of triangles: the subtris of the page's nodes.
    pub triangle_count: U32,
    /// XXH3-64 of the zstd frame.
    pub checksum: U64,
}

/// One node as decoded from a page (pages store it compactly, see `codec.rs`).
#[derive(
    Debug, Clone, Copy, PartialEq, FromBytes, IntoBytes, KnownLayout, Immutable, Unaligned,
)]
#[repr(C)]
pub struct NodeRecord {
    /// Parent id, or [`NO_NODE`].
    pub parent: U32,
    /// First child id (children are contiguous), or [`NO_NODE`] for a leaf.
    pub first_child: U32,
    /// Number of children: 0 for a leaf, else 2..=8.
    pub child_count: u8,
    /// Bit flags: [`FLAG_TWO_SIDED_CONE`]; other bits zero.
    pub flags: u8,
    /// Depth below the root.
    pub depth: U16,
    /// First leaf rank under the node.
    pub leaf_begin: U32,
    /// One past the last leaf rank under the node.
    pub leaf_end: U32,
    /// Index of the node's first subtri (global triangle index).
    pub subtri_begin: U32,
    /// Number of subtris.
    pub subtri_count: U32,
    /// Proxy vertex; for a leaf, the original position.
    pub proxy: [F32; 3],
    /// Largest distance from the proxy to any vertex under the node.
    pub error_radius: F32,
    /// Root-mean-square distance from the proxy to the planes of the triangles around the
    /// vertices under the node, area-weighted; at most `error_radius` (0 for a leaf).
    pub surface_error: F32,
    /// Bounding sphere of every triangle with a corner under the node: centre xyz, radius.
    pub sphere: [F32; 4],
    /// Cone of those triangles' normals: unit axis xyz, half-angle in radians (< 0: empty).
    pub cone: [F32; 4],
}

/// One triangle as decoded from a page.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, FromBytes, IntoBytes, KnownLayout, Immutable, Unaligned,
)]
#[repr(C)]
pub struct TriangleRecord {
    /// Corners as leaf ranks (original vertices in depth-first leaf order).
    pub corners: [U32; 3],
    /// Part id (index into the metadata's part names).
    pub part: U32,
}

const _: () = assert!(size_of::<SectionRef>() == 24);
const _: () = assert!(size_of::<Header>() == 128);
const _: () = assert!(size_of::<PageEntry>() == 40);
const _: () = assert!(size_of::<NodeRecord>() == 80);
const _: () = assert!(size_of::<TriangleRecord>() == 16);

/// Size of [`Header`] in bytes.
pub const HEADER_BYTES: usize = size_of::<Header>();
/// Size of [`PageEntry`] in bytes.
pub const PAGE_ENTRY_BYTES: usize = size_of::<PageEntry>();
/// Size of [`NodeRecord`] in bytes.
pub const NODE_BYTES: usize = size_of::<NodeRecord>();
/// Size of [`TriangleRecord`] in bytes.
pub const TRIANGLE_BYTES: usize = size_of::<TriangleRecord>();
